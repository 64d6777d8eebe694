#include <algorithm>
#include <chrono>

#include "xi/error.h"
#include "xi/render.h"

namespace xi {
namespace {

// The kernel files, one per wavefront stage, built into one program.
const std::vector<std::string> kStageFiles = {"generate.cl", "extend.cl", "shade.cl", "shadow.cl",
                                              "accumulate.cl"};

template <typename T>
cl::Buffer upload(cl::Context& ctx, const std::vector<T>& data) {
  return cl::Buffer(ctx, CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, sizeof(T) * data.size(),
                    const_cast<T*>(data.data()));
}

}  // namespace

Renderer::Renderer(Device& device, const Scene& scene, const RenderOptions& options)
    : device_(device), options_(options), scene_(compile_scene(scene)) {
  if (options.spp < 1) throw Error("spp must be at least 1", "--spp");
  if (options.max_depth < 1 || options.max_depth > 64) throw Error("max depth must be in 1..64", "--max-depth");
  Features f = options.all_features ? Features::everything() : scene_.features;
  program_ = build_program(device, kStageFiles, kernel_defines(f, options.sampler, options.strategy));
  generate_ = cl::Kernel(program_.program, "generate");
  extend_ = cl::Kernel(program_.program, "extend");
  shade_ = cl::Kernel(program_.program, "shade");
  shadow_ = cl::Kernel(program_.program, "shadow");
  accumulate_ = cl::Kernel(program_.program, "accumulate");

  cl::Context& ctx = device.context();
  pixels_ = (size_t)scene.width * scene.height;
  wave_ = std::min(pixels_, std::max<size_t>(options.wave_pixels, 1));
#define XI_ALLOCATE_BUFFER(type, name) name##_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(type) * wave_);
  XI_PATH_STATE(XI_ALLOCATE_BUFFER)
  XI_SHADOW_STATE(XI_ALLOCATE_BUFFER)
#undef XI_ALLOCATE_BUFFER
  queue_a_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * wave_);
  queue_b_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * wave_);
  counters_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(uint32_t) * XI_COUNTER_COUNT);
  nodes_ = upload(ctx, scene_.bvh.nodes);
  tri_verts_ = upload(ctx, scene_.tri_verts);
  tri_normals_ = upload(ctx, scene_.tri_normals);
  tri_material_ = upload(ctx, scene_.tri_material);
  materials_ = upload(ctx, scene_.materials);
  light_cdf_ = upload(ctx, scene_.light_cdf);
  light_tri_ = upload(ctx, scene_.light_tri);
  tri_light_pdf_ = upload(ctx, scene_.tri_light_pdf);
  film_sum_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(glm::vec4) * pixels_);
  film_sum_sq_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(glm::vec4) * pixels_);
  film_albedo_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(glm::vec4) * pixels_);
  film_normal_ = cl::Buffer(ctx, CL_MEM_READ_WRITE, sizeof(glm::vec4) * pixels_);
  cl::CommandQueue& q = device.queue();
  for (cl::Buffer* b : {&film_sum_, &film_sum_sq_, &film_albedo_, &film_normal_})
    q.enqueueFillBuffer(*b, 0.0f, 0, sizeof(glm::vec4) * pixels_);
  q.enqueueFillBuffer(counters_, 0u, 0, sizeof(uint32_t) * XI_COUNTER_COUNT);
  q.finish();
  auto start = std::chrono::steady_clock::now();
  warm_up();
  program_.build_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int Renderer::bind_path_state(cl::Kernel& kernel) {
  int arg = 0;
#define XI_BIND_BUFFER(type, name) kernel.setArg(arg++, name##_);
  XI_PATH_STATE(XI_BIND_BUFFER)
  return arg;
}

int Renderer::bind_shadow_state(cl::Kernel& kernel, int arg) {
  XI_SHADOW_STATE(XI_BIND_BUFFER)
  return arg;
}
#undef XI_BIND_BUFFER

void Renderer::launch(cl::Kernel& kernel, const char* stage, int bounce, size_t items) {
  size_t local = options_.local_size;
  // Zero items (the warm-up) launches a full wave whose work items return at once: PoCL specialises
  // its compiled work-group functions on the launch size, so a small dummy launch would not do.
  size_t n = items > 0 ? items : wave_;
  size_t global = local ? (n + local - 1) / local * local : n;
  cl::Event event;
  device_.queue().enqueueNDRangeKernel(kernel, cl::NullRange, cl::NDRange(global),
                                       local ? cl::NDRange(local) : cl::NullRange, nullptr, &event);
  event.wait();  // keeps the timings per stage honest; the in-order queue serialises them anyway
  if (items > 0)
    launches_.push_back(Launch{stage, passes_, bounce, items, event.getProfilingInfo<CL_PROFILING_COMMAND_START>(),
                               event.getProfilingInfo<CL_PROFILING_COMMAND_END>()});
}

// Each stage's arguments in the order its kernel declares them.

void Renderer::generate(uint32_t first, uint32_t count) {
  int arg = bind_path_state(generate_);
  generate_.setArg(arg++, queue_a_);
  generate_.setArg(arg++, scene_.camera);
  generate_.setArg(arg++, sampler_params());
  generate_.setArg(arg++, first);
  generate_.setArg(arg++, count);
  generate_.setArg(arg++, (uint32_t)passes_);
  launch(generate_, "generate", -1, count);
}

void Renderer::extend(const cl::Buffer& queue, uint32_t count, int bounce) {
  int arg = bind_path_state(extend_);
  extend_.setArg(arg++, queue);
  extend_.setArg(arg++, count);
  extend_.setArg(arg++, nodes_);
  extend_.setArg(arg++, tri_verts_);
  launch(extend_, "extend", bounce, count);
  extend_rays_ += count;
}

void Renderer::shade(const cl::Buffer& queue_in, uint32_t count, const cl::Buffer& queue_out, uint32_t first,
                     int bounce) {
  static const uint32_t zeros[2] = {0, 0};  // the output queue and the shadow queue start empty
  device_.queue().enqueueWriteBuffer(counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_RAYS_OUT, sizeof zeros, zeros);
  int arg = bind_path_state(shade_);
  shade_.setArg(arg++, queue_in);
  shade_.setArg(arg++, count);
  shade_.setArg(arg++, queue_out);
  arg = bind_shadow_state(shade_, arg);
  shade_.setArg(arg++, counters_);
  shade_.setArg(arg++, materials_);
  shade_.setArg(arg++, tri_verts_);
  shade_.setArg(arg++, tri_material_);
  shade_.setArg(arg++, tri_normals_);
  shade_.setArg(arg++, light_cdf_);
  shade_.setArg(arg++, light_tri_);
  shade_.setArg(arg++, tri_light_pdf_);
  shade_.setArg(arg++, scene_.features.emitters ? (uint32_t)scene_.light_tri.size() : 0u);
  shade_.setArg(arg++, sampler_params());
  shade_.setArg(arg++, first);
  shade_.setArg(arg++, (uint32_t)passes_);
  shade_.setArg(arg++, (uint32_t)options_.max_depth);
  shade_.setArg(arg++, scene_.background);
  launch(shade_, "shade", bounce, count);
}

void Renderer::shadow(uint32_t count, int bounce) {
  int arg = bind_shadow_state(shadow_, bind_path_state(shadow_));
  shadow_.setArg(arg++, count);
  shadow_.setArg(arg++, nodes_);
  shadow_.setArg(arg++, tri_verts_);
  launch(shadow_, "shadow", bounce, count);
  shadow_rays_ += count;
}

void Renderer::accumulate(uint32_t first, uint32_t count) {
  int arg = bind_path_state(accumulate_);
  accumulate_.setArg(arg++, film_sum_);
  accumulate_.setArg(arg++, film_sum_sq_);
  accumulate_.setArg(arg++, film_albedo_);
  accumulate_.setArg(arg++, film_normal_);
  accumulate_.setArg(arg++, counters_);
  accumulate_.setArg(arg++, first);
  accumulate_.setArg(arg++, count);
  launch(accumulate_, "accumulate", -1, count);
}

SamplerParams Renderer::sampler_params() const {
  return xi_make_sampler_params(options_.seed, (uint32_t)options_.spp);
}

// The wavefront: generate; extend, shade and shadow until no path is left; accumulate.
void Renderer::run_pass() {
  for (size_t first = 0; first < pixels_; first += wave_) {
    const uint32_t count = (uint32_t)std::min(wave_, pixels_ - first);
    generate((uint32_t)first, count);
    const cl::Buffer* in = &queue_a_;
    const cl::Buffer* out = &queue_b_;
    uint32_t rays = count;
    for (int bounce = 0; rays > 0; ++bounce) {
      if (bounce == options_.record_bounce) record(*in, rays);
      extend(*in, rays, bounce);
      shade(*in, rays, *out, (uint32_t)first, bounce);
      uint32_t counts[2];  // rays out, shadow rays
      device_.queue().enqueueReadBuffer(counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_RAYS_OUT, sizeof counts,
                                        counts);
      if (counts[1] > 0) shadow(counts[1], bounce);
      rays = counts[0];
      std::swap(in, out);
    }
    accumulate((uint32_t)first, count);
  }
  passes_++;
}

void Renderer::record(const cl::Buffer& queue, uint32_t count) {
  std::vector<uint32_t> slots(count);
  std::vector<glm::vec4> org(wave_), dir(wave_);
  cl::CommandQueue& q = device_.queue();
  q.enqueueReadBuffer(queue, CL_TRUE, 0, sizeof(uint32_t) * count, slots.data());
  q.enqueueReadBuffer(ray_org_, CL_TRUE, 0, sizeof(glm::vec4) * wave_, org.data());
  q.enqueueReadBuffer(ray_dir_, CL_TRUE, 0, sizeof(glm::vec4) * wave_, dir.data());
  for (uint32_t s : slots) {
    recorded_.org.push_back(org[s]);
    recorded_.dir.push_back(dir[s]);
  }
}

double Renderer::trace_closest(const RayBatch& rays, std::vector<glm::vec4>* hits) {
  const size_t n = rays.org.size();
  if (n > wave_ || rays.dir.size() != n) throw Error("ray batch larger than the wave or malformed");
  cl::CommandQueue& q = device_.queue();
  std::vector<uint32_t> identity(n);
  for (size_t i = 0; i < n; ++i) identity[i] = (uint32_t)i;
  q.enqueueWriteBuffer(ray_org_, CL_TRUE, 0, sizeof(glm::vec4) * n, rays.org.data());
  q.enqueueWriteBuffer(ray_dir_, CL_TRUE, 0, sizeof(glm::vec4) * n, rays.dir.data());
  q.enqueueWriteBuffer(queue_a_, CL_TRUE, 0, sizeof(uint32_t) * n, identity.data());
  extend(queue_a_, (uint32_t)n, 0);
  const Launch& l = launches_.back();
  hits->resize(n);
  q.enqueueReadBuffer(hit_, CL_TRUE, 0, sizeof(glm::vec4) * n, hits->data());
  return (l.end_ns - l.start_ns) * 1e-9;
}

// Launches every stage once with no work, so a driver that compiles per launch configuration
// (PoCL) does it now, counted in the kernel build, not in the first pass.
void Renderer::warm_up() {
  generate(0, 0);
  extend(queue_a_, 0, 0);
  shade(queue_a_, 0, queue_b_, 0, 0);
  shadow(0, 0);
  accumulate(0, 0);
}

std::vector<glm::vec4> Renderer::read(const cl::Buffer& film) const {
  std::vector<glm::vec4> v(pixels_);
  device_.queue().enqueueReadBuffer(film, CL_TRUE, 0, sizeof(glm::vec4) * pixels_, v.data());
  return v;
}

Image Renderer::mean() const {
  auto sum = read(film_sum_);
  Image img((int)scene_.camera.width, (int)scene_.camera.height);
  for (size_t i = 0; i < pixels_; ++i)
    if (sum[i].w > 0.0f) img.pixels[i] = glm::vec3(sum[i]) / sum[i].w;  // w: the sample count
  return img;
}

Renderer::Film Renderer::film() const {
  auto sum = read(film_sum_), sq = read(film_sum_sq_), albedo = read(film_albedo_), normal = read(film_normal_);
  const int w = (int)scene_.camera.width, h = (int)scene_.camera.height;
  Film f{Image(w, h), Image(w, h), Image(w, h), Image(w, h)};
  for (size_t i = 0; i < pixels_; ++i) {
    float n = sum[i].w;
    if (n <= 0.0f) continue;
    glm::vec3 m = glm::vec3(sum[i]) / n;
    f.mean.pixels[i] = m;
    f.albedo.pixels[i] = glm::vec3(albedo[i]) / n;
    glm::vec3 nn = glm::vec3(normal[i]);
    f.normal.pixels[i] = glm::length(nn) > 0.0f ? glm::normalize(nn) : nn;
    if (n >= 2.0f) f.variance.pixels[i] = glm::max((glm::vec3(sq[i]) - n * m * m) / (n - 1.0f), glm::vec3(0.0f)) / n;
  }
  return f;
}

uint32_t Renderer::nonfinite_samples() const {
  uint32_t c[XI_COUNTER_COUNT];
  device_.queue().enqueueReadBuffer(counters_, CL_TRUE, 0, sizeof c, c);
  return c[XI_COUNTER_NONFINITE];
}

}  // namespace xi
