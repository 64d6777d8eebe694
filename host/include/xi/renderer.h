// The wavefront renderer: path state in device buffers, one launch per stage, the progressive loop.
#pragma once
#include <cstdint>
#include <future>
#include <string>
#include <vector>

#include "xi/compiled_scene.h"
#include "xi/device.h"
#include "xi/film.h"
#include "xi/image.h"
#include "xi/kernel_config.h"
#include "xi/scene.h"

namespace xi {

class RayProbe;

// The largest work group xi launches (RenderOptions::local_size).
constexpr size_t kMaxLocalSize = XI_MAX_LOCAL_SIZE;  // layout.h

struct RenderOptions {
  int spp = 64;
  int max_depth = 8;            // bounces; 1 gives direct light only
  uint32_t seed = 0;
  int sampler = XI_SAMPLER_SOBOL;
  Strategy strategy = Strategy::Mis;
  // Work-group size, at most kMaxLocalSize; 0: the largest the kernel allows, within that. Fixed
  // rather than left to the driver: PoCL compiles a work-group function per distinct local size,
  // and queue lengths change every bounce.
  size_t local_size = 64;
  bool all_features = false;    // compile every feature in, whatever the scene uses
  // Paths each generate and shade work item takes, 1, 8 or 16; 0: the device's default (KernelConfig).
  int lanes = 0;
  // Children per BVH node, 4 or 8; 0: the device's default (KernelConfig::bvh_width_for).
  int bvh_width = 0;
  // Spatial splits in the BVH build (xi::build_bvh): faster rays where long triangles overlap,
  // a slower build. Off: every triangle in one leaf, the build as fast as plain binned SAH.
  bool spatial_splits = true;
  // Threads of the BVH build (xi::build_bvh); 0: every core. `xi render` gives it the cores PoCL
  // may use (POCL_MAX_PTHREAD_COUNT), which ranks sharing a host split between them.
  unsigned build_threads = 0;
  // Most paths in flight at once, (pixel, sample) items of one wave; 0 sizes it for the device
  // (default_paths_in_flight). The image does not depend on it.
  size_t paths_in_flight = 0;
  // Samples per pixel one pass adds, at most; 0: as many as the paths in flight hold (a small frame
  // on a GPU needs several to fill it). 1 gives one pass per spp (a convergence log per spp).
  int samples_per_pass = 0;
  FilmRows rows;                // the rows of the frame this renderer's film holds (default: all)
  // What each bounce's launches are sized by; the kernels read their exact queue length on the
  // device either way, so the image does not depend on it. Lagged: the previous bounce's length,
  // read back without stalling the queue. Exact: this bounce's, the host waiting for the shade that
  // counted it. Auto: exact on a CPU device, lagged elsewhere (Renderer::run_wave says why).
  enum class LaunchBound { Auto, Exact, Lagged };
  LaunchBound launch_bound = LaunchBound::Auto;
  // How bounce and shadow rays go through an 8-wide tree (camera rays always go in packets;
  // kernels/shared/layout.h); the image does not depend on it. On: in packets, all of them. Hybrid:
  // the first bounce's in hybrid packets (together while many enter a box, alone below), later ones
  // alone. Off: alone. Auto: On where the tree is small enough that each ray visits most of it
  // anyway, else Hybrid (KernelConfig::make decides).
  enum class RayPackets { Auto, On, Hybrid, Off };
  RayPackets ray_packets = RayPackets::Auto;
  // Rays per packet, 8 or 16; 0: the device's default (KernelConfig::make: 16 on a CPU device with
  // 512-bit vectors, else 8). The image does not depend on it.
  int packet_width = 0;
  // Which program shades (generate and shade). Scene: the scene's own, compiled for what it uses
  // (the constructor waits for its build unless it is cached). Generic: the one program that reads
  // the scene's shading word at run time (kernels/shared/shading.h). Auto: the scene's own if
  // cached; else, if the generic one is cached, that one at once while the scene's own builds in
  // the background and takes over between passes when ready; else as Scene. The image is the same
  // whichever shades.
  enum class ShadingProgram { Auto, Scene, Generic };
  ShadingProgram shading_program = ShadingProgram::Auto;
  bool profile = false;         // time every launch with OpenCL events (launches())
  // Adaptive sampling: with a threshold T > 0, a pixel stops taking samples once the relative
  // standard error of its mean (pixel_relative_error) is below T, judged after min_spp samples and
  // then at the fixed counts adaptive_check_after gives, so that the image does not depend on how
  // passes fall; spp is then the most any pixel takes. 0: every pixel takes spp samples.
  float noise_threshold = 0.0f;
  int min_spp = 16;
};

// Adaptive sampling's error of one pixel from its film sums (RGB sums and sums of squares, w: the
// finite samples n): the largest channel's standard error of the mean, sqrt(s²/n) with s² the
// unbiased sample variance, over sqrt(I² + kAdaptiveDarkFloor²), I the mean intensity (the
// channels' average): the error relative to the pixel's brightness as relMSE weighs it, so that
// pixels much darker than the floor are judged by an absolute error rather than never stopping.
// A pixel with fewer than 2 samples: infinity. (Renderer::check_pixels: a pixel stops once this
// is below the threshold for it and for its neighbours in the row.)
constexpr float kAdaptiveDarkFloor = 0.1f;
float pixel_relative_error(const glm::vec4& sum, const glm::vec4& sum_sq);
// The sample count of the adaptive check that follows one at `count` samples: about a quarter
// more, so that a pixel overshoots its stopping point by at most that, and checks stay few.
int adaptive_check_after(int count);

// The paths-in-flight budget for a device when RenderOptions::paths_in_flight is 0: enough to
// fill it, and within a quarter of its memory.
size_t default_paths_in_flight(Device& device);
// Device bytes per path in flight: path state, shadow rays and the two queues.
size_t path_bytes();

// Builds into the binary cache, and launches once, the programs any render on this device can start
// with before its scene's own shading program is built: the generic shading program and the
// tracing programs that RayPackets::Auto chooses from (on, hybrid), and the one for cut-out
// surfaces, for options.lanes and options.bvh_width (0: the
// device's defaults). A scene's first image then waits for no kernel build. Returns what it built,
// one KernelConfig::describe() line each.
std::vector<std::string> prebuild_kernels(Device& device, const RenderOptions& options);

// One kernel launch, timed by OpenCL profiling events (nanoseconds on the device clock).
struct Launch {
  const char* stage;
  int pass;
  int bounce;    // -1 for generate and accumulate
  size_t items;  // work items that did work (the queue length)
  uint64_t start_ns;
  uint64_t end_ns;
  size_t global = 0;  // work items launched (an upper bound on the queue length)
};

class Renderer {
 public:
  Renderer(Device& device, const Scene& scene, const RenderOptions& options);
  // Renders a scene compiled for this device and these options (compile_for), whose host arrays
  // it frees as each reaches the device: a large mesh's copies (the scene's, the compiled one and
  // the device's) are never all held at once.
  Renderer(Device& device, CompiledScene&& scene, const RenderOptions& options);
  static CompiledScene compile_for(Device& device, const Scene& scene, const RenderOptions& options);
  // The same, emptying the scene's triangles as soon as they are compiled
  // (compile_scene_freeing_triangles).
  static CompiledScene compile_freeing_triangles(Device& device, Scene& scene, const RenderOptions& options);
  ~Renderer();  // waits for a background build of the scene's shading program (it fills the cache)
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  // Renders samples_per_pass() more samples of every pixel (fewer in the last pass).
  void run_pass();
  // Runs passes until the film holds options().spp samples per pixel (adaptive sampling: until
  // every pixel has stopped or taken spp).
  void render();
  bool done() const { return spp_done_ >= options_.spp || (adaptive() && sampling_pixels() == 0); }
  bool adaptive() const { return options_.noise_threshold > 0.0f; }
  // The pixels still taking samples (all of them without adaptive sampling), and the samples the
  // film holds in all, dropped non-finite ones included.
  size_t sampling_pixels() const { return adaptive() ? active_.size() : pixels_; }
  uint64_t samples_taken() const { return samples_taken_; }
  int passes_done() const { return passes_; }
  int spp_done() const { return spp_done_; }
  int samples_per_pass() const { return samples_per_pass_; }
  size_t paths_in_flight() const { return paths_; }

  // The film (options().rows of the frame) resolved to images; with adaptive sampling its spp
  // image holds each pixel's sample count.
  Film film() const;
  Image mean() const;  // the first of the above, for cheap per-pass error tracking
  int film_width() const { return (int)scene_.camera.width; }
  int film_height() const { return options_.rows.count((int)scene_.camera.height); }
  // Lowers the spp of each pass (the processes of a distributed render agree on one); n >= 1.
  void limit_samples_per_pass(int n);
  uint32_t nonfinite_samples() const;
  // Between passes: the accumulated state (seconds left 0), and the way back to it.
  RenderState state() const;
  void restore(const RenderState& state);

  const std::vector<Launch>& launches() const { return launches_; }
  const Program& program() const { return program_; }
  const KernelConfig& kernels() const { return kernels_; }
  // Where the constructor's kernel time went: building (or loading) the tracing and the shading
  // program, and the first launches (where a driver may still generate code per launch
  // configuration). Seconds.
  struct KernelTimes {
    double trace_program = 0.0, shading_program = 0.0, first_launches = 0.0;
  };
  const KernelTimes& kernel_times() const { return kernel_times_; }
  // Whether the generic shading program is rendering now (RenderOptions::shading_program), and
  // the number of passes it rendered before the scene's own took over (-1: none took over).
  bool generic_shading() const { return generic_shading_; }
  int shading_switch_pass() const { return shading_switch_pass_; }
  // Whether the scene's own shading program is building in the background; waiting takes it.
  bool scene_shading_pending() const { return pending_shading_.valid(); }
  void wait_for_scene_shading();
  // The scene as compiled. Its buffers (XI_SCENE_BUFFERS) and its BVH's nodes and blocks are empty:
  // they are freed on the host once uploaded (the BVH's counts are in bvh.stats).
  const CompiledScene& compiled() const { return scene_; }
  // The lights that light sampling picks from: emissive triangles, punctual lights, the environment.
  uint32_t light_count() const { return light_count_; }
  // FNV-1a of the compiled geometry, materials, lights and camera (checkpoints' scene_hash).
  uint64_t scene_hash() const;
  const RenderOptions& options() const { return options_; }
  uint64_t extend_rays() const { return extend_rays_; }
  uint64_t shadow_rays() const { return shadow_rays_; }

 private:
  // The stages: each binds its kernel's arguments and launches it over `global` work items (an
  // upper bound on its queue: the kernel reads the length from counters_).
  void generate(const WaveParams& wave);
  void bind_generate(cl::Kernel& kernel, const WaveParams& wave, const cl::Buffer& counters) const;
  void bind_shade(cl::Kernel& kernel, const cl::Buffer& queue_in, const cl::Buffer& queue_out, int bounce,
                  const cl::Buffer& counters) const;
  void extend(const cl::Buffer& queue, int bounce, size_t global);
  void shade(const cl::Buffer& queue_in, const cl::Buffer& queue_out, int bounce, size_t global);
  void shadow(int bounce, size_t global);
  void accumulate(const WaveParams& wave);
  void bind_accumulate(const WaveParams& wave);
  void run_wave(const WaveParams& wave);
  WaveParams wave(size_t first_pixel, size_t pixels, int first_sample, uint32_t samples, bool listed = false) const;
  // Adaptive sampling: at a check, drops the pixels whose error is below the threshold from the
  // list of pixels still sampling (after a restore, rebuilds the list from the film's counts first).
  void check_pixels();
  void list_sampling_pixels(const std::vector<glm::vec4>& albedo);
  uint32_t pass_samples() const;
  void warm_up();
  // The constructor's steps, in order.
  void build_kernels();
  void size_waves();
  void check_memory() const;
  void allocate();
  // The scene's own generate and shade kernels, built on another thread and launched there once.
  struct ShadingKernels {
    cl::Kernel generate, shade;
  };
  ShadingKernels build_scene_shading(const std::vector<std::string>& defines) const;
  void take_scene_shading(bool wait);
  // Launches over global items (queue entries), items_per_work_item of them per work item.
  void launch(cl::Kernel& kernel, const char* stage, int bounce, size_t global, size_t items_per_work_item = 1);
  void finish_pass();
  SamplerParams sampler_params() const;
  int bind_path_state(cl::Kernel& kernel) const;               // returns the next argument index
  int bind_shadow_state(cl::Kernel& kernel, int arg) const;
  int bind_surface_buffers(cl::Kernel& kernel, int arg) const;  // XI_SURFACE_BUFFERS
  int bind_scene(cl::Kernel& kernel, int arg) const;            // XI_SCENE_BUFFERS, the light count, the environment
  std::vector<glm::vec4> read(const cl::Buffer& film) const;

  Device& device_;
  RenderOptions options_;
  CompiledScene scene_;
  KernelConfig kernels_;
  Program program_;  // every stage's kernels (two OpenCL programs; key and build time of both)
  KernelTimes kernel_times_;
  bool generic_shading_ = false;
  int shading_switch_pass_ = -1;
  std::future<ShadingKernels> pending_shading_;
  bool exact_bounds_ = false;  // RenderOptions::launch_bound, resolved for the device
  size_t pixels_ = 0;
  size_t paths_ = 0;           // path state slots: the most (pixel, sample) items of one wave
  int samples_per_pass_ = 1;
  int passes_ = 0, spp_done_ = 0;
  uint64_t samples_taken_ = 0;
  std::vector<uint32_t> active_;  // adaptive sampling: the film pixels still sampling, in order
  int next_check_ = 0;            // the sample count of the next adaptive check
  uint64_t extend_rays_ = 0, shadow_rays_ = 0;
  std::vector<Launch> launches_;
  std::vector<cl::Event> launch_events_;  // with profiling: the events of launches_ not yet read
  size_t counter_count_ = 0;
  std::vector<uint32_t> queue_counts_;  // the wave in flight's counters as read back mid-wave, same indices
  // Per wave of the pass in flight: the device counters copied back when the wave is done (queue
  // lengths for statistics and the profile), read when the pass finishes.
  std::vector<std::vector<uint32_t>> wave_counters_;
  std::vector<size_t> wave_first_launch_;
  // Measuring tools (bench/, tests) reach the extend stage through a RayProbe (an internal header).
  friend class RayProbe;
  RayProbe* probe_ = nullptr;

  cl::Kernel generate_, extend_, shade_, shadow_, accumulate_;
#define XI_DECLARE_BUFFER(type, name) cl::Buffer name##_;
  XI_PATH_STATE(XI_DECLARE_BUFFER)
  XI_SHADOW_STATE(XI_DECLARE_BUFFER)
#undef XI_DECLARE_BUFFER
  cl::Buffer queue_a_, queue_b_, counters_;
  cl::Buffer nodes_, tri_blocks_;
#define XI_DECLARE_SCENE_BUFFER(type, name) cl::Buffer name##_;
  XI_SCENE_BUFFERS(XI_DECLARE_SCENE_BUFFER)
#undef XI_DECLARE_SCENE_BUFFER
  uint32_t light_count_ = 0;
#define XI_DECLARE_FILM_BUFFER(name) cl::Buffer film_##name##_;
  XI_FILM_BUFFERS(XI_DECLARE_FILM_BUFFER)
#undef XI_DECLARE_FILM_BUFFER
  cl::Buffer pixel_list_;  // active_ on the device
};

}  // namespace xi
