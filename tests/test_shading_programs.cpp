// The generic shading program (kernels/shared/shading.h) renders what a scene's own program
// renders, bit for bit, so that it can start a render while the scene's own program builds and hand
// over between passes without changing the image.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "fixtures.h"
#include "xi/device.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace {

namespace fs = std::filesystem;
using Choice = xi::RenderOptions::ShadingProgram;

// The film sums of a whole render with the given shading program.
xi::RenderState render_with(const xi::Scene& scene, xi::RenderOptions options, Choice choice) {
  options.shading_program = choice;
  xi::Renderer r(xi::test::device(), scene, options);
  EXPECT_EQ(r.generic_shading(), choice == Choice::Generic);
  r.render();
  return r.state();
}

// Bitwise: the same sums, sums of squares, albedo and normal in every pixel.
void expect_same_film(const xi::RenderState& a, const xi::RenderState& b) {
  ASSERT_EQ(a.sum.size(), b.sum.size());
  size_t differ = 0;
  for (size_t i = 0; i < a.sum.size(); ++i)
    differ += std::memcmp(&a.sum[i], &b.sum[i], sizeof(glm::vec4)) != 0 ||
              std::memcmp(&a.sum_sq[i], &b.sum_sq[i], sizeof(glm::vec4)) != 0 ||
              std::memcmp(&a.albedo[i], &b.albedo[i], sizeof(glm::vec4)) != 0 ||
              std::memcmp(&a.normal[i], &b.normal[i], sizeof(glm::vec4)) != 0;
  EXPECT_EQ(differ, 0u) << "of " << a.sum.size() << " pixels";
  EXPECT_EQ(a.nonfinite, b.nonfinite);
}

xi::Scene small(const fs::path& file, int size = 24) {
  xi::Scene s = xi::load_scene(file);
  s.width = s.height = size;
  return s;
}

xi::RenderOptions options(int spp, uint32_t seed) {
  xi::RenderOptions o;
  o.spp = spp;
  o.seed = seed;
  return o;
}

// Every bundled scene (each uses other features: glass, mirrors, normals, a lens), and the bench's
// material scene (textures, the metallic-roughness material, an environment, under which shade
// partitions its work groups at every bounce), in 16 lanes, 8 and 1.
TEST(ShadingPrograms, GenericRendersEveryBundledSceneBitwise) {
  for (const char* name : {"cornell-box.json", "caustics.json", "mirror.json", "depth-of-field.json",
                           "soft-shadows.json", "../bench/scenes/material.json"}) {
    for (int lanes : {16, 8, 1}) {
      SCOPED_TRACE(testing::Message() << name << ", " << lanes << " lanes");
      const xi::Scene scene = small(fs::path(XI_SCENE_DIR) / name);
      xi::RenderOptions o = options(8, 11);
      o.lanes = lanes;
      expect_same_film(render_with(scene, o, Choice::Scene), render_with(scene, o, Choice::Generic));
    }
  }
}

// The sampler and the strategy are in the shading word too.
TEST(ShadingPrograms, GenericFollowsSamplerAndStrategy) {
  const xi::Scene scene = small(fs::path(XI_SCENE_DIR) / "cornell-box.json");
  for (int sampler : {XI_SAMPLER_RANDOM, XI_SAMPLER_GRID, XI_SAMPLER_STRATIFIED}) {
    SCOPED_TRACE(xi::sampler_name(sampler));
    xi::RenderOptions o = options(9, 5);
    o.sampler = sampler;
    expect_same_film(render_with(scene, o, Choice::Scene), render_with(scene, o, Choice::Generic));
  }
  for (xi::Strategy strategy : {xi::Strategy::Nee, xi::Strategy::Bsdf}) {
    SCOPED_TRACE(xi::strategy_name(strategy));
    xi::RenderOptions o = options(8, 5);
    o.strategy = strategy;
    expect_same_film(render_with(scene, o, Choice::Scene), render_with(scene, o, Choice::Generic));
  }
  // Must-fail: another strategy is another image, so agreeing above says something.
  xi::RenderOptions nee = options(8, 5), bsdf = options(8, 5);
  nee.strategy = xi::Strategy::Nee;
  bsdf.strategy = xi::Strategy::Bsdf;
  const xi::RenderState a = render_with(scene, nee, Choice::Generic), b = render_with(scene, bsdf, Choice::Generic);
  EXPECT_NE(std::memcmp(a.sum.data(), b.sum.data(), sizeof(glm::vec4) * a.sum.size()), 0);
}

// A cache of its own, holding only what prebuild_kernels puts there.
struct FreshCache {
  fs::path dir = fs::temp_directory_path() / ("xi-shading-test-" + std::to_string(::getpid()));
  FreshCache() {
    fs::remove_all(dir);
    fs::create_directories(dir);
    setenv("XI_CACHE_DIR", dir.c_str(), 1);
  }
  ~FreshCache() {
    unsetenv("XI_CACHE_DIR");
    fs::remove_all(dir);
  }
};

// With only the generic program cached, Auto renders with it at once while the scene's own builds;
// the scene's own takes over between passes, and the image is the one it renders alone.
TEST(ShadingPrograms, SceneProgramTakesOverBetweenPassesWithTheSameImage) {
  const xi::Scene scene = small(fs::path(XI_SCENE_DIR) / "mirror.json", 32);
  xi::RenderOptions o = options(12, 3);
  o.samples_per_pass = 3;  // four passes
  xi::RenderState switched;
  {
    FreshCache cache;
    const std::vector<std::string> built = xi::prebuild_kernels(xi::test::device(), o);
    ASSERT_FALSE(built.empty());
    xi::Renderer r(xi::test::device(), scene, o);  // Auto
    EXPECT_TRUE(r.generic_shading());
    EXPECT_TRUE(r.scene_shading_pending());
    r.run_pass();
    r.wait_for_scene_shading();
    EXPECT_FALSE(r.generic_shading());
    EXPECT_FALSE(r.scene_shading_pending());
    EXPECT_EQ(r.shading_switch_pass(), 1);
    r.render();
    EXPECT_EQ(r.passes_done(), 4);
    switched = r.state();
    // The scene's own program is cached now: the next render of the scene starts with it.
    xi::Renderer again(xi::test::device(), scene, o);
    EXPECT_FALSE(again.generic_shading());
    EXPECT_EQ(again.program().key, r.program().key);
  }
  expect_same_film(switched, render_with(scene, o, Choice::Scene));
}

// Without the generic program cached, Auto builds the scene's own and waits for it.
TEST(ShadingPrograms, AutoWithoutGenericBuildsTheScenesOwn) {
  FreshCache cache;
  const xi::Scene scene = small(fs::path(XI_SCENE_DIR) / "cornell-box.json", 8);
  xi::Renderer r(xi::test::device(), scene, options(1, 0));
  EXPECT_FALSE(r.generic_shading());
  EXPECT_FALSE(r.scene_shading_pending());
  EXPECT_FALSE(r.program().from_cache);
}

}  // namespace
