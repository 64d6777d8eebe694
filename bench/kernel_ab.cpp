// A/B of two kernel builds in one process: timing noise between processes on a shared machine hides
// the few per cent a kernel change is worth, while two renderers alternated in one process see the same
// machine state. Each side is a kernel folder (as XI_KERNEL_DIR) and optionally a BVH width: `DIR` or
// `DIR@WIDTH`.
//
//   xi_kernel_ab SCENE A B [RUNS] [WxH] [SPP]
//
// Extend alone on the same recorded rays (camera rays, then first-bounce rays, recorded through A, each
// traced as a render traces it: camera rays in packets on an 8-wide tree, bounce rays one by one),
// A and B alternated RUNS times (who goes first alternates too): Mrays/s medians and the median of the
// per-pair time ratios B/A, and how many hits differ bitwise. Then whole renders of SPP samples per
// pixel (random sampler; 0 skips them), alternated likewise: per-stage kernel time medians (ms), the
// median wall-time ratio, and how many pixels differ bitwise.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "xi/error.h"
#include "render/ray_probe.h"
#include "xi/renderer.h"

namespace {

struct Side {
  std::string dir;
  int bvh_width = 0;  // 0: the device's default
};

Side parse_side(const std::string& spec) {
  Side s;
  size_t at = spec.rfind('@');
  s.dir = spec.substr(0, at);
  if (at != std::string::npos) s.bvh_width = std::atoi(spec.c_str() + at + 1);
  return s;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// A renderer built from one side's kernels (XI_KERNEL_DIR is read when its programs are built).
std::unique_ptr<xi::Renderer> make_renderer(xi::Device& device, const xi::Scene& scene, const Side& side,
                                            xi::RenderOptions opt) {
  setenv("XI_KERNEL_DIR", side.dir.c_str(), 1);
  opt.bvh_width = side.bvh_width;
  return std::make_unique<xi::Renderer>(device, scene, opt);
}

const char* kStages[] = {"generate", "extend", "shade", "shadow", "accumulate"};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: xi_kernel_ab SCENE A B [RUNS] [WxH] [SPP]\n"
                         "  A, B: a kernel folder, or KERNEL_DIR@BVH_WIDTH\n");
    return 2;
  }
  try {
    xi::Scene scene = xi::load_scene(argv[1]);
    const Side side[2] = {parse_side(argv[2]), parse_side(argv[3])};
    const int runs = argc > 4 ? std::max(1, std::atoi(argv[4])) : 15;
    if (argc > 5 && std::sscanf(argv[5], "%dx%d", &scene.width, &scene.height) != 2)
      throw xi::Error("expected WIDTHxHEIGHT", argv[5]);
    const int spp = argc > 6 ? std::atoi(argv[6]) : 4;
    xi::Device device = xi::Device::open("");
    std::printf("scene %s, %dx%d, device %s; A = %s, B = %s; %d runs each\n", argv[1], scene.width, scene.height,
                device.info().name.c_str(), argv[2], argv[3], runs);

    for (int bounce : {0, 1}) {
      xi::RenderOptions opt;
      opt.spp = 1;
      opt.paths_in_flight = (size_t)scene.width * scene.height;  // one wave: trace_closest takes them all
      std::unique_ptr<xi::Renderer> r[2];
      for (int k = 0; k < 2; ++k) r[k] = make_renderer(device, scene, side[k], opt);
      xi::RayProbe probe[2] = {xi::RayProbe(*r[0]), xi::RayProbe(*r[1])};
      probe[0].record(bounce);
      r[0]->run_pass();
      const xi::RayBatch& rays = probe[0].recorded();
      std::vector<double> seconds[2], ratio;
      std::vector<glm::vec4> hits[2];
      for (int i = 0; i < runs; ++i) {
        for (int j = 0; j < 2; ++j) {
          const int k = i % 2 ? 1 - j : j;
          seconds[k].push_back(probe[k].trace_closest(rays, &hits[k], bounce));
        }
        ratio.push_back(seconds[1].back() / seconds[0].back());
      }
      size_t differ = 0;
      for (size_t i = 0; i < hits[0].size(); ++i)
        differ += std::memcmp(&hits[0][i], &hits[1][i], sizeof(glm::vec4)) != 0;
      const double n = (double)rays.org.size();
      std::printf("extend, %s rays (%zu): A %.2f Mrays/s, B %.2f Mrays/s, time B/A %.3f; hits that differ: %zu\n",
                  bounce ? "bounce" : "camera", rays.org.size(), n / median(seconds[0]) * 1e-6,
                  n / median(seconds[1]) * 1e-6, median(ratio), differ);
    }

    if (spp > 0) {
      xi::RenderOptions opt;
      opt.spp = spp;
      opt.sampler = XI_SAMPLER_RANDOM;
      opt.profile = true;  // launch timing by events
      std::vector<double> stage_ms[2][5], wall[2], ratio;
      std::unique_ptr<xi::Renderer> last[2];
      for (int i = 0; i < runs; ++i) {
        for (int j = 0; j < 2; ++j) {
          const int k = i % 2 ? 1 - j : j;
          last[k] = make_renderer(device, scene, side[k], opt);
          auto start = std::chrono::steady_clock::now();
          last[k]->render();
          wall[k].push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
          double ms[5] = {};
          for (const xi::Launch& l : last[k]->launches())
            for (int s = 0; s < 5; ++s)
              if (!std::strcmp(l.stage, kStages[s])) ms[s] += (double)(l.end_ns - l.start_ns) * 1e-6;
          for (int s = 0; s < 5; ++s) stage_ms[k][s].push_back(ms[s]);
        }
        ratio.push_back(wall[1].back() / wall[0].back());
      }
      for (int k = 0; k < 2; ++k) {
        std::printf("render %c, %d spp: wall %.1f ms;", "AB"[k], spp, median(wall[k]) * 1e3);
        for (int s = 0; s < 5; ++s) std::printf(" %s %.1f", kStages[s], median(stage_ms[k][s]));
        std::printf("\n");
      }
      const xi::Image a = last[0]->mean(), b = last[1]->mean();
      size_t differ = 0;
      for (size_t i = 0; i < a.pixels.size(); ++i)
        differ += std::memcmp(&a.pixels[i], &b.pixels[i], sizeof(glm::vec3)) != 0;
      std::printf("render: wall time B/A %.3f; pixels that differ: %zu of %zu\n", median(ratio), differ,
                  a.pixels.size());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "xi_kernel_ab: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
