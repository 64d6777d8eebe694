// Fixtures shared by the test files: the device every library test renders on.
#pragma once
#include "xi/device.h"
#include "xi/image.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace xi::test {

// The default OpenCL device ($XI_DEVICE, else the first CPU), opened once for the test binary.
inline Device& device() {
  static Device d = Device::open("");
  return d;
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

}  // namespace xi::test
