// The `xi` program as a user runs it: XI_CLI_PATH started through the shell in a fresh folder, with
// its exit code, stdout and stderr captured. Checks the files a render writes (and reads them back),
// `xi devices`, and that every kind of bad input fails with exit code 1, one line
// "xi: error: <what> (<where>)" naming the file and field at fault, and no file left behind.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli.h"
#include "cli_test.h"
#include "xi/kernel_config.h"
#include "xi/device.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/renderer.h"
#include "xi/scene.h"
#include "fixtures.h"

namespace fs = std::filesystem;
using json = nlohmann::json;

using namespace xi_test;

// ---------------------------------------------------------------------------------------------
// A successful render.

class CliRender : public CliTest {};

TEST_F(CliRender, WritesExrAndPngWithAttributes) {
  const Outcome r = run_xi({"render", "--spp", "2", "--resolution", "32x32", "-o", "out.exr", "--quiet"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out, "");  // --quiet: no summary
  EXPECT_EQ(r.err, "");  // no progress bar (stderr is not a terminal), no warning
  ASSERT_TRUE(fs::is_regular_file(work_ / "out.exr"));
  ASSERT_TRUE(fs::is_regular_file(work_ / "out.png"));

  const xi::Image exr = xi::read_exr(work_ / "out.exr");
  EXPECT_EQ(exr.width, 32);
  EXPECT_EQ(exr.height, 32);
  const xi::Image var = xi::read_exr(work_ / "out.exr", "variance");
  EXPECT_EQ(var.width, 32);
  EXPECT_EQ(var.height, 32);
  const xi::Image png = xi::read_png(work_ / "out.png");
  ASSERT_EQ(png.width, 32);
  ASSERT_EQ(png.height, 32);

  size_t lit = 0;
  for (size_t i = 0; i < exr.pixels.size(); ++i) {
    for (int c = 0; c < 3; ++c) {
      ASSERT_TRUE(std::isfinite(exr.pixels[i][c]) && exr.pixels[i][c] >= 0.0f) << "pixel " << i;
      ASSERT_TRUE(std::isfinite(var.pixels[i][c]) && var.pixels[i][c] >= 0.0f) << "pixel " << i;
      // The PNG is the EXR clipped to [0, 1], sRGB-encoded to 8 bits (exposure 1). Decoded back,
      // it is within half an 8-bit step of the clipped value; the widest step in linear terms is
      // the top one, 1 - decode(254/255) = 0.0089, so 0.005 allows a half step with margin.
      EXPECT_NEAR(png.pixels[i][c], std::clamp(exr.pixels[i][c], 0.0f, 1.0f), 0.005f) << "pixel " << i;
    }
    lit += exr.pixels[i].x + exr.pixels[i].y + exr.pixels[i].z > 0.0f;
  }
  EXPECT_GT(lit, exr.pixels.size() / 2);

  const xi::ExrAttributes attrs = xi::read_exr_attributes(work_ / "out.exr");
  auto get = [&](const std::string& name) -> const xi::ExrAttribute* {
    auto it = attrs.find(name);
    return it == attrs.end() ? nullptr : &it->second;
  };
  ASSERT_TRUE(get("spp") && std::holds_alternative<int>(*get("spp")));
  EXPECT_EQ(std::get<int>(*get("spp")), 2);
  ASSERT_TRUE(get("seed") && std::holds_alternative<int>(*get("seed")));
  EXPECT_EQ(std::get<int>(*get("seed")), (int)xi::load_scene(kCornell).render.seed);  // the scene's default
  ASSERT_TRUE(get("scene") && std::holds_alternative<std::string>(*get("scene")));
  EXPECT_EQ(fs::path(std::get<std::string>(*get("scene"))).filename(), "cornell-box.json");
  ASSERT_TRUE(get("device") && std::holds_alternative<std::string>(*get("device")));
  EXPECT_EQ(std::get<std::string>(*get("device")), xi::Device::open("").info().name);
  ASSERT_TRUE(get("renderSeconds") && std::holds_alternative<double>(*get("renderSeconds")));
  EXPECT_GT(std::get<double>(*get("renderSeconds")), 0.0);
  EXPECT_LT(std::get<double>(*get("renderSeconds")), 600.0);
}

TEST_F(CliRender, LeavesNoTemporaryFiles) {
  const Outcome r = run_xi(concat({"render", "-o", "out.exr"}, kFast));
  ASSERT_EQ(r.code, 0) << r.err;
  // The writers go through NAME.tmpPID and rename; nothing of that kind may remain.
  EXPECT_EQ(files(), (std::set<std::string>{"out.exr", "out.png"}));
  for (const auto& name : files()) EXPECT_EQ(name.find(".tmp"), std::string::npos) << name;
  // Rendering again over existing files replaces them, again without leftovers.
  const Outcome again = run_xi(concat({"render", "-o", "out.exr", "--seed", "3"}, kFast));
  ASSERT_EQ(again.code, 0) << again.err;
  EXPECT_EQ(files(), (std::set<std::string>{"out.exr", "out.png"}));
  EXPECT_EQ(std::get<int>(xi::read_exr_attributes(work_ / "out.exr").at("seed")), 3);
}

// --threads N: PoCL's CPU device runs N compute units (it reports them, and xi prints them); any
// other device says that it keeps its own. Out of range is refused.
TEST_F(CliRender, ThreadsCapsPoclsComputeUnits) {
  const Outcome r = run_xi({"render", "-o", "out.exr", "--threads", "1", "--spp", "1", "--resolution", "16x16"});
  ASSERT_EQ(r.code, 0) << r.err;
  const xi::DeviceInfo d = xi::Device::open("").info();
  if (d.platform.find("Portable Computing Language") != std::string::npos && d.type == "CPU") {
    EXPECT_NE(r.out.find("1 compute units)"), std::string::npos) << r.out;
    EXPECT_EQ(r.err.find("--threads"), std::string::npos) << r.err;
  } else {
    EXPECT_NE(r.err.find("warning: --threads 1"), std::string::npos) << r.err;
  }
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "-o", "out.exr", "--threads", "0"}, kFast)), {"--threads", "out of range"},
                    before);
}

// --threads N caps the BVH build too: an 81,920-triangle sphere, large enough to be built in
// subtrees on threads of their own, is built on one thread with --threads 1 and on more with 2,
// whatever the machine's cores.
TEST_F(CliRender, ThreadsCapsTheBvhBuild) {
  xi_test::write_text(work_ / "sphere.json", R"({"camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "film": {"width": 8, "height": 8}, "background": [1, 1, 1],
    "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [{"type": "sphere", "material": "w", "center": [0, 0, 0], "radius": 1, "subdivisions": 6}]})");
  for (const char* threads : {"1", "2"}) {
    const Outcome r = run_xi({"render", "sphere.json", "--spp", "1", "--threads", threads, "-o", "out.exr"});
    ASSERT_EQ(r.code, 0) << r.err;
    ASSERT_NE(r.out.find("81920 triangles"), std::string::npos) << r.out;
    const bool one = r.out.find(" on 1 thread;") != std::string::npos;
    EXPECT_EQ(one, std::string(threads) == "1") << "--threads " << threads << ": " << r.out;
  }
}

// A new scene's kernels are compiled once each, with their program: PoCL is not left to generate
// another work-group function for each launch configuration at the first launches (seconds per
// kernel), so its cache holds one function per kernel, the general one ("0-0-0").
TEST_F(CliRender, PoclCompilesOneWorkGroupFunctionPerKernel) {
  const xi::DeviceInfo d = xi::Device::open("").info();
  if (d.platform.find("Portable Computing Language") == std::string::npos)
    GTEST_SKIP() << "the default device is not PoCL's (" << d.platform << ")";
  const fs::path xi_cache = root_ / "xi-cache", pocl_cache = root_ / "pocl-cache";
  const Outcome r = run_xi(concat({"render", "-o", "out.exr", "--kernels", "scene"}, kFast),
                           "unset POCL_WORK_GROUP_SPECIALIZATION; export XI_CACHE_DIR=" + quote(xi_cache.string()) +
                               " POCL_CACHE_DIR=" + quote(pocl_cache.string()));
  ASSERT_EQ(r.code, 0) << r.err;
  // PoCL's cache: <two letters>/<program hash>/{program.bc, <kernel>/<work-group function>/...}.
  std::set<std::string> kernels;
  for (const auto& program : fs::recursive_directory_iterator(pocl_cache)) {
    if (program.path().filename() != "program.bc") continue;
    for (const auto& kernel : fs::directory_iterator(program.path().parent_path())) {
      if (!kernel.is_directory()) continue;
      kernels.insert(kernel.path().filename().string());
      std::set<std::string> functions;
      for (const auto& f : fs::directory_iterator(kernel.path())) functions.insert(f.path().filename().string());
      EXPECT_EQ(functions, std::set<std::string>{"0-0-0"}) << kernel.path();
    }
  }
  EXPECT_EQ(kernels, (std::set<std::string>{"accumulate", "extend", "generate", "shade", "shadow"}));
}

// A render that builds its kernels prints nothing on stderr. The hard case: 16-lane code built for a
// CPU without AVX-512 (PoCL's AVX2 kernel library and Haswell target, as an AVX2 machine's PoCL
// builds, chosen here by POCL_KERNELLIB_NAME) draws a warning per 512-bit vector argument, whose
// count PoCL prints on stderr unless the build asks for no warnings.
TEST_F(CliRender, KernelBuildsPrintNothing) {
  const xi::DeviceInfo d = xi::Device::open("").info();
  if (d.platform.find("Portable Computing Language") == std::string::npos || d.type != "CPU")
    GTEST_SKIP() << "the default device is not PoCL's CPU device (" << d.platform << ")";
  bool avx2_library = false;  // PoCL's kernel library for AVX2 CPUs, beside the others it chooses from
  std::error_code no_folder;
  for (const auto& f : fs::directory_iterator("/usr/share/pocl", no_folder))
    avx2_library |= f.path().filename().string().ends_with("-avx2.bc");
  if (!avx2_library || !xi::CpuVectors::of_this_cpu().avx2)
    GTEST_SKIP() << "PoCL has no AVX2 kernel library in /usr/share/pocl, or this CPU has no AVX2 and FMA";
  const std::string avx2 = "export POCL_KERNELLIB_NAME=avx2";
  const Outcome devices = run_xi({"devices"}, avx2);
  ASSERT_NE(devices.out.find("haswell"), std::string::npos) << "PoCL did not take the Haswell target:\n" << devices.out;
  const Outcome r = run_xi(concat({"render", "-o", "out.exr", "--lanes", "16", "--packet-width", "16"}, kFast),
                           avx2 + " XI_CACHE_DIR=" + quote((root_ / "xi-cache").string()) +
                               " POCL_CACHE_DIR=" + quote((root_ / "pocl-cache").string()));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
}

// -o may name the PNG instead of the EXR: both are written, the EXR beside the PNG (any other
// extension: CliBadInput.OutputNeitherExrNorPng).
TEST_F(CliRender, OutputNamedByItsPng) {
  const Outcome r = run_xi(concat({"render", "-o", "picture.png"}, kFast));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(files(), (std::set<std::string>{"picture.exr", "picture.png"}));
  const Outcome exr = run_xi(concat({"render", "-o", "same.exr"}, kFast));
  ASSERT_EQ(exr.code, 0) << exr.err;
  const xi::Image png = xi::read_png(work_ / "picture.png"), same_png = xi::read_png(work_ / "same.png");
  EXPECT_EQ(png.pixels, same_png.pixels);
  EXPECT_EQ(xi::read_exr(work_ / "picture.exr").pixels, xi::read_exr(work_ / "same.exr").pixels);
}

// The CLI passes --resolution, --spp and --seed through to the renderer: its EXR holds exactly the
// floats the library produces for the same settings (the EXR stores 32-bit floats, so bitwise).
TEST_F(CliRender, MatchesTheLibrary) {
  const Outcome r = run_xi({"render", "--spp", "3", "--seed", "17", "--resolution", "24x16", "-o", "out.exr", "--quiet"});
  ASSERT_EQ(r.code, 0) << r.err;
  const xi::Image cli = xi::read_exr(work_ / "out.exr");

  xi::Scene scene = xi::load_scene(kCornell);
  scene.width = 24;
  scene.height = 16;
  const xi::RenderOptions opt =
      xi::test::render_options(3, 17, xi::Strategy::Mis, scene.render.max_depth, xi::parse_sampler(scene.render.sampler));
  xi::Device& device = xi::test::device();
  xi::Renderer renderer(device, scene, opt);
  renderer.render();
  const xi::Image lib = renderer.mean();

  ASSERT_EQ(cli.width, 24);
  ASSERT_EQ(cli.height, 16);
  size_t differ = 0;
  for (size_t i = 0; i < lib.pixels.size(); ++i) differ += lib.pixels[i] != cli.pixels[i];
  EXPECT_EQ(differ, 0u);
}

// --layering overrides the scene's render.layering: a white rough dielectric under a white sky
// (one bounce) reflects all of it with albedo scaling (within its tables' 1%) and loses some with
// the Fresnel mix, which must come out darker by more than 5 standard errors.
TEST_F(CliRender, LayeringFlagChoosesTheModel) {
  xi_test::write_text(work_ / "white.json", R"({"camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 20},
    "film": {"width": 8, "height": 8}, "background": [1, 1, 1], "render": {"max_depth": 1},
    "materials": {"w": {"type": "pbr", "base_color": [1, 1, 1], "roughness": 0.5}},
    "shapes": [{"type": "quad", "material": "w", "vertices": [[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]]}]})");
  auto mean = [&](const std::string& layering, double* se) {
    const std::string out = (layering.empty() ? "default" : layering) + ".exr";
    std::vector<std::string> args = {"render", "white.json", "--spp", "256", "--sampler", "random", "-o", out, "--quiet"};
    if (!layering.empty()) args.insert(args.end(), {"--layering", layering});
    const Outcome r = run_xi(args);
    EXPECT_EQ(r.code, 0) << r.err;
    const xi::Image img = xi::read_exr(work_ / out);
    double sum = 0.0, var = 0.0;
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) sum += img.at(x, y).y;
    const size_t n = size_t(img.width) * img.height;
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) var += std::pow(img.at(x, y).y - sum / n, 2.0);
    *se = std::sqrt(var / (n - 1) / n);
    return sum / n;
  };
  double se_default, se_scaled, se_mix;
  const double by_default = mean("", &se_default), scaled = mean("albedo-scaling", &se_scaled),
               mix = mean("fresnel-mix", &se_mix);
  EXPECT_EQ(by_default, scaled);
  EXPECT_NEAR(scaled, 1.0, 0.01 + 4.0 * se_scaled);
  EXPECT_LT(mix, scaled - 5.0 * std::hypot(se_mix, se_scaled));
}

// ---------------------------------------------------------------------------------------------
// Devices.

// A point light is a delta: BSDF sampling alone never reaches it, so `--strategy bsdf` says it
// lights nothing, once; the other strategies reach it and say nothing.
TEST_F(CliRender, BsdfStrategyWarnsThatPunctualLightsLightNothing) {
  write_scene("point.json", [](json& j) {
    j["lights"] = {{{"type", "point"}, {"position", {278, 500, 279}}, {"intensity", 1e5}}};
  });
  const std::string warning = "--strategy bsdf: punctual lights are reached by light sampling only";
  for (const char* strategy : {"bsdf", "mis"}) {
    const Outcome r = run_xi({"render", "point.json", "--spp", "1", "--resolution", "16x16", "--strategy", strategy,
                              "-o", "out.exr", "--quiet"});
    ASSERT_EQ(r.code, 0) << r.err;
    const bool bsdf = std::string(strategy) == "bsdf";
    EXPECT_EQ(r.err.find(warning) != std::string::npos, bsdf) << strategy << ": " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), bsdf ? 1 : 0) << strategy << ": " << r.err;
  }
  // Without punctual lights, no warning.
  const Outcome r = run_xi({"render", "--spp", "1", "--resolution", "16x16", "--strategy", "bsdf", "-o", "out.exr",
                            "--quiet"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
}

class CliDevices : public CliTest {};

TEST_F(CliDevices, ListsAtLeastOne) {
  const Outcome r = run_xi({"devices"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  // A header, then one line per device starting with its index.
  std::istringstream lines(r.out);
  std::string line;
  int devices = 0;
  const std::regex device_line(R"(^\d+\s+\S.*)");
  while (std::getline(lines, line)) devices += std::regex_match(line, device_line);
  EXPECT_GE(devices, 1) << r.out;
  EXPECT_EQ(devices, (int)xi::list_devices().size()) << r.out;
  // The default device appears by name.
  EXPECT_NE(r.out.find(xi::Device::open("").info().name), std::string::npos) << r.out;
}

// The selectors that do match work, so the failures below are about the selector alone.
TEST_F(CliDevices, SelectsByIndexAndName) {
  const Outcome by_index = run_xi(concat({"render", "-o", "a.exr", "--device", "0"}, kFast));
  EXPECT_EQ(by_index.code, 0) << by_index.err;
  EXPECT_TRUE(fs::exists(work_ / "a.exr"));
  const std::string name = xi::Device::open("0").info().name;
  const Outcome by_name = run_xi(concat({"render", "-o", "b.exr", "--device", name.substr(0, 6)}, kFast));
  EXPECT_EQ(by_name.code, 0) << by_name.err;
  EXPECT_TRUE(fs::exists(work_ / "b.exr"));
}

TEST_F(CliDevices, UnknownNameFails) {
  const auto before = files();
  const Outcome r = run_xi(concat({"render", "-o", "out.exr", "--device", "nosuchdevice"}, kFast));
  expect_user_error(r, {"nosuchdevice", "--device"}, before);
}

// The same through $XI_DEVICE: the error names the variable, not a flag the user never typed.
TEST_F(CliDevices, UnknownEnvironmentDeviceNamesTheVariable) {
  const auto before = files();
  const xi::test::ScopedEnv device("XI_DEVICE", "nosuchdevice");
  const Outcome r = run_xi(concat({"render", "-o", "out.exr"}, kFast));
  expect_user_error(r, {"nosuchdevice", "XI_DEVICE"}, before);
  EXPECT_EQ(r.err.find("--device"), std::string::npos) << r.err;
}

TEST_F(CliDevices, IndexOutOfRangeFails) {
  const auto before = files();
  const Outcome r = run_xi(concat({"render", "-o", "out.exr", "--device", "99"}, kFast));
  expect_user_error(r, {"99", "--device"}, before);
}

// ---------------------------------------------------------------------------------------------
// Bad input: exit 1, one line naming the file and the field, no output.

class CliBadInput : public CliTest {
 protected:
  // Each value of `flag` on an otherwise good small render: one error naming the flag and the value,
  // a non-zero exit, and no file written.
  void expect_each_refused(const std::string& flag, std::initializer_list<std::string> values) {
    const auto before = files();
    for (const std::string& value : values) {
      SCOPED_TRACE(flag + " " + value);
      expect_user_error(run_xi({"render", "-o", "out.exr", "--quiet", "--resolution", "32x32", "--spp", "1", flag,
                                value}),
                        {flag, value}, before);
    }
  }
};

TEST_F(CliBadInput, MissingSceneFile) {
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "nosuch.json", "-o", "out.exr"}, kFast)), {"nosuch.json", "cannot open"},
                    before);
}

TEST_F(CliBadInput, SceneIsAFolder) {
  fs::create_directory(work_ / "folder.json");
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "folder.json", "-o", "out.exr"}, kFast)), {"folder.json"}, before);
}

TEST_F(CliBadInput, MalformedJson) {
  std::string text = read_text(kCornell);
  text.erase(text.rfind(']'));  // cut off the end: the shapes array is never closed
  write_text(work_ / "bad.json", text);
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "bad.json", "-o", "out.exr"}, kFast)), {"bad.json", "invalid JSON", "byte"},
                    before);
}

TEST_F(CliBadInput, UnknownMaterial) {
  write_scene("bad.json", [](json& j) { j["shapes"][2]["material"] = "unobtanium"; });
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "bad.json", "-o", "out.exr"}, kFast)),
                    {"bad.json", "/shapes/2/material", "unobtanium"}, before);
}

TEST_F(CliBadInput, MissingMeshFile) {
  write_scene("bad.json", [](json& j) {
    j["shapes"][3] = {{"type", "mesh"}, {"material", "white"}, {"file", "missing.obj"}};
  });
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "bad.json", "-o", "out.exr"}, kFast)),
                    {"bad.json", "/shapes/3/file", "missing.obj"}, before);
}

// 1e999 overflows a double: JSON allows the literal, the reader must reject it, naming the field.
// Once in an object member and once as an array element (the path tracking differs).
TEST_F(CliBadInput, NumberOutOfRange) {
  write_scene("fov.json", [](json& j) { j["camera"]["focal_length_mm"] = 123456.5; });
  std::string text = read_text(work_ / "fov.json");
  text.replace(text.find("123456.5"), 8, "1e999");
  write_text(work_ / "fov.json", text);
  write_scene("albedo.json", [](json& j) { j["materials"]["red"]["albedo"][1] = 123456.5; });
  text = read_text(work_ / "albedo.json");
  text.replace(text.find("123456.5"), 8, "1e999");
  write_text(work_ / "albedo.json", text);
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "fov.json", "-o", "out.exr"}, kFast)),
                    {"fov.json", "/camera/focal_length_mm", "1e999"}, before);
  expect_user_error(run_xi(concat({"render", "albedo.json", "-o", "out.exr"}, kFast)),
                    {"albedo.json", "/materials/red/albedo/1", "1e999"}, before);
}

// A number that fits a double but not a float (the kernels use floats) is rejected too.
TEST_F(CliBadInput, NumberBeyondFloat) {
  write_scene("bad.json", [](json& j) { j["materials"]["light"]["radiance"][0] = 1e300; });
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "bad.json", "-o", "out.exr"}, kFast)),
                    {"bad.json", "/materials/light/radiance/0", "finite"}, before);
}

// NaN and Infinity are not JSON: a syntax error, located by byte offset.
TEST_F(CliBadInput, NanLiteral) {
  for (const std::string literal : {"NaN", "Infinity"}) {
    SCOPED_TRACE(literal);
    write_scene("bad.json", [](json& j) { j["camera"]["focal_length_mm"] = 123456.5; });
    std::string text = read_text(work_ / "bad.json");
    text.replace(text.find("123456.5"), 8, literal);
    write_text(work_ / "bad.json", text);
    const auto before = files();
    expect_user_error(run_xi(concat({"render", "bad.json", "-o", "out.exr"}, kFast)),
                      {"bad.json", "invalid JSON", "byte"}, before);
  }
}

// A radiance of 1e20 seen directly squares beyond the largest float: the render succeeds, its mean
// finite, and says how many pixels' variance layer holds infinity; the bundled box says nothing of it.
TEST_F(CliRender, VarianceOverflowIsReported) {
  write_scene("bright.json", [](json& j) { j["materials"]["light"]["radiance"] = {1e20, 1e20, 1e20}; });
  const Outcome r = run_xi(concat({"render", "bright.json", "-o", "bright.exr"}, kFast));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.rfind("xi: warning: the variance of ", 0), 0u) << r.err;
  EXPECT_NE(r.err.find(" pixel(s) overflows single precision (samples above about 1e19)"), std::string::npos) << r.err;
  const xi::Image mean = xi::read_exr(work_ / "bright.exr");
  for (const glm::vec3& p : mean.pixels) ASSERT_TRUE(std::isfinite(p.x + p.y + p.z));
  const Outcome plain = run_xi(concat({"render", "-o", "plain.exr"}, kFast));
  ASSERT_EQ(plain.code, 0) << plain.err;
  EXPECT_EQ(plain.err, "");
}

// --paths-in-flight and --samples-per-pass change how the work is cut, never the image: the EXRs
// of all settings hold the same floats (bitwise), and the summary names what was chosen.
TEST_F(CliRender, PathsInFlightDoNotChangeTheImage) {
  const std::vector<std::string> base = {"render", "--spp", "5", "--resolution", "24x16", "--seed", "4"};
  ASSERT_EQ(run_xi(concat(base, {"-o", "a.exr", "--quiet"})).code, 0);
  const xi::Image a = xi::read_exr(work_ / "a.exr");
  struct Case { const char* paths; const char* per_pass; const char* summary; };
  // (An empty value: the flag left out, its default.)
  for (Case c : {Case{"100", "", "paths in flight: 100, 1 spp per pass"},
                 Case{"1000", "", "paths in flight: 768, 2 spp per pass"},
                 Case{"", "3", ", 3 spp per pass"}}) {
    SCOPED_TRACE(std::string(c.paths) + " paths, " + c.per_pass + " per pass");
    std::vector<std::string> args = concat(base, {"-o", "b.exr"});
    if (*c.paths) args = concat(args, {"--paths-in-flight", c.paths});
    if (*c.per_pass) args = concat(args, {"--samples-per-pass", c.per_pass});
    const Outcome r = run_xi(args);
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find(c.summary), std::string::npos) << r.out;
    const xi::Image b = xi::read_exr(work_ / "b.exr");
    ASSERT_EQ(a.pixels.size(), b.pixels.size());
    EXPECT_EQ(std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(glm::vec3)), 0);
    EXPECT_EQ(std::get<int>(xi::read_exr_attributes(work_ / "b.exr").at("spp")), 5);
  }
  const auto before = files();
  for (const char* bad : {"-1", "0"})
    expect_user_error(run_xi(concat(base, {"-o", "c.exr", "--paths-in-flight", bad})), {"--paths-in-flight", bad}, before);
  for (const char* bad : {"x", "0"})
    expect_user_error(run_xi(concat(base, {"-o", "c.exr", "--samples-per-pass", bad})), {"--samples-per-pass", bad}, before);
}

// --no-spatial-splits reaches the BVH build: a scene of slanted long triangles (a fan of blades
// through a box) is split by default (more references than triangles in the `bvh:` line) and not
// with the flag, and the two images are the same.
// The BVH build runs on the cores PoCL may use: with POCL_MAX_PTHREAD_COUNT=1 on one thread; with
// it unset, on a machine of several cores, subtrees go to threads of their own. The image is the same.
TEST_F(CliRender, BuildThreadsFollowPoclsCoreCount) {
  write_grid_scene("grid.json");
  const std::vector<std::string> base = {"render", "grid.json", "--spp", "1", "--resolution", "16x16"};
  const Outcome one = run_xi(concat(base, {"-o", "one.exr"}), "export POCL_MAX_PTHREAD_COUNT=1");
  const Outcome all = run_xi(concat(base, {"-o", "all.exr"}), "unset POCL_MAX_PTHREAD_COUNT");
  ASSERT_EQ(one.code, 0) << one.err;
  ASSERT_EQ(all.code, 0) << all.err;
  EXPECT_NE(one.out.find("scene: grid.json, 20032 triangles"), std::string::npos) << one.out;
  EXPECT_EQ(build_threads(one.out), 1) << one.out;
  if (std::thread::hardware_concurrency() > 1)
    EXPECT_GT(build_threads(all.out), 1) << all.out;
  else
    std::printf("note: one core here, so the unset case builds on one thread too\n");
  expect_same_image("one.exr", "all.exr");
}

TEST_F(CliRender, NoSpatialSplitsBuildsOneReferencePerTriangle) {
  std::string shapes;
  for (int i = 0; i < 40; ++i) {
    const float x = -1.0f + 0.05f * (float)i;
    shapes += ", {\"type\": \"triangle\", \"material\": \"white\", \"vertices\": [[" + std::to_string(x) +
              ", -1, -1], [" + std::to_string(-x) + ", 1, 1], [" + std::to_string(x + 0.02f) + ", -1, -0.9]]}";
  }
  std::ofstream(work_ / "blades.json")
      << R"({"camera": {"position": [0, 0, -4], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
  "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]},
                "light": {"type": "emitter", "radiance": [4, 4, 4]}},
  "shapes": [{"type": "quad", "material": "light", "vertices": [[-1, 2, -1], [1, 2, -1], [1, 2, 1], [-1, 2, 1]]})"
      << shapes << "]}";
  auto references = [](const std::string& out) {
    const size_t at = out.find(" triangle references");
    if (at == std::string::npos) return -1L;
    return std::stol(out.substr(out.rfind(' ', at - 1) + 1, at));
  };
  const std::vector<std::string> base = {"render", "blades.json", "--spp", "2", "--resolution", "24x16"};
  const Outcome split = run_xi(concat(base, {"-o", "a.exr"}));
  const Outcome plain = run_xi(concat(base, {"-o", "b.exr", "--no-spatial-splits"}));
  ASSERT_EQ(split.code, 0) << split.err;
  ASSERT_EQ(plain.code, 0) << plain.err;
  EXPECT_NE(split.out.find("scene: blades.json, 42 triangles"), std::string::npos) << split.out;
  EXPECT_GT(references(split.out), 42) << split.out;
  EXPECT_EQ(references(plain.out), 42) << plain.out;
  const xi::Image a = xi::read_exr(work_ / "a.exr"), b = xi::read_exr(work_ / "b.exr");
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  EXPECT_EQ(std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(glm::vec3)), 0);
}

// `xi render` says which rays go through the tree in packets and how many rays a packet holds, and
// --ray-packets and --packet-width change it but not the image (ties aside, none in this frame):
// the Cornell box's tree of 2 nodes takes bounce and shadow packets by default (hybrid ones when
// told), an 8-wide tree always takes camera packets, and a 4-wide one none; a mode it does not know
// is an error naming the modes.
TEST_F(CliRender, SaysWhichRaysGoInPackets) {
  const std::vector<std::string> base = {"render", kCornell.string(), "--spp", "2", "--resolution", "32x24"};
  const Outcome automatic = run_xi(concat(base, {"-o", "a.exr", "--bvh-width", "8", "--packet-width", "16"}));
  const Outcome off =
      run_xi(concat(base, {"-o", "b.exr", "--bvh-width", "8", "--ray-packets", "off", "--packet-width", "8"}));
  const Outcome four = run_xi(concat(base, {"-o", "c.exr", "--bvh-width", "4", "--ray-packets", "on"}));
  const Outcome hybrid =
      run_xi(concat(base, {"-o", "d.exr", "--bvh-width", "8", "--ray-packets", "hybrid", "--packet-width", "16"}));
  const Outcome unknown = run_xi(concat(base, {"-o", "e.exr", "--ray-packets", "some"}));
  for (const Outcome* o : {&automatic, &off, &four, &hybrid}) ASSERT_EQ(o->code, 0) << o->err;
  EXPECT_NE(automatic.out.find("; camera, bounce and shadow rays in packets of 16\n"), std::string::npos) << automatic.out;
  EXPECT_NE(off.out.find("; camera rays in packets of 8\n"), std::string::npos) << off.out;
  EXPECT_EQ(four.out.find("in packets"), std::string::npos) << four.out;
  EXPECT_NE(hybrid.out.find("; camera rays in packets of 16, the first bounce's in hybrid packets\n"),
            std::string::npos)
      << hybrid.out;
  EXPECT_NE(unknown.code, 0);
  EXPECT_NE(unknown.err.find("expected auto, on, hybrid or off"), std::string::npos) << unknown.err;
  for (const char* other : {"b.exr", "d.exr"}) {
    const xi::Image a = xi::read_exr(work_ / "a.exr"), b = xi::read_exr(work_ / other);
    ASSERT_EQ(a.pixels.size(), b.pixels.size());
    EXPECT_EQ(std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(glm::vec3)), 0) << other;
  }
}

// In a cache of its own: after `xi prebuild`, a scene whose own kernels were never built renders at
// once with the generic ones while its own build (the output says so), and the next render starts
// with its own; `--kernels generic` and `--kernels scene` give the same image, bit for bit.
TEST_F(CliRender, NewSceneStartsWithTheGenericKernels) {
  const std::string cache = "XI_CACHE_DIR=" + quote((work_ / "cache").string());
  const Outcome prebuilt = run_xi({"prebuild"}, "export " + cache);
  ASSERT_EQ(prebuilt.code, 0) << prebuilt.err;
  EXPECT_NE(prebuilt.out.find("built: generic shading; lanes "), std::string::npos) << prebuilt.out;
  EXPECT_NE(prebuilt.out.find("kernels ready in "), std::string::npos) << prebuilt.out;
  const std::vector<std::string> render = {"render", kCornell.string(), "--spp", "4", "--resolution", "32x24"};
  const Outcome first = run_xi(concat(render, {"-o", "a.exr"}), "export " + cache);
  ASSERT_EQ(first.code, 0) << first.err;
  EXPECT_NE(first.out.find("; the generic ones shade while this scene's own build\n"), std::string::npos)
      << first.out;
  EXPECT_NE(first.out.find("first pass done "), std::string::npos) << first.out;
  const Outcome second = run_xi(concat(render, {"-o", "b.exr"}), "export " + cache);
  ASSERT_EQ(second.code, 0) << second.err;
  EXPECT_NE(second.out.find("kernels: loaded from cache in "), std::string::npos) << second.out;
  EXPECT_EQ(second.out.find("generic"), std::string::npos) << second.out;
  const Outcome generic = run_xi(concat(render, {"-o", "c.exr", "--kernels", "generic", "--quiet"}), "export " + cache);
  const Outcome own = run_xi(concat(render, {"-o", "d.exr", "--kernels", "scene", "--quiet"}), "export " + cache);
  ASSERT_EQ(generic.code, 0) << generic.err;
  ASSERT_EQ(own.code, 0) << own.err;
  for (const char* other : {"a.exr", "c.exr", "d.exr"}) {
    const xi::Image a = xi::read_exr(work_ / "b.exr"), b = xi::read_exr(work_ / other);
    ASSERT_EQ(a.pixels.size(), b.pixels.size());
    EXPECT_EQ(std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(glm::vec3)), 0) << other;
  }
  // A glTF file with textures, rough coats and cut-out surfaces (its own tracing program): its
  // first render after the prebuild compiles nothing either.
  const Outcome cutouts = run_xi({"render", "/usr/share/assimp/models/glTF2/ClearCoat-glTF/ClearCoatTest.gltf", "--spp",
                                  "1", "--resolution", "16x16", "-o", "e.exr"},
                                 "export " + cache);
  ASSERT_EQ(cutouts.code, 0) << cutouts.err;
  EXPECT_NE(cutouts.out.find("kernels: loaded from cache in "), std::string::npos) << cutouts.out;
  EXPECT_NE(cutouts.out.find("; the generic ones shade while this scene's own build\n"), std::string::npos)
      << cutouts.out;
}

// A frame too large for the memory there is: one error naming what it needs and what there is,
// before anything is allocated (PoCL used to abort on an assertion), and no file. Which limit is met
// first (the device's memory, its largest allocation, or the host's) depends on what the driver
// reports in the child's own conditions (PoCL's CPU device sizes itself from the memory free at the
// time and from ulimit -v), so every one of them is a correct outcome; each names the film.
TEST_F(CliBadInput, FrameTooLargeForMemory) {
  const auto before = files();
  const auto expect_memory_error = [&](const Outcome& r, const std::string& film) {
    expect_user_error(r, {"the render needs ", film}, before);
    const bool named = r.err.find(" of device memory") != std::string::npos ||
                       r.err.find(" of host memory") != std::string::npos ||
                       r.err.find("the device allocates at most") != std::string::npos;
    EXPECT_TRUE(named) << "no memory limit named in: " << r.err;
  };
  // 16384 x 16384: 17.18 GB of film on the device, and 30 GB on the host to read it back, so it
  // fails wherever the device or the host has less than that.
  xi::Device& device = xi::test::device();
  const double device_memory = (double)device.device().getInfo<CL_DEVICE_GLOBAL_MEM_SIZE>();
  const double host_memory = (double)sysconf(_SC_PHYS_PAGES) * (double)sysconf(_SC_PAGE_SIZE);
  if (device_memory < 17.18e9 || host_memory < 30.0e9)
    expect_memory_error(run_xi({"render", "--resolution", "16384x16384", "--spp", "1", "-o", "big.exr"}),
                        "film 17.18 GB for 268435456 pixels");
  else
    std::printf("[ memory ] %s has %.1f GB and the host %.1f GB: a 16384x16384 film fits\n",
                device.info().name.c_str(), device_memory * 1e-9, host_memory * 1e-9);
  // 8192 x 8192 (4.29 GB of film) in an address space of 3 GB (ulimit -v, in KiB).
  if (device.info().type == "CPU")
    expect_memory_error(run_xi({"render", "--resolution", "8192x8192", "--spp", "1", "-o", "big.exr"}, "ulimit -v 3000000"),
                        "film 4.29 GB for 67108864 pixels");
  else
    std::printf("[ memory ] %s is not a CPU device: the address-space case is PoCL's\n", device.info().name.c_str());
}

TEST_F(CliBadInput, UnknownOption) {
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "-o", "out.exr", "--bogus"}, kFast)), {"--bogus"}, before);
  expect_user_error(run_xi({"devices", "--bogus"}), {"--bogus"}, before);
}

TEST_F(CliBadInput, MissingOptionValue) {
  const auto before = files();
  expect_user_error(run_xi({"render", "-o", "out.exr", "--quiet", "--spp"}), {"--spp", "missing value"}, before);
}

TEST_F(CliBadInput, BadSpp) {
  const auto before = files();
  for (const std::string spp : {"abc", "0", "-3", "1.5", "2x", "99999999999999"}) {
    SCOPED_TRACE(spp);
    expect_user_error(run_xi({"render", "-o", "out.exr", "--quiet", "--resolution", "32x32", "--spp", spp}),
                      {"--spp", spp}, before);
  }
}

TEST_F(CliBadInput, BadLanes) { expect_each_refused("--lanes", {"0", "3", "9", "17", "-1", "abc"}); }

TEST_F(CliBadInput, BadLayering) { expect_each_refused("--layering", {"kulla", "Albedo-Scaling", "mix"}); }

TEST_F(CliBadInput, BadBvhWidth) { expect_each_refused("--bvh-width", {"0", "5", "16", "-4", "wide"}); }

TEST_F(CliBadInput, BadRayPackets) { expect_each_refused("--ray-packets", {"yes", "1", "", "ON", "auto,on"}); }

TEST_F(CliBadInput, BadKernels) { expect_each_refused("--kernels", {"own", "Scene", "", "generic,scene", "1"}); }

TEST_F(CliBadInput, BadResolution) {
  const auto before = files();
  for (const std::string res : {"64", "0x10", "10x0", "-5x5", "10x", "x10", "10x10x", "10*10", "abc", "20000x10"}) {
    SCOPED_TRACE(res);
    expect_user_error(run_xi({"render", "-o", "out.exr", "--quiet", "--spp", "2", "--resolution", res}),
                      {"--resolution", res}, before);
  }
}

// Sizes past int's range are refused, not wrapped modulo 2^32 (4294967304x8 is not 8x8).
TEST_F(CliBadInput, ResolutionOverflow) {
  const auto before = files();
  for (const std::string res : {"4294967304x8", "8x4294967304", "99999999999999999999x8"}) {
    SCOPED_TRACE(res);
    expect_user_error(run_xi({"render", "-o", "out.exr", "--quiet", "--spp", "1", "--resolution", res}),
                      {"--resolution", res}, before);
  }
}

TEST_F(CliBadInput, OutputFolderDoesNotExist) {
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "-o", "nosuchdir/out.exr"}, kFast)), {"nosuchdir", "output folder"}, before);
  EXPECT_FALSE(fs::exists(work_ / "nosuchdir"));
}

// Every file a render will write is checked before it starts: the PNG beside the EXR (an existing
// folder of that name used to fail only after the EXR was written), the trace, the convergence
// log and the checkpoint, each named with its flag; nothing is written.
TEST_F(CliBadInput, OutputsCheckedBeforeTheRender) {
  fs::create_directory(work_ / "out.png");
  fs::create_directory(work_ / "ref");
  ASSERT_EQ(run_xi(concat({"render", "-o", "ref/ref.exr", "--quiet"}, kFast)).code, 0);
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "-o", "out.exr"}, kFast)), {"output is a folder", "(-o ", "out.png)"}, before);
  expect_user_error(run_xi(concat({"render", "-o", "a.exr", "--trace", "nosuchdir/t.json"}, kFast)),
                    {"output folder does not exist", "(--trace nosuchdir/t.json)"}, before);
  expect_user_error(run_xi(concat({"render", "-o", "a.exr", "--reference", "ref/ref.exr", "--convergence", "ref"}, kFast)),
                    {"output is a folder", "(--convergence ref)"}, before);
  expect_user_error(run_xi(concat({"render", "-o", "a.exr", "--checkpoint", "nosuchdir/c.ckpt"}, kFast)),
                    {"output folder does not exist", "(--checkpoint nosuchdir/c.ckpt)"}, before);
}

TEST_F(CliBadInput, OutputNeitherExrNorPng) {
  const auto before = files();
  for (const char* out : {"out.tiff", "out.hdr", "out"})
    expect_user_error(run_xi(concat({"render", "-o", out}, kFast)), {out, ".exr or a .png"}, before);
}

// ---------------------------------------------------------------------------------------------
// Commands.

class CliCommands : public CliTest {};

TEST_F(CliCommands, NoArgumentsPrintsUsageAndExits2) {
  const Outcome r = run_xi({});
  EXPECT_EQ(r.code, 2);
  EXPECT_EQ(r.err.rfind("usage: xi", 0), 0u) << r.err;
  EXPECT_NE(r.err.find("render"), std::string::npos);
  EXPECT_EQ(r.out, "");
  EXPECT_TRUE(files().empty());
}

TEST_F(CliCommands, HelpExits0) {
  for (const std::string h : {"help", "--help", "-h"}) {
    SCOPED_TRACE(h);
    const Outcome r = run_xi({h});
    EXPECT_EQ(r.code, 0);
    EXPECT_EQ(r.out.rfind("usage: xi", 0), 0u) << r.out;
    for (const char* word : {"render", "devices", "--spp", "--resolution", "--device", "--profile"})
      EXPECT_NE(r.out.find(word), std::string::npos) << word;
    EXPECT_EQ(r.err, "");
  }
}

// `xi COMMAND --help` (or -h, anywhere among its arguments) and `xi help COMMAND` print that
// command's part of the usage, exit 0 and do nothing else; an unknown command's --help still errs.
TEST_F(CliCommands, CommandHelpPrintsItsOwnOptions) {
  const auto before = files();
  struct Case {
    std::vector<std::string> argv;
    const char* own;     // one of the command's options
    const char* other;   // another command's option
  };
  for (const Case& c : {Case{{"render", "--help"}, "--spp", "--metric"}, Case{{"render", "scene.json", "-h"}, "--env", "--map"},
                        Case{{"diff", "-h"}, "--metric", "--spp"}, Case{{"warp", "--help"}, "--map", "--metric"},
                        Case{{"help", "tonemap"}, "--exposure", "--spp"}}) {
    SCOPED_TRACE(c.argv[0] + " " + c.argv[1]);
    const Outcome r = run_xi(c.argv);
    EXPECT_EQ(r.code, 0);
    EXPECT_EQ(r.out.rfind("usage: xi ", 0), 0u) << r.out;
    EXPECT_NE(r.out.find(c.own), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find(c.other), std::string::npos) << r.out;
    EXPECT_EQ(r.err, "");
  }
  EXPECT_EQ(files(), before);
  expect_user_error(run_xi({"frobnicate", "--help"}), {"unknown command", "frobnicate"}, before);
}

// Each command's flag table is the whole of its flags: its part of the usage text shows every flag
// in it (with its value's placeholder), its parser takes every one and refuses any other command's
// flag or an unknown one, and `xi help` prints the text made from the tables.
TEST_F(CliCommands, FlagTablesAreTheUsageAndTheParser) {
  namespace cli = xi::cli;
  const auto refuses = [](const std::vector<std::string>& argv, const cli::Command& command, const std::string& error) {
    try {
      const cli::Args args(argv, command);
    } catch (const xi::Error& e) {
      return e.message() == error;
    }
    return false;
  };
  const std::string usage = cli::usage_text();
  EXPECT_EQ(run_xi({"help"}).out, usage);
  std::set<std::string> every_flag = {"--no-such-flag"};
  for (const cli::Command* command : cli::commands())
    for (const cli::Flag& flag : command->flags) every_flag.insert(flag.name);
  for (const cli::Command* command : cli::commands()) {
    SCOPED_TRACE(command->name);
    const std::string own = cli::command_usage(command->name);
    EXPECT_NE(usage.find(own), std::string::npos);
    // the command's line, then one per flag and note (a description's further lines are indented more)
    size_t entries = 0;
    std::istringstream lines(own);
    for (std::string line; std::getline(lines, line);) entries += line.find_first_not_of(' ') < 24;
    EXPECT_EQ(entries, 1 + command->flags.size() + command->notes.size()) << own;
    std::set<std::string> own_flags;
    for (const cli::Flag& flag : command->flags) {
      SCOPED_TRACE(flag.name);
      own_flags.insert(flag.name);
      const std::string shown = std::string("\n      ") + flag.name + (flag.value ? std::string(" ") + flag.value : "") + " ";
      EXPECT_NE(own.find(shown), std::string::npos) << own;
      const cli::Args args(flag.value ? std::vector<std::string>{flag.name, "x"} : std::vector<std::string>{flag.name},
                           *command);
      EXPECT_TRUE(args.has(flag.name));
      EXPECT_EQ(args.get(flag.name), flag.value ? "x" : "1");
      EXPECT_TRUE(args.positional().empty());
      if (flag.value) EXPECT_TRUE(refuses({flag.name}, *command, "missing value"));
    }
    for (const std::string& other : every_flag) {
      if (own_flags.count(other)) continue;
      EXPECT_TRUE(refuses({other}, *command, "unknown option '" + other + "'")) << other;
      // asking about a flag the table lacks is a mistake in xi, not in what the user typed
      EXPECT_THROW(cli::Args({}, *command).has(other), std::logic_error) << other;
    }
  }
}

TEST_F(CliCommands, VersionPrintsTheProjectVersion) {
  for (const std::string v : {"--version", "version"}) {
    SCOPED_TRACE(v);
    const Outcome r = run_xi({v});
    EXPECT_EQ(r.code, 0);
    EXPECT_EQ(r.out, std::string("xi ") + XI_VERSION + "\n");
    EXPECT_EQ(r.err, "");
  }
}

TEST_F(CliCommands, UnknownCommandExits1) {
  const auto before = files();
  expect_user_error(run_xi({"frobnicate"}), {"unknown command", "frobnicate"}, before);
}

// ---------------------------------------------------------------------------------------------
// Error tracking, profiling output, xi diff and xi warp.

TEST_F(CliTest, ConvergenceLogTraceAndLayers) {
  ASSERT_EQ(run_xi(concat({"render", "-o", "ref.exr", "--seed", "9"}, kFast)).code, 0);
  auto r = run_xi(concat({"render", "-o", "img.exr", "--spp", "4", "--reference", "ref.exr", "--convergence", "c.csv",
                          "--trace", "t.json"},
                         {"--resolution", "32x32", "--quiet"}));
  ASSERT_EQ(r.code, 0) << r.err;
  // One CSV row per pass, spp counting up, seconds not decreasing.
  std::istringstream csv(read_text(work_ / "c.csv"));
  std::string line;
  std::getline(csv, line);
  EXPECT_EQ(line, "pass,spp,seconds,mse,rmse,relmse,mae,mrse");
  int rows = 0;
  double last_seconds = 0.0, last_rmse = 0.0;
  while (std::getline(csv, line)) {
    int pass = 0, spp = 0;
    double seconds = 0, mse = 0, rmse = 0;
    ASSERT_EQ(std::sscanf(line.c_str(), "%d,%d,%lf,%lf,%lf", &pass, &spp, &seconds, &mse, &rmse), 5) << line;
    EXPECT_EQ(pass, rows);
    EXPECT_EQ(spp, rows + 1);
    EXPECT_GE(seconds, last_seconds);
    EXPECT_NEAR(rmse, std::sqrt(mse), 1e-6 * rmse + 1e-12);
    last_seconds = seconds;
    last_rmse = rmse;
    rows++;
  }
  EXPECT_EQ(rows, 4);
  // The final row equals what xi diff says, and the EXR carries it.
  auto d = run_xi({"diff", "img.exr", "ref.exr", "--metric", "rmse"});
  ASSERT_EQ(d.code, 0) << d.err;
  EXPECT_NEAR(std::stod(d.out), last_rmse, 1e-6 * last_rmse);
  auto attrs = xi::read_exr_attributes(work_ / "img.exr");
  EXPECT_NEAR(std::get<double>(attrs.at("error.rmse")), last_rmse, 1e-6 * last_rmse);
  for (const char* layer : {"variance", "albedo", "normal"})
    EXPECT_EQ(xi::read_exr(work_ / "img.exr", layer).width, 32) << layer;
  // The trace is JSON with one complete event per launch: 4 passes (one spp each, as --convergence
  // asks) of generate and accumulate. A bounce is launched over an upper bound of its queue.
  json trace = json::parse(read_text(work_ / "t.json"));
  int generate = 0, accumulate = 0, extend = 0;
  size_t extend_items = 0;
  for (auto& e : trace["traceEvents"]) {
    EXPECT_EQ(e["ph"], "X");
    EXPECT_GE(e["dur"].get<double>(), 0.0);
    EXPECT_LE(e["args"]["items"].get<size_t>(), e["args"]["launched"].get<size_t>());
    if (e["name"] == "extend") extend_items += e["args"]["items"].get<size_t>();
    if (e["name"] == "generate") EXPECT_EQ(e["args"]["items"].get<int>(), 32 * 32);
    generate += e["name"] == "generate";
    accumulate += e["name"] == "accumulate";
    extend += e["name"] == "extend";
  }
  EXPECT_EQ(generate, 4);
  EXPECT_EQ(accumulate, 4);
  EXPECT_GE(extend, 4);
  EXPECT_GE(extend_items, 4u * 32 * 32);  // every camera ray, then the bounces
}

TEST_F(CliTest, ConvergenceNeedsAMatchingReference) {
  ASSERT_EQ(run_xi(concat({"render", "-o", "ref.exr"}, kFast)).code, 0);
  auto before = files();
  expect_user_error(run_xi(concat({"render", "-o", "a.exr", "--convergence", "c.csv"}, kFast)), {"--reference"},
                    before);
  expect_user_error(run_xi({"render", "-o", "a.exr", "--spp", "1", "--resolution", "16x16", "--reference", "ref.exr",
                            "--quiet"}),
                    {"ref.exr", "32x32"}, before);
}

TEST_F(CliTest, DiffReportsMetricsHeatmapAndErrors) {
  ASSERT_EQ(run_xi(concat({"render", "-o", "a.exr", "--seed", "1"}, kFast)).code, 0);
  ASSERT_EQ(run_xi(concat({"render", "-o", "b.exr", "--seed", "2"}, kFast)).code, 0);
  ASSERT_EQ(run_xi({"render", "-o", "small.exr", "--spp", "1", "--resolution", "16x16", "--quiet"}).code, 0);
  auto same = run_xi({"diff", "a.exr", "a.exr", "--metric", "mse"});
  EXPECT_EQ(same.code, 0);
  EXPECT_EQ(std::stod(same.out), 0.0);
  auto all = run_xi({"diff", "a.exr", "b.exr", "--heatmap", "h.png"});
  EXPECT_EQ(all.code, 0) << all.err;
  for (const char* m : {"mse", "rmse", "relmse", "mae", "mrse"}) EXPECT_NE(all.out.find(m), std::string::npos);
  EXPECT_EQ(xi::read_png(work_ / "h.png").width, 32);
  auto before = files();
  expect_user_error(run_xi({"diff", "a.exr", "small.exr"}), {"differ in size"}, before);
  expect_user_error(run_xi({"diff", "a.exr", "missing.exr"}), {"missing.exr"}, before);
  expect_user_error(run_xi({"diff", "a.exr", "b.exr", "--metric", "psnr"}), {"psnr"}, before);
  expect_user_error(run_xi({"diff", "a.exr", "b.exr", "--crop", "0,0,99,5"}), {"--crop"}, before);
}

// xi tonemap writes the PNG that render writes beside its EXR, byte for byte; with --exposure and
// --layer, what the library's write_png makes of the same values; refuses bad input with no file.
TEST_F(CliTest, TonemapWritesRendersPngAndRefusesBadInput) {
  ASSERT_EQ(run_xi(concat({"render", "-o", "a.exr"}, kFast)).code, 0);
  auto r = run_xi({"tonemap", "a.exr", "t.png"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(read_text(work_ / "t.png"), read_text(work_ / "a.png"));

  const xi::Image rgb = xi::read_exr(work_ / "a.exr");
  xi::write_png(work_ / "lib-exposure.png", rgb, 2.5f);
  ASSERT_EQ(run_xi({"tonemap", "a.exr", "exposure.png", "--exposure", "2.5"}).code, 0);
  EXPECT_EQ(read_text(work_ / "exposure.png"), read_text(work_ / "lib-exposure.png"));
  EXPECT_NE(read_text(work_ / "exposure.png"), read_text(work_ / "t.png"));  // the exposure did something

  xi::write_png(work_ / "lib-albedo.png", xi::read_exr(work_ / "a.exr", "albedo"));
  ASSERT_EQ(run_xi({"tonemap", "a.exr", "albedo.png", "--layer", "albedo"}).code, 0);
  EXPECT_EQ(read_text(work_ / "albedo.png"), read_text(work_ / "lib-albedo.png"));
  EXPECT_NE(read_text(work_ / "albedo.png"), read_text(work_ / "t.png"));

  xi::Image bad = rgb;
  bad.at(3, 2).y = NAN;
  bad.at(5, 7).x = INFINITY;
  xi::write_exr(work_ / "nan.exr", {{"", &bad}});
  auto before = files();
  expect_user_error(run_xi({"tonemap", "nan.exr", "n.png"}), {"2 non-finite pixel(s)", "nan.exr", "x=3, y=2"}, before);
  expect_user_error(run_xi({"tonemap", "missing.exr", "m.png"}), {"missing.exr"}, before);
  expect_user_error(run_xi({"tonemap", "a.exr", "m.jpg"}), {".png", "m.jpg"}, before);
  expect_user_error(run_xi({"tonemap", "a.exr", "m.png", "--exposure", "nan"}), {"--exposure", "nan"}, before);
  expect_user_error(run_xi({"tonemap", "a.exr", "m.png", "--layer", "bogus"}), {"bogus"}, before);
  expect_user_error(run_xi({"tonemap", "a.exr"}), {"IMAGE.exr OUT.png"}, before);
}

TEST_F(CliTest, WarpWritesPointsInTheDomain) {
  auto r = run_xi({"warp", "--map", "disc", "--sampler", "sobol", "-n", "256", "-o", "p.csv"});
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream csv(read_text(work_ / "p.csv"));
  std::string line;
  int n = 0;
  while (std::getline(csv, line)) {
    double x, y, z;
    ASSERT_EQ(std::sscanf(line.c_str(), "%lf,%lf,%lf", &x, &y, &z), 3) << line;
    EXPECT_LE(x * x + y * y, 1.0 + 1e-6);
    EXPECT_EQ(z, 0.0);
    n++;
  }
  EXPECT_EQ(n, 256);
  ASSERT_EQ(run_xi({"warp", "--map", "cosine-hemisphere", "-n", "512", "-o", "p.png"}).code, 0);
  EXPECT_EQ(xi::read_png(work_ / "p.png").width, 512);
  auto before = files();
  expect_user_error(run_xi({"warp", "--map", "torus", "-o", "q.png"}), {"torus"}, before);
  expect_user_error(run_xi({"warp", "--map", "disc", "-o", "q.txt"}), {".png or .csv"}, before);
}

// ---------------------------------------------------------------------------------------------
// What lies around the scene: --env, --env-strength, --env-rotate, --background.

class CliEnvironment : public CliTest {
 protected:
  // A quad far off the view's axis: nearly every pixel sees what lies around the scene.
  void write_open_scene(const std::string& name) {
    write_text(work_ / name, R"({
      "camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
      "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
      "shapes": [{"type": "quad", "material": "white", "vertices": [[0.5,0.5,0], [1,0.5,0], [1,1,0], [0.5,1,0]]}]})");
  }
};

TEST_F(CliEnvironment, BadFlagsFailBeforeTheRender) {
  write_open_scene("open.json");
  xi::write_png(work_ / "sky.png", xi::Image(4, 2));
  const auto before = files();
  auto render = [&](std::vector<std::string> flags) {
    return run_xi(concat(concat({"render", "open.json", "-o", "out.exr"}, kFast), flags));
  };
  expect_user_error(render({"--env-strength", "2"}), {"--env-strength 2", "needs an environment"}, before);
  expect_user_error(render({"--env-rotate", "30"}), {"--env-rotate 30", "needs an environment"}, before);
  expect_user_error(render({"--env", "none", "--env-strength", "2"}), {"--env-strength", "needs an environment"}, before);
  expect_user_error(render({"--env", "missing.hdr"}), {"--env missing.hdr", "not found"}, before);
  expect_user_error(render({"--env", "sky.png", "--background", "1"}), {"--background", "not both"}, before);
  for (const std::string s : {"-1", "abc", "inf", "nan", ""}) {
    SCOPED_TRACE(s);
    expect_user_error(render({"--env", "sky.png", "--env-strength", s}), {"--env-strength", "number >= 0"}, before);
  }
  expect_user_error(render({"--env", "sky.png", "--env-rotate", "north"}), {"--env-rotate north"}, before);
  for (const std::string b : {"1,2", "1,2,3,4", "-1", "0.5,-0.5,1", "red", "1,,2", ""}) {
    SCOPED_TRACE(b);
    expect_user_error(render({"--background", b}), {"--background"}, before);
  }
}

TEST_F(CliEnvironment, BackgroundIsSeenWhereRaysLeave) {
  write_open_scene("open.json");
  const Outcome r = run_xi({"render", "open.json", "-o", "out.exr", "--quiet", "--resolution", "8x8", "--spp", "1",
                            "--background", "0.5,0.25,2"});
  ASSERT_EQ(r.code, 0) << r.err;
  const xi::Image img = xi::read_exr(work_ / "out.exr");
  ASSERT_EQ(img.width, 8);
  const glm::vec3 corner = img.pixels[7 * 8 + 7];  // the bottom right: away from the quad
  EXPECT_FLOAT_EQ(corner.x, 0.5f);
  EXPECT_FLOAT_EQ(corner.y, 0.25f);
  EXPECT_FLOAT_EQ(corner.z, 2.0f);
}

TEST_F(CliCommands, HelpListsTheEnvironmentFlags) {
  const Outcome r = run_xi({"help"});
  for (const char* word : {"--env FILE|none", "--env-strength", "--env-rotate", "--background R,G,B|V"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word;
}

// An asset file without lights would be lit by the bundled sky: --background gives a constant
// radiance instead (and --env-strength then has no environment to scale).
TEST_F(CliEnvironment, BackgroundReplacesTheSkyOfAnUnlitAsset) {
  write_text(work_ / "tri.obj", "v 0.5 0.5 0\nv 1 0.5 0\nv 1 1 0\nf 1 2 3\n");
  const auto before = files();
  expect_user_error(run_xi(concat({"render", "tri.obj", "-o", "out.exr", "--background", "1", "--env-strength", "2"},
                                  kFast)),
                    {"--env-strength 2", "needs an environment"}, before);
  const Outcome r = run_xi({"render", "tri.obj", "-o", "out.exr", "--resolution", "8x8", "--spp", "1", "--background",
                            "0.5"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out.find("bundled sky"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("no light in the file and no environment"), std::string::npos) << r.out;
  const xi::Image img = xi::read_exr(work_ / "out.exr");
  ASSERT_EQ(img.width, 8);
  for (const glm::vec3& corner : {img.pixels[0], img.pixels[7], img.pixels[56], img.pixels[63]})
    for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(corner[c], 0.5f);
}
