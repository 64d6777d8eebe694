#include "xi/profile.h"

#include <algorithm>
#include <map>
#include <string>

#include "xi/error.h"
#include "xi/image.h"

namespace xi {
namespace {

const char* kStages[] = {"generate", "extend", "shade", "shadow", "accumulate"};

struct Totals {
  size_t launches = 0, items = 0;
  uint64_t ns = 0;
  void add(const Launch& l) {
    launches++;
    items += l.items;
    ns += l.end_ns - l.start_ns;
  }
};

}  // namespace

void print_profile(std::FILE* out, const std::vector<Launch>& launches, double wall_seconds) {
  std::map<std::string, Totals> stage;
  std::map<int, std::map<std::string, Totals>> bounce;
  uint64_t kernel_ns = 0;
  for (auto& l : launches) {
    stage[l.stage].add(l);
    if (l.bounce >= 0) bounce[l.bounce][l.stage].add(l);
    kernel_ns += l.end_ns - l.start_ns;
  }
  std::fprintf(out, "per bounce (queue lengths summed over passes):\n");
  std::fprintf(out, "%6s %12s %10s %12s %10s %12s %10s\n", "bounce", "extend in", "extend ms", "shade in", "shade ms",
               "shadow in", "shadow ms");
  for (auto& [b, s] : bounce)
    std::fprintf(out, "%6d %12zu %10.1f %12zu %10.1f %12zu %10.1f\n", b, s["extend"].items, s["extend"].ns * 1e-6,
                 s["shade"].items, s["shade"].ns * 1e-6, s["shadow"].items, s["shadow"].ns * 1e-6);
  const double wall_ns = wall_seconds * 1e9;
  std::fprintf(out, "per stage:\n%-11s %9s %11s %8s %14s\n", "stage", "launches", "total ms", "share", "Mitems/s");
  for (const char* name : kStages) {
    auto it = stage.find(name);
    if (it == stage.end()) continue;
    const Totals& t = it->second;
    std::fprintf(out, "%-11s %9zu %11.1f %7.1f%% %14.2f\n", name, t.launches, t.ns * 1e-6, 100.0 * t.ns / wall_ns,
                 t.ns ? t.items / (t.ns * 1e-3) : 0.0);
  }
  std::fprintf(out, "%-11s %9s %11.1f %7.1f%%\n", "kernels", "", kernel_ns * 1e-6, 100.0 * kernel_ns / wall_ns);
  std::fprintf(out, "%-11s %9s %11.1f %7.1f%%\n", "outside", "", (wall_ns - kernel_ns) * 1e-6,
               100.0 - 100.0 * kernel_ns / wall_ns);
  for (const char* name : {"extend", "shadow"})
    if (stage.count(name) && stage[name].ns)
      std::fprintf(out, "%s: %.2f Mrays/s\n", name, stage[name].items / (stage[name].ns * 1e-3));
}

void write_chrome_trace(const std::filesystem::path& path, const std::vector<Launch>& launches) {
  uint64_t t0 = launches.empty() ? 0 : launches.front().start_ns;
  for (auto& l : launches) t0 = std::min(t0, l.start_ns);
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    std::FILE* f = std::fopen(tmp.c_str(), "w");
    if (!f) throw Error("cannot open file for writing", tmp.string());
    std::fprintf(f, "{\"displayTimeUnit\":\"ms\",\"traceEvents\":[\n");
    for (size_t i = 0; i < launches.size(); ++i) {
      const Launch& l = launches[i];
      // Complete events ("ph":"X"), microseconds from the first launch.
      std::fprintf(f,
                   "{\"name\":\"%s\",\"cat\":\"kernel\",\"ph\":\"X\",\"pid\":1,\"tid\":1,\"ts\":%.3f,\"dur\":%.3f,"
                   "\"args\":{\"items\":%zu,\"launched\":%zu,\"pass\":%d,\"bounce\":%d}}%s\n",
                   l.stage, (l.start_ns - t0) * 1e-3, (l.end_ns - l.start_ns) * 1e-3, l.items, l.global, l.pass, l.bounce,
                   i + 1 < launches.size() ? "," : "");
    }
    std::fprintf(f, "]}\n");
    if (std::fclose(f) != 0) throw Error("cannot write file", tmp.string());
  });
}

}  // namespace xi
