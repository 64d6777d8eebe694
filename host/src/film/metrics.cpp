#include "xi/metrics.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "xi/error.h"

namespace xi {
namespace {

const char* kNames[] = {"mse", "rmse", "relmse", "mae", "mrse"};

// The summand of a metric for one channel value (rmse shares mse's).
double term(Metric m, double v, double r) {
  double d = v - r;
  switch (m) {
    case Metric::Mse:
    case Metric::Rmse: return d * d;
    case Metric::RelMse: return d * d / (r * r + 0.01);
    case Metric::Mae: return std::fabs(d);
    case Metric::Mrse: return d * d / ((r + 0.01) * (r + 0.01));
  }
  return 0.0;
}

}  // namespace

void check_finite(const Image& image, const std::string& name) {
  size_t bad = 0, first = 0;
  for (size_t i = 0; i < image.pixels.size(); ++i)
    if (!std::isfinite(image.pixels[i].x) || !std::isfinite(image.pixels[i].y) || !std::isfinite(image.pixels[i].z))
      if (bad++ == 0) first = i;
  if (bad)
    throw Error(std::to_string(bad) + " non-finite pixel(s) in the " + name,
                "first at x=" + std::to_string(first % image.width) + ", y=" + std::to_string(first / image.width));
}

namespace {

void check_pair(const Image& image, const Image& reference) {
  if (image.width != reference.width || image.height != reference.height)
    throw Error("images differ in size: " + std::to_string(image.width) + "x" + std::to_string(image.height) +
                " vs reference " + std::to_string(reference.width) + "x" + std::to_string(reference.height));
  check_finite(image, "image");
  check_finite(reference, "reference");
}

double pixel_term(Metric m, const glm::vec3& v, const glm::vec3& r) {
  return (term(m, v.x, r.x) + term(m, v.y, r.y) + term(m, v.z, r.z)) / 3.0;
}

}  // namespace

Metric parse_metric(const std::string& name) {
  for (Metric m : all_metrics())
    if (name == kNames[(int)m]) return m;
  throw Error("unknown metric '" + name + "'", "expected mse, rmse, relmse, mae or mrse");
}

const char* metric_name(Metric m) { return kNames[(int)m]; }

Crop parse_crop(const std::string& text, int width, int height) {
  Crop c;
  char extra;
  if (std::sscanf(text.c_str(), "%d,%d,%d,%d%c", &c.x0, &c.y0, &c.x1, &c.y1, &extra) != 4)
    throw Error("expected x0,y0,x1,y1, got '" + text + "'", "--crop");
  if (c.x0 < 0 || c.y0 < 0 || c.x1 > width || c.y1 > height || c.x0 >= c.x1 || c.y0 >= c.y1)
    throw Error("crop " + text + " is empty or outside the " + std::to_string(width) + "x" + std::to_string(height) +
                    " image",
                "--crop");
  return c;
}

double image_metric(const Image& image, const Image& reference, Metric metric, const std::optional<Crop>& crop) {
  check_pair(image, reference);
  Crop c = crop.value_or(Crop{0, 0, image.width, image.height});
  double sum = 0.0;
  for (int y = c.y0; y < c.y1; ++y)
    for (int x = c.x0; x < c.x1; ++x) sum += pixel_term(metric, image.at(x, y), reference.at(x, y));
  double mean = sum / ((double)(c.x1 - c.x0) * (c.y1 - c.y0));
  return metric == Metric::Rmse ? std::sqrt(mean) : mean;
}

Image error_heatmap(const Image& image, const Image& reference, Metric metric) {
  check_pair(image, reference);
  std::vector<double> e(image.pixels.size());
  for (size_t i = 0; i < e.size(); ++i) e[i] = pixel_term(metric, image.pixels[i], reference.pixels[i]);
  std::vector<double> sorted = e;
  size_t k = std::min(sorted.size() - 1, (size_t)(0.99 * (double)sorted.size()));
  std::nth_element(sorted.begin(), sorted.begin() + (ptrdiff_t)k, sorted.end());
  double scale = sorted[k] > 0.0 ? sorted[k] : 1.0;
  // A small perceptual ramp (black, purple, orange, yellow), linearly interpolated.
  const glm::vec3 ramp[] = {{0.0f, 0.0f, 0.0f}, {0.25f, 0.02f, 0.35f}, {0.85f, 0.25f, 0.05f}, {1.0f, 0.95f, 0.3f}};
  Image out(image.width, image.height);
  for (size_t i = 0; i < e.size(); ++i) {
    float t = (float)std::min(1.0, e[i] / scale) * 3.0f;
    int j = std::min(2, (int)t);
    glm::vec3 srgb = glm::mix(ramp[j], ramp[j + 1], t - (float)j);
    out.pixels[i] = glm::pow(srgb, glm::vec3(2.2f));  // write_png encodes to sRGB again
  }
  return out;
}

}  // namespace xi
