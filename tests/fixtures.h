// Fixtures shared by the test files: the device every library test renders on, the one builder of
// render options, renders through the library, block statistics of a render, and scoped test state
// (environment variables, temporary folders).
#pragma once
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#include <gtest/gtest.h>

#include "sampling.h"
#include "xi/device.h"
#include "xi/image.h"
#include "xi/kernel_config.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace xi::test {

// The default OpenCL device ($XI_DEVICE, else the first CPU), opened once for the test binary.
inline Device& device() {
  static Device d = Device::open("");
  return d;
}

// The render options the tests set: samples per pixel, seed, strategy, depth and sampler. The
// random sampler by default: independent samples, so the film's variance of the mean is unbiased.
// The other fields keep RenderOptions' defaults; a test that needs one sets it on the result.
inline RenderOptions render_options(int spp, uint32_t seed, Strategy strategy = Strategy::Mis, int max_depth = 8,
                                    int sampler = XI_SAMPLER_RANDOM) {
  RenderOptions o;
  o.spp = spp;  // also tells grid / stratified / sobol how large the sample set is
  o.seed = seed;
  o.strategy = strategy;
  o.max_depth = max_depth;
  o.sampler = sampler;
  return o;
}

// A render through the library on that device: the mean, the variance of each pixel's mean, the
// mean first-hit albedo, and how many samples were dropped as non-finite.
struct Shot {
  Image mean, variance, albedo;
  uint32_t nonfinite = 0;
};

inline Shot render_shot(const Scene& scene, const RenderOptions& options) {
  Renderer r(device(), scene, options);
  r.render();
  Film f = r.film();
  return {std::move(f.mean), std::move(f.variance), std::move(f.albedo), r.nonfinite_samples()};
}

// The same at a resolution of w × h.
inline Shot render_shot(Scene scene, int w, int h, const RenderOptions& options) {
  scene.width = w;
  scene.height = h;
  return render_shot(scene, options);
}

// The mean of channel c over the pixels [x0, x1) × [y0, y1) and its standard error: the pixels are
// independent estimates (each has its own random numbers), so Var(block mean) = Σ Var(pixel mean) / n².
struct MeanSe {
  double mean = 0.0, se = 0.0;
};

inline MeanSe block_mean(const Image& mean, const Image& variance, int x0, int y0, int x1, int y1, int c = 0) {
  MeanSe r;
  double var = 0.0;
  const double n = (double)(x1 - x0) * (y1 - y0);
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      r.mean += mean.at(x, y)[c];
      var += variance.at(x, y)[c];
    }
  r.mean /= n;
  r.se = std::sqrt(var) / n;
  return r;
}

inline MeanSe block_mean(const Shot& s, int x0, int y0, int x1, int y1, int c = 0) {
  return block_mean(s.mean, s.variance, x0, y0, x1, y1, c);
}

// Sets or unsets an environment variable for one scope, restoring what the program was started with.
struct ScopedEnv {
  std::string name;
  std::optional<std::string> saved;
  ScopedEnv(const char* variable, const char* value) : name(variable) {
    if (const char* env = std::getenv(variable)) saved = env;
    value ? setenv(variable, value, 1) : unsetenv(variable);
  }
  ~ScopedEnv() { saved ? setenv(name.c_str(), saved->c_str(), 1) : unsetenv(name.c_str()); }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;
};

// A fresh, empty folder for the running test, named after it (ctest runs tests in parallel).
inline std::filesystem::path fresh_test_dir(const std::string& prefix) {
  namespace fs = std::filesystem;
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  fs::path dir = fs::temp_directory_path() / (prefix + info->test_suite_name() + "_" + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

}  // namespace xi::test
