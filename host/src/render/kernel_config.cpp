#include "xi/kernel_config.h"

#include "xi/error.h"
#include "xi/renderer.h"

namespace xi {
namespace {

// The largest 8-wide tree whose bounce and shadow rays go in packets when RenderOptions::ray_packets
// is Auto: in a tree this small each ray visits most nodes anyway, so a packet of rays in different
// directions costs little more than one ray; in a larger tree they part ways, and only the first
// bounce's, still neighbours, go in (hybrid) packets.
constexpr size_t kRayPacketNodes = 8;

bool is_cpu(const DeviceInfo& device) { return device.type == "CPU"; }

}  // namespace

CpuVectors CpuVectors::of_this_cpu() {
  CpuVectors v;
#if defined(__x86_64__) || defined(__i386__)
  v.avx512 = __builtin_cpu_supports("avx512f");
  v.avx2 = v.avx512 || (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"));
#endif
  return v;
}

Strategy parse_strategy(const std::string& name) {
  if (name == "mis") return Strategy::Mis;
  if (name == "nee") return Strategy::Nee;
  if (name == "bsdf") return Strategy::Bsdf;
  throw Error("unknown strategy '" + name + "'", "expected mis, nee or bsdf");
}

const char* strategy_name(Strategy s) {
  return s == Strategy::Mis ? "mis" : s == Strategy::Nee ? "nee" : "bsdf";
}

int parse_sampler(const std::string& name) {
  for (int s = XI_SAMPLER_RANDOM; s <= XI_SAMPLER_SOBOL; ++s)
    if (name == sampler_name(s)) return s;
  throw Error("unknown sampler '" + name + "'", "expected random, grid, stratified or sobol");
}

const char* sampler_name(int sampler) {
  switch (sampler) {
    case XI_SAMPLER_RANDOM: return "random";
    case XI_SAMPLER_GRID: return "grid";
    case XI_SAMPLER_STRATIFIED: return "stratified";
    case XI_SAMPLER_SOBOL: return "sobol";
  }
  return "?";
}

bool sampler_is_progressive(int sampler) { return sampler == XI_SAMPLER_RANDOM || sampler == XI_SAMPLER_SOBOL; }

int KernelConfig::bvh_width_for(const DeviceInfo& device, const RenderOptions& options) {
  const int width = options.bvh_width ? options.bvh_width : (is_cpu(device) ? 8 : 4);
  if (width != 4 && width != 8) throw Error("BVH width must be 4 or 8, not " + std::to_string(width), "--bvh-width");
  return width;
}

KernelConfig KernelConfig::make(const DeviceInfo& device, const CompiledScene& scene, const RenderOptions& options,
                                CpuVectors cpu) {
  KernelConfig c;
  c.features = options.all_features ? Features::everything() : scene.features;
  c.features.multiple_scattering = scene.features.multiple_scattering;
  c.features.albedo_scaling = scene.features.albedo_scaling;
  c.sampler = options.sampler;
  c.strategy = options.strategy;
  c.cpu_device = is_cpu(device);
  // A CPU device runs on this CPU: its vectors set the lanes and the packets below, as measured by
  // bench/widths.py. Sixteen paths per work item fill 512-bit vectors; with AVX2, as two 256-bit
  // operations each, they ran faster than eight as well.
  c.lanes = options.lanes ? options.lanes : !c.cpu_device ? 1 : cpu.avx2 ? 16 : 8;
  if (c.lanes != 1 && c.lanes != 8 && c.lanes != 16)
    throw Error("lanes must be 1, 8 or 16, not " + std::to_string(c.lanes), "--lanes");
  c.bvh_width = scene.bvh.width;
  // Shadow rays through cut-out surfaces go one at a time (shadow.cl).
  using RayPackets = RenderOptions::RayPackets;
  const bool packets = c.bvh_width == 8 && !c.features.alpha;
  const RayPackets choice = options.ray_packets != RayPackets::Auto               ? options.ray_packets
                            : scene.bvh.nodes8.size() <= kRayPacketNodes ? RayPackets::On
                                                                         : RayPackets::Hybrid;
  c.ray_packets = packets && choice == RayPackets::On;
  c.hybrid_packets = packets && choice == RayPackets::Hybrid;
  // With 512-bit vectors a packet of sixteen rays tests a box or a triangle in one instruction, as
  // eight do with 256-bit ones.
  c.packet_width = options.packet_width ? options.packet_width : (c.cpu_device && cpu.avx512 ? 16 : 8);
  if (c.packet_width != 8 && c.packet_width != 16)
    throw Error("packet width must be 8 or 16, not " + std::to_string(c.packet_width), "--packet-width");
  return c;
}

uint32_t KernelConfig::shading_word() const {
  uint32_t word = (uint32_t)sampler << XI_SAMPLER_SHIFT;
#define XI_FEATURE_BIT(name, bit, report, in_all)                                           \
  static_assert((bit) < (1u << XI_SAMPLER_SHIFT), "feature " report "'s bit overlaps the sampler's"); \
  if (features.name) word |= bit;
  XI_FEATURES(XI_FEATURE_BIT)
#undef XI_FEATURE_BIT
  if (features.lights()) {
    if (strategy != Strategy::Bsdf) word |= XI_USE_NEE;  // (so BSDF sampling alone never reaches a punctual light)
    if (strategy == Strategy::Mis) word |= XI_USE_MIS;
  }
  return word;
}

std::vector<std::string> KernelConfig::trace_defines() const {
  std::vector<std::string> d{"XI_BVH_WIDTH=" + std::to_string(bvh_width),
                             std::string("XI_RAY_PACKETS=") + (ray_packets ? "1" : "0"),
                             std::string("XI_HYBRID_PACKETS=") + (hybrid_packets ? "1" : "0"),
                             "XI_PACKET_WIDTH=" + std::to_string(packet_width)};
  if (cpu_device) d.push_back("XI_CPU_DEVICE");
  if (features.alpha) d.push_back("XI_ALPHA");
  return d;
}

std::vector<std::string> KernelConfig::shading_defines() const {
  std::vector<std::string> d{generic ? "XI_GENERIC" : "XI_SHADING=" + std::to_string(shading_word()),
                             "XI_LANES=" + std::to_string(lanes)};
  if (cpu_device) d.push_back("XI_CPU_DEVICE");
  return d;
}

std::vector<std::string> KernelConfig::defines() const {
  std::vector<std::string> d = shading_defines();
  for (const std::string& flag : trace_defines())
    if (flag != "XI_CPU_DEVICE") d.push_back(flag);
  return d;
}

KernelConfig KernelConfig::as_generic() const {
  KernelConfig c = *this;
  c.generic = true;
  return c;
}

std::string KernelConfig::describe() const {
  const std::string shading = generic ? "generic shading"
                                      : features.describe() + "; sampler " + sampler_name(sampler) + "; strategy " +
                                            strategy_name(strategy);
  // Packets exist on 8-wide trees only (camera rays always, bounce and shadow rays with ray packets).
  const std::string packets = bvh_width == 8 ? "; packets of " + std::to_string(packet_width) + " rays" : "";
  return shading + "; lanes " + std::to_string(lanes) + "; bvh " + std::to_string(bvh_width) + "-wide" + packets +
         "; ray packets " + (ray_packets ? "on" : hybrid_packets ? "hybrid" : "off") +
         (features.alpha ? "; cut-outs" : "") +
         (cpu_device ? "; cpu device" : "");
}

}  // namespace xi
