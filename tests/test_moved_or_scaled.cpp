// Renders that must not depend on where a scene sits or how large it is. Rays are spawned from
// intersection points offset by their rounding-error bounds, so every bundled scene, moved far from
// the origin or scaled by 1e-4 and 1e4, must match per 8×8 block of pixels within noise (a
// two-sided z-test on block means with the variance layer; the two renders use different seeds, so
// they are independent) the same geometry brought back: the transformed scene's vertices mapped
// back to the original place. Moving a mesh by 1e6 rounds its vertices to a 1/16 grid, which
// changes a fine mesh itself (the caustics scene's glass sphere has edges of 0.37); comparing with
// the same rounded geometry near the origin isolates what the renderer does with it.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "fixtures.h"
#include "stats.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace fs = std::filesystem;

namespace {

// p -> scale * p + shift, applied to everything that has a position or a length.
struct Similarity {
  const char* name;
  float scale;
  glm::vec3 shift;
};

xi::Scene transformed(xi::Scene s, const Similarity& t, bool inverse = false) {
  auto map = [&](glm::vec3 p) { return inverse ? (p - t.shift) / t.scale : t.scale * p + t.shift; };
  for (xi::Vertex& v : s.vertices) v.position = map(v.position);
  s.camera.position = map(s.camera.position);
  s.camera.look_at = map(s.camera.look_at);
  s.camera.aperture_radius *= inverse ? 1.0f / t.scale : t.scale;
  s.camera.focus_distance *= inverse ? 1.0f / t.scale : t.scale;
  return s;
}

// With the scene's depth and RenderOptions' default sampler (sobol).
xi::test::Shot render(const xi::Scene& scene, uint32_t seed, int spp) {
  xi::test::Shot shot = xi::test::render_shot(
      scene, xi::test::render_options(spp, seed, xi::Strategy::Mis, scene.render.max_depth, XI_SAMPLER_SOBOL));
  EXPECT_EQ(shot.nonfinite, 0u) << scene.source;
  return shot;
}

constexpr int kRes = 64, kBlock = 8, kSpp = 64;
const std::vector<Similarity> kTransforms = {
    {"moved by 1e3 (1, -2, 3)", 1.0f, glm::vec3(1e3f, -2e3f, 3e3f)},
    {"moved by 1e5 (1, -2, 3)", 1.0f, glm::vec3(1e5f, -2e5f, 3e5f)},
    {"moved by 1e6 (1, 1, 1)", 1.0f, glm::vec3(1e6f)},
    {"scaled by 1e-4", 1e-4f, glm::vec3(0.0f)},
    {"scaled by 1e4", 1e4f, glm::vec3(0.0f)},
};

// Plus, per scene, a scale to just above the smallest extent the scene loader accepts (1e-6, the
// longest side of the geometry's bounding box: SceneErrors.GeometryBelowTheSmallestExtent).
Similarity smallest_accepted(const xi::Scene& s) {
  glm::vec3 lo(INFINITY), hi(-INFINITY);
  for (const xi::Triangle& t : s.triangles)
    for (int k = 0; k < 3; ++k) lo = glm::min(lo, s.position(t, k)), hi = glm::max(hi, s.position(t, k));
  const glm::vec3 size = hi - lo;
  return {"scaled to an extent of 1.01e-6", 1.01e-6f / std::max({size.x, size.y, size.z}), glm::vec3(0.0f)};
}

}  // namespace

// One test per bundled scene, so that ctest runs them side by side; together they are one family.
static const std::vector<std::string> kBundledScenes = {"caustics.json", "cornell-box.json", "depth-of-field.json",
                                                        "mirror.json", "soft-shadows.json"};

class MovedOrScaledScene : public testing::TestWithParam<std::string> {};

TEST(MovedOrScaled, EveryBundledSceneIsCovered) {
  std::vector<std::string> found;
  for (auto& e : fs::directory_iterator(XI_SCENE_DIR))
    if (e.path().extension() == ".json") found.push_back(e.path().filename().string());
  std::sort(found.begin(), found.end());
  EXPECT_EQ(found, kBundledScenes) << "a bundled scene was added or removed: update kBundledScenes";
}

TEST_P(MovedOrScaledScene, RendersTheSameMovedFarAwayOrScaled) {
  const int blocks = (kRes / kBlock) * (kRes / kBlock);
  // α = 0.01 for the whole family (every bundled scene × transforms × blocks × channels), Šidák-corrected.
  const double z_max =
      xi::stats::sidak_critical_z(0.01, (int)(kBundledScenes.size() * (kTransforms.size() + 1) * blocks * 3));
  {
    const fs::path path = fs::path(XI_SCENE_DIR) / GetParam();
    xi::Scene scene = xi::load_scene(path);
    scene.width = scene.height = kRes;
    std::vector<Similarity> transforms = kTransforms;
    transforms.push_back(smallest_accepted(scene));
    for (const Similarity& t : transforms) {
      SCOPED_TRACE(path.filename().string() + ", " + t.name);
      const xi::Scene far = transformed(scene, t);
      const xi::test::Shot base = render(transformed(far, t, true), 1, kSpp);
      const xi::test::Shot moved = render(far, 2, kSpp);
      int rejected = 0;
      double worst = 0.0;
      for (int by = 0; by < kRes; by += kBlock)
        for (int bx = 0; bx < kRes; bx += kBlock)
          for (int c = 0; c < 3; ++c) {
            double ma = 0, mb = 0, va = 0, vb = 0;  // block means and the variances of those means
            for (int y = by; y < by + kBlock; ++y)
              for (int x = bx; x < bx + kBlock; ++x) {
                ma += base.mean.at(x, y)[c];
                mb += moved.mean.at(x, y)[c];
                va += base.variance.at(x, y)[c];
                vb += moved.variance.at(x, y)[c];
                ASSERT_TRUE(std::isfinite(moved.mean.at(x, y)[c])) << "pixel " << x << ", " << y;
              }
            const double n = kBlock * kBlock;
            ma /= n, mb /= n, va /= n * n, vb /= n * n;
            if (va + vb == 0.0) {  // no noise on either side (background, a light seen directly)
              rejected += std::abs(ma - mb) > 1e-6 * std::max(std::abs(ma), 1.0);
              continue;
            }
            const double z = (ma - mb) / std::sqrt(va + vb);
            worst = std::max(worst, std::abs(z));
            if (std::abs(z) > z_max) {
              rejected++;
              ADD_FAILURE() << "block (" << bx << ", " << by << ") channel " << c << ": " << ma << " vs " << mb
                            << ", z = " << z << " (limit " << z_max << ")";
            }
          }
      EXPECT_EQ(rejected, 0);
      std::printf("[ scale  ] %-20s %-24s worst |z| = %.2f of %.2f\n", path.filename().string().c_str(), t.name, worst,
                  z_max);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Bundled, MovedOrScaledScene, testing::ValuesIn(kBundledScenes),
                         [](const testing::TestParamInfo<std::string>& info) {
                           std::string name = info.param.substr(0, info.param.find('.'));
                           std::replace(name.begin(), name.end(), '-', '_');
                           return name;
                         });
