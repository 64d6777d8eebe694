// Adaptive sampling (RenderOptions::noise_threshold, `xi render --noise-threshold`): the stop rule
// on sums whose error is known, a scene whose per-pixel variance is known in closed form (pixels
// that see an emitter's edge: each sample is the emitter's radiance or 0, a Bernoulli variable), and
// the image's independence of how the work is cut: paths in flight, lanes, a stop and resume, and
// the `spp` layer's counts. Bad input: thresholds that are no number, and samplers whose patterns are
// complete only at their spp.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <set>

#include "analytic.h"
#include "cli_test.h"
#include "fixtures.h"
#include "xi/image.h"
#include "xi/renderer.h"
#include "xi/scene.h"

using namespace xi_test;

namespace {

// The sums of the samples `values`, as the film holds them (w: their count).
void film_sums(const std::vector<glm::vec3>& values, glm::vec4* sum, glm::vec4* sum_sq) {
  *sum = *sum_sq = glm::vec4(0.0f);
  for (const glm::vec3& v : values) {
    *sum += glm::vec4(v, 1.0f);
    *sum_sq += glm::vec4(v * v, 1.0f);
  }
}

}  // namespace

// Samples 1 and 3 (every channel): mean 2, sample variance 2, standard error 1: relative error
// 1 / sqrt(2² + 0.1²). The largest channel's error counts, over the mean intensity; dark pixels are
// judged against the floor; a constant pixel has none; fewer than two samples are never enough.
TEST(AdaptiveStopRule, RelativeErrorOfKnownSums) {
  glm::vec4 sum, sq;
  film_sums({glm::vec3(1.0f), glm::vec3(3.0f)}, &sum, &sq);
  EXPECT_FLOAT_EQ(xi::pixel_relative_error(sum, sq), 1.0f / std::sqrt(4.01f));
  // Red 1 and 3, green and blue constant 2: the mean intensity is still 2, the worst channel's
  // error 1.
  film_sums({glm::vec3(1.0f, 2.0f, 2.0f), glm::vec3(3.0f, 2.0f, 2.0f)}, &sum, &sq);
  EXPECT_FLOAT_EQ(xi::pixel_relative_error(sum, sq), 1.0f / std::sqrt(4.01f));
  // Four samples 0, 0, 0, 2e-4: mean 5e-5, s² = 1e-8, standard error 5e-5, judged against ~0.1.
  film_sums({glm::vec3(0.0f), glm::vec3(0.0f), glm::vec3(0.0f), glm::vec3(2e-4f)}, &sum, &sq);
  EXPECT_NEAR(xi::pixel_relative_error(sum, sq), 5e-5 / std::hypot(5e-5, xi::kAdaptiveDarkFloor), 1e-7);
  film_sums(std::vector<glm::vec3>(16, glm::vec3(0.25f)), &sum, &sq);
  EXPECT_EQ(xi::pixel_relative_error(sum, sq), 0.0f);
  film_sums(std::vector<glm::vec3>(16, glm::vec3(0.0f)), &sum, &sq);
  EXPECT_EQ(xi::pixel_relative_error(sum, sq), 0.0f);
  film_sums({glm::vec3(1.0f)}, &sum, &sq);
  EXPECT_TRUE(std::isinf(xi::pixel_relative_error(sum, sq)));
}

// Checks fall at fixed counts, each about a quarter past the one before.
TEST(AdaptiveStopRule, ChecksAtFixedCounts) {
  std::vector<int> counts = {16};
  while (counts.back() < 200) counts.push_back(xi::adaptive_check_after(counts.back()));
  EXPECT_EQ(counts, (std::vector<int>{16, 20, 25, 31, 38, 47, 58, 72, 90, 112, 140, 175, 218}));
  EXPECT_EQ(xi::adaptive_check_after(1), 2);
  EXPECT_EQ(xi::adaptive_check_after(3), 4);
}

// A black background and, in front of the camera, two emitters of radiance 1 whose vertical edges
// cross pixel columns: column A is covered to f = 0.7, column B to f = 0.2. A camera sample there
// sees 1 with probability f, else 0: the error of a pixel's mean after n samples is
// sqrt(f (1 − f) / (n − 1)) / sqrt(f² + 0.1²) with the unbiased variance estimate the stop rule
// uses, so column A stops at the first check where that is below T: with T = 0.06, 140 samples (at
// 112 the error is 0.0615, at 140 0.0550: sobol's stratified jitter puts the fraction of hits
// within a few 1/n of f, which moves the error by about 1%, far from either side). Column B would
// need about 900, and so takes the most, 512. Every other pixel sees a constant (0 or 1), has no
// variance and stops at the least spp, but for the neighbours of A and B in their rows, which sample
// as long as A and B do. The image is exact where the variance is 0.
TEST(AdaptiveSampling, EdgePixelsStopWhereTheirBernoulliVarianceSays) {
  xi::Scene scene;
  scene.width = 48;
  scene.height = 4;
  scene.camera.position = glm::vec3(0.0f, 0.0f, -5.0f);
  scene.camera.look_at = glm::vec3(0.0f);
  scene.camera.up = glm::vec3(0.0f, 1.0f, 0.0f);
  scene.camera.vfov_degrees = 10.0f;
  xi::Material light;
  light.type = xi::MaterialType::Diffuse;  // black, emitting
  light.emission = glm::vec3(1.0f);
  light.two_sided = true;
  scene.materials.push_back(light);
  const xi::test::View view(scene);
  // World x on the plane z = 0 of film column position fx (the film's x is linear in it there).
  const double f0 = view.film(glm::dvec3(0.0, 0.0, 0.0)).x, f1 = view.film(glm::dvec3(1.0, 0.0, 0.0)).x;
  auto world_x = [&](double fx) { return (fx - f0) / (f1 - f0); };
  const int column_a = 30, column_b = 10;
  const double fraction_a = 0.7, fraction_b = 0.2;
  // Emitter A covers film x from column_a + 0.3 on, emitter B film x up to column_b + 0.2.
  auto quad = [&](double fx_from, double fx_to) {
    double xa = world_x(fx_from), xb = world_x(fx_to);
    if (xa > xb) std::swap(xa, xb);
    const std::array<glm::vec3, 4> v = {glm::vec3(xa, -50, 0), glm::vec3(xb, -50, 0), glm::vec3(xb, 50, 0),
                                        glm::vec3(xa, 50, 0)};
    for (int t = 0; t < 2; ++t) scene.add_triangle(v[0], v[1 + t], v[2 + t], 0);
  };
  quad(column_a + (1.0 - fraction_a), 60.0);
  quad(-12.0, column_b + fraction_b);
  // The covered fractions, by brute force over each pixel's footprint (the edge is vertical).
  auto covered = [&](int column) {
    const int k = 4000;
    int hits = 0;
    for (int i = 0; i < k; ++i) {
      const glm::dvec3 d = view.ray(column + (i + 0.5) / k, 2.0);
      const double x = view.o.x + d.x * (-view.o.z / d.z);
      const double fx = view.film(glm::dvec3(x, 0.0, 0.0)).x;
      hits += fx >= column_a + (1.0 - fraction_a) || fx < column_b + fraction_b;
    }
    return (double)hits / k;
  };
  ASSERT_NEAR(covered(column_a), fraction_a, 1e-3);
  ASSERT_NEAR(covered(column_b), fraction_b, 1e-3);

  xi::RenderOptions o;
  o.spp = 512;
  o.max_depth = 1;
  o.seed = 5;
  o.sampler = XI_SAMPLER_SOBOL;
  o.noise_threshold = 0.06f;
  o.min_spp = 16;
  xi::Renderer r(xi::test::device(), scene, o);
  r.render();
  const xi::Film film = r.film();
  auto error = [](double f, int n) { return std::sqrt(f * (1.0 - f) / (n - 1.0)) / std::hypot(f, 0.1); };
  ASSERT_GT(error(fraction_a, 112), o.noise_threshold);
  ASSERT_LT(error(fraction_a, 140), o.noise_threshold);
  ASSERT_GT(error(fraction_b, 512), o.noise_threshold);
  std::printf("[ adaptive ] column A (f %.1f): %g spp, predicted 140 (error %.4f at 140, %.4f at 112); column B "
              "(f %.1f): %g spp, predicted 512 (error %.4f there)\n",
              fraction_a, film.spp.at(column_a, 1).x, error(fraction_a, 140), error(fraction_a, 112), fraction_b,
              film.spp.at(column_b, 1).x, error(fraction_b, 512));
  for (int y = 0; y < scene.height; ++y)
    for (int x = 0; x < scene.width; ++x) {
      SCOPED_TRACE(testing::Message() << "pixel " << x << ", " << y);
      const float spp = film.spp.at(x, y).x, mean = film.mean.at(x, y).x;
      if (x == column_a) {
        EXPECT_EQ(spp, 140.0f);
        EXPECT_NEAR(mean, fraction_a, 0.02);
      } else if (x == column_b) {
        EXPECT_EQ(spp, 512.0f);
        EXPECT_NEAR(mean, fraction_b, 0.02);
      } else {
        EXPECT_EQ(spp, std::abs(x - column_a) == 1 ? 140.0f : std::abs(x - column_b) == 1 ? 512.0f : 16.0f);
        EXPECT_EQ(mean, (x > column_a || x < column_b) ? 1.0f : 0.0f);
      }
    }
  EXPECT_EQ(r.spp_done(), 512);
  EXPECT_EQ(r.sampling_pixels(), (size_t)scene.height * 3);  // column B and its neighbours took the most
  EXPECT_EQ(r.samples_taken(), (uint64_t)(scene.width - 6) * scene.height * 16 +
                                   (uint64_t)scene.height * 3 * (140 + 512));
}

namespace {

class AdaptiveCli : public CliTest {};

const std::vector<std::string> kAdaptive = {"render", "--resolution", "24x16", "--spp", "96", "--noise-threshold",
                                            "0.15", "--min-spp", "8", "--seed", "3", "--quiet"};

// The layers of two EXRs, the spp layer too, bit for bit.
void expect_same_adaptive(const fs::path& a, const fs::path& b) {
  for (const char* layer : {"", "variance", "albedo", "normal", "spp"}) {
    SCOPED_TRACE(std::string("layer '") + layer + "' of " + a.string() + " and " + b.string());
    const xi::Image x = xi::read_exr(a, layer), y = xi::read_exr(b, layer);
    ASSERT_EQ(x.pixels.size(), y.pixels.size());
    EXPECT_EQ(std::memcmp(x.pixels.data(), y.pixels.data(), x.pixels.size() * sizeof(glm::vec3)), 0);
  }
}

}  // namespace

// The counts: every pixel took the least spp, a check's count or the most, the mean of them is the
// sppMean attribute, and some pixels stopped early while some went on (the Cornell box at this
// threshold has both). The image is the same bit for bit whatever the paths in flight, the vector
// lanes (8 or 16: one lane alone is scalar code, which rounds differently) or the threads, and after
// stopping and resuming (a budget shorter than any pass: one pass per run).
TEST_F(AdaptiveCli, SppLayerCountsAndTheImageDoesNotDependOnHowWorkIsCut) {
  const Outcome plain = run_xi(concat(kAdaptive, {"-o", "a.exr"}));
  ASSERT_EQ(plain.code, 0) << plain.err;
  const xi::Image spp = xi::read_exr(work_ / "a.exr", "spp");
  std::set<int> allowed = {96};
  for (int c = 8; c < 96; c = xi::adaptive_check_after(c)) allowed.insert(c);
  double total = 0.0;
  int least = 0, most = 0;
  for (const glm::vec3& n : spp.pixels) {
    EXPECT_TRUE(allowed.count((int)n.x)) << n.x;
    EXPECT_EQ(n.x, n.y);
    total += n.x;
    least += n.x == 8.0f;
    most += n.x == 96.0f;
  }
  const auto attrs = xi::read_exr_attributes(work_ / "a.exr");
  EXPECT_DOUBLE_EQ(std::get<double>(attrs.at("sppMean")), total / spp.pixels.size());
  EXPECT_EQ(attr_int("a.exr", "spp"), 96);
  EXPECT_EQ(attr_int("a.exr", "minSpp"), 8);
  EXPECT_GT(least, 0);
  EXPECT_GT(most, 0);
  EXPECT_LT(least + most, (int)spp.pixels.size());
  std::printf("[ adaptive ] 24x16 Cornell box: %d pixels stopped at 8 spp, %d took 96, mean %.2f spp\n", least, most,
              total / spp.pixels.size());
  ASSERT_EQ(run_xi({"tonemap", "a.exr", "spp.png", "--layer", "spp"}).code, 0);
  EXPECT_TRUE(fs::exists(work_ / "spp.png"));

  for (const std::vector<std::string>& flags :
       {std::vector<std::string>{"--paths-in-flight", "1000"}, {"--paths-in-flight", "37"},
        {"--lanes", "8", "--threads", "1"}, {"--samples-per-pass", "3"}}) {
    SCOPED_TRACE(flags[0] + " " + flags[1]);
    ASSERT_EQ(run_xi(concat(concat(kAdaptive, flags), {"-o", "b.exr"})).code, 0);
    expect_same_adaptive(work_ / "a.exr", work_ / "b.exr");
  }

  // Stopped after every pass and resumed, until done.
  const std::vector<std::string> cut = concat(kAdaptive, {"--samples-per-pass", "5", "-o", "cut.exr"});
  Outcome r = run_xi(concat(cut, {"--time", "1e-9", "--checkpoint", "ck.bin"}));
  int runs = 1;
  while (r.code == 0 && fs::exists(work_ / "ck.bin") && runs < 100) {
    r = run_xi(concat(cut, {"--time", "1e-9", "--resume", "ck.bin"}));
    ++runs;
  }
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_GT(runs, 3);
  EXPECT_FALSE(fs::exists(work_ / "ck.bin"));
  expect_same_adaptive(work_ / "a.exr", work_ / "cut.exr");

  // A checkpoint of another threshold is refused.
  ASSERT_EQ(run_xi(concat(cut, {"--time", "1e-9", "--checkpoint", "ck.bin"})).code, 0);
  std::vector<std::string> other = cut;
  other[6] = "0.2";
  const Outcome refused = run_xi(concat(other, {"--resume", "ck.bin"}));
  EXPECT_EQ(refused.code, 1);
  EXPECT_NE(refused.err.find("--noise-threshold 0.15"), std::string::npos) << refused.err;
}

TEST_F(AdaptiveCli, BadThresholdsAndPatternSamplersAreRefused) {
  const auto before = files();
  const std::vector<std::string> base = {"render", "--resolution", "16x16", "--spp", "8", "-o", "x.exr"};
  for (const std::string bad : {"nan", "-0.1", "0", "abc", "inf", ""}) {
    SCOPED_TRACE(bad);
    expect_user_error(run_xi(concat(base, {"--noise-threshold", bad})), {"--noise-threshold"}, before);
  }
  for (const std::string sampler : {"grid", "stratified"}) {
    SCOPED_TRACE(sampler);
    expect_user_error(run_xi(concat(base, {"--noise-threshold", "0.05", "--sampler", sampler})),
                      {"--noise-threshold", sampler, "only complete at 8 spp"}, before);
  }
  expect_user_error(run_xi(concat(base, {"--min-spp", "4"})), {"--min-spp", "needs --noise-threshold"}, before);
  expect_user_error(run_xi(concat(base, {"--noise-threshold", "0.05", "--min-spp", "0"})), {"--min-spp"}, before);
}
