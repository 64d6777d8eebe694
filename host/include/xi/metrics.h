// Image error metrics against a reference, per channel, averaged over pixels and channels:
//   mse    = mean (v − r)²            rmse = √mse            mae = mean |v − r|
//   relmse = mean (v − r)² / (r² + 0.01)
//   mrse   = mean (v − r)² / (r + 0.01)²   (squared error relative to the reference value itself)
#pragma once
#include <optional>
#include <string>
#include <vector>

#include "xi/image.h"

namespace xi {

enum class Metric { Mse, Rmse, RelMse, Mae, Mrse };
Metric parse_metric(const std::string& name);  // throws xi::Error
const char* metric_name(Metric m);
inline const std::vector<Metric>& all_metrics() {
  static const std::vector<Metric> all{Metric::Mse, Metric::Rmse, Metric::RelMse, Metric::Mae, Metric::Mrse};
  return all;
}

struct Crop {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // pixels [x0, x1) × [y0, y1)
};
Crop parse_crop(const std::string& text, int width, int height);  // "x0,y0,x1,y1"; throws xi::Error

// Throws xi::Error if the image holds a non-finite value: how many, in the image called `name`, and the first.
void check_finite(const Image& image, const std::string& name);

// Throws xi::Error if the sizes differ or either image holds a non-finite value (naming the pixel).
double image_metric(const Image& image, const Image& reference, Metric metric,
                    const std::optional<Crop>& crop = std::nullopt);

// The per-pixel error term of `metric` (averaged over channels), in false colour: black (none)
// through purple and orange to yellow (at the 99th percentile and above).
Image error_heatmap(const Image& image, const Image& reference, Metric metric);

}  // namespace xi
