#include "xi/checkpoint.h"

#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "xi/error.h"
#include "xi/hash.h"
#include "xi/image.h"

namespace xi {
namespace {

// Layout: magic, header length, JSON header (key and counters), pixel count, the four film buffers,
// then an FNV-1a checksum of every byte before it.
constexpr char kMagic[8] = {'X', 'I', 'C', 'K', 'P', 'T', '0', '1'};

void append(std::string* out, const void* data, size_t n) { out->append(static_cast<const char*>(data), n); }

template <typename T>
void append(std::string* out, const T& v) {
  append(out, &v, sizeof v);
}

}  // namespace

CheckpointKey checkpoint_key(const Renderer& renderer, const std::filesystem::path& scene_file,
                             const std::string& device_name) {
  const RenderOptions& o = renderer.options();
  const CompiledScene& s = renderer.compiled();
  return CheckpointKey{std::filesystem::absolute(scene_file).string(),
                       hex(renderer.scene_hash()),
                       (int)s.camera.width,
                       (int)s.camera.height,
                       o.spp,
                       o.max_depth,
                       o.seed,
                       sampler_name(o.sampler),
                       strategy_name(o.strategy),
                       (double)o.noise_threshold,
                       renderer.adaptive() ? o.min_spp : 0,
                       renderer.program().key,
                       device_name};
}

void write_checkpoint(const std::filesystem::path& path, const CheckpointKey& key, const RenderState& st) {
  const nlohmann::json header = {
      {"scene", key.scene},       {"scene_hash", key.scene_hash}, {"width", key.width},
      {"height", key.height},     {"spp", key.spp},               {"max_depth", key.max_depth},
      {"seed", key.seed},         {"sampler", key.sampler},       {"strategy", key.strategy},
      {"noise_threshold", key.noise_threshold}, {"min_spp", key.min_spp},
      {"kernels", key.kernels},   {"device", key.device},         {"spp_done", st.spp_done},
      {"passes", st.passes},      {"seconds", st.seconds},        {"extend_rays", st.extend_rays},
      {"shadow_rays", st.shadow_rays}, {"nonfinite", st.nonfinite}};
  const std::string text = header.dump();
  std::string data(kMagic, sizeof kMagic);
  append(&data, (uint64_t)text.size());
  data += text;
  append(&data, (uint64_t)st.sum.size());
  for (auto* v : film_buffers(st)) append(&data, v->data(), sizeof(glm::vec4) * v->size());
  Hasher h;
  h.add(data.data(), data.size());
  append(&data, h.h);
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out.write(data.data(), (std::streamsize)data.size());
    out.close();
    if (!out) throw Error("cannot write checkpoint", tmp.string());
  });
}

RenderState read_checkpoint(const std::filesystem::path& path, const CheckpointKey& expected) {
  const std::string where = "--resume " + path.string();
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) throw Error("cannot read checkpoint: " + ec.message(), where);
  if (size < sizeof kMagic + 3 * sizeof(uint64_t)) throw Error("not an xi checkpoint (too short)", where);
  std::string data(size, '\0');
  std::ifstream in(path, std::ios::binary);
  if (!in.read(data.data(), (std::streamsize)size)) throw Error("cannot read checkpoint", where);
  if (std::memcmp(data.data(), kMagic, sizeof kMagic) != 0) throw Error("not an xi checkpoint", where);
  uint64_t sum = 0;
  std::memcpy(&sum, data.data() + size - sizeof sum, sizeof sum);
  Hasher h;
  h.add(data.data(), size - sizeof sum);
  if (h.h != sum) throw Error("checkpoint is damaged or truncated (checksum mismatch)", where);

  size_t at = sizeof kMagic;
  auto take = [&](void* out, size_t n) {
    if (n > size - sizeof sum - at) throw Error("checkpoint is damaged (sizes do not add up)", where);
    std::memcpy(out, data.data() + at, n);
    at += n;
  };
  uint64_t header_size = 0, pixels = 0;
  take(&header_size, sizeof header_size);
  std::string text(std::min<uint64_t>(header_size, size), '\0');
  take(text.data(), header_size);
  take(&pixels, sizeof pixels);
  nlohmann::json j;
  CheckpointKey key;
  RenderState st;
  try {
    j = nlohmann::json::parse(text);
    key = CheckpointKey{j.at("scene"),           j.at("scene_hash"), j.at("width"),   j.at("height"),
                        j.at("spp"),             j.at("max_depth"),  j.at("seed"),    j.at("sampler"),
                        j.at("strategy"),        j.at("noise_threshold"), j.at("min_spp"), j.at("kernels"),
                        j.at("device")};
    st.spp_done = j.at("spp_done");
    st.passes = j.at("passes");
    st.seconds = j.at("seconds");
    st.extend_rays = j.at("extend_rays");
    st.shadow_rays = j.at("shadow_rays");
    st.nonfinite = j.at("nonfinite");
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("checkpoint header is malformed: ") + e.what(), where);
  }

  // The first difference, in the user's terms.
  auto refuse = [&](const std::string& what, const std::string& then, const std::string& now) {
    throw Error("checkpoint was made with " + what + " " + then + ", this render has " + now, where);
  };
  if (key.scene_hash != expected.scene_hash)
    throw Error("checkpoint was made for another scene (" + key.scene + ", or the scene or its film size changed)",
                where);
  if (key.width != expected.width || key.height != expected.height)
    refuse("a film of", std::to_string(key.width) + "x" + std::to_string(key.height),
           std::to_string(expected.width) + "x" + std::to_string(expected.height));
  if (key.spp != expected.spp) refuse("--spp", std::to_string(key.spp), std::to_string(expected.spp));
  if (key.seed != expected.seed) refuse("--seed", std::to_string(key.seed), std::to_string(expected.seed));
  if (key.sampler != expected.sampler) refuse("--sampler", key.sampler, expected.sampler);
  if (key.strategy != expected.strategy) refuse("--strategy", key.strategy, expected.strategy);
  if (key.noise_threshold != expected.noise_threshold || key.min_spp != expected.min_spp) {
    auto adaptive = [](const CheckpointKey& k) {
      return k.noise_threshold > 0.0 ? "--noise-threshold " + nlohmann::json(k.noise_threshold).dump() + " --min-spp " +
                                           std::to_string(k.min_spp)
                                     : std::string("no adaptive sampling");
    };
    throw Error("checkpoint was made with " + adaptive(key) + ", this render has " + adaptive(expected), where);
  }
  if (key.max_depth != expected.max_depth)
    refuse("--max-depth", std::to_string(key.max_depth), std::to_string(expected.max_depth));
  if (key.device != expected.device) refuse("device", key.device, expected.device);
  if (key.kernels != expected.kernels)
    refuse("kernel build", key.kernels, expected.kernels + " (the kernels, their options or the driver changed)");

  if (pixels != (uint64_t)expected.width * expected.height || size - sizeof sum - at != 4 * pixels * sizeof(glm::vec4))
    throw Error("checkpoint is damaged (its film is not " + std::to_string(expected.width) + "x" +
                    std::to_string(expected.height) + ")",
                where);
  for (auto* v : film_buffers(st)) {
    v->resize(pixels);
    take(v->data(), sizeof(glm::vec4) * pixels);
  }
  if (st.spp_done < 0 || st.spp_done > key.spp)
    throw Error("checkpoint is damaged (" + std::to_string(st.spp_done) + " spp done)", where);
  return st;
}

}  // namespace xi
