// Sample sets warped on the device by kernels/tools.cl: the very code the renderer runs, for
// `xi warp` pictures and the χ² tests.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "xi/device.h"

namespace xi {

int parse_warp_map(const std::string& name);  // XI_MAP_*; throws xi::Error
const char* warp_map_name(int map);
bool warp_map_is_3d(int map);

struct WarpedSamples {
  std::vector<glm::vec3> points;   // warped
  std::vector<glm::vec2> squares;  // the (ξ₁, ξ₂) each came from
};

// n points of `sampler`'s set (spp = n) for `pixel`, dimension pair `pair`, warped by `map`.
WarpedSamples warp_samples(Device& device, int map, int sampler, uint32_t n, uint32_t seed,
                           uint32_t pixel = 0, uint32_t pair = 0);

}  // namespace xi
