// Image metrics (xi diff, convergence logs) on images with hand-computed answers, and EXR/PNG files.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <unistd.h>

#include "xi/error.h"
#include "xi/image.h"
#include "xi/metrics.h"

namespace {

// A 2×1 image pair whose metrics are easy to work out by hand.
struct Pair {
  xi::Image image{2, 1}, reference{2, 1};
  Pair() {
    reference.pixels = {glm::vec3(1.0f), glm::vec3(0.0f)};
    image.pixels = {glm::vec3(1.5f), glm::vec3(0.1f)};
  }
};

}  // namespace

TEST(Metrics, FormulasOnAHandComputedPair) {
  Pair p;
  // Per channel, pixel 0: d = 0.5, r = 1; pixel 1: d = 0.1, r = 0. Means over 2 pixels (channels equal).
  const double tol = 1e-6;  // float inputs, double sums
  EXPECT_NEAR(xi::image_metric(p.image, p.reference, xi::Metric::Mse), (0.25 + 0.01) / 2, tol);
  EXPECT_NEAR(xi::image_metric(p.image, p.reference, xi::Metric::Rmse), std::sqrt((0.25 + 0.01) / 2), tol);
  EXPECT_NEAR(xi::image_metric(p.image, p.reference, xi::Metric::Mae), (0.5 + 0.1) / 2, tol);
  EXPECT_NEAR(xi::image_metric(p.image, p.reference, xi::Metric::RelMse), (0.25 / 1.01 + 0.01 / 0.01) / 2, tol);
  EXPECT_NEAR(xi::image_metric(p.image, p.reference, xi::Metric::Mrse),
              (0.25 / (1.01 * 1.01) + 0.01 / (0.01 * 0.01)) / 2, 1e-4);
  for (xi::Metric m : xi::all_metrics()) EXPECT_EQ(xi::image_metric(p.reference, p.reference, m), 0.0);
}

TEST(Metrics, CropSelectsPixels) {
  Pair p;
  EXPECT_NEAR(xi::image_metric(p.image, p.reference, xi::Metric::Mse, xi::parse_crop("1,0,2,1", 2, 1)), 0.01, 1e-6);
  EXPECT_THROW(xi::parse_crop("0,0,3,1", 2, 1), xi::Error);  // outside
  EXPECT_THROW(xi::parse_crop("1,0,1,1", 2, 1), xi::Error);  // empty
  EXPECT_THROW(xi::parse_crop("1,2,3", 2, 1), xi::Error);    // malformed
}

TEST(Metrics, RejectsMismatchAndNonFinite) {
  Pair p;
  xi::Image small(1, 1);
  EXPECT_THROW(xi::image_metric(small, p.reference, xi::Metric::Mse), xi::Error);
  p.image.pixels[1].y = NAN;
  try {
    xi::image_metric(p.image, p.reference, xi::Metric::Mse);
    FAIL() << "NaN must be reported";
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find("x=1, y=0"), std::string::npos) << e.what();  // names the pixel
  }
  EXPECT_THROW(xi::parse_metric("psnr"), xi::Error);
}

TEST(Metrics, HeatmapIsBrighterWhereTheErrorIsLarger) {
  Pair p;
  xi::Image h = xi::error_heatmap(p.image, p.reference, xi::Metric::Mse);
  auto lum = [](glm::vec3 c) { return c.x + c.y + c.z; };
  EXPECT_GT(lum(h.pixels[0]), lum(h.pixels[1]));
  EXPECT_EQ(lum(xi::error_heatmap(p.reference, p.reference, xi::Metric::Mse).pixels[0]), 0.0f);
}

TEST(ImageFiles, ExrLayersAndAttributesRoundTrip) {
  auto path = std::filesystem::temp_directory_path() / ("xi-metrics-" + std::to_string(::getpid()) + ".exr");
  xi::Image a(3, 2), b(3, 2);
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    a.pixels[i] = glm::vec3((float)i, 0.5f, -1.0f);
    b.pixels[i] = glm::vec3(0.25f * (float)i);
  }
  xi::write_exr(path, {{"", &a}, {"variance", &b}}, {{"spp", 7}, {"scene", std::string("s.json")}, {"t", 1.5}});
  xi::Image a2 = xi::read_exr(path), b2 = xi::read_exr(path, "variance");
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    EXPECT_EQ(a2.pixels[i], a.pixels[i]);  // 32-bit float channels: exact
    EXPECT_EQ(b2.pixels[i], b.pixels[i]);
  }
  auto attrs = xi::read_exr_attributes(path);
  EXPECT_EQ(std::get<int>(attrs.at("spp")), 7);
  EXPECT_EQ(std::get<std::string>(attrs.at("scene")), "s.json");
  EXPECT_EQ(std::get<double>(attrs.at("t")), 1.5);
  EXPECT_THROW(xi::read_exr(path, "albedo"), xi::Error);  // a layer that is not there
  std::filesystem::remove(path);
  EXPECT_THROW(xi::read_exr(path), xi::Error);  // a file that is not there
}
