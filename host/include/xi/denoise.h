// Denoising a render with Intel Open Image Denoise 2 (OIDN), loaded at run time: xi builds and
// runs without it, and only denoising needs it.
#pragma once
#include <memory>
#include <string>

#include "xi/image.h"

namespace xi {

class Device;

// Loads OIDN once per process (later calls return at once), from the first place that has it:
//  1. $XI_OIDN_PATH, a folder holding libOpenImageDenoise.so.2 or the library file itself; when
//     it is set, only there;
//  2. oidn/lib beside the running program;
//  3. build/oidn/lib of the source tree xi was built from, which `scripts/install-deps.sh
//     --denoise` fills (for the programs of any build folder);
//  4. the system's library path (libOpenImageDenoise.so.2, then libOpenImageDenoise.so).
// Throws xi::Error naming where it looked and how to install it. A failed search is not
// remembered: a later call looks again.
void load_denoiser();

// OIDN's filter quality (its trained networks: high is its default and best, fast the quickest).
enum class DenoiseQuality { High, Balanced, Fast };
// How the albedo and normal guides are cleaned before they guide the colour, as Cycles offers:
// accurate, each denoised alone at the filter's quality; fast, at OIDN's fast quality; none, used
// as rendered (OIDN then expects them noisy, and keeps some of their noise out of the result).
enum class DenoisePrefilter { Accurate, Fast, None };

struct DenoiseOptions {
  // The OpenCL device the image was rendered on. OIDN denoises on its GPU device that is the same
  // hardware (the same UUID or PCI address, else the same name) if it has one, else on its CPU
  // device. Null: the CPU device.
  Device* render_device = nullptr;
  DenoiseQuality quality = DenoiseQuality::High;
  DenoisePrefilter prefilter = DenoisePrefilter::Accurate;
};
// Parses --denoise-quality (high, balanced, fast) and --denoise-prefilter (accurate, fast, none).
DenoiseQuality parse_denoise_quality(const std::string& name);
DenoisePrefilter parse_denoise_prefilter(const std::string& name);

// An OIDN device and the filters of its last image, kept for the next image of the same size
// (snapshots of one render). By default each image is denoised as Cycles' "accurate" prefilter
// does: the albedo and the normal are first denoised alone (OIDN's RT filter on each), then the
// colour with them, as clean auxiliary images (cleanAux), as HDR.
class Denoiser {
 public:
  // Loads OIDN (load_denoiser) and opens its device; throws xi::Error with OIDN's message.
  explicit Denoiser(const DenoiseOptions& options = {});
  ~Denoiser();
  Denoiser(const Denoiser&) = delete;
  Denoiser& operator=(const Denoiser&) = delete;

  // The denoised colour: linear HDR radiance (>= 0). The albedo (in [0, 1]) and the normal (in
  // [-1, 1]) are optional guides; a normal needs an albedo too. Every image must be finite and of
  // the colour's size; throws xi::Error otherwise, or with OIDN's message if it fails.
  Image run(const Image& color, const Image* albedo = nullptr, const Image* normal = nullptr);

  // What denoises, for summaries: "OIDN 2.5.1 (CPU device)", "OIDN 2.5.1 (CUDA device NVIDIA H200)".
  const std::string& description() const;
  // The wall time of the last run() (copies, prefilters and the main filter).
  double last_seconds() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// One image through a Denoiser made for it.
Image denoise(const Image& color, const Image* albedo = nullptr, const Image* normal = nullptr,
              const DenoiseOptions& options = {});

}  // namespace xi
