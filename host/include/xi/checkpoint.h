// Checkpoints: a render's state written between passes, to resume it bitwise after a stop.
#pragma once
#include <filesystem>
#include <string>

#include "xi/renderer.h"

namespace xi {

// What a checkpoint must agree on with the render that resumes it: anything that changes a pixel.
struct CheckpointKey {
  std::string scene;       // the scene file (reported, not compared: the scene hash is)
  std::string scene_hash;  // of the compiled scene: geometry, materials, lights, camera and film size
  int width = 0, height = 0;
  int spp = 0, max_depth = 0;
  uint32_t seed = 0;
  std::string sampler, strategy;
  double noise_threshold = 0.0;  // adaptive sampling (0: off)
  int min_spp = 0;
  std::string kernels;  // Program::key: kernel sources, build options, device and driver
  std::string device;
  bool operator==(const CheckpointKey&) const = default;
};

CheckpointKey checkpoint_key(const Renderer& renderer, const std::filesystem::path& scene_file,
                             const std::string& device_name);

// Written atomically (a temporary file renamed over the old checkpoint), with a checksum.
void write_checkpoint(const std::filesystem::path& path, const CheckpointKey& key, const RenderState& state);

// Reads a checkpoint and checks it against the render about to resume it: a file that is not a
// checkpoint, is damaged, or was made for another scene, spp, seed, sampler, strategy, depth,
// adaptive sampling, kernel build or device is refused with an xi::Error naming the first difference.
RenderState read_checkpoint(const std::filesystem::path& path, const CheckpointKey& expected);

}  // namespace xi
