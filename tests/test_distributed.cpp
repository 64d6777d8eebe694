// A frame split into shares of rows, as the processes of `mpirun -np N xi render` split it: the
// shares rendered apart and put together must be the one-process render, bit for bit.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>

#include "fixtures.h"
#include "xi/error.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace {

namespace fs = std::filesystem;

bool same_bits(const std::vector<glm::vec4>& a, const std::vector<glm::vec4>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(glm::vec4) * a.size()) == 0;
}

xi::Scene small_scene(const char* file, int width, int height) {
  xi::Scene scene = xi::load_scene(fs::path(XI_SCENE_DIR) / file);
  scene.width = width;
  scene.height = height;
  return scene;
}

xi::RenderState render_state(const xi::Scene& scene, xi::RenderOptions options) {
  xi::Renderer r(xi::test::device(), scene, options);
  r.render();
  return r.state();
}

// Every share count from 1 to 4 (4 leaves a share of 2 rows of 11, and one of 3), on the Cornell box
// and on the glass sphere of the caustics scene, with the sobol and the random sampler.
TEST(FilmShares, SharesOfRowsPutTogetherAreTheFrameBitwise) {
  for (const char* file : {"cornell-box.json", "caustics.json"}) {
    const xi::Scene scene = small_scene(file, 19, 11);
    for (int sampler : {XI_SAMPLER_SOBOL, XI_SAMPLER_RANDOM}) {
      xi::RenderOptions options = xi::test::render_options(6, 3, xi::Strategy::Mis, 8, sampler);
      options.samples_per_pass = 4;  // two passes, the second shorter
      const xi::RenderState whole = render_state(scene, options);
      for (int shares = 1; shares <= 4; ++shares) {
        SCOPED_TRACE(testing::Message() << file << ", sampler " << sampler << ", " << shares << " shares");
        xi::RenderState frame = whole;
        for (auto* v : {&frame.sum, &frame.sum_sq, &frame.albedo, &frame.normal})
          std::fill(v->begin(), v->end(), glm::vec4(-1.0f));  // every pixel must be overwritten
        uint64_t extend_rays = 0;
        for (int rank = 0; rank < shares; ++rank) {
          xi::RenderOptions share_options = options;
          share_options.rows = xi::FilmRows{rank, shares};
          share_options.samples_per_pass = 1 + rank;  // passes of any size: the sums stay in sample order
          const xi::RenderState share = render_state(scene, share_options);
          ASSERT_EQ(share.sum.size(), (size_t)scene.width * share_options.rows.count(scene.height));
          xi::insert_rows(&frame, share, share_options.rows, scene.width, scene.height);
          extend_rays += share.extend_rays;
          // select_rows takes back exactly what insert_rows put in
          const xi::RenderState back = xi::select_rows(frame, share_options.rows, scene.width, scene.height);
          EXPECT_TRUE(same_bits(back.sum, share.sum));
        }
        EXPECT_TRUE(same_bits(frame.sum, whole.sum));
        EXPECT_TRUE(same_bits(frame.sum_sq, whole.sum_sq));
        EXPECT_TRUE(same_bits(frame.albedo, whole.albedo));
        EXPECT_TRUE(same_bits(frame.normal, whole.normal));
        EXPECT_EQ(extend_rays, whole.extend_rays);  // the same paths, traced once each
      }
    }
  }
}

// A share restored from the frame's state part way (a checkpoint read by every process) goes on
// exactly as the whole frame does.
TEST(FilmShares, ShareResumedFromTheFrameStateContinuesBitwise) {
  const xi::Scene scene = small_scene("cornell-box.json", 16, 9);
  xi::RenderOptions options;
  options.spp = 5;
  options.samples_per_pass = 2;
  xi::Renderer whole(xi::test::device(), scene, options);
  whole.run_pass();
  const xi::RenderState part = whole.state();
  whole.render();
  const xi::RenderState done = whole.state();
  const xi::FilmRows rows{1, 2};
  xi::RenderOptions share_options = options;
  share_options.rows = rows;
  xi::Renderer share(xi::test::device(), scene, share_options);
  share.restore(xi::select_rows(part, rows, scene.width, scene.height));
  share.render();
  const xi::RenderState want = xi::select_rows(done, rows, scene.width, scene.height);
  EXPECT_TRUE(same_bits(share.state().sum, want.sum));
  EXPECT_TRUE(same_bits(share.state().sum_sq, want.sum_sq));
}

TEST(FilmShares, RowsOutsideTheFrameAreRefused) {
  const xi::Scene scene = small_scene("cornell-box.json", 8, 4);
  xi::RenderOptions options;
  options.rows = xi::FilmRows{4, 5};  // the fifth process of five: a frame 4 rows high has no row for it
  EXPECT_THROW(xi::Renderer(xi::test::device(), scene, options), xi::Error);
  EXPECT_EQ((xi::FilmRows{3, 5}.count(4)), 1);
  EXPECT_EQ((xi::FilmRows{0, 3}.count(10)), 4);  // rows 0, 3, 6, 9
  EXPECT_EQ((xi::FilmRows{2, 3}.count(10)), 3);  // rows 2, 5, 8
}

}  // namespace
