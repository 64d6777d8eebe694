// Long renders: stopping on a signal, --time, --snapshot-every, checkpoints and --resume. Film sums
// are added in sample order, so every way of stopping and resuming must give the very bits of an
// uninterrupted render with the same spp: these tests compare images bitwise, not statistically.
#include <gtest/gtest.h>

#include <signal.h>

#include <algorithm>
#include <cstring>
#include <random>
#include <regex>

#include "cli_test.h"
#include "xi/checkpoint.h"
#include "xi/compiled_scene.h"
#include "xi/hash.h"
#include "xi/device.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/renderer.h"
#include "xi/scene.h"
#include "brute_force.h"
#include "fixtures.h"
#include "render/ray_probe.h"

using namespace xi_test;

namespace {

// expect_same_image, attr_int, has_temp_files and wait_for_output are CliTest's (cli_test.h).
class LongRender : public CliTest {};

// 1 spp per pass on a tiny frame: many short passes, so a signal lands mid-render.
const std::vector<std::string> kSmall = {"render", "--resolution", "16x16", "--samples-per-pass", "1", "--seed", "3",
                                         "--quiet"};

}  // namespace

TEST_F(LongRender, SignalWritesThePassesDoneAndTheCheckpointResumes) {
  // A snapshot after every pass tells the test the render is under way.
  const pid_t pid =
      start_xi(concat(kSmall, {"--spp", "1000", "-o", "cut.exr", "--snapshot-every", "1", "--checkpoint", "ck.bin"}));
  ASSERT_TRUE(wait_for("cut.exr"));
  kill(pid, SIGTERM);
  const Outcome r = wait_xi(pid);
  EXPECT_EQ(r.code, 143) << r.err;  // 128 + SIGTERM
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.err, m, std::regex("stopped by SIGTERM after pass (\\d+): (\\d+) of 1000 spp")))
      << r.err;
  const int spp = std::stoi(m[2]);
  EXPECT_EQ(std::stoi(m[1]), spp);  // one spp per pass
  EXPECT_GE(spp, 1);
  EXPECT_LT(spp, 1000);
  EXPECT_EQ(attr_int("cut.exr", "spp"), spp);
  EXPECT_EQ(attr_int("cut.exr", "sppTarget"), 1000);
  EXPECT_TRUE(fs::exists(work_ / "ck.bin"));
  EXPECT_FALSE(has_temp_files());

  // The stopped image is the render of the spp it reports.
  ASSERT_EQ(run_xi(concat(kSmall, {"--spp", std::to_string(spp), "-o", "straight.exr"})).code, 0);
  expect_same_image("cut.exr", "straight.exr");

  // Resumed to the end, it is the uninterrupted render; the checkpoint goes once the image holds it.
  const Outcome resumed = run_xi(concat(kSmall, {"--spp", "1000", "-o", "resumed.exr", "--resume", "ck.bin"}));
  ASSERT_EQ(resumed.code, 0) << resumed.err;
  EXPECT_FALSE(fs::exists(work_ / "ck.bin"));
  ASSERT_EQ(run_xi(concat(kSmall, {"--spp", "1000", "-o", "full.exr"})).code, 0);
  expect_same_image("resumed.exr", "full.exr");
  EXPECT_EQ(attr_int("resumed.exr", "spp"), 1000);
  EXPECT_EQ(xi::read_exr_attributes(work_ / "resumed.exr").count("sppTarget"), 0u);
}

TEST_F(LongRender, SecondSignalStopsAtOnceWritingNothing) {
  // Two different signals back to back (two SIGINTs could merge while pending): the second arrives
  // long before the pass in flight ends, even on a GPU, where a pass here takes milliseconds.
  const pid_t pid = start_xi({"render", "--resolution", "256x256", "--samples-per-pass", "16", "--spp", "4096", "-o",
                              "out.exr"});
  ASSERT_TRUE(wait_for_output("paths in flight"));
  kill(pid, SIGINT);
  kill(pid, SIGTERM);
  const Outcome r = wait_xi(pid);
  // 128 + the signal handled second: pending signals may be handled in either order.
  EXPECT_TRUE(r.code == 128 + SIGTERM || r.code == 128 + SIGINT) << r.code << ": " << r.err;
  EXPECT_EQ(r.err.find("stopped by"), std::string::npos) << r.err;
  EXPECT_EQ(files(), std::set<std::string>{}) << "no image, no temporary file";
}

TEST_F(LongRender, NonProgressiveSamplerStopsWithoutAnImage) {
  // A grid pattern is complete only at its spp: stopped, it leaves its state but no image.
  const std::vector<std::string> grid = concat(kSmall, {"--sampler", "grid", "--spp", "1024", "--checkpoint", "ck.bin"});
  std::vector<std::string> loud = concat(grid, {"-o", "out.exr"});
  loud.erase(std::find(loud.begin(), loud.end(), "--quiet"));  // its setup lines say when it starts
  const pid_t pid = start_xi(loud);
  ASSERT_TRUE(wait_for_output("paths in flight"));
  usleep(100000);
  kill(pid, SIGINT);
  const Outcome r = wait_xi(pid);
  EXPECT_EQ(r.code, 130) << r.err;
  EXPECT_NE(r.err.find("grid pattern is incomplete, no image written; state saved to ck.bin"), std::string::npos)
      << r.err;
  EXPECT_EQ(files(), std::set<std::string>{"ck.bin"});  // no image, no temporary file
  ASSERT_EQ(run_xi(concat(grid, {"--resume", "ck.bin", "-o", "resumed.exr"})).code, 0);
  ASSERT_EQ(run_xi(concat(kSmall, {"--sampler", "grid", "--spp", "1024", "-o", "full.exr"})).code, 0);
  expect_same_image("resumed.exr", "full.exr");
}

TEST_F(LongRender, TimeStopsAfterThePassThatCrossesTheBudget) {
  ASSERT_EQ(run_xi(concat(concat({"render"}, kFast), {"-o", "ref.exr"})).code, 0);  // any 32×32 image will do
  const Outcome r = run_xi({"render", "--resolution", "32x32", "--spp", "100000", "--samples-per-pass", "1", "--time",
                            "0.3", "--reference", "ref.exr", "--convergence", "log.csv", "-o", "out.exr", "--quiet"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("stopped by the time budget"), std::string::npos) << r.err;
  // The log's seconds are the render time after each pass: the budget falls in the last pass.
  std::istringstream csv(read_text(work_ / "log.csv"));
  std::string line;
  std::vector<std::pair<int, double>> rows;  // spp, seconds
  std::getline(csv, line);
  while (std::getline(csv, line)) {
    std::smatch m;
    ASSERT_TRUE(std::regex_search(line, m, std::regex("^\\d+,(\\d+),([0-9.]+),"))) << line;
    rows.push_back({std::stoi(m[1]), std::stod(m[2])});
  }
  ASSERT_GE(rows.size(), 2u);
  EXPECT_GE(rows.back().second, 0.3 - 1e-6);
  EXPECT_LT(rows[rows.size() - 2].second, 0.3 + 1e-6);
  const int spp = rows.back().first;
  EXPECT_EQ(attr_int("out.exr", "spp"), spp);
  EXPECT_EQ(attr_int("out.exr", "sppTarget"), 100000);
  ASSERT_EQ(run_xi({"render", "--resolution", "32x32", "--spp", std::to_string(spp), "-o", "straight.exr", "--quiet"}).code, 0);
  expect_same_image("out.exr", "straight.exr");
}

TEST_F(LongRender, ResumedAnyNumberOfTimesEqualsStraight) {
  const std::vector<std::string> base = {"render", "--resolution", "24x16", "--spp", "12", "--samples-per-pass", "2",
                                         "--seed", "7", "--quiet", "-o", "cut.exr"};
  // A budget shorter than any pass: every run adds exactly one pass, then checkpoints.
  Outcome r = run_xi(concat(base, {"--time", "1e-9", "--checkpoint", "ck.bin"}));
  for (int spp = 2; spp < 12; spp += 2) {
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(attr_int("cut.exr", "spp"), spp);
    ASSERT_TRUE(fs::exists(work_ / "ck.bin"));
    r = run_xi(concat(base, {"--time", "1e-9", "--resume", "ck.bin"}));
  }
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(attr_int("cut.exr", "spp"), 12);
  EXPECT_FALSE(fs::exists(work_ / "ck.bin"));
  std::vector<std::string> straight = base;
  straight.back() = "straight.exr";
  ASSERT_EQ(run_xi(straight).code, 0);
  expect_same_image("cut.exr", "straight.exr");
}

TEST_F(LongRender, RefusesAnotherRendersCheckpoint) {
  const std::vector<std::string> base = {"render", "--resolution", "24x16", "--spp", "12", "--samples-per-pass", "2",
                                         "--seed", "7", "--quiet"};
  ASSERT_EQ(run_xi(concat(base, {"--time", "1e-9", "--checkpoint", "ck.bin", "-o", "cut.exr"})).code, 0);
  const std::string saved = read_text(work_ / "ck.bin");
  struct Case {
    std::vector<std::string> args;
    std::vector<std::string> needles;
  };
  const fs::path mirror = fs::path(XI_SCENE_DIR) / "mirror.json";
  const std::vector<Case> cases = {
      {{"--seed", "8"}, {"--seed 7", "has 8"}},
      {{"--spp", "13"}, {"--spp 12", "has 13"}},
      {{"--sampler", "random"}, {"--sampler sobol", "has random"}},
      {{"--strategy", "nee"}, {"--strategy mis", "has nee"}},
      {{"--max-depth", "3"}, {"--max-depth", "has 3"}},
      {{"--resolution", "24x18"}, {"another scene"}},
      {{mirror.string()}, {"another scene"}},
  };
  const auto before = files();
  for (const Case& c : cases) {
    SCOPED_TRACE(c.args[0]);
    expect_user_error(run_xi(concat(concat(base, c.args), {"--resume", "ck.bin", "-o", "x.exr"})), c.needles, before);
  }
  // Another kernel build: the same kernels with one more comment line.
  const fs::path kernels = root_ / "kernels";
  fs::copy(xi::kernel_dir(), kernels, fs::copy_options::recursive);
  write_text(kernels / "shade.cl", read_text(kernels / "shade.cl") + "\n// edited\n");
  setenv("XI_KERNEL_DIR", kernels.c_str(), 1);
  expect_user_error(run_xi(concat(base, {"--resume", "ck.bin", "-o", "x.exr"})), {"kernel build"}, before);
  unsetenv("XI_KERNEL_DIR");
  // Damaged, foreign or missing files.
  write_text(work_ / "ck.bin", saved.substr(0, saved.size() / 2));
  expect_user_error(run_xi(concat(base, {"--resume", "ck.bin", "-o", "x.exr"})), {"damaged or truncated", "ck.bin"}, before);
  write_text(work_ / "ck.bin", "P3\n1 1\n255\n0 0 0\n" + std::string(64, ' '));
  expect_user_error(run_xi(concat(base, {"--resume", "ck.bin", "-o", "x.exr"})), {"not an xi checkpoint"}, before);
  expect_user_error(run_xi(concat(base, {"--resume", "none.bin", "-o", "x.exr"})), {"no such checkpoint", "none.bin"}, before);
  // Flags that need a progressive sampler, or bad values.
  expect_user_error(run_xi(concat(base, {"--sampler", "grid", "--time", "10"})), {"--time", "grid"}, before);
  expect_user_error(run_xi(concat(base, {"--sampler", "stratified", "--snapshot-every", "1"})),
                    {"--snapshot-every", "stratified"}, before);
  expect_user_error(run_xi(concat(base, {"--time", "soon"})), {"--time", "soon"}, before);
  expect_user_error(run_xi(concat(base, {"--time", "-1"})), {"--time"}, before);
  expect_user_error(run_xi(concat(base, {"--checkpoint-every", "5"})), {"--checkpoint-every", "--checkpoint"}, before);
}

// The library side: a checkpoint round-trips the state exactly, and one from another device is
// refused (a test machine has one device, so the key is changed by hand).
TEST(Checkpoint, RoundTripsAndRefusesAnotherDevice) {
  xi::Device& device = xi::test::device();
  xi::Scene scene = xi::load_scene(kCornell);
  scene.width = 8;
  scene.height = 8;
  xi::RenderOptions o;
  o.spp = 4;
  o.samples_per_pass = 1;
  xi::Renderer renderer(device, scene, o);
  renderer.run_pass();
  xi::RenderState state = renderer.state();
  state.seconds = 1.25;
  const xi::CheckpointKey key = xi::checkpoint_key(renderer, kCornell, device.info().name);
  const fs::path file = fs::temp_directory_path() / ("xi_checkpoint_" + std::to_string(::getpid()) + ".bin");
  xi::write_checkpoint(file, key, state);
  const xi::RenderState back = xi::read_checkpoint(file, key);
  EXPECT_EQ(back.spp_done, 1);
  EXPECT_EQ(back.passes, 1);
  EXPECT_EQ(back.seconds, 1.25);
  EXPECT_EQ(back.extend_rays, state.extend_rays);
  EXPECT_GT(back.extend_rays, 0u);
  ASSERT_EQ(back.sum.size(), 64u);
  EXPECT_EQ(std::memcmp(back.sum.data(), state.sum.data(), 64 * sizeof(glm::vec4)), 0);
  EXPECT_EQ(std::memcmp(back.sum_sq.data(), state.sum_sq.data(), 64 * sizeof(glm::vec4)), 0);

  xi::CheckpointKey other = key;
  other.device = "Some Other GPU";
  xi::write_checkpoint(file, other, state);
  try {
    xi::read_checkpoint(file, key);
    ADD_FAILURE() << "a checkpoint from another device was accepted";
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find("device Some Other GPU"), std::string::npos) << e.what();
  }
  fs::remove(file);
}

namespace {

// What Renderer::scene_hash reads back from the device, hashed from the compiled scene itself.
uint64_t compiled_hash(const xi::CompiledScene& cs) {
  xi::Hasher h;
  h.add(cs.tri_vertices);
  h.add(cs.vertices);
  h.add(cs.tri_material);
  h.add(cs.materials);
  h.add(cs.light_cdf);
  h.add(cs.light_tri);
  h.add(cs.tri_light_pdf);
  h.add(&cs.camera, sizeof cs.camera);
  h.add(&cs.background, sizeof cs.background);
  return h.h;
}

}  // namespace

// The renderer frees its host copy of the triangles and the BVH once they are on the device, and
// the checkpoint key's scene hash, read back from there, is the hash of the compiled arrays
// themselves: a checkpoint of the same scene is recognised, one of a changed scene is not.
TEST(Checkpoint, SceneHashComesFromTheDeviceAndMatchesTheCompiledScene) {
  xi::Device& device = xi::test::device();
  xi::Scene scene = xi::load_scene(kCornell);
  scene.width = 8;
  scene.height = 8;
  xi::RenderOptions o;
  o.spp = 1;
  xi::Renderer renderer(device, scene, o);
  const xi::CompiledScene& kept = renderer.compiled();
  EXPECT_TRUE(kept.tri_vertices.empty() && kept.vertices.empty() &&
              kept.tri_material.empty() && kept.tri_light_pdf.empty() && kept.bvh.nodes.empty() &&
              kept.bvh.nodes8.empty() && kept.bvh.blocks.empty());
  EXPECT_GT(kept.bvh.stats.references, 0u);

  const xi::CompiledScene cs = xi::compile_scene(scene, kept.bvh.width, o.spatial_splits);
  const uint64_t hash = compiled_hash(cs);
  EXPECT_EQ(renderer.scene_hash(), hash);

  scene.vertices[scene.triangles[0].v[0]].position.x += 1.0f;  // a changed scene hashes otherwise
  xi::Renderer moved(device, scene, o);
  EXPECT_NE(moved.scene_hash(), hash);
}

// A scene whose arrays are larger than the part the renderer uploads at a time (32 MB), each part's
// host pages handed back once written: what arrives on the device is the compiled scene, whole. A
// 1.3M-triangle sphere: the scene hash (vertices, normals, materials, lights, read back from the
// device) is the compiled arrays' own, and rays traced on the device's BVH meet the sphere where a
// test of every triangle does.
TEST(SceneUpload, LargeArraysArriveWholeInParts) {
  xi::Device& device = xi::test::device();
  xi::Scene scene = xi::parse_scene(R"({"camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0],
      "fov": 40}, "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
      "shapes": [{"type": "sphere", "material": "white", "center": [0, 0, 0], "radius": 1, "subdivisions": 8}]})",
                                    "sphere.json", ".");
  scene.width = scene.height = 8;
  // Each triangle over three vertices of its own (the icosphere shares them), so that the vertices
  // and their normals fill two parts.
  xi::Mesh shared = std::move(static_cast<xi::Mesh&>(scene));
  static_cast<xi::Mesh&>(scene) = xi::Mesh{};
  for (const xi::Triangle& t : shared.triangles) {
    const glm::vec3 n[3] = {shared.normal(t, 0), shared.normal(t, 1), shared.normal(t, 2)};
    scene.add_triangle(shared.position(t, 0), shared.position(t, 1), shared.position(t, 2), t.material,
                       t.has_normals ? n : nullptr).texcoords = t.texcoords;
  }
  scene.texcoords = std::move(shared.texcoords);
  shared = xi::Mesh{};
  ASSERT_TRUE(scene.triangles[0].has_normals);
  ASSERT_GT(sizeof(glm::vec4) * scene.vertices.size(), size_t(32) << 20) << "the vertices fill two parts";
  xi::RenderOptions o;
  o.spp = 1;
  xi::Renderer renderer(device, scene, o);
  const xi::CompiledScene cs = xi::compile_scene(scene, renderer.compiled().bvh.width, o.spatial_splits);
  const uint64_t hash = compiled_hash(cs);
  EXPECT_EQ(renderer.scene_hash(), hash);

  // From random points around the sphere towards random points inside it: every ray hits.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  auto random_point = [&](float radius) {
    glm::vec3 p;
    do p = glm::vec3(u(rng), u(rng), u(rng));
    while (glm::dot(p, p) > 1.0f || glm::dot(p, p) < 0.01f);
    return radius * p;
  };
  xi::RayBatch rays;
  for (int i = 0; i < 64; ++i) {
    const glm::vec3 o = 3.0f * glm::normalize(random_point(1.0f)), target = random_point(0.9f);
    rays.org.push_back(glm::vec4(o, 0.0f));
    rays.dir.push_back(glm::vec4(glm::normalize(target - o), 0.0f));
  }
  std::vector<glm::vec4> hits;
  xi::RayProbe(renderer).trace_closest(rays, &hits, 1);
  ASSERT_EQ(hits.size(), rays.org.size());
  xi::test::BruteForce brute(scene);
  for (size_t i = 0; i < hits.size(); ++i) {
    const auto ref = brute.hits(glm::vec3(rays.org[i]), glm::vec3(rays.dir[i]), INFINITY);
    ASSERT_FALSE(ref.empty()) << "ray " << i;
    uint32_t position;
    std::memcpy(&position, &hits[i].w, sizeof position);
    ASSERT_LT(position, cs.bvh.order.size()) << "ray " << i << " missed";
    // The nearest hit, or one at the same distance (a shared edge or vertex).
    const uint32_t tri = cs.bvh.order[position];
    const bool found = std::any_of(ref.begin(), ref.end(), [&](const xi::test::HostHit& r) {
      return r.tri == tri && r.t <= ref[0].t * (1.0f + 1e-5f);
    });
    EXPECT_TRUE(found) << "ray " << i << ": triangle " << tri << " at t " << hits[i].x << ", nearest " << ref[0].tri
                       << " at " << ref[0].t;
    EXPECT_NEAR(hits[i].x, ref[0].t, 1e-5f * ref[0].t) << "ray " << i;
  }
}
