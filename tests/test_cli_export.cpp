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
#include "xi/image.h"
#include "xi/scene.h"

namespace fs = std::filesystem;
using json = nlohmann::json;

using namespace xi_test;

namespace {

struct Ply {
  std::vector<std::string> header;
  size_t vertices = 0, faces = 0;
  size_t floats = 6;           // per vertex: x y z nx ny nz, then u v where the material has textures
  std::vector<float> vertex;
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
    if (line == "property float v") p.floats = 8;
  }
  size_t at = end + std::strlen("end_header\n");
  const size_t need = p.vertices * p.floats * 4 + p.faces * (1 + 3 * 4);
  EXPECT_EQ(data.size() - at, need) << path << ": body size";
  if (data.size() - at != need) return p;
  p.vertex.resize(p.vertices * p.floats);
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
      const xi::Material& m = scene.materials.at(mesh.at("material_index").get<size_t>());
      const bool textured = m.has_textures();
      EXPECT_EQ(mesh.at("texcoords").get<bool>(), textured);
      EXPECT_EQ(ply.floats, textured ? 8u : 6u);
      EXPECT_EQ(mesh.at("triangles").get<size_t>(), tris.size());
      EXPECT_EQ(mesh.at("flat_triangles").get<size_t>(), flat[material]);
      ASSERT_EQ(ply.faces, tris.size());
      ASSERT_EQ(ply.vertices, 3 * tris.size());
      ASSERT_EQ(ply.face.size(), tris.size());
      total += ply.faces;
      for (size_t i = 0; i < tris.size(); ++i) {
        const xi::Triangle& t = *tris[i];
        const glm::vec3 e1 = scene.position(t, 1) - scene.position(t, 0), e2 = scene.position(t, 2) - scene.position(t, 0);
        const glm::vec3 face = glm::normalize(glm::cross(e1, e2));
        for (int k = 0; k < 3; ++k) {
          const int32_t index = ply.face[i][k];
          ASSERT_TRUE(index >= 0 && size_t(index) < ply.vertices) << "triangle " << i;
          const float* v = &ply.vertex[ply.floats * size_t(index)];
          for (int c = 0; c < 3; ++c) ASSERT_EQ(v[c], scene.position(t, k)[c]) << "triangle " << i << " vertex " << k;
          if (ply.floats == 8)  // texture coordinates of set 0, as the scene has them (v down)
            for (int c = 0; c < 2; ++c) ASSERT_EQ(v[6 + c], xi::texcoords_of(scene.texcoords, t).uv[0][k][c]) << "triangle " << i << " vertex " << k;
          const glm::vec3 n(v[3], v[4], v[5]), want = t.has_normals ? scene.normal(t, k) : face;
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

// Textures, pbr parameters, lights and the environment: texture coordinates in the textured
// materials' PLY files, the images as PNG files of the same texels, and the manifest's fields.
TEST_F(CliExport, TexturesMaterialsLightsAndEnvironment) {
  xi::Image tex(3, 2);  // an 8-bit sRGB image, each texel distinct
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 3; ++x) tex.at(x, y) = glm::vec3(0.1f * x, 0.3f * y, 0.05f + 0.2f * x * y);
  xi::write_png(work_ / "t.png", tex);
  const std::string sky = (fs::path(XI_SCENE_DIR) / "sky.hdr").string();
  write_scene("textured.json", [&](json& j) {
    j["materials"]["tex"] = {{"type", "diffuse"},
                             {"albedo", {{"file", "t.png"}, {"wrap", "mirror"}, {"scale", {2, 1}}, {"rotation", 90}}}};
    j["materials"]["gold"] = {{"type", "pbr"}, {"base_color", {1, 0.8, 0.4}}, {"metallic", 1}, {"roughness", 0.3},
                              {"ior", 1.6}, {"base_color_texture", "t.png"}};
    j["shapes"].push_back({{"type", "quad"}, {"material", "tex"},
                           {"vertices", {{0, 1, 0}, {100, 1, 0}, {100, 1, 100}, {0, 1, 100}}}});
    j["shapes"].push_back({{"type", "sphere"}, {"material", "gold"}, {"center", {300, 100, 300}}, {"radius", 50},
                           {"subdivisions", 1}});
    j["environment"] = {{"file", sky}, {"strength", 2.5}, {"rotation", 30}};
    j["lights"] = {{{"type", "point"}, {"position", {1, 2, 3}}, {"intensity", 4}, {"name", "bulb"}},
                   {{"type", "spot"}, {"position", {0, 500, 0}}, {"direction", {0, -1, 0}}, {"intensity", 10},
                    {"inner_angle", 10}, {"outer_angle", 30}, {"color", {1, 0.5, 0.25}}},
                   {{"type", "sun"}, {"direction", {0, -1, 0}}, {"intensity", 3}, {"angular_radius", 0.5}}};
  });
  check_export(work_ / "textured.json");
  const xi::Scene scene = xi::load_scene(work_ / "textured.json");
  const json manifest = json::parse(read_text(work_ / "out" / "manifest.json"));

  // Every image, as a PNG of the same texels (read back sRGB-decoded, as xi's decoder does).
  ASSERT_EQ(manifest.at("images").size(), scene.images.size());
  ASSERT_EQ(scene.images.size(), 1u);
  const json& image = manifest.at("images").at(0);
  EXPECT_EQ(image.at("width"), 3);
  EXPECT_EQ(image.at("height"), 2);
  EXPECT_EQ(image.at("srgb"), true);
  const xi::Image back = xi::read_png(work_ / "out" / image.at("file").get<std::string>());
  const xi::Image want = xi::read_png(work_ / "t.png");
  ASSERT_EQ(back.width, 3);
  ASSERT_EQ(back.height, 2);
  for (size_t i = 0; i < back.pixels.size(); ++i) EXPECT_EQ(back.pixels[i], want.pixels[i]) << "texel " << i;

  // The materials, by index, with their texture slots.
  const json& materials = manifest.at("materials");
  ASSERT_EQ(materials.size(), scene.materials.size());
  std::map<std::string, json> by_name;
  for (const json& m : materials) by_name[m.at("name")] = m;
  const json& t = by_name.at("tex");
  EXPECT_EQ(t.at("type"), "diffuse");
  const json& slot = t.at("textures").at("base_color_texture");
  EXPECT_EQ(slot.at("file"), image.at("file"));
  EXPECT_EQ(slot.at("texcoord"), 0);
  EXPECT_EQ(slot.at("wrap_s"), "mirror");
  EXPECT_EQ(slot.at("wrap_t"), "mirror");
  for (const xi::Material& m : scene.materials)
    if (m.name == "tex")
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          EXPECT_FLOAT_EQ(slot.at("transform").at(3 * r + c).get<float>(),
                          m.textures[XI_TEXTURE_BASE_COLOR].transform[c][r]);
  const json& g = by_name.at("gold");
  EXPECT_EQ(g.at("type"), "pbr");
  EXPECT_FLOAT_EQ(g.at("metallic").get<float>(), 1.0f);
  EXPECT_FLOAT_EQ(g.at("roughness").get<float>(), 0.3f);
  EXPECT_FLOAT_EQ(g.at("ior").get<float>(), 1.6f);
  EXPECT_FLOAT_EQ(g.at("albedo").at(1).get<float>(), 0.8f);
  EXPECT_EQ(g.at("textures").at("base_color_texture").at("wrap_s"), "repeat");
  EXPECT_EQ(by_name.at("white").at("textures"), json::object());

  const json& env = manifest.at("environment");
  EXPECT_EQ(fs::path(env.at("file").get<std::string>()), fs::absolute(sky));
  EXPECT_FLOAT_EQ(env.at("strength").get<float>(), 2.5f);
  EXPECT_FLOAT_EQ(env.at("rotation").get<float>(), 30.0f);

  const json& lights = manifest.at("lights");
  ASSERT_EQ(lights.size(), 3u);
  EXPECT_EQ(lights[0].at("type"), "point");
  EXPECT_EQ(lights[0].at("name"), "bulb");
  EXPECT_EQ(lights[0].at("position"), json({1.0, 2.0, 3.0}));
  EXPECT_FLOAT_EQ(lights[0].at("intensity").at(0).get<float>(), 4.0f);
  EXPECT_EQ(lights[1].at("type"), "spot");
  EXPECT_NEAR(lights[1].at("inner_cone_degrees").get<float>(), 10.0f, 1e-4f);
  EXPECT_NEAR(lights[1].at("outer_cone_degrees").get<float>(), 30.0f, 1e-4f);
  EXPECT_FLOAT_EQ(lights[1].at("intensity").at(2).get<float>(), 2.5f);
  EXPECT_EQ(lights[2].at("type"), "directional");
  EXPECT_NEAR(lights[2].at("angular_radius_degrees").get<float>(), 0.5f, 1e-5f);
  EXPECT_FLOAT_EQ(lights[2].at("direction").at(1).get<float>(), -1.0f);
}

TEST_F(CliExport, WithoutTexturesNoTextureCoordinatesImagesOrEnvironment) {
  check_export(kCornell);
  const json manifest = json::parse(read_text(work_ / "out" / "manifest.json"));
  EXPECT_EQ(manifest.at("images"), json::array());
  EXPECT_EQ(manifest.at("lights"), json::array());
  EXPECT_TRUE(manifest.at("environment").is_null());
  for (const json& mesh : manifest.at("meshes")) EXPECT_EQ(mesh.at("texcoords"), false);
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
