// `xi export SCENE OUT_DIR`: the scene's triangles, one binary PLY per material plus manifest.json, read
// back and set against the scene as xi loads it; and a bad output folder fails as a user error should.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include "cli_test.h"
#include "xi/scene.h"

namespace fs = std::filesystem;
using json = nlohmann::json;

using namespace xi_test;

namespace {

struct Ply {
  std::vector<std::string> header;
  size_t vertices = 0, faces = 0;
  std::vector<float> vertex;  // x y z nx ny nz per vertex
  std::vector<std::array<int32_t, 3>> face;
};

// Reads the layout `xi export` writes; a failed expectation leaves the rest empty.
Ply read_ply(const fs::path& path) {
  Ply p;
  const std::string data = read_text(path);
  const size_t end = data.find("end_header\n");
  if (end == std::string::npos) {
    ADD_FAILURE() << path << ": no end_header";
    return p;
  }
  std::istringstream lines(data.substr(0, end));
  for (std::string line; std::getline(lines, line);) {
    p.header.push_back(line);
    std::istringstream w(line);
    std::string word, name;
    size_t count = 0;
    if (w >> word && word == "element" && w >> name >> count) (name == "vertex" ? p.vertices : p.faces) = count;
  }
  size_t at = end + std::strlen("end_header\n");
  const size_t need = p.vertices * 6 * 4 + p.faces * (1 + 3 * 4);
  EXPECT_EQ(data.size() - at, need) << path << ": body size";
  if (data.size() - at != need) return p;
  p.vertex.resize(p.vertices * 6);
  std::memcpy(p.vertex.data(), data.data() + at, p.vertex.size() * 4);  // (a little-endian host)
  at += p.vertex.size() * 4;
  for (size_t i = 0; i < p.faces; ++i, at += 13) {
    EXPECT_EQ(data[at], 3) << "face " << i;
    std::array<int32_t, 3> f;
    std::memcpy(f.data(), data.data() + at + 1, 12);
    p.face.push_back(f);
  }
  return p;
}

class CliExport : public CliTest {
 protected:
  // Exports `scene` to work_/out and checks every file against xi's own load of it: the manifest's
  // counts, each PLY's header, and every vertex position (bit for bit) and normal of every triangle.
  void check_export(const fs::path& scene_path) {
    const Outcome r = run_xi({"export", scene_path.string(), "out"});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(r.err, "");
    EXPECT_NE(r.out.find("wrote"), std::string::npos) << r.out;
    EXPECT_FALSE(has_temp_files());

    const xi::Scene scene = xi::load_scene(scene_path);
    // Per material: the triangles without vertex normals first, then those with, each in scene order.
    std::map<std::string, std::vector<const xi::Triangle*>> by_material;
    std::map<std::string, size_t> flat;
    for (bool smooth : {false, true})
      for (const xi::Triangle& t : scene.triangles)
        if (t.has_normals == smooth) by_material[scene.materials[t.material].name].push_back(&t);
    for (const xi::Triangle& t : scene.triangles) flat[scene.materials[t.material].name] += !t.has_normals;

    const json manifest = json::parse(read_text(work_ / "out" / "manifest.json"));
    EXPECT_EQ(manifest.at("triangles").get<size_t>(), scene.triangles.size());
    size_t total = 0, files = 0;
    for (const json& mesh : manifest.at("meshes")) {
      const std::string material = mesh.at("material");
      SCOPED_TRACE("material " + material);
      ASSERT_TRUE(by_material.count(material));
      const auto& tris = by_material[material];
      const Ply ply = read_ply(work_ / "out" / mesh.at("file").get<std::string>());
      ++files;
      EXPECT_EQ(ply.header.at(0), "ply");
      EXPECT_EQ(ply.header.at(1), "format binary_little_endian 1.0");
      EXPECT_EQ(mesh.at("triangles").get<size_t>(), tris.size());
      EXPECT_EQ(mesh.at("flat_triangles").get<size_t>(), flat[material]);
      ASSERT_EQ(ply.faces, tris.size());
      ASSERT_EQ(ply.vertices, 3 * tris.size());
      ASSERT_EQ(ply.face.size(), tris.size());
      total += ply.faces;
      for (size_t i = 0; i < tris.size(); ++i) {
        const xi::Triangle& t = *tris[i];
        const glm::vec3 e1 = t.v[1] - t.v[0], e2 = t.v[2] - t.v[0];
        const glm::vec3 face = glm::normalize(glm::cross(e1, e2));
        for (int k = 0; k < 3; ++k) {
          const int32_t index = ply.face[i][k];
          ASSERT_TRUE(index >= 0 && size_t(index) < ply.vertices) << "triangle " << i;
          const float* v = &ply.vertex[6 * size_t(index)];
          for (int c = 0; c < 3; ++c) ASSERT_EQ(v[c], t.v[k][c]) << "triangle " << i << " vertex " << k;
          const glm::vec3 n(v[3], v[4], v[5]), want = t.has_normals ? t.n[k] : face;
          ASSERT_LT(glm::length(n - want), 1e-5f) << "triangle " << i << " vertex " << k;
        }
      }
    }
    EXPECT_EQ(total, scene.triangles.size());
    EXPECT_EQ(files, by_material.size());  // one file per material with triangles, no more
  }
};

TEST_F(CliExport, CornellBox) { check_export(kCornell); }

TEST_F(CliExport, SceneWithASphere) {
  const fs::path scene = fs::path(XI_SCENE_DIR) / "mirror.json";
  ASSERT_NE(read_text(scene).find("\"sphere\""), std::string::npos);
  check_export(scene);
  const xi::Scene s = xi::load_scene(scene);
  size_t smooth = 0;
  for (const xi::Triangle& t : s.triangles) smooth += t.has_normals;
  EXPECT_GT(smooth, 1000u);  // the icosphere's vertex normals were checked above
}

TEST_F(CliExport, FlatAndSmoothTrianglesOfOneMaterial) {
  write_scene("ball.json", [](json& j) {
    j["shapes"].push_back({{"type", "sphere"}, {"material", "white"}, {"center", {300, 100, 300}}, {"radius", 50},
                           {"subdivisions", 2}, {"transform", {{"scale", {1, 2, -1}}}}});  // mirrored: winding swapped
  });
  check_export(work_ / "ball.json");
  const json manifest = json::parse(read_text(work_ / "out" / "manifest.json"));
  bool mixed = false;
  for (const json& mesh : manifest.at("meshes"))
    mixed |= mesh.at("material") == "white" && mesh.at("flat_triangles") == 26 && mesh.at("triangles") == 26 + 320;
  EXPECT_TRUE(mixed) << manifest.dump();
}

TEST_F(CliExport, IntoAnExistingFolderReplacesTheManifest) {
  fs::create_directory(work_ / "out");
  write_text(work_ / "out" / "manifest.json", "stale");
  check_export(kCornell);
}

TEST_F(CliExport, BadOutputFolderIsOneError) {
  write_text(work_ / "file", "x");
  const auto before = files();
  expect_user_error(run_xi({"export", kCornell.string(), "file"}), {"not a folder", "file"}, before);
  expect_user_error(run_xi({"export", kCornell.string(), "no/such/folder"}), {"does not exist", "no/such/folder"},
                    before);
  expect_user_error(run_xi({"export", kCornell.string()}), {"expected SCENE OUT_DIR"}, before);
  // A bad scene: its error, and no output folder made.
  expect_user_error(run_xi({"export", "missing.json", "out"}), {"missing.json"}, before);
}

}  // namespace
