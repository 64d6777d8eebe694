// Denoising with Intel Open Image Denoise: xi::Denoiser on a render with an exact answer, and
// `xi render --denoise` and `xi denoise` as a user runs them: the layers and attributes they write,
// that the two agree, and that a missing OIDN or a bad input is one error and no file.
//
// Tests that need OIDN skip, saying so, where it is not installed (scripts/install-deps.sh
// --denoise installs it). The CLI's error and bad-input tests need no OIDN: they fail before it
// loads. DenoiseImages opens no OpenCL device, yet stays out of the sanitizer build: the TBB that
// OIDN runs on loads its hwloc binding (libtbbbind) with RTLD_DEEPBIND, which AddressSanitizer's
// runtime refuses.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStringAttribute.h>

#include "cli_test.h"
#include "fixtures.h"
#include "xi/denoise.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace fs = std::filesystem;
using namespace xi_test;

namespace {

const fs::path kTestScenes = fs::path(XI_TEST_DATA_DIR) / "scenes";

// Why OIDN does not load, or "" if it does.
std::string oidn_missing() {
  try {
    xi::load_denoiser();
    return "";
  } catch (const xi::Error& e) {
    return e.what();
  }
}

#define REQUIRE_OIDN()                                              \
  if (const std::string missing = oidn_missing(); !missing.empty()) \
  GTEST_SKIP() << "OIDN not installed: bash scripts/install-deps.sh --denoise\n  (" << missing << ")"

double mse_to(const xi::Image& image, double exact) {
  double sum = 0.0;
  for (const glm::vec3& p : image.pixels)
    for (int c = 0; c < 3; ++c) sum += (p[c] - exact) * (p[c] - exact);
  return sum / (3.0 * image.pixels.size());
}

double image_mean(const xi::Image& image) {
  double sum = 0.0;
  for (const glm::vec3& p : image.pixels) sum += p.x + p.y + p.z;
  return sum / (3.0 * image.pixels.size());
}

xi::Image filled(int w, int h, glm::vec3 value) {
  xi::Image image(w, h);
  std::fill(image.pixels.begin(), image.pixels.end(), value);
  return image;
}

bool same_pixels(const xi::Image& a, const xi::Image& b) {
  return a.width == b.width && a.height == b.height &&
         std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(glm::vec3)) == 0;
}

// The closed furnace of test_analytic.cpp (radiance Le / (1 − ρ) = 2 at every pixel, up to a
// shading-normal bias below 3e-4) at 64 × 64 and 4 spp: noisy, with first-hit albedo and normal.
xi::Film furnace_film(uint32_t seed) {
  xi::Scene scene = xi::load_scene(kTestScenes / "closed-furnace.json");
  scene.width = scene.height = 64;
  xi::Renderer r(xi::test::device(), scene, xi::test::render_options(4, seed, xi::Strategy::Mis, 64));
  r.render();
  return r.film();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// The library.

// Denoised, the noisy furnace comes much closer to its exact value: its MSE against 2 drops by a
// factor of at least 20 (measured: 151 and 80 on OIDN 2.5.1's CPU device; the seeds are fixed),
// and its mean stays within 1% of 2 (the denoiser smooths noise, it does not remove light).
TEST(DenoiseLibrary, FurnaceComesCloserToItsExactValue) {
  REQUIRE_OIDN();
  const double exact = 2.0;
  for (uint32_t seed : {5u, 6u}) {
    const xi::Film film = furnace_film(seed);
    xi::Denoiser denoiser;
    const xi::Image out = denoiser.run(film.mean, &film.albedo, &film.normal);
    const double before = mse_to(film.mean, exact), after = mse_to(out, exact);
    std::printf("  seed %u: MSE %.3g noisy, %.3g denoised (%.0fx less), mean %.4f, %s in %.3f s\n", seed, before,
                after, before / after, image_mean(out), denoiser.description().c_str(), denoiser.last_seconds());
    EXPECT_GT(before, 1e-3) << "the render should be noisy";
    EXPECT_LT(after * 20.0, before) << "seed " << seed;
    EXPECT_NEAR(image_mean(out), exact, 0.01 * exact) << "seed " << seed;
  }
}

// Every quality and prefilter denoises the furnace too (MSE at least 10× lower; seed 5), and they
// are different filters: fast quality or no prefilter changes the result.
TEST(DenoiseLibrary, EveryQualityAndPrefilterDenoises) {
  REQUIRE_OIDN();
  const xi::Film film = furnace_film(5);
  const double before = mse_to(film.mean, 2.0);
  xi::Image best;
  for (auto quality : {xi::DenoiseQuality::High, xi::DenoiseQuality::Balanced, xi::DenoiseQuality::Fast})
    for (auto prefilter : {xi::DenoisePrefilter::Accurate, xi::DenoisePrefilter::Fast, xi::DenoisePrefilter::None}) {
      xi::DenoiseOptions o;
      o.quality = quality;
      o.prefilter = prefilter;
      xi::Denoiser denoiser(o);
      const xi::Image out = denoiser.run(film.mean, &film.albedo, &film.normal);
      const double after = mse_to(out, 2.0);
      std::printf("  quality %d, prefilter %d: MSE %.3g (%.0fx less) in %.3f s\n", (int)quality, (int)prefilter,
                  after, before / after, denoiser.last_seconds());
      EXPECT_LT(after * 10.0, before) << (int)quality << " " << (int)prefilter;
      if (quality == xi::DenoiseQuality::High && prefilter == xi::DenoisePrefilter::Accurate) best = out;
      else if (prefilter != xi::DenoisePrefilter::Fast || quality != xi::DenoiseQuality::High)
        EXPECT_FALSE(same_pixels(out, best)) << (int)quality << " " << (int)prefilter;
    }
  EXPECT_THROW(xi::parse_denoise_quality("best"), xi::Error);
  EXPECT_THROW(xi::parse_denoise_prefilter("slow"), xi::Error);
}

// With the render's OpenCL device a CPU one, OIDN's CPU device denoises.
TEST(DenoiseLibrary, CpuRenderDeviceGivesOidnsCpuDevice) {
  REQUIRE_OIDN();
  if (xi::test::device().info().type != "CPU") GTEST_SKIP() << "the test device is not a CPU";
  xi::Denoiser denoiser(xi::DenoiseOptions{&xi::test::device()});
  EXPECT_NE(denoiser.description().find("(CPU device)"), std::string::npos) << denoiser.description();
}

// ---------------------------------------------------------------------------------------------
// The library on images made here (no OpenCL device).

// A constant radiance of 1 with independent noise of standard deviation 0.2 (a fixed seed), flat
// albedo and normal: denoised, its MSE against 1 drops by a factor of at least 20 (measured: 132
// with the guides, 92 without). OIDN's CPU device answers the same input bit for bit, also
// after an image of another size (its filters made anew) and through xi::denoise.
TEST(DenoiseImages, NoisyConstantImageComesCloserAndRepeatsBitForBit) {
  REQUIRE_OIDN();
  std::mt19937 rng(17);
  std::normal_distribution<float> noise(0.0f, 0.2f);
  xi::Image color(96, 64);
  for (glm::vec3& p : color.pixels) p = glm::max(glm::vec3(1.0f + noise(rng), 1.0f + noise(rng), 1.0f + noise(rng)), 0.0f);
  const xi::Image albedo = filled(96, 64, glm::vec3(0.5f)), normal = filled(96, 64, glm::vec3(0.0f, 0.0f, 1.0f));
  xi::Denoiser denoiser;
  EXPECT_EQ(denoiser.description().rfind("OIDN 2.", 0), 0u) << denoiser.description();
  EXPECT_NE(denoiser.description().find("(CPU device)"), std::string::npos) << denoiser.description();
  const xi::Image guided = denoiser.run(color, &albedo, &normal);
  EXPECT_GT(denoiser.last_seconds(), 0.0);
  const xi::Image alone = denoiser.run(color);
  const double before = mse_to(color, 1.0);
  std::printf("  MSE %.3g noisy, %.3g denoised with albedo and normal, %.3g with the colour alone\n", before,
              mse_to(guided, 1.0), mse_to(alone, 1.0));
  EXPECT_LT(mse_to(guided, 1.0) * 20.0, before);
  EXPECT_LT(mse_to(alone, 1.0) * 20.0, before);
  EXPECT_EQ(denoiser.run(filled(8, 4, glm::vec3(0.25f))).width, 8);
  EXPECT_TRUE(same_pixels(denoiser.run(color, &albedo, &normal), guided));
  EXPECT_TRUE(same_pixels(xi::denoise(color, &albedo, &normal), guided));
}

// Inputs OIDN cannot take are one xi::Error each, naming what is wrong.
TEST(DenoiseImages, BadInputsAreErrors) {
  REQUIRE_OIDN();
  xi::Denoiser denoiser;
  const xi::Image color = filled(16, 16, glm::vec3(1.0f)), albedo = filled(16, 16, glm::vec3(0.5f)),
                  small = filled(8, 16, glm::vec3(0.5f));
  auto expect_error = [&](const xi::Image& c, const xi::Image* a, const xi::Image* n, const std::string& needle) {
    try {
      denoiser.run(c, a, n);
      ADD_FAILURE() << "no error; expected one with '" << needle << "'";
    } catch (const xi::Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_error(color, &small, nullptr, "the albedo is 8x16 but the colour is 16x16");
  expect_error(color, &albedo, &small, "the normal is 8x16");
  expect_error(color, nullptr, &albedo, "needs an albedo");
  expect_error(xi::Image(), nullptr, nullptr, "empty");
  xi::Image nan = color;
  nan.at(3, 2).y = NAN;
  expect_error(nan, nullptr, nullptr, "1 non-finite pixel(s) in the colour");
}

// ---------------------------------------------------------------------------------------------
// The CLI: `xi render --denoise` and `xi denoise`.

class CliDenoise : public CliTest {
 protected:
  // Layer `la` of work_/a and layer `lb` of work_/b hold the same bits.
  void expect_same_layer(const std::string& a, const std::string& la, const std::string& b, const std::string& lb) {
    SCOPED_TRACE("layer '" + la + "' of " + a + " and '" + lb + "' of " + b);
    EXPECT_TRUE(same_pixels(xi::read_exr(work_ / a, la), xi::read_exr(work_ / b, lb)));
  }
  // An EXR as another program might write it: R, G, B in half floats, an alpha channel, an
  // attribute of its own, no albedo or normal.
  void write_foreign_exr(const std::string& name, int w, int h) {
    Imf::Header header(w, h);
    header.insert("owner", Imf::StringAttribute("another renderer"));
    std::vector<Imath::half> rgb((size_t)w * h * 3), alpha((size_t)w * h, Imath::half(1.0f));
    for (size_t i = 0; i < rgb.size(); ++i) rgb[i] = Imath::half(0.25f + 0.5f * float((i * 7919) % 13) / 13.0f);
    Imf::FrameBuffer fb;
    for (int c = 0; c < 3; ++c) {
      const std::string channel(1, "RGB"[c]);
      header.channels().insert(channel, Imf::Channel(Imf::HALF));
      fb.insert(channel, Imf::Slice(Imf::HALF, (char*)(rgb.data() + c), 3 * sizeof(Imath::half),
                                    3 * sizeof(Imath::half) * w));
    }
    header.channels().insert("A", Imf::Channel(Imf::HALF));
    fb.insert("A", Imf::Slice(Imf::HALF, (char*)alpha.data(), sizeof(Imath::half), sizeof(Imath::half) * w));
    Imf::OutputFile file((work_ / name).c_str(), header);
    file.setFrameBuffer(fb);
    file.writePixels(h);
  }
};

// --denoise: R, G, B are denoised, layer noisy is the plain render's R, G, B bit for bit (the same
// seed), the other layers are the plain render's, the PNG is the denoised image's, and the time
// and the denoiser are recorded and printed.
TEST_F(CliDenoise, RenderDenoiseKeepsTheRenderInLayerNoisy) {
  REQUIRE_OIDN();
  const std::vector<std::string> render = {"render", "--spp", "4", "--resolution", "48x32", "--seed", "9"};
  ASSERT_EQ(run_xi(concat(render, {"--quiet", "-o", "plain.exr"})).code, 0);
  const Outcome r = run_xi(concat(render, {"--denoise", "-o", "den.exr"}));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_NE(r.out.find("denoised with OIDN 2."), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(" device"), std::string::npos) << r.out;
  expect_same_layer("den.exr", "noisy", "plain.exr", "");
  for (const char* layer : {"variance", "albedo", "normal"}) expect_same_layer("den.exr", layer, "plain.exr", layer);
  EXPECT_FALSE(same_pixels(xi::read_exr(work_ / "den.exr"), xi::read_exr(work_ / "plain.exr")));
  const xi::ExrAttributes attrs = xi::read_exr_attributes(work_ / "den.exr");
  ASSERT_TRUE(attrs.count("denoiseSeconds"));
  EXPECT_GT(std::get<double>(attrs.at("denoiseSeconds")), 0.0);
  EXPECT_EQ(std::get<std::string>(attrs.at("denoiser")).rfind("OIDN 2.", 0), 0u);
  EXPECT_FALSE(xi::read_exr_attributes(work_ / "plain.exr").count("denoiseSeconds"));
  xi::write_png(work_ / "expected.png", xi::read_exr(work_ / "den.exr"));
  EXPECT_EQ(read_text(work_ / "den.png"), read_text(work_ / "expected.png")) << "the PNG is not the denoised image";
}

// `xi denoise` of a render equals `xi render --denoise` of it: every layer bit for bit, and OUT
// keeps the input's attributes.
TEST_F(CliDenoise, DenoiseCommandEqualsRenderDenoise) {
  REQUIRE_OIDN();
  const std::vector<std::string> render = {"render", "--spp", "4", "--resolution", "40x40", "--seed", "3", "--quiet"};
  ASSERT_EQ(run_xi(concat(render, {"-o", "plain.exr"})).code, 0);
  ASSERT_EQ(run_xi(concat(render, {"--denoise", "-o", "den.exr"})).code, 0);
  const Outcome r = run_xi({"denoise", "plain.exr", "out.exr"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_NE(r.out.find("denoised plain.exr with OIDN 2."), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("wrote out.exr"), std::string::npos) << r.out;
  for (const char* layer : {"", "noisy", "variance", "albedo", "normal"}) expect_same_layer("out.exr", layer, "den.exr", layer);
  const xi::ExrAttributes in = xi::read_exr_attributes(work_ / "plain.exr"), out = xi::read_exr_attributes(work_ / "out.exr");
  for (const auto& [name, value] : in) EXPECT_TRUE(out.count(name) && out.at(name) == value) << name;
  EXPECT_TRUE(out.count("denoiseSeconds"));
  EXPECT_FALSE(has_temp_files());
}

// A snapshot is denoised as the final image is: a long render's first snapshot has layer noisy;
// SIGTERM then writes the image so far, denoised too.
TEST_F(CliDenoise, SnapshotsAreDenoised) {
  REQUIRE_OIDN();
  const pid_t pid = start_xi({"render", "--spp", "100000", "--resolution", "32x32", "--samples-per-pass", "1",
                              "--snapshot-every", "1", "--denoise", "--quiet", "-o", "snap.exr"});
  ASSERT_TRUE(wait_for("snap.exr", 120.0));
  const xi::Image noisy = xi::read_exr(work_ / "snap.exr", "noisy");
  EXPECT_EQ(noisy.width, 32);
  const xi::ExrAttributes attrs = xi::read_exr_attributes(work_ / "snap.exr");
  EXPECT_TRUE(attrs.count("denoiseSeconds"));
  EXPECT_EQ(std::get<int>(attrs.at("sppTarget")), 100000);
  kill(pid, SIGTERM);
  const Outcome r = wait_xi(pid, 120.0);
  EXPECT_EQ(r.code, 128 + SIGTERM) << r.err;
  EXPECT_EQ(xi::read_exr(work_ / "snap.exr", "noisy").width, 32);
}

// An EXR with R, G, B alone: one warning, the colour denoised alone, every channel and attribute
// of the input kept (its half-float R, G, B as layer noisy, bit for bit).
TEST_F(CliDenoise, ForeignExrWithoutGuidesWarnsAndDenoisesTheColour) {
  REQUIRE_OIDN();
  write_foreign_exr("foreign.exr", 24, 16);
  const Outcome r = run_xi({"denoise", "foreign.exr", "out.exr"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.rfind("xi: warning: foreign.exr has no albedo and normal layers", 0), 0u) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  expect_same_layer("out.exr", "noisy", "foreign.exr", "");
  EXPECT_EQ(xi::read_exr(work_ / "out.exr").width, 24);
  EXPECT_EQ(std::get<std::string>(xi::read_exr_attributes(work_ / "out.exr").at("owner")), "another renderer");
  Imf::InputFile out((work_ / "out.exr").c_str());
  ASSERT_TRUE(out.header().channels().findChannel("A"));
  EXPECT_EQ(out.header().channels().findChannel("A")->type, Imf::HALF);
  EXPECT_EQ(out.header().channels().findChannel("noisy.R")->type, Imf::HALF);
  EXPECT_EQ(out.header().channels().findChannel("R")->type, Imf::FLOAT);
}

// Without OIDN (XI_OIDN_PATH naming an empty folder): `xi render --denoise` is one error naming
// where it looked and how to install it, before the render (nothing on stdout), and no file; so
// is `xi denoise`.
TEST_F(CliDenoise, MissingOidnIsOneErrorAndNoFile) {
  const fs::path empty = work_ / "no-oidn";
  fs::create_directories(empty);
  const xi::Image image = filled(8, 8, glm::vec3(0.5f));
  xi::write_exr(work_ / "in.exr", {{"", &image}});
  const auto before = files();
  const std::string setup = "export XI_OIDN_PATH=" + quote(empty.string());
  const std::vector<std::string> needles = {"OIDN", "is not installed", "XI_OIDN_PATH=" + empty.string(),
                                            "bash scripts/install-deps.sh --denoise"};
  expect_user_error(run_xi(concat({"render", "--denoise", "-o", "out.exr"}, kFast), setup), needles, before);
  expect_user_error(run_xi({"denoise", "in.exr", "out.exr"}, setup), needles, before);
}

// Bad input to `xi denoise`: one error line naming the file and the fault, and no output file.
// (All of these fail before OIDN is loaded, so they need none.)
TEST_F(CliDenoise, BadInputIsOneErrorAndNoFile) {
  const int w = 32, h = 32;
  const xi::Image image = filled(w, h, glm::vec3(0.5f));
  write_text(work_ / "text.exr", "this is not an EXR file\n");
  xi::write_exr(work_ / "albedo-only.exr", {{"albedo", &image}});
  xi::write_exr(work_ / "denoised.exr", {{"", &image}, {"noisy", &image}});
  xi::Image nan = image;
  nan.at(5, 7).x = NAN;
  xi::write_exr(work_ / "nan.exr", {{"", &nan}, {"albedo", &image}, {"normal", &image}});
  {  // albedo stored at half the resolution (x and y sampling 2)
    Imf::Header header(w, h);
    std::vector<float> full((size_t)w * h, 0.5f), half_res((size_t)w * h / 4, 0.5f);
    Imf::FrameBuffer fb;
    for (const char* c : {"R", "G", "B"}) {
      header.channels().insert(c, Imf::Channel(Imf::FLOAT));
      fb.insert(c, Imf::Slice(Imf::FLOAT, (char*)full.data(), sizeof(float), sizeof(float) * w));
    }
    for (const char* c : {"albedo.R", "albedo.G", "albedo.B"}) {
      header.channels().insert(c, Imf::Channel(Imf::FLOAT, 2, 2));
      fb.insert(c, Imf::Slice(Imf::FLOAT, (char*)half_res.data(), sizeof(float), sizeof(float) * w / 2, 2, 2));
    }
    Imf::OutputFile file((work_ / "small-albedo.exr").c_str(), header);
    file.setFrameBuffer(fb);
    file.writePixels(h);
  }
  const auto before = files();
  expect_user_error(run_xi({"denoise", "missing.exr", "out.exr"}), {"no such EXR file", "missing.exr"}, before);
  expect_user_error(run_xi({"denoise", "text.exr", "out.exr"}), {"cannot read EXR", "text.exr"}, before);
  expect_user_error(run_xi({"denoise", "albedo-only.exr", "out.exr"}), {"no R, G, B channels", "albedo-only.exr"},
                    before);
  expect_user_error(run_xi({"denoise", "small-albedo.exr", "out.exr"}),
                    {"channel 'albedo.B' is stored at 16x16 but the image is 32x32", "small-albedo.exr"}, before);
  expect_user_error(run_xi({"denoise", "nan.exr", "out.exr"}),
                    {"1 non-finite pixel(s) in the colour of nan.exr", "x=5, y=7"}, before);
  expect_user_error(run_xi({"denoise", "denoised.exr", "out.exr"}), {"already denoised", "denoised.exr"}, before);
  expect_user_error(run_xi({"denoise", "nan.exr", "out.png"}), {"must be an .exr file"}, before);
  expect_user_error(run_xi({"denoise", "nan.exr", "no-such-folder/out.exr"}), {"output folder does not exist"}, before);
  expect_user_error(run_xi({"denoise", "nan.exr"}), {"expected IN.exr OUT.exr"}, before);
  expect_user_error(run_xi({"denoise", "nan.exr", "out.exr", "--denoise-quality", "best"}),
                    {"--denoise-quality best", "high, balanced or fast"}, before);
  expect_user_error(run_xi({"render", "--spp", "1", "-o", "r.exr", "--denoise-prefilter", "fast"}),
                    {"--denoise-prefilter", "needs --denoise"}, before);
  expect_user_error(run_xi({"render", "--spp", "1", "-o", "r.exr", "--denoise", "--denoise-prefilter", "slow"}),
                    {"--denoise-prefilter slow", "accurate, fast or none"}, before);
}

// `xi help denoise` and `xi render --help` document it.
TEST_F(CliDenoise, HelpDocumentsIt) {
  const Outcome help = run_xi({"help", "denoise"});
  EXPECT_EQ(help.code, 0);
  EXPECT_NE(help.out.find("denoise IN.exr OUT.exr"), std::string::npos) << help.out;
  EXPECT_NE(help.out.find("install-deps.sh --denoise"), std::string::npos) << help.out;
  EXPECT_NE(run_xi({"render", "--help"}).out.find("--denoise"), std::string::npos);
}
