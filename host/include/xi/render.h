// The wavefront integrator: path state in device buffers, stage launches, the progressive loop.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "xi/compiled_scene.h"
#include "xi/device.h"
#include "xi/image.h"
#include "xi/scene.h"

namespace xi {

struct RenderOptions {
  int spp = 64;
  int max_depth = 8;            // bounces; 1 gives direct light only
  uint32_t seed = 0;
  int sampler = XI_SAMPLER_SOBOL;
  Strategy strategy = Strategy::Mis;
  // Work-group size. Fixed rather than left to the driver: PoCL compiles a work-group function per
  // distinct local size, and queue lengths change every bounce.
  size_t local_size = 64;
  bool all_features = false;    // compile every feature in, whatever the scene uses
  size_t wave_pixels = 1 << 20; // most paths in flight at once (memory bound)
  int record_bounce = -1;       // if >= 0, keep the rays entering extend at this bounce (bench/)
};

struct RayBatch {
  std::vector<glm::vec4> org, dir;  // xyz used
};

// One kernel launch, timed by OpenCL profiling events (nanoseconds on the device clock).
struct Launch {
  const char* stage;
  int pass;
  int bounce;    // -1 for generate and accumulate
  size_t items;  // work items that did work (the queue length)
  uint64_t start_ns;
  uint64_t end_ns;
};

class Renderer {
 public:
  Renderer(Device& device, const Scene& scene, const RenderOptions& options);

  // Renders one more sample per pixel (sample index = passes_done()).
  void run_pass();
  int passes_done() const { return passes_; }

  // The film resolved to images: per pixel, the mean radiance, the variance of that mean (sample
  // variance / sample count), and the mean first-hit albedo and normal.
  struct Film {
    Image mean, variance, albedo, normal;
  };
  Film film() const;
  Image mean() const;  // the first of the above, for cheap per-pass error tracking
  uint32_t nonfinite_samples() const;

  const std::vector<Launch>& launches() const { return launches_; }
  const Program& program() const { return program_; }
  const CompiledScene& compiled() const { return scene_; }
  const RenderOptions& options() const { return options_; }
  uint64_t extend_rays() const { return extend_rays_; }
  const RayBatch& recorded_rays() const { return recorded_; }
  // Runs the extend stage alone on the given rays (at most wave size); returns the kernel's time in
  // seconds and the hits (t or −1, u, v, triangle in BVH order as float bits).
  double trace_closest(const RayBatch& rays, std::vector<glm::vec4>* hits);
  uint64_t shadow_rays() const { return shadow_rays_; }

 private:
  // The stages: each binds its kernel's arguments and launches it (through launch(), which times it).
  void generate(uint32_t first, uint32_t count);
  void extend(const cl::Buffer& queue, uint32_t count, int bounce);
  void shade(const cl::Buffer& queue_in, uint32_t count, const cl::Buffer& queue_out, uint32_t first, int bounce);
  void shadow(uint32_t count, int bounce);
  void accumulate(uint32_t first, uint32_t count);
  void warm_up();
  void record(const cl::Buffer& queue, uint32_t count);
  void launch(cl::Kernel& kernel, const char* stage, int bounce, size_t items);
  SamplerParams sampler_params() const;
  int bind_path_state(cl::Kernel& kernel);               // returns the next argument index
  int bind_shadow_state(cl::Kernel& kernel, int arg);
  std::vector<glm::vec4> read(const cl::Buffer& film) const;

  Device& device_;
  RenderOptions options_;
  CompiledScene scene_;
  Program program_;
  size_t pixels_ = 0;
  size_t wave_ = 0;
  int passes_ = 0;
  uint64_t extend_rays_ = 0, shadow_rays_ = 0;
  std::vector<Launch> launches_;
  RayBatch recorded_;

  cl::Kernel generate_, extend_, shade_, shadow_, accumulate_;
#define XI_DECLARE_BUFFER(type, name) cl::Buffer name##_;
  XI_PATH_STATE(XI_DECLARE_BUFFER)
  XI_SHADOW_STATE(XI_DECLARE_BUFFER)
#undef XI_DECLARE_BUFFER
  cl::Buffer queue_a_, queue_b_, counters_;
  cl::Buffer nodes_, tri_verts_, tri_normals_, tri_material_, materials_;
  cl::Buffer light_cdf_, light_tri_, tri_light_pdf_;
  cl::Buffer film_sum_, film_sum_sq_, film_albedo_, film_normal_;
};

}  // namespace xi
