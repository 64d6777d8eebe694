// View transforms (xi/view.h): how linear radiance becomes the 8-bit PNG. Each view against its
// published formula, worked out here independently (by hand, with the arithmetic in the comments,
// and by a double-precision transcription), and `xi render` / `xi tonemap` writing their PNGs
// through the view they are given or default to.
#include <gtest/gtest.h>

#include <png.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "cli_test.h"
#include "xi/image.h"
#include "xi/view.h"

namespace {

namespace fs = std::filesystem;
using xi::View;
using dvec3 = glm::dvec3;

// Today's PNG: each channel scaled, clipped to [0, 1], sRGB-encoded (IEC 61966-2-1), rounded.
unsigned char clip_and_encode(float linear, float exposure) {
  float v = std::fmin(std::fmax(exposure * linear, 0.0f), 1.0f);
  v = v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
  return (unsigned char)std::lround(255.0f * v);
}

// Khronos PBR Neutral, transcribed from the spec's reference code in double precision.
dvec3 pbr_neutral(dvec3 c) {
  const double start_compression = 0.8 - 0.04, desaturation = 0.15;
  const double x = std::min(c.x, std::min(c.y, c.z));
  const double offset = x < 0.08 ? x - 6.25 * x * x : 0.04;
  c -= offset;
  const double peak = std::max(c.x, std::max(c.y, c.z));
  if (peak < start_compression) return c;
  const double d = 1.0 - start_compression;
  const double new_peak = 1.0 - d * d / (peak + d - start_compression);
  c *= new_peak / peak;
  const double g = 1.0 - 1.0 / (desaturation * (peak - new_peak) + 1.0);
  return c * (1.0 - g) + dvec3(new_peak) * g;
}

// AgX base ("minimal AgX"), in double precision: inset (rows here), log2 between the EVs, the
// sigmoid's polynomial, outset, 2.2 power.
dvec3 agx(dvec3 c) {
  const double inset[3][3] = {{0.842479062253094, 0.0784335999999992, 0.0792237451477643},
                              {0.0423282422610123, 0.878468636469772, 0.0791661274605434},
                              {0.0423756549057051, 0.0784336, 0.879142973793104}};
  const double outset[3][3] = {{1.19687900512017, -0.0980208811401368, -0.0990297440797205},
                               {-0.0528968517574562, 1.15190312990417, -0.0989611768448433},
                               {-0.0529716355144438, -0.0980434501171241, 1.15107367264116}};
  const double min_ev = -12.47393, max_ev = 4.026069;
  dvec3 e, s, out;
  for (int i = 0; i < 3; ++i) {
    const double v = inset[i][0] * c.x + inset[i][1] * c.y + inset[i][2] * c.z;
    e[i] = (std::clamp(v > 0 ? std::log2(v) : min_ev, min_ev, max_ev) - min_ev) / (max_ev - min_ev);
    const double x = e[i];
    s[i] = 15.5 * std::pow(x, 6) - 40.14 * std::pow(x, 5) + 31.96 * std::pow(x, 4) - 6.868 * std::pow(x, 3) +
           0.4298 * x * x + 0.1191 * x - 0.00232;
  }
  for (int i = 0; i < 3; ++i)
    out[i] = std::pow(std::max(0.0, outset[i][0] * s.x + outset[i][1] * s.y + outset[i][2] * s.z), 2.2);
  return glm::clamp(out, 0.0, 1.0);
}

void expect_near(glm::vec3 got, dvec3 want, double tol, const std::string& what) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], want[c], tol) << what << ", channel " << c;
}

double saturation(glm::vec3 c) {
  const float hi = std::max(c.r, std::max(c.g, c.b)), lo = std::min(c.r, std::min(c.g, c.b));
  return hi > 0.0f ? (hi - lo) / hi : 0.0;
}

}  // namespace

TEST(View, NamesRoundTripAndUnknownNamesAreRefused) {
  for (View v : {View::Standard, View::Neutral, View::Agx}) EXPECT_EQ(xi::view_from_name(xi::view_name(v)), v);
  EXPECT_EQ(xi::view_name(View::Neutral), std::string("neutral"));
  for (const char* bad : {"", "Neutral", "filmic", "agx "}) EXPECT_FALSE(xi::view_from_name(bad).has_value()) << bad;
}

// Standard is the PNG as it always was, bit for bit: clip, sRGB, round; NaN and negatives black.
TEST(View, StandardIsClipAndSrgbBitForBit) {
  std::vector<float> values = {-1.0f, -0.0f, 0.0f,  1e-6f, 0.0031308f, 0.0031309f, 0.18f,
                               0.5f,  0.999f, 1.0f, 1.5f,  1e30f,      NAN};
  for (int i = 0; i <= 4096; ++i) values.push_back(i / 4096.0f * 1.25f);
  for (float e : {1.0f, 2.5f, 0.3f})
    for (float v : values) {
      const glm::u8vec3 got = xi::display_pixel(View::Standard, glm::vec3(v, 0.5f * v, 2.0f * v), e);
      EXPECT_EQ(got.r, clip_and_encode(v, e)) << v << " x " << e;
      EXPECT_EQ(got.g, clip_and_encode(0.5f * v, e)) << v << " x " << e;
      EXPECT_EQ(got.b, clip_and_encode(2.0f * v, e)) << v << " x " << e;
    }
  EXPECT_EQ(xi::apply_view(View::Standard, glm::vec3(2.0f, 0.25f, -1.0f)), glm::vec3(1.0f, 0.25f, 0.0f));
}

// PBR Neutral by hand. Below a peak of 0.76 (after the offset) the colour is only shifted: by 0.04
// once its smallest channel is >= 0.08, by x - 6.25 x^2 below that.
TEST(View, NeutralFollowsTheKhronosFormula) {
  // grey 0.5: 0.5 - 0.04 = 0.46
  expect_near(xi::apply_view(View::Neutral, glm::vec3(0.5f)), dvec3(0.46), 1e-6, "grey 0.5");
  // (0.5, 0.3, 0.05): x = 0.05 < 0.08, offset 0.05 - 6.25 * 0.0025 = 0.034375
  expect_near(xi::apply_view(View::Neutral, {0.5f, 0.3f, 0.05f}), {0.465625, 0.265625, 0.015625}, 1e-6, "dark");
  // black stays black: offset 0 - 0 = 0
  expect_near(xi::apply_view(View::Neutral, glm::vec3(0.0f)), dvec3(0.0), 0.0, "black");
  // Grey g >= 0.8: peak p = g - 0.04, d = 1 - 0.76 = 0.24, new peak 1 - d^2 / (p + d - 0.76) =
  // 1 - 0.0576 / (g - 0.56); a grey stays grey (the desaturation mixes toward the same grey).
  //   g = 1:  1 - 0.0576 / 0.44  = 0.86909091
  //   g = 4:  1 - 0.0576 / 3.44  = 0.98325581
  //   g = 16: 1 - 0.0576 / 15.44 = 0.99626943
  expect_near(xi::apply_view(View::Neutral, glm::vec3(1.0f)), dvec3(0.86909091), 1e-6, "grey 1");
  expect_near(xi::apply_view(View::Neutral, glm::vec3(4.0f)), dvec3(0.98325581), 1e-6, "grey 4");
  expect_near(xi::apply_view(View::Neutral, glm::vec3(16.0f)), dvec3(0.99626943), 1e-6, "grey 16");
  // (4, 1, 0.5): offset 0.04 -> (3.96, 0.96, 0.46), peak 3.96, new peak 0.98325581; scaled by
  // 0.98325581 / 3.96 -> (0.98325581, 0.23836504, 0.11421556); g = 1 - 1 / (0.15 (3.96 -
  // 0.98325581) + 1) = 1 - 1 / 1.44651163 = 0.30868167; mixed toward the new peak:
  // c (1 - g) + 0.98325581 g = (0.98325581, 0.46829917, 0.38247307).
  expect_near(xi::apply_view(View::Neutral, {4.0f, 1.0f, 0.5f}), {0.98325581, 0.46829917, 0.38247307}, 1e-6, "colour");
  // And the transcription everywhere on a grid of colours.
  for (float r : {0.0f, 0.05f, 0.3f, 0.79f, 0.81f, 2.0f, 50.0f})
    for (float g : {0.0f, 0.07f, 0.9f, 5.0f})
      for (float b : {0.02f, 1.0f, 300.0f})
        expect_near(xi::apply_view(View::Neutral, {r, g, b}), glm::clamp(pbr_neutral({r, g, b}), 0.0, 1.0), 2e-6,
                    "grid");
}

// AgX by its formula: black to black, mid grey 0.18 about 0.2145 (sRGB code 128), increasing, and
// bright or saturated colours compressed and desaturated.
TEST(View, AgxFollowsItsFormula) {
  // 0: log2 clamps to the bottom EV, encoded 0, the polynomial -0.00232, outset ~ -0.00232 < 0: 0.
  expect_near(xi::apply_view(View::Agx, glm::vec3(0.0f)), dvec3(0.0), 0.0, "black");
  // Mid grey: the inset's rows sum to 1.000136, 0.999963, 0.999952 (about 1), so red's log2 is
  // log2(0.18 * 1.000136) = -2.473734, encoded (-2.473734 + 12.47393) / 16.499999 = 0.606072; the
  // polynomial there is 0.496755 (green's and blue's 0.496724, 0.496722); the outset's rows sum to
  // 0.999828, 1.000045, 1.000059, so about 0.4967 again; 0.4967^2.2 = 0.2145, sRGB code 128.
  expect_near(xi::apply_view(View::Agx, glm::vec3(0.18f)), dvec3(0.2145), 2e-4, "mid grey");
  const glm::u8vec3 grey = xi::display_pixel(View::Agx, glm::vec3(0.18f));
  EXPECT_NEAR(grey.r, 128, 1);
  for (float r : {0.0f, 1e-4f, 0.01f, 0.18f, 1.0f, 3.0f, 16.0f, 17.0f, 1000.0f})
    for (glm::vec3 tint : {glm::vec3(1.0f), glm::vec3(1.0f, 0.2f, 0.05f), glm::vec3(0.1f, 0.5f, 1.0f)})
      expect_near(xi::apply_view(View::Agx, r * tint), agx(dvec3(r * tint)), 2e-5, "transcription");
  // Increasing over 2^-12 .. 2^4 (beyond 2^4.026 every channel is at the top of the range).
  float last = -1.0f;
  for (float ev = -12.0f; ev <= 4.0f; ev += 0.25f) {
    const float shown = xi::apply_view(View::Agx, glm::vec3(std::exp2(ev))).g;
    EXPECT_GT(shown, last) << "at " << ev << " EV";
    last = shown;
  }
  // Values above 1 stay below 1 (standard clips them to 1), and a pure red loses saturation.
  EXPECT_LT(xi::apply_view(View::Agx, glm::vec3(1.0f)).g, 0.6f);
  EXPECT_LT(xi::apply_view(View::Agx, glm::vec3(4.0f)).g, 0.87f);
  EXPECT_LT(saturation(xi::apply_view(View::Agx, {1.0f, 0.0f, 0.0f})), 0.95);
  EXPECT_LT(saturation(xi::apply_view(View::Agx, {100.0f, 0.0f, 0.0f})), 0.2);
}

// The views differ where they should: a check that would fail if apply_view ignored its view.
TEST(View, ViewsDifferAboveTheirKnee) {
  for (float v : {0.85f, 1.0f, 2.0f, 10.0f}) {
    const glm::vec3 standard = xi::apply_view(View::Standard, glm::vec3(v));
    EXPECT_LT(xi::apply_view(View::Neutral, glm::vec3(v)).g, standard.g - 0.003f) << v;
    EXPECT_LT(xi::apply_view(View::Agx, glm::vec3(v)).g, standard.g - 0.003f) << v;
    EXPECT_NE(xi::display_pixel(View::Neutral, glm::vec3(v)), xi::display_pixel(View::Standard, glm::vec3(v))) << v;
  }
  // Negatives and NaN are black in every view.
  for (View view : {View::Standard, View::Neutral, View::Agx})
    EXPECT_EQ(xi::apply_view(view, {-1.0f, NAN, 0.0f}), glm::vec3(0.0f)) << xi::view_name(view);
}

namespace {

// An 8-bit RGB PNG's bytes as they are (no sRGB decoding).
std::vector<glm::u8vec3> png_bytes(const fs::path& path, int* width = nullptr) {
  png_image img{};
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, path.c_str())) {
    ADD_FAILURE() << "cannot read " << path;
    return {};
  }
  img.format = PNG_FORMAT_RGB;
  std::vector<glm::u8vec3> px(size_t(img.width) * img.height);
  EXPECT_TRUE(png_image_finish_read(&img, nullptr, px.data(), 0, nullptr));
  if (width) *width = int(img.width);
  return px;
}

class ViewCli : public xi_test::CliTest {
 protected:
  // The PNG's every pixel is `view` of the EXR's (scaled by `exposure`); returns how many pixels
  // standard would have shown differently.
  int expect_png_follows(const std::string& stem, View view, float exposure = 1.0f) {
    const xi::Image exr = xi::read_exr(work_ / (stem + ".exr"));
    int width = 0;
    const std::vector<glm::u8vec3> png = png_bytes(work_ / (stem + ".png"), &width);
    EXPECT_EQ(width, exr.width);
    EXPECT_EQ(png.size(), exr.pixels.size());
    int mismatches = 0, unlike_standard = 0;
    for (size_t i = 0; i < std::min(png.size(), exr.pixels.size()); ++i) {
      mismatches += png[i] != xi::display_pixel(view, exr.pixels[i], exposure);
      unlike_standard += png[i] != xi::display_pixel(View::Standard, exr.pixels[i], exposure);
    }
    EXPECT_EQ(mismatches, 0) << stem << ".png does not follow " << xi::view_name(view);
    return unlike_standard;
  }
  // A triangle lit by a constant background of 2 alone: pixels from dark to twice white.
  void write_triangle() { xi_test::write_text(work_ / "tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0.5\nf 1 2 3\n"); }
};

}  // namespace

// An asset file's PNG is PBR Neutral by default; a JSON scene's standard (as always); --view and
// --exposure change the PNG only; the EXR records both.
TEST_F(ViewCli, RenderDefaultsPerInputKindAndFlags) {
  write_triangle();
  const std::vector<std::string> fast = {"--spp", "2", "--resolution", "24x24", "--quiet", "--background", "2"};
  const auto asset = run_xi(xi_test::concat({"render", "tri.obj", "-o", "tri.exr"}, fast));
  ASSERT_EQ(asset.code, 0) << asset.err;
  EXPECT_EQ(asset.out, "");
  EXPECT_GT(expect_png_follows("tri", View::Neutral), 24 * 24 / 2) << "the background alone should differ";
  const xi::ExrAttributes attrs = xi::read_exr_attributes(work_ / "tri.exr");
  EXPECT_EQ(std::get<std::string>(attrs.at("pngView")), "neutral");
  EXPECT_EQ(std::get<float>(attrs.at("pngExposure")), 1.0f);
  // The EXR is linear whatever the view: the background is 2.
  EXPECT_FLOAT_EQ(xi::read_exr(work_ / "tri.exr").at(23, 0).x, 2.0f);

  const auto agx = run_xi(xi_test::concat({"render", "tri.obj", "-o", "agx.png", "--view", "agx", "--exposure", "0.5"}, fast));
  ASSERT_EQ(agx.code, 0) << agx.err;
  EXPECT_GT(expect_png_follows("agx", View::Agx, 0.5f), 0);
  EXPECT_EQ(std::get<std::string>(xi::read_exr_attributes(work_ / "agx.exr").at("pngView")), "agx");
  const auto standard =
      run_xi(xi_test::concat({"render", "tri.obj", "-o", "std.exr", "--view", "standard", "--exposure", "0.25"}, fast));
  ASSERT_EQ(standard.code, 0) << standard.err;
  EXPECT_EQ(expect_png_follows("std", View::Standard, 0.25f), 0);
  const xi::Image tri = xi::read_exr(work_ / "tri.exr"), std_exr = xi::read_exr(work_ / "std.exr");
  EXPECT_EQ(tri.pixels, std_exr.pixels) << "the view and the exposure must leave the EXR alone";

  // The Cornell box (its light seen directly: values above 1) is shown as it always was.
  const auto json_scene = run_xi(xi_test::concat({"render", "-o", "box.exr"}, xi_test::kFast));
  ASSERT_EQ(json_scene.code, 0) << json_scene.err;
  expect_png_follows("box", View::Standard);
  EXPECT_EQ(std::get<std::string>(xi::read_exr_attributes(work_ / "box.exr").at("pngView")), "standard");
  ASSERT_EQ(run_xi(xi_test::concat({"render", "-o", "box-neutral.exr", "--view", "neutral"}, xi_test::kFast)).code, 0);
  EXPECT_GT(expect_png_follows("box-neutral", View::Neutral), 0);
}

TEST_F(ViewCli, BadViewOrExposureIsOneErrorAndNoFile) {
  write_triangle();
  const auto before = files();
  expect_user_error(run_xi(xi_test::concat({"render", "tri.obj", "--view", "bogus"}, xi_test::kFast)),
                    {"unknown view 'bogus'", "standard, neutral or agx", "--view bogus"}, before);
  expect_user_error(run_xi(xi_test::concat({"render", "--view", "Filmic"}, xi_test::kFast)), {"--view Filmic"}, before);
  for (const char* e : {"-1", "0", "nan", "two"})
    expect_user_error(run_xi(xi_test::concat({"render", "tri.obj", "--exposure", e}, xi_test::kFast)),
                      {"--exposure", std::string("'") + e + "'"}, before);
}

// `xi tonemap`: standard unless told; --view agx and neutral give those views of the EXR.
TEST_F(ViewCli, TonemapTakesAView) {
  ASSERT_EQ(run_xi(xi_test::concat({"render", "-o", "a.exr"}, xi_test::kFast)).code, 0);
  ASSERT_EQ(run_xi({"tonemap", "a.exr", "t.png"}).code, 0);
  EXPECT_EQ(xi_test::read_text(work_ / "t.png"), xi_test::read_text(work_ / "a.png"));
  const auto agx = run_xi({"tonemap", "a.exr", "agx.png", "--view", "agx"});
  ASSERT_EQ(agx.code, 0) << agx.err;
  EXPECT_EQ(agx.out + agx.err, "");
  fs::copy_file(work_ / "a.exr", work_ / "agx.exr");  // expect_png_follows reads STEM.exr
  EXPECT_GT(expect_png_follows("agx", View::Agx), 0);
  ASSERT_EQ(run_xi({"tonemap", "a.exr", "neutral.png", "--view", "neutral", "--exposure", "3"}).code, 0);
  fs::copy_file(work_ / "a.exr", work_ / "neutral.exr");
  EXPECT_GT(expect_png_follows("neutral", View::Neutral, 3.0f), 0);
  const auto before = files();
  expect_user_error(run_xi({"tonemap", "a.exr", "m.png", "--view", "aces"}), {"unknown view 'aces'", "--view aces"},
                    before);
}

TEST_F(ViewCli, HelpListsTheViewFlags) {
  const auto render = run_xi({"help", "render"});
  for (const char* word : {"--view V", "--exposure E", "--orbit YAW,PITCH", "neutral", "agx"})
    EXPECT_NE(render.out.find(word), std::string::npos) << word;
  const auto tonemap = run_xi({"tonemap", "--help"});
  EXPECT_NE(tonemap.out.find("--view V"), std::string::npos) << tonemap.out;
  EXPECT_EQ(tonemap.out.find("--orbit"), std::string::npos) << tonemap.out;
}
