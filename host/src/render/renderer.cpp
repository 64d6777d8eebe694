#include "xi/renderer.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>

#include "../parallel.h"
#include "memory.h"
#include "ray_probe.h"
#include "xi/error.h"
#include "xi/hash.h"

namespace xi {
namespace {

// The kernel files, one per wavefront stage, built as two programs: generate and shade take
// XI_LANES paths per work item (kernels/shared/lanes.h), the tracing stages and accumulate one.
const std::vector<std::string> kTraceFiles = {"extend.cl", "shadow.cl", "accumulate.cl"};
const std::vector<std::string> kLaneFiles = {"generate.cl", "shade.cl"};

// A launch size past PoCL's limit for "small grid" work-group functions (where its work-group
// specialisation is on, which xi turns off unless the user set it, it compiles a kernel once for
// launches below the limit and once for those above): warming up at 1 and at this many items
// compiles both before the first pass.
constexpr size_t kLargeLaunch = (size_t)1 << 20;

// The niceness of the thread that builds a scene's own shading program behind the generic one.
constexpr int kBackgroundBuildNice = 10;

// Enqueues a kernel over global_items queue entries, items_per_work_item of them per work item, in
// work groups of `local` (0: the largest the kernel allows, at most kMaxLocalSize).
void enqueue_items(cl::CommandQueue& queue, cl::Kernel& kernel, size_t global_items, size_t items_per_work_item,
                   size_t local, cl::Event* event = nullptr) {
  const size_t n = std::max<size_t>((global_items + items_per_work_item - 1) / items_per_work_item, 1);
  // 0: the largest work group the kernel allows, at most kMaxLocalSize. (Left to itself, PoCL
  // chose 4096 work items, whose values kept across shade's barriers overflowed its threads'
  // stacks.)
  if (local == 0)
    local = std::min(kMaxLocalSize, kernel.getWorkGroupInfo<CL_KERNEL_WORK_GROUP_SIZE>(
                                        queue.getInfo<CL_QUEUE_DEVICE>()));
  const size_t global = local ? (n + local - 1) / local * local : n;
  queue.enqueueNDRangeKernel(kernel, cl::NullRange, cl::NDRange(global), local ? cl::NDRange(local) : cl::NullRange,
                             nullptr, event);
}

// Uploads a host array of the compiled scene, then frees it: from then on the device's copy is the
// only one (a large mesh's triangles and BVH are most of a render's memory). In parts, each handed
// back once written, so that the array is never held whole twice (on a CPU device both copies are
// host memory). Each part is copied through a mapping of the buffer on every core: on a CPU device
// the copy is where the buffer's fresh pages are first written, and faulting them in is most of
// its time.
template <typename T, typename Allocator>
cl::Buffer upload_and_free(cl::Context& ctx, cl::CommandQueue& queue, std::vector<T, Allocator>& data) {
  constexpr size_t kPart = size_t(32) << 20;
  const size_t bytes = sizeof(T) * data.size();
  cl::Buffer buffer(ctx, CL_MEM_READ_ONLY, bytes);
  const char* host = reinterpret_cast<const char*>(data.data());
  for (size_t at = 0; at < bytes; at += kPart) {
    const size_t part = std::min(kPart, bytes - at);
    char* mapped =
        static_cast<char*>(queue.enqueueMapBuffer(buffer, CL_TRUE, CL_MAP_WRITE_INVALIDATE_REGION, at, part));
    parallel_chunks(part, parts_for(part / sizeof(T)), [&](size_t begin, size_t end, unsigned) {
      std::memcpy(mapped + begin, host + at + begin, end - begin);
    });
    queue.enqueueUnmapMemObject(buffer, mapped);
    queue.finish();
    release_pages(host + at, part);
  }
  std::vector<T, Allocator>().swap(data);
  return buffer;
}

}  // namespace

size_t path_bytes() {
  size_t bytes = 2 * sizeof(uint32_t);
#define XI_ADD_SIZE(type, name) bytes += sizeof(type);
  XI_PATH_STATE(XI_ADD_SIZE)
  XI_SHADOW_STATE(XI_ADD_SIZE)
#undef XI_ADD_SIZE
  return bytes;
}

size_t default_paths_in_flight(Device& device) {
  // A CPU: 2^20 paths, so a 512×512 frame takes 4 spp per pass in few launches. A GPU needs
  // hundreds of thousands of paths to hide its memory latency, and tens of millions so that the gaps
  // between launches (tens of microseconds each) are a small part of a pass.
  size_t paths = device.info().type == "GPU" ? (size_t)1 << 25 : (size_t)1 << 20;
  // At most a quarter of the device memory, and no buffer over the device's largest allocation.
  const size_t bytes = path_bytes();
  const size_t mem = device.device().getInfo<CL_DEVICE_GLOBAL_MEM_SIZE>();
  const size_t max_alloc = device.device().getInfo<CL_DEVICE_MAX_MEM_ALLOC_SIZE>();
  paths = std::min({paths, mem / 4 / bytes, max_alloc / sizeof(glm::vec4)});
  return std::max<size_t>(paths, 1024);
}

std::vector<std::string> prebuild_kernels(Device& device, const RenderOptions& options) {
  // A renderer of one small triangle builds and launches every stage's program in its constructor.
  Scene scene;
  scene.width = scene.height = 8;
  scene.camera.position = glm::vec3(0.0f, 0.0f, -2.0f);
  scene.camera.look_at = glm::vec3(0.0f);
  Material white;
  white.albedo = glm::vec3(0.5f);
  scene.materials.push_back(white);
  scene.add_triangle(glm::vec3(-1.0f, -1.0f, 0.0f), glm::vec3(1.0f, -1.0f, 0.0f), glm::vec3(0.0f, 1.0f, 0.0f));
  RenderOptions o = options;
  o.spp = 1;
  o.shading_program = RenderOptions::ShadingProgram::Generic;
  std::vector<std::string> built;
  auto build = [&]() {
    Renderer r(device, scene, o);
    const std::string line = r.kernels().as_generic().describe();
    if (std::find(built.begin(), built.end(), line) == built.end()) built.push_back(line);
  };
  for (auto packets : {RenderOptions::RayPackets::On, RenderOptions::RayPackets::Hybrid}) {
    o.ray_packets = packets;
    build();
  }
  // Cut-out surfaces need their own tracing program (shadow rays look their alpha up).
  scene.materials[0].alpha_mode = AlphaMode::Mask;
  build();
  return built;
}

float pixel_relative_error(const glm::vec4& sum, const glm::vec4& sum_sq) {
  const float n = sum.w;
  if (!(n >= 2.0f)) return INFINITY;
  const glm::vec3 mean = glm::vec3(sum) / n;
  const glm::vec3 variance = glm::max((glm::vec3(sum_sq) - n * mean * mean) / (n - 1.0f), glm::vec3(0.0f));
  const glm::vec3 standard_error = glm::sqrt(variance / n);
  const float intensity = (mean.x + mean.y + mean.z) / 3.0f;
  return std::max({standard_error.x, standard_error.y, standard_error.z}) /
         std::sqrt(intensity * intensity + kAdaptiveDarkFloor * kAdaptiveDarkFloor);
}

int adaptive_check_after(int count) { return count + std::max(1, count / 4); }

CompiledScene Renderer::compile_for(Device& device, const Scene& scene, const RenderOptions& options) {
  return compile_scene(scene, KernelConfig::bvh_width_for(device.info(), options), options.spatial_splits,
                       options.build_threads);
}

CompiledScene Renderer::compile_freeing_triangles(Device& device, Scene& scene, const RenderOptions& options) {
  return compile_scene_freeing_triangles(scene, KernelConfig::bvh_width_for(device.info(), options),
                                         options.spatial_splits, options.build_threads);
}

Renderer::Renderer(Device& device, const Scene& scene, const RenderOptions& options)
    : Renderer(device, compile_for(device, scene, options), options) {}

Renderer::Renderer(Device& device, CompiledScene&& scene, const RenderOptions& options)
    : device_(device),
      options_(options),
      scene_(std::move(scene)),
      kernels_(KernelConfig::make(device.info(), scene_, options)) {
  if (options.spp < 1) throw Error("spp must be at least 1", "--spp");
  if (options.max_depth < 1 || options.max_depth > 64) throw Error("max depth must be in 1..64", "--max-depth");
  if (options.samples_per_pass < 0) throw Error("samples per pass must be at least 1 (0: automatic)");
  if (!(options.noise_threshold >= 0.0f) || !std::isfinite(options.noise_threshold))
    throw Error("the noise threshold must be a finite number >= 0 (0: off)", "--noise-threshold");
  if (options.min_spp < 1) throw Error("the least spp of adaptive sampling must be at least 1", "--min-spp");
  // Grid and stratified patterns are complete only at their spp: a pixel stopped early would hold
  // part of a pattern, which is no estimate of the pixel.
  if (adaptive() && !sampler_is_progressive(options.sampler))
    throw Error(std::string("the ") + sampler_name(options.sampler) + " sampler's pattern is only complete at " +
                    std::to_string(options.spp) + " spp, so a pixel cannot stop early",
                "--noise-threshold; use --sampler sobol or random");
  exact_bounds_ = options.launch_bound == RenderOptions::LaunchBound::Auto
                      ? device.info().type == "CPU"
                      : options.launch_bound == RenderOptions::LaunchBound::Exact;
  // The kernels read 3 texture coordinates per triangle wherever their word has textures, an
  // --all-features build of a scene without any too: zeros then.
  if (kernels_.features.textures && scene_.tri_uv.size() < 3 * scene_.tri_vertices.size())
    scene_.tri_uv.assign(3 * scene_.tri_vertices.size(), glm::vec4(0.0f));
  build_kernels();
  size_waves();
  check_memory();
  allocate();
  if (adaptive()) {
    active_.resize(pixels_);
    for (size_t i = 0; i < pixels_; ++i) active_[i] = (uint32_t)i;
    next_check_ = std::min(options_.min_spp, options_.spp);
  }
  auto start = std::chrono::steady_clock::now();
  warm_up();
  kernel_times_.first_launches = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  program_.build_seconds += kernel_times_.first_launches;
  if (generic_shading_ && options.shading_program == RenderOptions::ShadingProgram::Auto)
    pending_shading_ = std::async(std::launch::async, &Renderer::build_scene_shading, this, kernels_.shading_defines());
}

void Renderer::build_kernels() {
  program_ = build_program(device_, kTraceFiles, kernels_.trace_defines());
  extend_ = cl::Kernel(program_.program, "extend");
  shadow_ = cl::Kernel(program_.program, "shadow");
  accumulate_ = cl::Kernel(program_.program, "accumulate");

  using Choice = RenderOptions::ShadingProgram;
  const std::vector<std::string> own = kernels_.shading_defines(), generic = kernels_.as_generic().shading_defines();
  generic_shading_ = options_.shading_program == Choice::Generic ||
                     (options_.shading_program == Choice::Auto && !program_cached(device_, kLaneFiles, own) &&
                      program_cached(device_, kLaneFiles, generic));
  Program shading = build_program(device_, kLaneFiles, generic_shading_ ? generic : own);
  generate_ = cl::Kernel(shading.program, "generate");
  shade_ = cl::Kernel(shading.program, "shade");
  // One key, build time and cache state for all the kernels (checkpoints and `xi render` use them).
  // The key is the scene's own program's whichever shades, since both render the same image.
  program_.key += program_key(device_, kLaneFiles, own);
  kernel_times_.trace_program = program_.build_seconds;
  kernel_times_.shading_program = shading.build_seconds;
  program_.build_seconds += shading.build_seconds;
  program_.from_cache = program_.from_cache && shading.from_cache;
}

void Renderer::wait_for_scene_shading() { take_scene_shading(true); }

Renderer::~Renderer() {
  if (pending_shading_.valid()) pending_shading_.wait();
}

// Between passes: the scene's own generate and shade replace the generic ones once built.
void Renderer::take_scene_shading(bool wait) {
  if (!pending_shading_.valid()) return;
  if (!wait && pending_shading_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
  ShadingKernels own = pending_shading_.get();  // rethrows a failed build, with its log
  generate_ = own.generate;
  shade_ = own.shade;
  generic_shading_ = false;
  shading_switch_pass_ = passes_;
}

// On a thread of its own: builds the program, then launches both kernels once with no work on a
// queue of its own, with counters of their own, so that a driver that compiles per launch
// configuration (PoCL with work-group specialisation) does it here rather than in the render's
// queue. At a lower priority: the generic program renders as fast, so on a CPU device the passes
// come first.
Renderer::ShadingKernels Renderer::build_scene_shading(const std::vector<std::string>& defines) const {
  setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), kBackgroundBuildNice);
  Program program = build_program(device_, kLaneFiles, defines);
  ShadingKernels k{cl::Kernel(program.program, "generate"), cl::Kernel(program.program, "shade")};
  cl::CommandQueue queue(device_.context(), device_.device());
  cl::Buffer counters(device_.context(), CL_MEM_READ_WRITE, sizeof(uint32_t) * counter_count_);
  queue.enqueueFillBuffer(counters, 0u, 0, sizeof(uint32_t) * counter_count_);
  bind_generate(k.generate, wave(0, 1, 0, 0), counters);
  bind_shade(k.shade, queue_a_, queue_b_, 0, counters);
  for (size_t items : {(size_t)1, kLargeLaunch})
    for (cl::Kernel* kernel : {&k.generate, &k.shade})
      enqueue_items(queue, *kernel, items, (size_t)kernels_.lanes, options_.local_size);
  queue.finish();
  return k;
}

// Paths in flight: a wave holds several samples of every pixel when the budget allows it.
void Renderer::size_waves() {
  const FilmRows rows = options_.rows;
  const int height = (int)scene_.camera.height;
  if (rows.first < 0 || rows.stride < 1 || rows.count(height) < 1)
    throw Error("the film's rows start at " + std::to_string(rows.first) + " every " + std::to_string(rows.stride) +
                ": no row of a frame " + std::to_string(height) + " high");
  pixels_ = (size_t)scene_.camera.width * rows.count(height);
  const size_t budget = options_.paths_in_flight ? options_.paths_in_flight : default_paths_in_flight(device_);
  const int fits = (int)std::clamp<size_t>(budget / pixels_, 1, (size_t)options_.spp);
  samples_per_pass_ = options_.samples_per_pass > 0 ? std::min(options_.samples_per_pass, fits) : fits;
  paths_ = std::min(budget, pixels_ * samples_per_pass_);
  if (paths_ > UINT32_MAX / 2) throw Error("too many paths in flight", std::to_string(paths_));
}

void Renderer::check_memory() const {
  MemoryNeeds needs{pixels_, paths_, path_bytes()};
  const Bvh& bvh = scene_.bvh;
  auto add = [&](size_t b) {
    needs.scene_bytes += b;
    needs.largest_scene_buffer = std::max(needs.largest_scene_buffer, b);
  };
  add(sizeof(BvhNode) * bvh.nodes.size() + sizeof(BvhNode8) * bvh.nodes8.size());
  add(sizeof(TriBlock) * bvh.blocks.size());
  if (adaptive()) add(sizeof(uint32_t) * pixels_);  // the list of pixels still sampling
#define XI_COUNT_BUFFER(type, name) add(sizeof(scene_.name[0]) * scene_.name.size());
  XI_SCENE_BUFFERS(XI_COUNT_BUFFER)
#undef XI_COUNT_BUFFER
  xi::check_memory(device_, needs);
}

void Renderer::allocate() {
  cl::Context& ctx = device_.context();
  cl::CommandQueue& queue = device_.queue();
#define XI_ALLOCATE_BUFFER(type, name) name##_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(type) * paths_);
  XI_PATH_STATE(XI_ALLOCATE_BUFFER)
  XI_SHADOW_STATE(XI_ALLOCATE_BUFFER)
#undef XI_ALLOCATE_BUFFER
  queue_a_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * paths_);
  queue_b_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * paths_);
  counter_count_ = XI_COUNTER_COUNT(options_.max_depth);
  counters_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * counter_count_);
  queue_counts_.assign(counter_count_, 0);
  nodes_ = scene_.bvh.width == 8 ? upload_and_free(ctx, queue, scene_.bvh.nodes8)
                                 : upload_and_free(ctx, queue, scene_.bvh.nodes);
  std::vector<BvhNode>().swap(scene_.bvh.nodes);  // the 4-wide nodes an 8-wide tree was collapsed from
  tri_blocks_ = upload_and_free(ctx, queue, scene_.bvh.blocks);
  light_count_ = scene_.features.lights() ? (uint32_t)scene_.light_tri.size() : 0u;
#define XI_UPLOAD_BUFFER(type, name) name##_ = upload_and_free(ctx, queue, scene_.name);
  XI_SCENE_BUFFERS(XI_UPLOAD_BUFFER)
#undef XI_UPLOAD_BUFFER
#define XI_ALLOCATE_FILM_BUFFER(name) film_##name##_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(glm::vec4) * pixels_);
  XI_FILM_BUFFERS(XI_ALLOCATE_FILM_BUFFER)
#undef XI_ALLOCATE_FILM_BUFFER
  pixel_list_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * (adaptive() ? pixels_ : 1));
  cl::CommandQueue& q = device_.queue();
#define XI_CLEAR_FILM_BUFFER(name) q.enqueueFillBuffer(film_##name##_, 0.0f, 0, sizeof(glm::vec4) * pixels_);
  XI_FILM_BUFFERS(XI_CLEAR_FILM_BUFFER)
#undef XI_CLEAR_FILM_BUFFER
  q.enqueueFillBuffer(counters_, 0u, 0, sizeof(uint32_t) * counter_count_);
  q.finish();
}

int Renderer::bind_path_state(cl::Kernel& kernel) const {
  int arg = 0;
#define XI_BIND_BUFFER(type, name) kernel.setArg(arg++, name##_);
  XI_PATH_STATE(XI_BIND_BUFFER)
  return arg;
}

int Renderer::bind_shadow_state(cl::Kernel& kernel, int arg) const {
  XI_SHADOW_STATE(XI_BIND_BUFFER)
  return arg;
}
#undef XI_BIND_BUFFER

// Enqueues without waiting: the in-order queue runs the stages one after the other. Only with
// profiling does a launch carry an event, read when the pass is done.
void Renderer::launch(cl::Kernel& kernel, const char* stage, int bounce, size_t global_items,
                      size_t items_per_work_item) {
  cl::Event event;
  enqueue_items(device_.queue(), kernel, global_items, items_per_work_item, options_.local_size,
                options_.profile ? &event : nullptr);
  if (options_.profile) {
    launches_.push_back(Launch{stage, passes_, bounce, global_items, 0, 0, global_items});
    launch_events_.push_back(event);
  }
}

// Each stage's arguments in the order its kernel declares them.

void Renderer::bind_generate(cl::Kernel& kernel, const WaveParams& wave, const cl::Buffer& counters) const {
  int arg = bind_path_state(kernel);
  kernel.setArg(arg++, queue_a_);
  kernel.setArg(arg++, counters);
  kernel.setArg(arg++, pixel_list_);
  kernel.setArg(arg++, scene_.camera);
  kernel.setArg(arg++, sampler_params());
  kernel.setArg(arg++, kernels_.shading_word());
  kernel.setArg(arg++, wave);
}

void Renderer::generate(const WaveParams& wave) {
  bind_generate(generate_, wave, counters_);
  launch(generate_, "generate", -1, (size_t)wave.pixels * wave.samples, (size_t)kernels_.lanes);
}

void Renderer::extend(const cl::Buffer& queue, int bounce, size_t global) {
  int arg = bind_path_state(extend_);
  extend_.setArg(arg++, queue);
  extend_.setArg(arg++, counters_);
  extend_.setArg(arg++, (uint32_t)bounce);
  extend_.setArg(arg++, nodes_);
  extend_.setArg(arg++, tri_blocks_);
  launch(extend_, "extend", bounce, global,
         XI_RAYS_PER_ITEM(XI_EXTEND_RAYS(kernels_.bvh_width, bounce, kernels_.ray_packets, kernels_.hybrid_packets),
                          kernels_.packet_width));
}

// The scene's buffers in their lists' order: the surface buffers (shadow), all of them with the
// light count and the environment (shade).
#define XI_BIND_SCENE_BUFFER(type, name) kernel.setArg(arg++, name##_);
int Renderer::bind_surface_buffers(cl::Kernel& kernel, int arg) const {
  XI_SURFACE_BUFFERS(XI_BIND_SCENE_BUFFER)
  return arg;
}

int Renderer::bind_scene(cl::Kernel& kernel, int arg) const {
  XI_SCENE_BUFFERS(XI_BIND_SCENE_BUFFER)
  kernel.setArg(arg++, light_count_);
  kernel.setArg(arg++, scene_.environment);
  return arg;
}
#undef XI_BIND_SCENE_BUFFER

void Renderer::bind_shade(cl::Kernel& kernel, const cl::Buffer& queue_in, const cl::Buffer& queue_out, int bounce,
                          const cl::Buffer& counters) const {
  int arg = bind_path_state(kernel);
  kernel.setArg(arg++, queue_in);
  kernel.setArg(arg++, queue_out);
  arg = bind_shadow_state(kernel, arg);
  kernel.setArg(arg++, counters);
  kernel.setArg(arg++, (uint32_t)bounce);
  arg = bind_scene(kernel, arg);
  kernel.setArg(arg++, sampler_params());
  kernel.setArg(arg++, kernels_.shading_word());
  kernel.setArg(arg++, (uint32_t)options_.max_depth);
  kernel.setArg(arg++, scene_.background);
}

void Renderer::shade(const cl::Buffer& queue_in, const cl::Buffer& queue_out, int bounce, size_t global) {
  bind_shade(shade_, queue_in, queue_out, bounce, counters_);
  launch(shade_, "shade", bounce, global, (size_t)kernels_.lanes);
}

void Renderer::shadow(int bounce, size_t global) {
  int arg = bind_shadow_state(shadow_, bind_path_state(shadow_));
  shadow_.setArg(arg++, counters_);
  shadow_.setArg(arg++, (uint32_t)bounce);
  shadow_.setArg(arg++, nodes_);
  shadow_.setArg(arg++, tri_blocks_);
  arg = bind_surface_buffers(shadow_, arg);
  shadow_.setArg(arg++, options_.seed);
  launch(shadow_, "shadow", bounce, global,
         XI_RAYS_PER_ITEM(XI_SHADOW_RAYS(kernels_.bvh_width, bounce, kernels_.ray_packets, kernels_.hybrid_packets),
                          kernels_.packet_width));
}

void Renderer::bind_accumulate(const WaveParams& wave) {
  int arg = bind_path_state(accumulate_);
#define XI_BIND_FILM_BUFFER(name) accumulate_.setArg(arg++, film_##name##_);
  XI_FILM_BUFFERS(XI_BIND_FILM_BUFFER)
#undef XI_BIND_FILM_BUFFER
  accumulate_.setArg(arg++, counters_);
  accumulate_.setArg(arg++, pixel_list_);
  accumulate_.setArg(arg++, wave);
}

void Renderer::accumulate(const WaveParams& wave) {
  bind_accumulate(wave);
  launch(accumulate_, "accumulate", -1, wave.pixels);
}

SamplerParams Renderer::sampler_params() const {
  return xi_make_sampler_params(options_.seed, (uint32_t)options_.spp);
}

// One wave: generate; extend, shade and shadow until no path is left; accumulate. The kernels read
// their queue lengths on the device, so the host need not wait for a bounce to finish. A GPU does
// not: it launches bounce b + 1 over the length of bounce b's queue (a bound, since paths only end)
// and bounce b's shadow rays over it too (at most one per path), each length read back without
// stalling, the copy being queued right after the shade that counted it. A CPU device waits for the
// lengths shade b counts, and launches shadow b and bounce b + 1 over exactly those: PoCL hands a
// launch's work groups to its threads in large contiguous chunks, so over a loose bound the live
// groups, all at the front, fall in one thread's chunk while the others draw groups that exit at
// once, and the launch takes as long as one thread alone would. Host and device share the
// cores there, so the wait costs only a launch's latency.
void Renderer::run_wave(const WaveParams& wave) {
  cl::CommandQueue& q = device_.queue();
  q.enqueueFillBuffer(counters_, 0u, sizeof(uint32_t), sizeof(uint32_t) * (counter_count_ - 1));  // keeps NONFINITE
  wave_first_launch_.push_back(launches_.size());
  generate(wave);
  std::vector<cl::Event> counted(options_.max_depth + 1);  // counted[b]: what shade b counted arrived
  const cl::Buffer* in = &queue_a_;
  const cl::Buffer* out = &queue_b_;
  size_t bound = (size_t)wave.pixels * wave.samples;
  for (int bounce = 0; bounce <= options_.max_depth && bound > 0; ++bounce) {
    if (probe_) probe_->entering_extend(*in, bounce);
    extend(*in, bounce, bound);
    shade(*in, *out, bounce, bound);
    static_assert(XI_COUNTER_RAYS(1) == XI_COUNTER_SHADOW(0) + 1, "shade's two counts are adjacent");
    q.enqueueReadBuffer(counters_, CL_FALSE, sizeof(uint32_t) * XI_COUNTER_SHADOW(bounce), 2 * sizeof(uint32_t),
                        &queue_counts_[XI_COUNTER_SHADOW(bounce)], nullptr, &counted[bounce]);
    if (probe_) probe_->leaving_shade(bounce);
    if (exact_bounds_) {
      counted[bounce].wait();
      shadow(bounce, queue_counts_[XI_COUNTER_SHADOW(bounce)]);
      bound = queue_counts_[XI_COUNTER_RAYS(bounce + 1)];
    } else {
      shadow(bounce, bound);
      if (bounce > 0) {  // this bounce's queue length, known once the previous shade is done
        counted[bounce - 1].wait();
        bound = queue_counts_[XI_COUNTER_RAYS(bounce)];
      }
    }
    std::swap(in, out);
  }
  accumulate(wave);
  wave_counters_.emplace_back(counter_count_);
  q.enqueueReadBuffer(counters_, CL_FALSE, 0, sizeof(uint32_t) * counter_count_, wave_counters_.back().data());
}

void Renderer::limit_samples_per_pass(int n) {
  if (n < 1) throw Error("samples per pass must be at least 1");
  samples_per_pass_ = std::min(samples_per_pass_, n);  // the path state holds fewer at once
}

WaveParams Renderer::wave(size_t first_pixel, size_t pixels, int first_sample, uint32_t samples, bool listed) const {
  return WaveParams{(uint32_t)first_pixel, (uint32_t)pixels, (uint32_t)first_sample, samples, scene_.camera.width,
                    (uint32_t)options_.rows.first, (uint32_t)options_.rows.stride, listed ? 1u : 0u};
}

// The spp of the next pass: samples_per_pass(), but no further than spp, and with adaptive sampling
// no further than the next check; as pixels stop, the paths in flight hold more samples of those
// left (unless --samples-per-pass fixed the pass).
uint32_t Renderer::pass_samples() const {
  int samples = samples_per_pass_;
  if (adaptive()) {
    if (options_.samples_per_pass == 0)
      samples = (int)std::clamp<size_t>(paths_ / active_.size(), (size_t)samples, (size_t)options_.spp);
    samples = std::min(samples, next_check_ - spp_done_);
  }
  return (uint32_t)std::min(samples, options_.spp - spp_done_);
}

void Renderer::run_pass() {
  if (done()) return;
  take_scene_shading(false);
  const uint32_t samples = pass_samples();
  const size_t pixels = sampling_pixels();
  const bool listed = pixels < pixels_;  // some have stopped: the waves go through the list
  const size_t pixels_per_wave = paths_ / samples;  // all pixels when samples > 1
  for (size_t first = 0; first < pixels; first += pixels_per_wave)
    run_wave(wave(first, std::min(pixels_per_wave, pixels - first), spp_done_, samples, listed));
  finish_pass();
  spp_done_ += (int)samples;
  samples_taken_ += (uint64_t)pixels * samples;
  passes_++;
  if (adaptive() && spp_done_ >= next_check_) check_pixels();
}

// Every pixel still sampling has taken spp_done_ samples: those whose error is below the threshold
// stop here, unless a neighbour in the same row is still above it. A few samples can miss what
// makes a pixel noisy (a rare bright path), and its neighbours, which see much the same, are a
// second opinion; rows, not columns, since the processes of a distributed render hold interleaved
// rows. The decision reads only the row's own sums, so the image does not depend on waves,
// passes or processes.
void Renderer::check_pixels() {
  const std::vector<glm::vec4> sum = read(film_sum_), sum_sq = read(film_sum_sq_);
  std::vector<uint8_t> noisy(pixels_, 0);
  for (uint32_t p : active_) noisy[p] = !(pixel_relative_error(sum[p], sum_sq[p]) < options_.noise_threshold);
  const uint32_t width = scene_.camera.width;
  std::vector<uint32_t> still;
  still.reserve(active_.size());
  for (uint32_t p : active_) {
    const uint32_t x = p % width;
    const bool near_noisy = noisy[p] || (x > 0 && noisy[p - 1]) || (x + 1 < width && noisy[p + 1]);
    if (near_noisy) still.push_back(p);
  }
  active_.swap(still);
  if (!active_.empty())
    device_.queue().enqueueWriteBuffer(pixel_list_, CL_TRUE, 0, sizeof(uint32_t) * active_.size(), active_.data());
  next_check_ = adaptive_check_after(spp_done_);
}

// After a restore: the pixels that have taken spp_done_ samples are those still sampling, and if
// spp_done_ is a check's count, that check (made before the state was saved) is made again, with
// the same outcome.
void Renderer::list_sampling_pixels(const std::vector<glm::vec4>& albedo) {
  active_.clear();
  for (size_t i = 0; i < pixels_; ++i)
    if (albedo[i].w == (float)spp_done_) active_.push_back((uint32_t)i);
  if (!active_.empty())
    device_.queue().enqueueWriteBuffer(pixel_list_, CL_TRUE, 0, sizeof(uint32_t) * active_.size(), active_.data());
  next_check_ = std::min(options_.min_spp, options_.spp);
  while (next_check_ < spp_done_) next_check_ = adaptive_check_after(next_check_);
  if (next_check_ == spp_done_ && spp_done_ < options_.spp) check_pixels();
}

void Renderer::render() {
  while (!done()) run_pass();
}

// Waits for the pass, then takes the queue lengths of its waves (ray counts; with profiling, the
// items of each launch and its times).
void Renderer::finish_pass() {
  device_.queue().finish();
  for (size_t w = 0; w < wave_counters_.size(); ++w) {
    const std::vector<uint32_t>& c = wave_counters_[w];
    for (int b = 0; b <= options_.max_depth; ++b) {
      extend_rays_ += c[XI_COUNTER_RAYS(b)];
      shadow_rays_ += c[XI_COUNTER_SHADOW(b)];
    }
    if (!options_.profile) continue;
    const size_t end = w + 1 < wave_first_launch_.size() ? wave_first_launch_[w + 1] : launches_.size();
    for (size_t i = wave_first_launch_[w]; i < end; ++i) {
      Launch& l = launches_[i];
      if (l.bounce >= 0)
        l.items = c[std::string(l.stage) == "shadow" ? XI_COUNTER_SHADOW(l.bounce) : XI_COUNTER_RAYS(l.bounce)];
    }
  }
  for (size_t i = launches_.size() - launch_events_.size(), k = 0; k < launch_events_.size(); ++i, ++k) {
    launches_[i].start_ns = launch_events_[k].getProfilingInfo<CL_PROFILING_COMMAND_START>();
    launches_[i].end_ns = launch_events_[k].getProfilingInfo<CL_PROFILING_COMMAND_END>();
  }
  launch_events_.clear();
  wave_counters_.clear();
  wave_first_launch_.clear();
}

// Launches every stage with no work (every queue is empty), small and large, so that a driver that
// compiles per launch configuration (PoCL with work-group specialisation) does it now, counted in
// the kernel build, not in a pass.
void Renderer::warm_up() {
  bind_generate(generate_, wave(0, 1, 0, 0), counters_);  // no items; one pixel so that nothing divides by zero
  bind_accumulate(wave(0, 0, 0, 0));
  for (size_t items : {(size_t)1, kLargeLaunch}) {
    launch(generate_, "generate", -1, items, (size_t)kernels_.lanes);
    extend(queue_a_, 0, items);
    shade(queue_a_, queue_b_, 0, items);
    shadow(0, items);
    launch(accumulate_, "accumulate", -1, items);
  }
  device_.queue().finish();
  launches_.clear();
  launch_events_.clear();
}

uint64_t Renderer::scene_hash() const {
  Hasher h;
  // The device's copies of what the host no longer holds, a slice at a time.
  auto add_device = [&](const cl::Buffer& buffer) {
    std::vector<unsigned char> slice((size_t)1 << 24);
    const size_t bytes = buffer.getInfo<CL_MEM_SIZE>();
    for (size_t offset = 0; offset < bytes; offset += slice.size()) {
      const size_t n = std::min(slice.size(), bytes - offset);
      device_.queue().enqueueReadBuffer(buffer, CL_TRUE, offset, n, slice.data());
      h.add(slice.data(), n);
    }
  };
  for (const cl::Buffer* b : {&tri_vertices_, &vertices_, &tri_material_, &materials_, &light_cdf_, &light_tri_,
                              &tri_light_pdf_})
    add_device(*b);
  h.add(&scene_.camera, sizeof scene_.camera);
  h.add(&scene_.background, sizeof scene_.background);
  return h.h;
}

std::vector<glm::vec4> Renderer::read(const cl::Buffer& film) const {
  std::vector<glm::vec4> v(pixels_);
  device_.queue().enqueueReadBuffer(film, CL_TRUE, 0, sizeof(glm::vec4) * pixels_, v.data());
  return v;
}

Image Renderer::mean() const {
  auto sum = read(film_sum_);
  Image img(film_width(), film_height());
  for (size_t i = 0; i < pixels_; ++i)
    if (sum[i].w > 0.0f) img.pixels[i] = glm::vec3(sum[i]) / sum[i].w;  // w: the sample count
  return img;
}

Film Renderer::film() const { return resolve_film(state(), film_width(), film_height()); }

RenderState Renderer::state() const {
  RenderState st;
  st.spp_done = spp_done_;
  st.passes = passes_;
  st.extend_rays = extend_rays_;
  st.shadow_rays = shadow_rays_;
  st.nonfinite = nonfinite_samples();
#define XI_READ_FILM_BUFFER(name) st.name = read(film_##name##_);
  XI_FILM_BUFFERS(XI_READ_FILM_BUFFER)
#undef XI_READ_FILM_BUFFER
  return st;
}

void Renderer::restore(const RenderState& st) {
  check_film_pixels(st, pixels_, "the render state");
  if (st.spp_done < 0 || st.spp_done > options_.spp)
    throw Error("render state has " + std::to_string(st.spp_done) + " spp, the render " + std::to_string(options_.spp));
  cl::CommandQueue& q = device_.queue();
#define XI_WRITE_FILM_BUFFER(name) \
  q.enqueueWriteBuffer(film_##name##_, CL_TRUE, 0, sizeof(glm::vec4) * pixels_, st.name.data());
  XI_FILM_BUFFERS(XI_WRITE_FILM_BUFFER)
#undef XI_WRITE_FILM_BUFFER
  q.enqueueWriteBuffer(counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_NONFINITE, sizeof st.nonfinite,
                      &st.nonfinite);
  spp_done_ = st.spp_done;
  passes_ = st.passes;
  extend_rays_ = st.extend_rays;
  shadow_rays_ = st.shadow_rays;
  samples_taken_ = 0;
  for (const glm::vec4& a : st.albedo) samples_taken_ += (uint64_t)a.w;
  if (adaptive()) list_sampling_pixels(st.albedo);
}

uint32_t Renderer::nonfinite_samples() const {
  uint32_t c = 0;
  device_.queue().enqueueReadBuffer(counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_NONFINITE, sizeof c, &c);
  return c;
}

}  // namespace xi
