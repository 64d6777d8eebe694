#include <algorithm>

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
  cl::CommandQueue& q = device.queue();
  q.enqueueFillBuffer(film_sum_, 0.0f, 0, sizeof(glm::vec4) * pixels_);
  q.enqueueFillBuffer(film_sum_sq_, 0.0f, 0, sizeof(glm::vec4) * pixels_);
  q.enqueueFillBuffer(counters_, 0u, 0, sizeof(uint32_t) * XI_COUNTER_COUNT);
  q.finish();
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
  size_t global = local ? (items + local - 1) / local * local : items;
  cl::Event event;
  device_.queue().enqueueNDRangeKernel(kernel, cl::NullRange, cl::NDRange(global),
                                       local ? cl::NDRange(local) : cl::NullRange, nullptr, &event);
  event.wait();  // keeps the timings per stage honest; the queue would serialise them anyway
  launches_.push_back(Launch{stage, passes_, bounce, items,
                             event.getProfilingInfo<CL_PROFILING_COMMAND_START>(),
                             event.getProfilingInfo<CL_PROFILING_COMMAND_END>()});
}

void Renderer::run_pass() {
  cl::CommandQueue& q = device_.queue();
  const uint32_t sample = (uint32_t)passes_;
  SamplerParams sp = xi_make_sampler_params(options_.seed, (uint32_t)options_.spp);
  for (size_t first = 0; first < pixels_; first += wave_) {
    const uint32_t count = (uint32_t)std::min(wave_, pixels_ - first);
    int arg = bind_path_state(generate_);
    generate_.setArg(arg++, queue_a_);
    generate_.setArg(arg++, scene_.camera);
    generate_.setArg(arg++, sp);
    generate_.setArg(arg++, (uint32_t)first);
    generate_.setArg(arg++, count);
    generate_.setArg(arg++, sample);
    launch(generate_, "generate", -1, count);

    cl::Buffer* in = &queue_a_;
    cl::Buffer* out = &queue_b_;
    uint32_t rays = count;
    for (int bounce = 0; rays > 0; ++bounce) {
      arg = bind_path_state(extend_);
      extend_.setArg(arg++, *in);
      extend_.setArg(arg++, rays);
      extend_.setArg(arg++, nodes_);
      extend_.setArg(arg++, tri_verts_);
      launch(extend_, "extend", bounce, rays);
      extend_rays_ += rays;

      static const uint32_t zeros[2] = {0, 0};
      q.enqueueWriteBuffer(counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_RAYS_OUT, sizeof zeros, zeros);
      arg = bind_path_state(shade_);
      shade_.setArg(arg++, *in);
      shade_.setArg(arg++, rays);
      shade_.setArg(arg++, *out);
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
      shade_.setArg(arg++, sp);
      shade_.setArg(arg++, (uint32_t)first);
      shade_.setArg(arg++, sample);
      shade_.setArg(arg++, (uint32_t)options_.max_depth);
      shade_.setArg(arg++, scene_.background);
      launch(shade_, "shade", bounce, rays);

      uint32_t counts[2];
      q.enqueueReadBuffer(counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_RAYS_OUT, sizeof counts, counts);
      const uint32_t shadows = counts[XI_COUNTER_SHADOW - XI_COUNTER_RAYS_OUT];
      if (shadows > 0) {
        arg = bind_shadow_state(shadow_, bind_path_state(shadow_));
        shadow_.setArg(arg++, shadows);
        shadow_.setArg(arg++, nodes_);
        shadow_.setArg(arg++, tri_verts_);
        launch(shadow_, "shadow", bounce, shadows);
        shadow_rays_ += shadows;
      }
      rays = counts[0];
      std::swap(in, out);
    }

    arg = bind_path_state(accumulate_);
    accumulate_.setArg(arg++, film_sum_);
    accumulate_.setArg(arg++, film_sum_sq_);
    accumulate_.setArg(arg++, counters_);
    accumulate_.setArg(arg++, (uint32_t)first);
    accumulate_.setArg(arg++, count);
    launch(accumulate_, "accumulate", -1, count);
  }
  passes_++;
}

void Renderer::read_film(std::vector<glm::vec4>* sum, std::vector<glm::vec4>* sum_sq) const {
  sum->resize(pixels_);
  device_.queue().enqueueReadBuffer(film_sum_, CL_TRUE, 0, sizeof(glm::vec4) * pixels_, sum->data());
  if (sum_sq) {
    sum_sq->resize(pixels_);
    device_.queue().enqueueReadBuffer(film_sum_sq_, CL_TRUE, 0, sizeof(glm::vec4) * pixels_, sum_sq->data());
  }
}

Image Renderer::mean() const {
  std::vector<glm::vec4> sum;
  read_film(&sum, nullptr);
  Image img((int)scene_.camera.width, (int)scene_.camera.height);
  for (size_t i = 0; i < pixels_; ++i)
    img.pixels[i] = sum[i].w > 0.0f ? glm::vec3(sum[i]) / sum[i].w : glm::vec3(0.0f);
  return img;
}

Image Renderer::variance_of_mean() const {
  std::vector<glm::vec4> sum, sq;
  read_film(&sum, &sq);
  Image img((int)scene_.camera.width, (int)scene_.camera.height);
  for (size_t i = 0; i < pixels_; ++i) {
    float n = sum[i].w;
    if (n < 2.0f) continue;
    glm::vec3 m = glm::vec3(sum[i]) / n;
    glm::vec3 s2 = glm::max((glm::vec3(sq[i]) - n * m * m) / (n - 1.0f), glm::vec3(0.0f));
    img.pixels[i] = s2 / n;
  }
  return img;
}

uint32_t Renderer::nonfinite_samples() const {
  uint32_t c[XI_COUNTER_COUNT];
  device_.queue().enqueueReadBuffer(counters_, CL_TRUE, 0, sizeof c, c);
  return c[XI_COUNTER_NONFINITE];
}

}  // namespace xi
