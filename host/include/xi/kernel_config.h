// Every option the kernels are compiled with, in one place: what the scene uses, the sampler and
// light transport strategy, and the choices made for the device (lanes, BVH width, ray packets).
#pragma once
#include <string>
#include <vector>

#include "sampling.h"
#include "shading.h"
#include "xi/compiled_scene.h"
#include "xi/device.h"

namespace xi {

struct RenderOptions;

// Light transport strategies: MIS combines light and BSDF sampling; nee uses light sampling alone
// for direct light; bsdf uses BSDF sampling alone.
enum class Strategy { Mis, Nee, Bsdf };
Strategy parse_strategy(const std::string& name);   // throws xi::Error
const char* strategy_name(Strategy s);
int parse_sampler(const std::string& name);         // XI_SAMPLER_*; throws xi::Error
const char* sampler_name(int sampler);
// Whether every prefix of a render is a render with fewer spp (random, sobol); grid and stratified
// patterns are only complete at the spp they were made for.
bool sampler_is_progressive(int sampler);

// The vector units of the CPU a CPU device runs on, which set its default lanes and packet width.
struct CpuVectors {
  bool avx2 = false;    // 256-bit vectors with fused multiply-add, or wider
  bool avx512 = false;  // 512-bit vectors
  static CpuVectors of_this_cpu();
};

// Each field maps to -D flags, so a feature the scene does not use compiles no code. The flags are
// part of the binary cache's key (build_program hashes its options). A render builds two programs:
// the tracing stages (extend, shadow, accumulate), whose flags do not depend on the scene's
// materials, so one build serves many scenes; and the shading stages (generate, shade), built for
// the scene's shading word, or generic: the word read at run time (kernels/shared/shading.h).
struct KernelConfig {
  Features features;
  int sampler = XI_SAMPLER_SOBOL;
  Strategy strategy = Strategy::Mis;
  int lanes = 1;                // paths per generate and shade work item (kernels/shared/lanes.h): 1, 8 or 16
  int bvh_width = 4;            // children per BVH node (kernels/shared/layout.h): 4 or 8
  bool ray_packets = false;     // bounce and shadow rays in packets, as camera rays go (8-wide trees)
  bool hybrid_packets = false;  // else the first bounce's in hybrid packets (8-wide trees)
  int packet_width = 8;         // rays per packet (kernels/shared/packet.h): 8 or 16
  bool cpu_device = false;      // prefetch hints and the triangle test's early exit, for a CPU
  bool generic = false;         // the shading stages read the shading word at run time

  // The BVH width a render on this device traverses: options.bvh_width, or the device's default
  // (8 on a CPU, whose vector registers test eight boxes as cheaply as four; 4 elsewhere). Needed
  // before the scene is compiled, since the tree is built for it.
  static int bvh_width_for(const DeviceInfo& device, const RenderOptions& options);
  // The configuration of a render: the scene (compiled for bvh_width_for), the device, the options;
  // `cpu` is the CPU a CPU device runs on. Throws xi::Error for an option out of range.
  static KernelConfig make(const DeviceInfo& device, const CompiledScene& scene, const RenderOptions& options,
                           CpuVectors cpu = CpuVectors::of_this_cpu());

  // The shading word: features, strategy and sampler (kernels/shared/shading.h).
  uint32_t shading_word() const;
  std::vector<std::string> trace_defines() const;    // extend.cl, shadow.cl, accumulate.cl
  std::vector<std::string> shading_defines() const;  // generate.cl, shade.cl
  std::vector<std::string> defines() const;          // both, for one program holding every stage
  KernelConfig as_generic() const;
  // One line for --profile, e.g. "diffuse emitters; sampler sobol; mis; lanes 8; bvh 8-wide; ...".
  std::string describe() const;
  bool operator==(const KernelConfig&) const = default;
};

}  // namespace xi
