// The environment light's host side: loading an equirectangular HDR image (Radiance .hdr or
// OpenEXR), its importance-sampling distribution, and the EnvironmentData record the kernels read.
// Orientation, texel placement and the layout of the distribution: kernels/shared/environment.h.
#pragma once
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "layout.h"

namespace xi {

// The largest map accepted: 16384 × 8192 (the largest HDRIs commonly published, "16K"). Beyond it
// the texels alone (16 bytes each) take over 2 GiB of device memory, more than many devices allow
// in one buffer.
constexpr int kEnvironmentMaxWidth = 16384;
constexpr int kEnvironmentMaxHeight = 8192;

struct EnvironmentMap {
  int width = 0;
  int height = 0;
  std::vector<glm::vec4> texels;  // linear RGB radiance (w = 0), row-major, top row (+y) first
  // The sampling distribution (environment.h): the CDFs over H + 1 rows of bilinear patches (a
  // marginal and a conditional of W per row), their guide tables, then the patches' vertex weights;
  // empty when the map is black everywhere (it then cannot be sampled: pick probability 0).
  std::vector<float> cdf;
  // The mean luminance over the sphere, (1/4π) ∫ Y dω with each texel's luminance over its cell's
  // solid angle: the radiance of a uniform environment of the same power.
  double mean_luminance = 0.0;
  std::string source;  // the file it came from, for messages
  bool has_distribution() const { return !cdf.empty(); }
};

// Reads a .hdr (Radiance RGBE) or .exr (OpenEXR: R, G, B channels, or Y) file and builds its
// distribution. Throws xi::Error naming the file: missing, unreadable or corrupt, not high
// dynamic range (an 8-bit .png/.jpg/...), an unknown extension, empty, larger than the limits
// above, or with a texel that is NaN, infinite or negative (its x, y named).
EnvironmentMap load_environment(const std::filesystem::path& path);

// An environment from texels already in memory (tests, generated maps): checks them as
// load_environment does (`source` names them in messages) and builds the distribution.
EnvironmentMap make_environment(int width, int height, std::vector<glm::vec4> texels,
                                const std::string& source = "<memory>");

// Fills map.cdf (and mean_luminance) from map.texels by the rules in environment.h, in double,
// stored as float with every CDF's last entry exactly 1. Leaves cdf empty for a black map.
void build_environment_distribution(EnvironmentMap& map);

// The kernels' record: strength multiplies the texels; rotation_degrees turns the map about the
// world's +y (Mitsuba's to_world rotate(y, angle): positive angles turn +z toward +x);
// pick_probability is the chance the light sampler picks the environment, forced to 0 where the
// map has no distribution or the strength is not positive.
EnvironmentData make_environment_data(const EnvironmentMap& map, float strength, float rotation_degrees,
                                      float pick_probability);

}  // namespace xi
