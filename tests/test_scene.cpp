// Scene loader: the Cornell box file, shape generation, transforms, meshes and every kind of bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include "scene/geometry.h"
#include "scene/ply.h"
#include "xi/compiled_scene.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/scene.h"
#include "xi/texture.h"
#include "fixtures.h"

namespace fs = std::filesystem;

namespace {

const std::string kCamera = R"("camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40})";
const std::string kMaterials = R"("materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}})";
const std::string kQuad = R"({"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]]})";

// A complete scene from its parts, so each test only spells out what it is about.
std::string scene_text(const std::string& shapes, const std::string& materials = kMaterials,
                       const std::string& camera = kCamera) {
  return "{" + camera + ", " + materials + ", \"shapes\": [" + shapes + "]}";
}

// A fresh directory per test (ctest may run tests in parallel).
fs::path temp_dir() { return xi::test::fresh_test_dir("xi_scene_"); }  // fixtures.h

xi::Scene parse(const std::string& text, const fs::path& dir = fs::temp_directory_path()) {
  return xi::parse_scene(text, "test.json", dir);
}

glm::vec3 face_normal(const xi::Mesh& m, const xi::Triangle& t) {
  return glm::cross(m.position(t, 1) - m.position(t, 0), m.position(t, 2) - m.position(t, 0));
}
glm::vec3 centroid(const xi::Mesh& m, const xi::Triangle& t) {
  return (m.position(t, 0) + m.position(t, 1) + m.position(t, 2)) / 3.0f;
}
float area(const xi::Mesh& m, const xi::Triangle& t) { return 0.5f * glm::length(face_normal(m, t)); }

// The call must throw xi::Error (not some other exception) whose what() mentions `needle`.
template <class F>
void expect_error(F&& call, const std::string& needle) {
  try {
    call();
    ADD_FAILURE() << "no exception; expected one mentioning " << needle;
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << "what(): " << e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "not an xi::Error: " << e.what();
  }
}
void expect_parse_error(const std::string& text, const std::string& needle) {
  expect_error([&] { parse(text); }, needle);
}

const xi::Material& material(const xi::Scene& s, const std::string& name) {
  for (const auto& m : s.materials)
    if (m.name == name) return m;
  throw std::runtime_error("no material " + name);
}

void expect_vec(glm::vec3 a, glm::vec3 b, float eps = 1e-4f) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

const std::string kCornell = std::string(XI_SCENE_DIR) + "/cornell-box.json";

}  // namespace

TEST(Scene, CornellBoxContents) {
  const xi::Scene s = xi::load_scene(kCornell);
  std::ifstream in(kCornell);
  const auto doc = nlohmann::json::parse(in);
  size_t quads = 0;
  for (const auto& shape : doc["shapes"]) quads += shape["type"] == "quad";
  EXPECT_EQ(quads, 16u);
  EXPECT_EQ(s.triangles.size(), 2 * quads);

  EXPECT_EQ(s.width, 512);
  EXPECT_EQ(s.height, 512);
  EXPECT_EQ(s.render.spp, 64);
  EXPECT_EQ(s.render.max_depth, 8);
  EXPECT_EQ(s.render.seed, 0u);
  EXPECT_NEAR(s.camera.vfov_degrees, glm::degrees(2.0 * std::atan(12.5 / 35.0)), 1e-4);
  EXPECT_NEAR(s.camera.vfov_degrees, 39.3077, 1e-3);
  EXPECT_NEAR(s.camera.focus_distance, 800.0f, 1e-3);
  EXPECT_EQ(s.camera.aperture_radius, 0.0f);

  ASSERT_EQ(s.materials.size(), 4u);
  expect_vec(material(s, "white").albedo, {0.725f, 0.71f, 0.68f}, 0.0f);
  expect_vec(material(s, "red").albedo, {0.63f, 0.065f, 0.05f}, 0.0f);
  expect_vec(material(s, "green").albedo, {0.14f, 0.45f, 0.091f}, 0.0f);
  const xi::Material& light = material(s, "light");
  EXPECT_EQ(light.type, xi::MaterialType::Diffuse);
  expect_vec(light.emission, {17, 12, 4}, 0.0f);
  expect_vec(light.albedo, {0.78f, 0.78f, 0.78f}, 0.0f);
  EXPECT_FALSE(light.two_sided);
  for (const auto& m : s.materials) EXPECT_EQ(m.is_emitter(), m.name == "light") << m.name;

  // Exactly the two light triangles emit; they sit below the ceiling and face down.
  int emitting = 0;
  for (const auto& t : s.triangles) {
    if (!s.materials[t.material].is_emitter()) continue;
    ++emitting;
    for (int k = 0; k < 3; ++k) EXPECT_FLOAT_EQ(s.position(t, k).y, 548.7f);
    expect_vec(glm::normalize(face_normal(s, t)), {0, -1, 0}, 1e-6f);
  }
  EXPECT_EQ(emitting, 2);
}

TEST(Scene, CornellBoxFacesPointInward) {
  const xi::Scene s = xi::load_scene(kCornell);
  ASSERT_EQ(s.triangles.size(), 32u);
  // Walls, ceiling, floor and light (quads 0-5) face the box centre.
  const glm::vec3 box_centre(278, 274, 280);
  for (size_t i = 0; i < 12; ++i) {
    const auto& t = s.triangles[i];
    EXPECT_GT(glm::dot(glm::normalize(face_normal(s, t)), glm::normalize(box_centre - centroid(s, t))), 0.5f)
        << "wall triangle " << i;
  }
  // Short block (quads 6-10) and tall block (quads 11-15) face away from their own centroid.
  for (size_t first : {12u, 22u}) {
    glm::vec3 block_centre(0.0f);
    for (size_t i = first; i < first + 10; ++i) block_centre += centroid(s, s.triangles[i]) / 10.0f;
    for (size_t i = first; i < first + 10; ++i) {
      const auto& t = s.triangles[i];
      EXPECT_GT(glm::dot(face_normal(s, t), centroid(s, t) - block_centre), 0.0f) << "block triangle " << i;
    }
  }
  // The camera sees the front of the back wall.
  EXPECT_LT(glm::dot(face_normal(s, s.triangles[6]), s.camera.look_at - s.camera.position), 0.0f);
}

TEST(Scene, SphereNormalsAreUnitAndOutward) {
  const glm::vec3 c(1, 2, 3);
  const float r = 2.0f;
  const xi::Scene s = parse(scene_text(R"({"type": "sphere", "material": "white", "center": [1, 2, 3], "radius": 2})"));
  ASSERT_EQ(s.triangles.size(), 20u * 256u);  // 20 · 4^4
  double total = 0.0;
  for (const auto& t : s.triangles) {
    ASSERT_TRUE(t.has_normals);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(glm::length(s.normal(t, k)), 1.0f, 1e-6f);
      expect_vec(s.normal(t, k), (s.position(t, k) - c) / r, 1e-5f);  // exact sphere normal
    }
    ASSERT_GT(glm::dot(face_normal(s, t), centroid(s, t) - c), 0.0f);  // winding faces outward
    total += area(s, t);
  }
  const double exact = 4.0 * M_PI * r * r;
  EXPECT_NEAR(total / exact, 1.0, 0.01);
  EXPECT_LT(total, exact);  // inscribed polyhedron

  const xi::Scene coarse =
      parse(scene_text(R"({"type": "sphere", "material": "white", "center": [0,0,0], "radius": 1, "subdivisions": 0})"));
  EXPECT_EQ(coarse.triangles.size(), 20u);
}

TEST(Scene, TransformScaleRotateTranslate) {
  // (1,0,0) → scale 2 → (2,0,0) → 90° about y → (0,0,-2) → translate → (1,2,1).
  const xi::Scene s = parse(scene_text(R"({"type": "triangle", "material": "white",
      "vertices": [[1,0,0], [0,1,0], [0,0,1]],
      "transform": {"translate": [1,2,3], "scale": 2, "rotate": {"axis": [0,1,0], "degrees": 90}}})"));
  ASSERT_EQ(s.triangles.size(), 1u);
  expect_vec(s.position(s.triangles[0], 0), {1, 2, 1});
  expect_vec(s.position(s.triangles[0], 1), {1, 4, 3});
  expect_vec(s.position(s.triangles[0], 2), {3, 2, 3});
  EXPECT_FALSE(s.triangles[0].has_normals);

  // The same transform as a row-major matrix.
  const xi::Scene m = parse(scene_text(R"({"type": "triangle", "material": "white",
      "vertices": [[1,0,0], [0,1,0], [0,0,1]],
      "transform": {"matrix": [0,0,2,1, 0,2,0,2, -2,0,0,3, 0,0,0,1]}})"));
  for (int k = 0; k < 3; ++k) expect_vec(m.position(m.triangles[0], k), s.position(s.triangles[0], k));

  // Per-axis scale.
  const xi::Scene a = parse(scene_text(R"({"type": "triangle", "material": "white",
      "vertices": [[1,1,1], [0,1,0], [0,0,1]], "transform": {"scale": [2,3,4]}})"));
  expect_vec(a.position(a.triangles[0], 0), {2, 3, 4});
}

TEST(Scene, TransformNormalsAndMirroring) {
  // Non-uniform scale: normals follow the inverse transpose and stay unit length.
  const xi::Scene s = parse(scene_text(R"({"type": "sphere", "material": "white", "center": [0,0,0], "radius": 1,
      "subdivisions": 2, "transform": {"scale": [1, 3, 1]}})"));
  for (const auto& t : s.triangles)
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(glm::length(s.normal(t, k)), 1.0f, 1e-5f);
      // Ellipsoid x² + y²/9 + z² = 1: normal ∝ (x, y/9, z).
      expect_vec(s.normal(t, k), glm::normalize(s.position(t, k) * glm::vec3(1, 1.0f / 9.0f, 1)), 1e-5f);
    }
  // A mirroring scale keeps the front face outward (the winding is swapped with it).
  const xi::Scene m = parse(scene_text(R"({"type": "sphere", "material": "white", "center": [0,0,0], "radius": 1,
      "subdivisions": 1, "transform": {"scale": [-1, 1, 1]}})"));
  for (const auto& t : m.triangles) {
    EXPECT_GT(glm::dot(face_normal(m, t), centroid(m, t)), 0.0f);
    EXPECT_GT(glm::dot(m.normal(t, 0), m.position(t, 0)), 0.0f);
  }
}

TEST(Scene, MeshLoadsThroughAssimp) {
  const fs::path dir = temp_dir();
  fs::create_directories(dir / "meshes");
  std::ofstream(dir / "meshes" / "cube.obj") << R"(# unit cube, 6 quads → 12 triangles
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 4 8 7 3
f 1 5 8 4
f 2 3 7 6
)";
  const xi::Scene s = parse(scene_text(R"({"type": "mesh", "material": "white", "file": "meshes/cube.obj"})"), dir);
  ASSERT_EQ(s.triangles.size(), 12u);
  float total = 0.0f;
  glm::vec3 lo(1e9f), hi(-1e9f);
  for (const auto& t : s.triangles) {
    EXPECT_FALSE(t.has_normals);  // the file has no vn lines
    EXPECT_GT(glm::dot(face_normal(s, t), centroid(s, t) - glm::vec3(0.5f)), 0.0f);  // faces listed outward
    total += area(s, t);
    for (int k = 0; k < 3; ++k) lo = glm::min(lo, s.position(t, k)), hi = glm::max(hi, s.position(t, k));
  }
  EXPECT_NEAR(total, 6.0f, 1e-5f);
  expect_vec(lo, {0, 0, 0}, 0.0f);
  expect_vec(hi, {1, 1, 1}, 0.0f);

  // With a transform, and through load_scene so the path is relative to the scene file.
  std::ofstream(dir / "scene.json")
      << scene_text(R"({"type": "mesh", "material": "white", "file": "meshes/cube.obj", "transform": {"scale": 2}})");
  const xi::Scene big = xi::load_scene(dir / "scene.json");
  total = 0.0f;
  for (const auto& t : big.triangles) total += area(big, t);
  EXPECT_NEAR(total, 24.0f, 1e-4f);

  // Vertex normals in the file are kept.
  std::ofstream(dir / "tri.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n";
  const xi::Scene n = parse(scene_text(R"({"type": "mesh", "material": "white", "file": "tri.obj"})"), dir);
  ASSERT_EQ(n.triangles.size(), 1u);
  EXPECT_TRUE(n.triangles[0].has_normals);
  expect_vec(n.normal(n.triangles[0], 0), {0, 0, 1}, 0.0f);
  fs::remove_all(dir);
}

TEST(Scene, DefaultsAndOptionalFields) {
  const xi::Scene s = parse("{" + kCamera + R"(, "materials": {
      "white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5], "radiance": [1, 2, 3], "two_sided": true},
      "m": {"type": "mirror"}, "g": {"type": "glass", "ior": 1.33},
      "e": {"type": "emitter", "radiance": [4, 5, 6]}},
      "shapes": [)" + kQuad + "]}");
  EXPECT_EQ(s.width, 512);
  EXPECT_EQ(s.height, 512);
  EXPECT_EQ(s.render.sampler, "sobol");
  EXPECT_EQ(s.camera.vfov_degrees, 40.0f);
  EXPECT_FLOAT_EQ(s.camera.focus_distance, 5.0f);
  expect_vec(s.background, {0, 0, 0}, 0.0f);
  EXPECT_EQ(material(s, "m").type, xi::MaterialType::Mirror);
  expect_vec(material(s, "m").albedo, {1, 1, 1}, 0.0f);
  EXPECT_EQ(material(s, "g").type, xi::MaterialType::Dielectric);
  EXPECT_FLOAT_EQ(material(s, "g").ior, 1.33f);
  expect_vec(material(s, "e").albedo, {0, 0, 0}, 0.0f);
  expect_vec(material(s, "e").emission, {4, 5, 6}, 0.0f);
  EXPECT_TRUE(material(s, "white").two_sided);
  expect_vec(material(s, "white").emission, {1, 2, 3}, 0.0f);
  // Triangles point at their material by index.
  EXPECT_EQ(s.materials[s.triangles[0].material].name, "white");
  // Quad split: v0 v1 v2 and v0 v2 v3, winding kept.
  expect_vec(s.position(s.triangles[1], 2), {0, 1, 0}, 0.0f);
  expect_vec(glm::normalize(face_normal(s, s.triangles[0])), {0, 0, 1}, 0.0f);
  expect_vec(glm::normalize(face_normal(s, s.triangles[1])), {0, 0, 1}, 0.0f);
}

// The features of the quad scene with these materials and, where given, this "render" block.
xi::Features quad_features(const std::string& render, const std::string& materials) {
  std::string text = scene_text(kQuad, materials);
  if (!render.empty()) text = "{" + render + ", " + text.substr(1);
  return xi::compile_scene(parse(text)).features;
}

// "render": {"multiple_scattering": ...}: on by default, and a feature only where a pbr material
// is; false turns it off; anything but a boolean is refused, naming the key.
TEST(Scene, MultipleScatteringSwitch) {
  const std::string pbr = R"("materials": {"white": {"type": "pbr", "base_color": [1, 1, 1], "metallic": 1,
      "roughness": 0.8}})";
  EXPECT_TRUE(quad_features("", pbr).multiple_scattering);
  EXPECT_NE(quad_features("", pbr).describe().find("multiple-scattering"), std::string::npos);
  EXPECT_FALSE(quad_features(R"("render": {"multiple_scattering": false})", pbr).multiple_scattering);
  EXPECT_FALSE(quad_features("", kMaterials).multiple_scattering);  // no pbr material: nothing to compensate
  EXPECT_TRUE(parse(scene_text(kQuad)).render.multiple_scattering);
  expect_parse_error("{\"render\": {\"multiple_scattering\": 1}, " + scene_text(kQuad).substr(1),
                     "/render/multiple_scattering");
}

// "render": {"layering": ...}: albedo scaling by default, a feature only where a pbr material is;
// "fresnel-mix" turns it off; an unknown name is refused, naming the key and the names it takes.
TEST(Scene, LayeringChoice) {
  const std::string pbr = R"("materials": {"white": {"type": "pbr", "base_color": [0.5, 0.5, 0.5], "roughness": 0.5}})";
  EXPECT_TRUE(quad_features("", pbr).albedo_scaling);
  EXPECT_NE(quad_features("", pbr).describe().find("albedo-scaling"), std::string::npos);
  EXPECT_TRUE(quad_features(R"("render": {"layering": "albedo-scaling"})", pbr).albedo_scaling);
  EXPECT_FALSE(quad_features(R"("render": {"layering": "fresnel-mix"})", pbr).albedo_scaling);
  EXPECT_FALSE(quad_features("", kMaterials).albedo_scaling);  // no pbr material: no layer
  EXPECT_EQ(parse(scene_text(kQuad)).render.layering, xi::Layering::AlbedoScaling);
  expect_parse_error("{\"render\": {\"layering\": \"kulla\"}, " + scene_text(kQuad).substr(1),
                     "/render/layering");
  try {
    parse("{\"render\": {\"layering\": \"kulla\"}, " + scene_text(kQuad).substr(1));
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find("albedo-scaling or fresnel-mix"), std::string::npos) << e.what();
  }
  EXPECT_EQ(xi::parse_layering(xi::layering_name(xi::Layering::FresnelMix)), xi::Layering::FresnelMix);
}

// A pbr material's layers in JSON: specular, clear coat, sheen, anisotropy, iridescence and volume keys, their defaults (none
// of them), each turning on its kernel feature; out-of-range values and a volume without
// transmission are refused, naming the key.
TEST(Scene, PbrLayers) {
  const std::string layered = R"("materials": {"white": {"type": "pbr", "base_color": [0.5, 0.5, 0.5],
      "transmission": 1, "specular": 0.5, "specular_color": [1, 0.5, 2], "clearcoat": 0.8, "clearcoat_roughness": 0.1,
      "sheen_color": [0.2, 0.3, 0.4], "sheen_roughness": 0.6, "attenuation_color": [0.5, 0.5, 0.25],
      "attenuation_distance": 2, "anisotropy_strength": 0.5, "anisotropy_rotation": -0.75, "iridescence": 0.9,
      "iridescence_ior": 1.8, "iridescence_thickness_minimum": 200, "iridescence_thickness_maximum": 500}})";
  const xi::Scene s = parse(scene_text(kQuad, layered));
  const xi::Material& m = s.materials.at(0);
  EXPECT_EQ(m.specular, 0.5f);
  EXPECT_EQ(m.specular_color, glm::vec3(1.0f, 0.5f, 2.0f));
  EXPECT_FLOAT_EQ(m.clearcoat, 0.8f);
  EXPECT_FLOAT_EQ(m.clearcoat_roughness, 0.1f);
  EXPECT_EQ(m.sheen_color, glm::vec3(0.2f, 0.3f, 0.4f));
  EXPECT_FLOAT_EQ(m.sheen_roughness, 0.6f);
  EXPECT_NEAR(m.volume_absorption().z, std::log(4.0) / 2.0, 1e-6);
  EXPECT_FLOAT_EQ(m.anisotropy_strength, 0.5f);
  EXPECT_FLOAT_EQ(m.anisotropy_rotation, -0.75f);
  EXPECT_FLOAT_EQ(m.iridescence, 0.9f);
  EXPECT_FLOAT_EQ(m.iridescence_ior, 1.8f);
  EXPECT_FLOAT_EQ(m.iridescence_thickness_minimum, 200.0f);
  EXPECT_FLOAT_EQ(m.iridescence_thickness_maximum, 500.0f);
  const xi::Features f = xi::compile_scene(s).features;
  EXPECT_TRUE(f.specular && f.clearcoat && f.sheen && f.volume && f.anisotropy && f.iridescence);
  const xi::Features plain = xi::compile_scene(parse(scene_text(kQuad, R"("materials": {"white": {"type": "pbr"}})"))).features;
  EXPECT_FALSE(plain.specular || plain.clearcoat || plain.sheen || plain.volume || plain.anisotropy || plain.iridescence);
  auto with = [&](const std::string& keys) {
    return scene_text(kQuad, R"("materials": {"white": {"type": "pbr", )" + keys + "}}");
  };
  expect_parse_error(with(R"("sheen_roughness": 2)"), "/materials/white/sheen_roughness");
  expect_parse_error(with(R"("clearcoat": -1)"), "/materials/white/clearcoat");
  expect_parse_error(with(R"("anisotropy_strength": 1.5)"), "/materials/white/anisotropy_strength");
  expect_parse_error(with(R"("iridescence_ior": 0.5)"), "/materials/white/iridescence_ior");
  expect_parse_error(with(R"("iridescence_thickness_maximum": -1)"), "/materials/white/iridescence_thickness_maximum");
  expect_parse_error(with(R"("attenuation_distance": 0, "transmission": 1)"), "/materials/white/attenuation_distance");
  expect_parse_error(with(R"("attenuation_color": [0.5, 0.5, 0.5])"), "needs transmission");
}

TEST(SceneErrors, MalformedJson) {
  expect_parse_error(R"({"camera": {"position": [0, 0,, 0]}})", "line 1, column 31");
  expect_parse_error(R"({"camera": {"position": [0, 0,, 0]}})", "test.json: byte 31");
  expect_parse_error(R"({"camera": )", "test.json");
}

TEST(SceneErrors, MissingFile) {
  expect_error([] { xi::load_scene("/nonexistent/dir/no-such-scene.json"); }, "no-such-scene.json");
}

TEST(SceneErrors, MissingMeshFile) {
  expect_parse_error(scene_text(R"({"type": "mesh", "material": "white", "file": "missing-mesh.obj"})"),
                     "missing-mesh.obj");
  expect_parse_error(scene_text(R"({"type": "mesh", "material": "white", "file": "missing-mesh.obj"})"),
                     "test.json: /shapes/0/file");
}

TEST(SceneErrors, AssimpFailure) {
  const fs::path dir = temp_dir();
  std::ofstream(dir / "garbage.obj") << "this is not\x01 a mesh {{{\n";
  std::ofstream(dir / "empty.obj") << "# no faces\nv 0 0 0\n";
  expect_error([&] { parse(scene_text(R"({"type": "mesh", "material": "white", "file": "empty.obj"})"), dir); },
               "/shapes/0/file");
  expect_error([&] { parse(scene_text(R"({"type": "mesh", "material": "white", "file": "garbage.obj"})"), dir); },
               "/shapes/0/file");
  fs::remove_all(dir);
}

TEST(SceneErrors, NonFiniteMeshData) {
  // Assimp reads an overflowing coordinate as Inf; the mesh must be refused, naming file and triangle.
  const fs::path dir = temp_dir();
  std::ofstream(dir / "inf.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1e39\nf 1 2 3\nf 2 4 3\n";
  const std::string text = scene_text(R"({"type": "mesh", "material": "white", "file": "inf.obj"})");
  expect_error([&] { parse(text, dir); }, "inf.obj: triangle 1 has a non-finite vertex");
  expect_error([&] { parse(text, dir); }, "/shapes/0/file");
  fs::remove_all(dir);
}

TEST(SceneErrors, UnknownMaterial) {
  expect_parse_error(scene_text(kQuad + R"(, {"type": "quad", "material": "whte",
      "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]]})"), "unknown material 'whte' (test.json: /shapes/1/material)");
}

TEST(SceneErrors, UnknownKey) {
  expect_parse_error(scene_text(kQuad, R"("materials": {"white": {"type": "diffuse", "albdeo": [0.5, 0.5, 0.5]}})"),
                     "/materials/white/albdeo");
  EXPECT_NO_THROW(parse(scene_text(kQuad)));  // the base scene itself is fine
  expect_parse_error("{\"films\": {}, " + scene_text(kQuad).substr(1), "unknown key 'films' (test.json: /films)");
  expect_parse_error(scene_text(R"({"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]],
      "transform": {"rotate": {"axis": [0,1,0], "degree": 90}}})"), "/shapes/0/transform/rotate/degree");
}

TEST(SceneErrors, HugeNumber) {
  expect_parse_error(scene_text(kQuad, R"("materials": {"white": {"type": "diffuse", "albedo": [0.5, 1e999, 0.5]}})"),
                     "test.json: /materials/white/albedo/1");
  expect_parse_error(scene_text(kQuad, R"("materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5],
      "radiance": [-1e999, 0, 0]}})"), "test.json: /materials/white/radiance/0");
  expect_parse_error(scene_text(kQuad + R"(, {"type": "sphere", "material": "white", "center": [0, 0, 0], "radius": 1e999})"),
                     "test.json: /shapes/1/radius");
  expect_parse_error(scene_text(R"({"type": "triangle", "material": "white", "vertices": [[0,0,0], [1,1e999,0], [0,1,0]]})"),
                     "test.json: /shapes/0/vertices/1/1");
  // Finite as a double, infinite as a float.
  expect_parse_error(scene_text(R"({"type": "triangle", "material": "white", "vertices": [[0,0,0], [1e300,0,0], [0,1,0]]})"),
                     "/shapes/0/vertices/1/0");
}

TEST(SceneErrors, WrongType) {
  expect_parse_error(scene_text(kQuad, R"("materials": {"white": {"type": "diffuse", "albedo": [0.5, "0.5", 0.5]}})"),
                     "expected a number (test.json: /materials/white/albedo/1)");
  expect_parse_error(scene_text(kQuad).replace(1, 0, R"("film": {"width": 512.5}, )"), "/film/width");
}

TEST(SceneErrors, AlbedoAboveOne) {
  expect_parse_error(scene_text(kQuad, R"("materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 1.2]}})"),
                     "/materials/white/albedo/2");
}

TEST(SceneErrors, EmptyShapes) {
  expect_parse_error(scene_text(""), "test.json: /shapes");
}

TEST(SceneErrors, ZeroAreaQuad) {
  expect_parse_error(scene_text(kQuad + R"(, {"type": "quad", "material": "white",
      "vertices": [[0,0,0], [1,1,1], [2,2,2], [3,3,3]]})"), "/shapes/1/vertices");
  // Non-zero area overall, but the second triangle (v0 v2 v3) is degenerate.
  expect_parse_error(scene_text(R"({"type": "quad", "material": "white",
      "vertices": [[0,0,0], [1,0,0], [1,1,0], [0.5,0.5,0]]})"), "/shapes/0/vertices");
}

TEST(SceneErrors, FovOutOfRange) {
  const std::string cam = R"("camera": {"position": [0,0,-5], "look_at": [0,0,0], "up": [0,1,0], "fov": 180})";
  expect_parse_error(scene_text(kQuad, kMaterials, cam), "/camera/fov");
}

TEST(SceneErrors, BadCameraAndTransform) {
  expect_parse_error(scene_text(kQuad, kMaterials,
      R"("camera": {"position": [0,0,-5], "look_at": [0,0,0], "up": [0,0,2], "fov": 40})"), "/camera/up");
  expect_parse_error(scene_text(kQuad, kMaterials,
      R"("camera": {"position": [0,0,0], "look_at": [0,0,0], "up": [0,1,0], "fov": 40})"), "/camera/look_at");
  expect_parse_error(scene_text(kQuad, kMaterials,
      R"("camera": {"position": [0,0,-5], "look_at": [0,0,0], "up": [0,1,0]})"), "/camera");
  expect_parse_error(scene_text(R"({"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]],
      "transform": {"scale": [1, 0, 1]}})"), "/shapes/0/transform");
  expect_parse_error(scene_text(R"({"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]],
      "transform": {"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 5,0,0,1]}})"), "/shapes/0/transform/matrix");
  expect_parse_error(scene_text(kQuad, R"("materials": {"white": {"type": "glass", "ior": 0.5}})"),
                     "/materials/white/ior");
  expect_parse_error(scene_text(kQuad).replace(1, 0, R"("render": {"sampler": "halton"}, )"), "/render/sampler");
  expect_parse_error(scene_text(kQuad).replace(1, 0, R"("render": {"seed": 4294967296}, )"), "/render/seed");
}

// A scene built in code meets the same limits when compiled (check_scene_limits): a vertex beyond
// +-1e9, geometry spanning less than 1e-6, a NaN or negative radiance, an infinite background,
// texture coordinates beyond the scene's.
TEST(SceneErrors, CompileSceneChecksTheLimits) {
  const xi::Scene good = parse(scene_text(kQuad, R"("materials": {"white": {"type": "emitter", "radiance": [1e20, 1, 0]}})"));
  EXPECT_NO_THROW(xi::compile_scene(good));  // radiance has no upper limit (HardCases: a 1e-6 light of 1e12)
  auto refused = [&](const std::function<void(xi::Scene&)>& change, const std::string& needle) {
    xi::Scene s = good;
    change(s);
    expect_error([&] { xi::compile_scene(s); }, needle);
  };
  refused([](xi::Scene& s) { s.vertices[s.triangles[0].v[1]].position.x = 2e9f; }, "triangle 0 has a non-finite vertex coordinate or one beyond +-1e9");
  refused([](xi::Scene& s) { s.vertices[s.triangles[1].v[2]].position.y = NAN; }, "triangle 1 has a non-finite vertex coordinate");
  refused([](xi::Scene& s) { for (auto& v : s.vertices) v.position *= 1e-7f; }, "the geometry spans only 1e-07 units");
  refused([](xi::Scene& s) { s.materials[0].emission.y = NAN; }, "material 'white' has a negative or non-finite radiance");
  refused([](xi::Scene& s) { s.materials[0].emission.z = -1.0f; }, "material 'white' has a negative or non-finite radiance");
  refused([](xi::Scene& s) { s.background = glm::vec3(INFINITY); }, "the background radiance is negative or not finite");
  const size_t kept = good.texcoords.size();  // the quad's two triangles have theirs
  ASSERT_EQ(kept, 2u);
  refused([&](xi::Scene& s) { s.triangles[1].texcoords = uint32_t(kept); },
          "triangle 1 names texture coordinates 2 of 2");
  const size_t vertices = good.vertices.size();
  refused([&](xi::Scene& s) { s.triangles[1].v[2] = uint32_t(vertices); },
          "triangle 1 names vertex " + std::to_string(vertices) + " of " + std::to_string(vertices));
}

// A triangle's corners index the mesh's vertices: check_scene_limits refuses one beyond them (the
// index one past the last too) before anything reads the vertex.
TEST(SceneErrors, VertexIndexBeyondTheMesh) {
  xi::Scene good;
  good.materials.emplace_back().name = "white";
  good.add_triangle({0, 0, 0}, {1, 0, 0}, {1, 1, 0});
  good.add_triangle({0, 0, 0}, {1, 1, 0}, {0, 1, 0});
  ASSERT_EQ(good.vertices.size(), 6u);
  EXPECT_NO_THROW(xi::check_scene_limits(good));
  for (const uint32_t index : {6u, 7u, 0xffffffffu}) {
    xi::Scene s = good;
    s.triangles[1].v[2] = index;
    expect_error([&] { xi::check_scene_limits(s); }, "triangle 1 names vertex " + std::to_string(index) + " of 6");
  }
  xi::Scene s = good;
  s.triangles[0].v[0] = 6;
  expect_error([&] { xi::check_scene_limits(s); }, "names vertex");
}

// add_triangle gives each triangle three vertices of its own (with normals where given); append
// adds another mesh after the vertices, triangles and texture coordinates there, its indices
// offset by theirs and its materials by first_material, its shared vertices still shared.
TEST(SceneMesh, AddTriangleAndAppend) {
  xi::Mesh a;
  a.add_triangle({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 2).texcoords = 0;
  a.texcoords.emplace_back().uv[0][1] = glm::vec2(0.5f, 0.125f);
  const glm::vec3 n[3] = {{0, 0, 1}, {0, 1, 0}, {1, 0, 0}};
  const xi::Triangle& added = a.add_triangle({0, 0, 1}, {1, 0, 1}, {0, 1, 1}, 3, n);
  EXPECT_EQ(&added, &a.triangles.back());
  ASSERT_EQ(a.vertices.size(), 6u);
  ASSERT_EQ(a.triangles.size(), 2u);
  for (int t = 0; t < 2; ++t)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(a.triangles[t].v[k], uint32_t(3 * t + k)) << t << " " << k;
  EXPECT_EQ(a.triangles[0].material, 2u);
  EXPECT_EQ(a.triangles[1].material, 3u);
  EXPECT_FALSE(a.triangles[0].has_normals);
  EXPECT_TRUE(a.triangles[1].has_normals);
  EXPECT_EQ(a.triangles[1].texcoords, xi::kNoTexcoords);
  EXPECT_EQ(a.position(a.triangles[1], 1), glm::vec3(1, 0, 1));
  for (int k = 0; k < 3; ++k) EXPECT_EQ(a.normal(a.triangles[1], k), n[k]) << k;

  // A quad over four shared vertices: (p0, p1, p2) and (p0, p2, p3).
  xi::Mesh b;
  for (const glm::vec3 p : {glm::vec3(5, 0, 0), glm::vec3(6, 0, 0), glm::vec3(6, 1, 0), glm::vec3(5, 1, 0)})
    b.vertices.push_back({p, glm::vec3(0, 0, 1)});
  b.triangles.resize(2);
  b.triangles[0].v[0] = 0, b.triangles[0].v[1] = 1, b.triangles[0].v[2] = 2;
  b.triangles[1].v[0] = 0, b.triangles[1].v[1] = 2, b.triangles[1].v[2] = 3;
  b.triangles[0].material = 0, b.triangles[1].material = 1;
  b.triangles[0].texcoords = 0;
  b.triangles[1].has_normals = true;
  b.texcoords.emplace_back().uv[0][1] = glm::vec2(0.25f, 0.75f);
  a.append(std::move(b), 5);

  ASSERT_EQ(a.vertices.size(), 10u);
  ASSERT_EQ(a.triangles.size(), 4u);
  ASSERT_EQ(a.texcoords.size(), 2u);
  const uint32_t want[2][3] = {{6, 7, 8}, {6, 8, 9}};
  for (int t = 0; t < 2; ++t)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(a.triangles[2 + t].v[k], want[t][k]) << t << " " << k;
  EXPECT_EQ(a.triangles[2].material, 5u);
  EXPECT_EQ(a.triangles[3].material, 6u);
  EXPECT_EQ(a.triangles[2].texcoords, 1u);
  EXPECT_EQ(a.triangles[3].texcoords, xi::kNoTexcoords);
  EXPECT_FALSE(a.triangles[2].has_normals);
  EXPECT_TRUE(a.triangles[3].has_normals);
  EXPECT_EQ(a.position(a.triangles[3], 2), glm::vec3(5, 1, 0));
  EXPECT_EQ(a.normal(a.triangles[3], 1), glm::vec3(0, 0, 1));
  EXPECT_EQ(xi::texcoords_of(a.texcoords, a.triangles[2]).uv[0][1], glm::vec2(0.25f, 0.75f));
  // What was there is as it was.
  for (int k = 0; k < 3; ++k) EXPECT_EQ(a.triangles[0].v[k], uint32_t(k));
  EXPECT_EQ(a.triangles[0].material, 2u);
  EXPECT_EQ(xi::texcoords_of(a.texcoords, a.triangles[0]).uv[0][1], glm::vec2(0.5f, 0.125f));
  EXPECT_EQ(a.position(a.triangles[1], 1), glm::vec3(1, 0, 1));
}

// The box of the corners only: a vertex no triangle names does not widen it. Over enough triangles
// to be split between threads, the extremes in different parts.
TEST(SceneMesh, BoundsOfTheTrianglesCorners) {
  xi::Mesh mesh;
  const auto [empty_lo, empty_hi] = mesh.bounds();
  EXPECT_GT(empty_lo.x, empty_hi.x) << "no triangles: an empty box";
  const size_t n = 300000;
  for (size_t i = 0; i < n; ++i) {
    const float x = float(i) * 1e-3f;
    mesh.add_triangle({x, 0, 0}, {x, 1, 0}, {x, 0, -1});
  }
  mesh.vertices.push_back({glm::vec3(1e6f), glm::vec3(0.0f)});  // named by no triangle
  mesh.vertices[3 * 100].position.y = -7.0f;                      // the first part's
  mesh.vertices[3 * (n - 5) + 2].position.z = 9.5f;             // the last part's
  const auto [lo, hi] = mesh.bounds();
  EXPECT_EQ(lo, glm::vec3(0.0f, -7.0f, -1.0f));
  EXPECT_EQ(hi, glm::vec3(float(n - 1) * 1e-3f, 1.0f, 9.5f));
}

// The first index that fails, wherever the parts split the range.
TEST(Parallel, FirstWhereFindsTheFirst) {
  const size_t n = 1 << 20;
  EXPECT_EQ(xi::first_where(n, [](size_t) { return false; }), SIZE_MAX);
  EXPECT_EQ(xi::first_where(0, [](size_t) { return true; }), SIZE_MAX);
  for (size_t first : {size_t(0), size_t(70000), n / 2 + 3, n - 1}) {
    // Failing at `first` and at every index a quarter of the range beyond it: each part's first
    // failure is found, and the earliest wins.
    EXPECT_EQ(xi::first_where(n, [&](size_t i) { return i >= first && (i - first) % (n / 4) == 0; }), first);
  }
}

// The other end of single precision: geometry whose bounding box's longest side is below 1e-6 is
// refused, in a scene file after every transform (edges of 1e-12 made normals and light areas
// underflow: the Cornell box rendered black but for its light). AssetScene.GeometryBelowTheSmallestExtent:
// the same for an asset file.
TEST(SceneErrors, GeometryBelowTheSmallestExtent) {
  const std::string tiny = R"({"type": "quad", "material": "white",
      "vertices": [[0,0,0], [5e-7,0,0], [5e-7,5e-7,0], [0,5e-7,0]])";
  expect_parse_error(scene_text(tiny + "}"),
                     "the geometry spans only 5e-07 units (the longest side of its bounding box; at least 1e-6): "
                     "single precision cannot shade so small a scene; scale it up with a transform (test.json: /shapes)");
  // The same quad scaled up by its transform, or beside a larger shape, is a scene.
  EXPECT_EQ(parse(scene_text(tiny + R"(, "transform": {"scale": 4}})")).triangles.size(), 2u);
  EXPECT_EQ(parse(scene_text(kQuad + ", " + tiny + "}")).triangles.size(), 4u);
}

TEST(SceneErrors, CoordinatesBeyondTheLimit) {
  // Finite floats whose sums, extents or cross products overflow single precision: the BVH builder
  // indexed a bin by a NaN (coordinates of 3e38), light pdfs came out NaN (edges of 1e11).
  expect_parse_error(scene_text(R"({"type": "quad", "material": "white",
      "vertices": [[3e38,3e38,0], [3e38,-3e38,0], [-3e38,-3e38,0], [-3e38,3e38,0]]})"),
                     "quad has a vertex coordinate beyond +-1e9 (after its transform) (test.json: /shapes/0/vertices)");
  expect_parse_error(scene_text(R"({"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]],
      "transform": {"scale": 1e30}})"), "beyond +-1e9 (after its transform) (test.json: /shapes/0/vertices)");
  expect_parse_error(scene_text(kQuad + R"(, {"type": "sphere", "material": "white", "center": [0, 0, 0], "radius": 1e30})"),
                     "sphere reaches a vertex coordinate beyond +-1e9 (after its transform) (test.json: /shapes/1)");
  const fs::path dir = temp_dir();
  std::ofstream(dir / "far.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2e9 0 0\nf 1 2 3\nf 2 4 3\n";
  expect_error([&] { parse(scene_text(R"({"type": "mesh", "material": "white", "file": "far.obj"})"), dir); },
               "far.obj: triangle 1 has a non-finite vertex coordinate or one beyond +-1e9");
  fs::remove_all(dir);

  expect_parse_error(scene_text(kQuad, kMaterials,
      R"("camera": {"position": [0, 0, -2e9], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40})"),
                     "coordinate beyond +-1e9 (test.json: /camera/position)");

  // At the limit the scene loads and compiles (BVH, light pdfs), with every value finite.
  const xi::Scene s = parse(scene_text(R"({"type": "quad", "material": "light",
      "vertices": [[1e9,1e9,0], [1e9,-1e9,0], [-1e9,-1e9,0], [-1e9,1e9,0]]})",
      R"("materials": {"light": {"type": "emitter", "radiance": [1, 1, 1]}})"));
  const xi::CompiledScene cs = xi::compile_scene(s);
  ASSERT_EQ(cs.tri_vertices.size(), 2u);
  for (size_t i = 0; i < cs.tri_vertices.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      const glm::vec3 v = cs.position(i, k);
      EXPECT_TRUE(std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z));
    }
  for (float p : cs.light_cdf) EXPECT_TRUE(std::isfinite(p));
  for (float p : cs.tri_light_pdf) EXPECT_TRUE(std::isfinite(p) && p > 0.0f) << p;
}

// A light scaled to nothing (xi_fuzz --seed 20261129 --case 31571: scale 1e-45) has an area whose
// inverse, the bound on its area density, overflows single precision: it stays in the scene, hit
// by BSDF samples alone, and every light pdf the kernels read is finite. One of area 1e-20 (side
// 1e-10) is still sampled, with a finite density (HardCases.TinyAndHugeLightsMatchLambertsFormula
// renders it).
TEST(SceneErrors, LightTooSmallForItsDensityIsNotSampled) {
  const std::string materials = R"("materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]},
      "light": {"type": "emitter", "radiance": [1, 1, 1]}})";
  auto light = [](const char* scale) {
    return std::string(R"({"type": "quad", "material": "light", "vertices": [[0,1,0], [1,1,0], [1,1,1], [0,1,1]],
        "transform": {"scale": )") + scale + "}}";
  };
  struct Case {
    std::string shapes;
    size_t sampled;  // light triangles sampled
  };
  const Case cases[] = {{light("1") + ", " + light("1e-45"), 2},
                        {light("1e-45"), 0},  // alone: its density was 1/area = inf
                        {light("1") + ", " + light("1e-10"), 4}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.shapes);
    const xi::CompiledScene cs = xi::compile_scene(parse(scene_text(kQuad + ", " + c.shapes, materials)));
    EXPECT_EQ(cs.features.emitters ? cs.light_tri.size() : 0u, c.sampled);
    for (float p : cs.tri_light_pdf) EXPECT_TRUE(std::isfinite(p)) << p;
    for (float p : cs.light_cdf) EXPECT_TRUE(std::isfinite(p)) << p;
  }
}

TEST(SceneErrors, ControlCharactersInNamesAreEscaped) {
  // A key holding a newline (a JSON escape) must not break the error onto two lines.
  const std::string text = "{\"back\\nground\": [0, 0, 0], " + scene_text(kQuad).substr(1);
  try {
    parse(text);
    ADD_FAILURE() << "no error";
  } catch (const xi::Error& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    EXPECT_EQ(what, "unknown key 'back\\nground' (test.json: /back\\nground)");
  }
}

// ---------------------------------------------------------------------------------------------
// Mesh headers that declare more elements than the file can hold. Assimp's OFF and PLY loaders
// allocate (and zero) what the header says before reading, so these are refused before Assimp
// sees them; every element takes at least one byte of the file (a line in OFF, a value in PLY).

namespace {

std::string mesh_scene(const std::string& file) {
  return scene_text(R"({"type": "mesh", "material": "white", "file": )" + nlohmann::json(file).dump() + "}");
}

void write_bytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out << bytes;
  ASSERT_TRUE(out.good()) << p;
}

}  // namespace

// The file of Assimp's invalid corpus that made xi allocate until the kernel killed it: 309 bytes
// declaring 353535235358 vertices, which Assimp's 32-bit parser wraps to 1347917086 (16 GB zeroed).
TEST(MeshLimits, AssimpOutOfMemoryOffIsRefused) {
  const fs::path file = fs::path(XI_ASSIMP_INVALID_DIR) / "OutOfMemory.off";
  ASSERT_TRUE(fs::is_regular_file(file)) << file << " is missing: scripts/install-deps.sh installs assimp-testmodels";
  expect_parse_error(mesh_scene(file.string()),
                     "cannot load mesh " + file.string() + ": its header declares 353535235358 vertices and 6 faces, " +
                         "but the file has only " + std::to_string(fs::file_size(file)) + " bytes (test.json: /shapes/0/file)");
}

TEST(MeshLimits, OffCountsAgainstTheFileSize) {
  const fs::path dir = temp_dir();
  const std::string body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  write_bytes(dir / "exact.off", "OFF\n3 1 0\n" + body);
  EXPECT_EQ(parse(mesh_scene("exact.off"), dir).triangles.size(), 1u);  // honest counts load
  write_bytes(dir / "faces.off", "OFF\n3 2000000000 0\n" + body);
  expect_error([&] { parse(mesh_scene("faces.off"), dir); }, "faces.off: its header declares 3 vertices and 2000000000 faces");
  // Comment lines, a prefixed keyword, and a count that a 32-bit parser would wrap to 3.
  write_bytes(dir / "wrap.off", "# made by hand\nCOFF\n# counts\n4294967299 1 0\n" + body);
  expect_error([&] { parse(mesh_scene("wrap.off"), dir); }, "wrap.off: its header declares 4294967299 vertices and 1 faces");
  // Assimp recognises OFF by its first bytes whatever the extension.
  write_bytes(dir / "mesh.dat", "OFF\n3 1 0\n" + body);
  EXPECT_EQ(parse(mesh_scene("mesh.dat"), dir).triangles.size(), 1u);
  write_bytes(dir / "huge.dat", "OFF\n3000000000 1 0\n" + body);
  expect_error([&] { parse(mesh_scene("huge.dat"), dir); }, "huge.dat: its header declares 3000000000 vertices");
  fs::remove_all(dir);
}

TEST(MeshLimits, PlyCountsAgainstTheFileSize) {
  const fs::path dir = temp_dir();
  auto header = [](const std::string& format, const std::string& vertices, const std::string& faces) {
    return "ply\nformat " + format + " 1.0\nelement vertex " + vertices +
           "\nproperty float x\nproperty float y\nproperty float z\nelement face " + faces +
           "\nproperty list uchar int vertex_indices\nend_header\n";
  };
  const std::string ascii = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  std::string binary;  // three vertices and a face, little-endian
  for (float f : {0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 0.f, 1.f, 0.f}) binary.append(reinterpret_cast<const char*>(&f), 4);
  binary += '\3';
  for (int32_t i : {0, 1, 2}) binary.append(reinterpret_cast<const char*>(&i), 4);

  write_bytes(dir / "ascii.ply", header("ascii", "3", "1") + ascii);
  write_bytes(dir / "binary.ply", header("binary_little_endian", "3", "1") + binary);
  EXPECT_EQ(parse(mesh_scene("ascii.ply"), dir).triangles.size(), 1u);  // honest counts load
  EXPECT_EQ(parse(mesh_scene("binary.ply"), dir).triangles.size(), 1u);

  write_bytes(dir / "vertices.ply", header("ascii", "2000000000", "1") + ascii);
  expect_error([&] { parse(mesh_scene("vertices.ply"), dir); },
               "vertices.ply: its header declares 2000000000 'vertex', 1 'face' elements, but the file has only");
  write_bytes(dir / "faces.ply", header("binary_little_endian", "3", "1000000000") + binary);
  expect_error([&] { parse(mesh_scene("faces.ply"), dir); }, "faces.ply: its header declares 3 'vertex', 1000000000 'face'");
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// Binary PLY files of triangles, read without Assimp (scene/ply.h): the same triangles as
// Assimp's reader gives, or, for any file outside what that reader takes, Assimp's as before.

namespace {

// One PLY property: its type as the header spells it and its name.
struct PlyProperty {
  std::string type, name;
};

// A value of a PLY type, in the byte order asked for.
void put(std::string& out, const std::string& type, double v, bool big_endian) {
  unsigned char b[8];
  size_t n = 0;
  auto raw = [&](auto x) {
    n = sizeof(x);
    std::memcpy(b, &x, n);
  };
  if (type == "char" || type == "int8") raw((int8_t)v);
  else if (type == "uchar" || type == "uint8") raw((uint8_t)v);
  else if (type == "short" || type == "int16") raw((int16_t)v);
  else if (type == "ushort" || type == "uint16") raw((uint16_t)v);
  else if (type == "int" || type == "int32") raw((int32_t)v);
  else if (type == "uint" || type == "uint32") raw((uint32_t)v);
  else if (type == "float" || type == "float32") raw((float)v);
  else raw(v);
  if (big_endian) std::reverse(b, b + n);
  out.append(reinterpret_cast<const char*>(b), n);
}

// A binary PLY: vertices of `props` (one row of values each), faces as index lists of the given
// count and index types; `extra` header lines go before the elements.
std::string ply_bytes(bool big_endian, const std::vector<PlyProperty>& props, const std::vector<std::vector<double>>& vertices,
                      const std::vector<std::vector<int64_t>>& faces, const std::string& count_type = "uchar",
                      const std::string& index_type = "int", const std::string& extra = "") {
  std::string s = std::string("ply\nformat binary_") + (big_endian ? "big" : "little") + "_endian 1.0\n" + extra +
                  "element vertex " + std::to_string(vertices.size()) + "\n";
  for (const PlyProperty& p : props) s += "property " + p.type + " " + p.name + "\n";
  s += "element face " + std::to_string(faces.size()) + "\nproperty list " + count_type + " " + index_type +
       " vertex_indices\nend_header\n";
  for (const auto& v : vertices)
    for (size_t k = 0; k < props.size(); ++k) put(s, props[k].type, v[k], big_endian);
  for (const auto& f : faces) {
    put(s, count_type, (double)f.size(), big_endian);
    for (int64_t i : f) put(s, index_type, (double)i, big_endian);
  }
  return s;
}

// A small grid of w × h quads, two triangles each, with normals and texture coordinates that are
// not trivially derived from the positions (values of every kind a type can hold).
void grid(int w, int h, std::vector<std::vector<double>>* vertices, std::vector<std::vector<int64_t>>* faces) {
  for (int y = 0; y <= h; ++y)
    for (int x = 0; x <= w; ++x)
      vertices->push_back({x * 1.25 - 3.0, 0.1 * x * y, y * 0.75 + 1.0 / 3.0, 0.3, 0.9, -0.1 * x, x / 7.0, 1.0 - y / 9.0, 200.0});
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int64_t a = y * (w + 1) + x, b = a + 1, c = a + w + 1, d = c + 1;
      faces->push_back({a, b, d});
      faces->push_back({a, d, c});
    }
}

// The triangles Assimp gives for a mesh file, as load_mesh reads them. (The files here have no two
// vertices that aiProcess_JoinIdenticalVertices would merge: the two readers agree bit for bit.)
xi::Mesh assimp_triangles(const fs::path& path) {
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(
      path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_PreTransformVertices);
  xi::Mesh out;
  if (!scene) return out;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) xi::scene_detail::mesh_triangles(*scene->mMeshes[i], 0, true, out);
  return out;
}

// Field by field and bit for bit (NaN payloads and signed zeros too): each corner's position and
// normal, wherever in its mesh's vertices it is.
void expect_same_triangles(const xi::Mesh& a, const xi::Mesh& b) {
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  for (size_t i = 0; i < a.triangles.size(); ++i) {
    SCOPED_TRACE(testing::Message() << "triangle " << i);
    const xi::Triangle &s = a.triangles[i], &t = b.triangles[i];
    const xi::TriangleTexcoords &sc = xi::texcoords_of(a.texcoords, s), &tc = xi::texcoords_of(b.texcoords, t);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(std::memcmp(&a.position(s, k), &b.position(t, k), sizeof(glm::vec3)), 0) << "corner " << k;
      EXPECT_EQ(std::memcmp(&a.normal(s, k), &b.normal(t, k), sizeof(glm::vec3)), 0) << "corner " << k;
    }
    EXPECT_EQ(std::memcmp(sc.uv, tc.uv, sizeof sc.uv), 0);
    EXPECT_EQ(std::memcmp(sc.tangent, tc.tangent, sizeof sc.tangent), 0);
    EXPECT_EQ(s.has_normals, t.has_normals);
    EXPECT_EQ(s.material, t.material);
  }
}

}  // namespace

TEST(MeshPly, SameTrianglesAsAssimp) {
  const fs::path dir = temp_dir();
  std::vector<std::vector<double>> vertices;
  std::vector<std::vector<int64_t>> faces;
  grid(6, 5, &vertices, &faces);
  const std::vector<PlyProperty> full = {{"float", "x"},  {"float", "y"}, {"float", "z"},     {"float", "nx"}, {"float", "ny"},
                                         {"float", "nz"}, {"float", "u"}, {"float", "v"}, {"uchar", "red"}};
  struct Case {
    std::string name;
    bool big_endian;
    std::vector<PlyProperty> props;
    std::string count_type = "uchar", index_type = "int", extra = "";
  };
  auto with = [&](std::vector<std::pair<size_t, PlyProperty>> changes) {
    std::vector<PlyProperty> p = full;
    for (auto& [k, prop] : changes) p[k] = prop;
    return p;
  };
  const std::vector<Case> cases = {
      {"plain", false, {full[0], full[1], full[2]}},
      {"normals-uv-colour", false, full},
      {"big-endian", true, full, "uint8", "uint32"},
      {"doubles", false, with({{0, {"double", "x"}}, {1, {"float64", "y"}}, {2, {"double", "z"}}, {6, {"double", "s"}}, {7, {"double", "t"}}})},
      {"integers", false, with({{0, {"short", "x"}}, {1, {"int8", "y"}}, {2, {"ushort", "z"}}, {3, {"char", "nx"}}})},
      {"uv-names", true, with({{6, {"float", "texture_u"}}, {7, {"float", "texture_v"}}}), "uchar", "ushort"},
      {"extra-properties", false, with({{8, {"float", "quality"}}}), "int", "uint", "comment made by hand\nobj_info none\n"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    std::vector<std::vector<double>> v = vertices;
    for (auto& row : v) row.resize(c.props.size());
    const fs::path file = dir / (c.name + ".ply");
    write_bytes(file, ply_bytes(c.big_endian, c.props, v, faces, c.count_type, c.index_type, c.extra));
    const xi::Mesh reference = assimp_triangles(file);
    ASSERT_EQ(reference.triangles.size(), faces.size());
    xi::Mesh ours;  // appended after what is there: its corners index the vertices after these
    ours.add_triangle(glm::vec3(7), glm::vec3(8), glm::vec3(9)).texcoords = 0;
    ours.texcoords.emplace_back();
    ASSERT_TRUE(xi::scene_detail::read_binary_ply(file, true, ours));
    ASSERT_EQ(ours.triangles.size(), 1 + faces.size());
    ours.triangles.erase(ours.triangles.begin());
    expect_same_triangles(ours, reference);
  }
  fs::remove_all(dir);
}

// Assimp's own PLY models: those this reader takes give Assimp's triangles.
TEST(MeshPly, AssimpModels) {
  const fs::path models = "/usr/share/assimp/models/PLY";
  if (!fs::is_directory(models)) GTEST_SKIP() << models << " is missing: scripts/install-deps.sh installs assimp-testmodels";
  size_t read = 0;
  for (const auto& entry : fs::directory_iterator(models)) {
    if (entry.path().extension() != ".ply") continue;
    SCOPED_TRACE(entry.path().string());
    xi::Mesh ours;
    if (!xi::scene_detail::read_binary_ply(entry.path(), true, ours)) continue;
    read++;
    expect_same_triangles(ours, assimp_triangles(entry.path()));
  }
  EXPECT_GE(read, 1u);  // cube_binary.ply at least
}

// Whatever it does not take it leaves to Assimp, with `out` untouched, and the scene still loads.
TEST(MeshPly, LeavesOtherFilesToAssimp) {
  const fs::path dir = temp_dir();
  const std::vector<PlyProperty> xyz = {{"float", "x"}, {"float", "y"}, {"float", "z"}};
  const std::vector<std::vector<double>> quad = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  const std::vector<std::vector<int64_t>> tris = {{0, 1, 2}, {0, 2, 3}};
  std::string crlf = ply_bytes(false, xyz, quad, tris);
  crlf.replace(crlf.find("\nformat"), 1, "\r\n");
  std::string with_edge = ply_bytes(false, xyz, quad, tris);
  with_edge.insert(with_edge.find("end_header"), "element edge 0\nproperty int vertex1\nproperty int vertex2\n");
  std::string face_flags = ply_bytes(false, xyz, quad, {});
  face_flags.replace(face_flags.find("element face 0"), 14, "element face 1");
  face_flags.insert(face_flags.find("end_header"), "property uchar flags\n");
  put(face_flags, "uchar", 3, false);
  for (int i : {0, 1, 2}) put(face_flags, "int", i, false);
  put(face_flags, "uchar", 7, false);
  const std::string short_file = ply_bytes(false, xyz, quad, tris);
  const struct {
    std::string name, bytes;
    size_t triangles;  // what the scene gets through Assimp
  } cases[] = {
      {"ascii", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", 1},
      {"quad", ply_bytes(false, xyz, quad, {{0, 1, 2, 3}}), 2},
      {"mixed", ply_bytes(true, xyz, quad, {{0, 1, 2}, {0, 1, 2, 3}}), 3},
      {"crlf", crlf, 2},
      {"edge", with_edge, 2},
      {"face-flags", face_flags, 1},
      {"index-type-float", ply_bytes(false, xyz, quad, tris, "uchar", "float"), 2},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    write_bytes(dir / (c.name + ".ply"), c.bytes);
    xi::Mesh out;
    out.vertices.resize(4), out.triangles.resize(3), out.texcoords.resize(2);
    EXPECT_FALSE(xi::scene_detail::read_binary_ply(dir / (c.name + ".ply"), true, out));
    EXPECT_EQ(out.vertices.size(), 4u);
    EXPECT_EQ(out.triangles.size(), 3u);
    EXPECT_EQ(out.texcoords.size(), 2u);
    EXPECT_EQ(parse(mesh_scene(c.name + ".ply"), dir).triangles.size(), c.triangles);
  }
  // An index out of range, a file cut short: declined after reading part of it, `out` as it was.
  write_bytes(dir / "bad-index.ply", ply_bytes(false, xyz, quad, {{0, 1, 2}, {0, 2, 4}}));
  write_bytes(dir / "negative-index.ply", ply_bytes(false, xyz, quad, {{0, 1, 2}, {0, -1, 3}}));
  write_bytes(dir / "short.ply", short_file.substr(0, short_file.size() - 1));
  for (const char* name : {"bad-index.ply", "negative-index.ply", "short.ply"}) {
    SCOPED_TRACE(name);
    xi::Mesh out;
    out.vertices.resize(4), out.triangles.resize(3), out.texcoords.resize(2);
    EXPECT_FALSE(xi::scene_detail::read_binary_ply(dir / name, true, out));
    EXPECT_EQ(out.vertices.size(), 4u);
    EXPECT_EQ(out.triangles.size(), 3u);
    EXPECT_EQ(out.texcoords.size(), 2u);
  }
  fs::remove_all(dir);
}

// A PLY mesh among other shapes: the scene's triangles in the shapes' order, each with its
// material, the mesh's transform applied and its degenerate triangles dropped, as through Assimp.
TEST(MeshPly, InASceneBetweenOtherShapes) {
  const fs::path dir = temp_dir();
  std::vector<std::vector<double>> vertices;
  std::vector<std::vector<int64_t>> faces;
  grid(4, 3, &vertices, &faces);
  faces.push_back({0, 0, 1});  // degenerate: dropped
  const std::vector<PlyProperty> props = {{"float", "x"},  {"float", "y"}, {"float", "z"}, {"float", "nx"},
                                          {"float", "ny"}, {"float", "nz"}, {"float", "u"}, {"float", "v"}};
  for (auto& row : vertices) row.resize(props.size());
  write_bytes(dir / "grid.ply", ply_bytes(false, props, vertices, faces));
  // The same grid as an OBJ, which Assimp reads.
  std::ofstream obj(dir / "grid.obj");
  obj.precision(17);
  for (const auto& v : vertices) obj << "v " << (float)v[0] << " " << (float)v[1] << " " << (float)v[2] << "\n";
  obj.close();
  const std::string materials = R"("materials": {"a": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]},
      "b": {"type": "diffuse", "albedo": [0.2, 0.2, 0.2]}})";
  auto scene = [&](const std::string& file) {
    return scene_text(R"({"type": "quad", "material": "a", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]]},
        {"type": "mesh", "material": "b", "file": ")" + file + R"(", "transform": {"scale": 2, "translate": [1, 2, 3]}},
        {"type": "triangle", "material": "a", "vertices": [[0,0,5], [1,0,5], [0,1,5]]})", materials);
  };
  const xi::Scene s = parse(scene("grid.ply"), dir);
  const size_t mesh = faces.size() - 1;
  ASSERT_EQ(s.triangles.size(), 2 + mesh + 1);
  const uint32_t a = s.triangles[0].material, b = s.triangles[2].material;
  EXPECT_NE(a, b);
  for (size_t i = 0; i < s.triangles.size(); ++i)
    EXPECT_EQ(s.triangles[i].material, i >= 2 && i < 2 + mesh ? b : a) << "triangle " << i;
  EXPECT_EQ(s.position(s.triangles.back(), 0), glm::vec3(0, 0, 5));
  EXPECT_TRUE(s.triangles[2].has_normals);
  // The positions Assimp gives for the same vertices in an OBJ, after the same transform.
  std::vector<std::vector<int64_t>> obj_faces = faces;
  obj_faces.pop_back();
  std::ofstream(dir / "grid.obj", std::ios::app) << [&] {
    std::string f;
    for (const auto& t : obj_faces) f += "f " + std::to_string(t[0] + 1) + " " + std::to_string(t[1] + 1) + " " + std::to_string(t[2] + 1) + "\n";
    return f;
  }();
  const xi::Scene through_assimp = parse(scene("grid.obj"), dir);
  ASSERT_EQ(through_assimp.triangles.size(), s.triangles.size());
  for (size_t i = 2; i < 2 + mesh; ++i)
    for (int k = 0; k < 3; ++k)
      EXPECT_EQ(s.position(s.triangles[i], k), through_assimp.position(through_assimp.triangles[i], k)) << "triangle " << i;
  fs::remove_all(dir);
}

// A mesh file's triangles share its vertices: a quad of 4 vertices and 2 faces, as an OBJ (through
// Assimp) and as a binary PLY (xi's reader), loads as 2 triangles over 4 vertices, each moved by
// the shape's transform once.
TEST(MeshPly, MeshFilesShareTheirVertices) {
  const fs::path dir = temp_dir();
  const std::vector<std::vector<double>> quad = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  write_bytes(dir / "quad.ply", ply_bytes(false, {{"float", "x"}, {"float", "y"}, {"float", "z"}}, quad, {{0, 1, 2}, {0, 2, 3}}));
  std::ofstream(dir / "quad.obj") << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n";
  for (const char* file : {"quad.ply", "quad.obj"}) {
    SCOPED_TRACE(file);
    const xi::Scene s = parse(scene_text(R"({"type": "mesh", "material": "white", "file": ")" + std::string(file) +
                                         R"(", "transform": {"translate": [2, 0, 0]}})"), dir);
    ASSERT_EQ(s.triangles.size(), 2u);
    ASSERT_EQ(s.vertices.size(), 4u);
    const xi::Triangle &t0 = s.triangles[0], &t1 = s.triangles[1];
    EXPECT_EQ(t0.v[0], t1.v[0]);  // the diagonal's ends, p0 and p2, are one vertex each
    EXPECT_EQ(t0.v[2], t1.v[1]);
    for (const xi::Triangle& t : s.triangles)
      for (int k = 0; k < 3; ++k) EXPECT_LT(t.v[k], 4u);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(s.position(t0, k), glm::vec3(quad[k][0] + 2, quad[k][1], quad[k][2])) << k;
      const int c = k == 0 ? 0 : k + 1;
      EXPECT_EQ(s.position(t1, k), glm::vec3(quad[c][0] + 2, quad[c][1], quad[c][2])) << k;
    }
  }
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// Metallic-roughness materials, textures, texture coordinates, lights and the environment.

namespace {

// A w × h PNG of one grey level (xi's own writer: sRGB-encoded 8-bit).
void write_test_png(const fs::path& p, int w = 2, int h = 2, float grey = 0.5f) {
  xi::Image img(w, h);
  for (auto& px : img.pixels) px = glm::vec3(grey);
  xi::write_png(p, img);
}

// A scene in `dir` whose materials are `materials` (a JSON object's inside) and whose one quad uses
// the first of them, named "m", plus `extra` top-level members (each ending in a comma).
std::string pbr_scene(const std::string& materials, const std::string& extra = "") {
  return "{" + kCamera + ", " + extra + R"("materials": {)" + materials + R"(}, "shapes": [
      {"type": "quad", "material": "m", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]]}]})";
}

// The KHR_texture_transform of (u, v), spelt out: scale, then rotate (as the sample model and the
// viewers do: counter-clockwise as drawn with v down), then offset.
glm::vec2 khr_transform(glm::vec2 uv, glm::vec2 offset, float radians, glm::vec2 scale) {
  const glm::vec2 s = uv * scale;
  const float c = std::cos(radians), n = std::sin(radians);
  return offset + glm::vec2(c * s.x + n * s.y, -n * s.x + c * s.y);
}

glm::vec2 apply_slot(const xi::TextureSlot& slot, glm::vec2 uv) {
  const glm::vec3 r = slot.transform * glm::vec3(uv, 1.0f);
  return {r.x, r.y};
}

}  // namespace

TEST(ScenePbr, DefaultsOfEveryField) {
  const xi::Scene s = parse(pbr_scene(R"("m": {"type": "pbr"})"));
  const xi::Material& m = material(s, "m");
  EXPECT_EQ(m.type, xi::MaterialType::Pbr);
  expect_vec(m.albedo, {1, 1, 1}, 0.0f);
  EXPECT_EQ(m.metallic, 0.0f);
  EXPECT_EQ(m.roughness, 0.5f);
  EXPECT_EQ(m.ior, 1.5f);
  EXPECT_EQ(m.transmission, 0.0f);
  EXPECT_EQ(m.alpha, 1.0f);
  EXPECT_EQ(m.alpha_mode, xi::AlphaMode::Opaque);
  EXPECT_EQ(m.alpha_cutoff, 0.5f);
  EXPECT_EQ(m.normal_scale, 1.0f);
  EXPECT_FALSE(m.two_sided);
  EXPECT_FALSE(m.is_emitter());
  for (const xi::TextureSlot& t : m.textures) EXPECT_FALSE(t.used());
  EXPECT_TRUE(s.images.empty());
  EXPECT_TRUE(s.lights.empty());
  EXPECT_FALSE(s.environment.has_value());
}

TEST(ScenePbr, EveryFieldIsRead) {
  const fs::path dir = temp_dir();
  write_test_png(dir / "base.png");
  write_test_png(dir / "mr.png");
  write_test_png(dir / "n.png");
  const xi::Scene s = parse(pbr_scene(R"("m": {"type": "pbr", "base_color": [0.1, 0.2, 0.3], "metallic": 0.7,
      "roughness": 0.2, "ior": 1.8, "transmission": 0.4, "radiance": [5, 6, 7], "two_sided": true, "alpha": 0.25,
      "alpha_mode": "mask", "alpha_cutoff": 0.3, "base_color_texture": "base.png",
      "metallic_roughness_texture": {"file": "mr.png", "texcoord": 1, "wrap": "clamp"},
      "normal_texture": {"file": "n.png", "wrap_s": "mirror", "wrap_t": "clamp"}, "normal_scale": 0.5,
      "emissive_texture": "base.png"},
      "b": {"type": "pbr", "alpha_mode": "blend", "emissive_texture": "base.png"})"),
                            dir);
  const xi::Material& m = material(s, "m");
  expect_vec(m.albedo, {0.1f, 0.2f, 0.3f}, 0.0f);
  EXPECT_FLOAT_EQ(m.metallic, 0.7f);
  EXPECT_FLOAT_EQ(m.roughness, 0.2f);
  EXPECT_FLOAT_EQ(m.ior, 1.8f);
  EXPECT_FLOAT_EQ(m.transmission, 0.4f);
  expect_vec(m.emission, {5, 6, 7}, 0.0f);
  EXPECT_TRUE(m.two_sided);
  EXPECT_FLOAT_EQ(m.alpha, 0.25f);
  EXPECT_EQ(m.alpha_mode, xi::AlphaMode::Mask);
  EXPECT_FLOAT_EQ(m.alpha_cutoff, 0.3f);
  EXPECT_FLOAT_EQ(m.normal_scale, 0.5f);
  // Colour images are decoded as sRGB, data as linear: the same file twice, each use once.
  ASSERT_EQ(s.images.size(), 3u);  // base.png (sRGB), mr.png, n.png: "b" reuses base.png as a colour
  ASSERT_TRUE(m.textures[XI_TEXTURE_BASE_COLOR].used());
  EXPECT_TRUE(s.images[m.textures[XI_TEXTURE_BASE_COLOR].image].srgb);
  EXPECT_EQ(m.textures[XI_TEXTURE_EMISSIVE].image, m.textures[XI_TEXTURE_BASE_COLOR].image);
  EXPECT_FALSE(s.images[m.textures[XI_TEXTURE_METALLIC_ROUGHNESS].image].srgb);
  EXPECT_FALSE(s.images[m.textures[XI_TEXTURE_NORMAL].image].srgb);
  EXPECT_EQ(s.images[m.textures[XI_TEXTURE_BASE_COLOR].image].width, 2);
  EXPECT_EQ(m.textures[XI_TEXTURE_BASE_COLOR].texcoord, 0);
  EXPECT_EQ(m.textures[XI_TEXTURE_BASE_COLOR].wrap_s, xi::Wrap::Repeat);
  EXPECT_EQ(m.textures[XI_TEXTURE_METALLIC_ROUGHNESS].texcoord, 1);
  EXPECT_EQ(m.textures[XI_TEXTURE_METALLIC_ROUGHNESS].wrap_s, xi::Wrap::Clamp);
  EXPECT_EQ(m.textures[XI_TEXTURE_METALLIC_ROUGHNESS].wrap_t, xi::Wrap::Clamp);
  EXPECT_EQ(m.textures[XI_TEXTURE_NORMAL].wrap_s, xi::Wrap::Mirror);
  EXPECT_EQ(m.textures[XI_TEXTURE_NORMAL].wrap_t, xi::Wrap::Clamp);
  const xi::Material& b = material(s, "b");
  EXPECT_EQ(b.alpha_mode, xi::AlphaMode::Blend);
  EXPECT_EQ(b.textures[XI_TEXTURE_EMISSIVE].image, m.textures[XI_TEXTURE_BASE_COLOR].image);
  expect_vec(b.emission, {1, 1, 1}, 0.0f);  // an emissive texture alone: radiance 1 times the texture
  // A normal texture turns on the normal-map feature; a scene without one compiles none of it.
  EXPECT_TRUE(xi::compile_scene(s).features.normal_map);
  const xi::Scene plain = parse(pbr_scene(R"("m": {"type": "pbr", "base_color_texture": "base.png"})"), dir);
  EXPECT_FALSE(xi::compile_scene(plain).features.normal_map);
}

TEST(ScenePbr, DiffuseAlbedoMayBeAnImage) {
  const fs::path dir = temp_dir();
  write_test_png(dir / "wood.png", 3, 1);
  const xi::Scene s = parse(pbr_scene(R"("m": {"type": "diffuse", "albedo": "wood.png"},
      "n": {"type": "diffuse", "albedo": {"file": "wood.png", "scale": [2, 2]}})"), dir);
  const xi::Material& m = material(s, "m");
  EXPECT_EQ(m.type, xi::MaterialType::Diffuse);
  expect_vec(m.albedo, {1, 1, 1}, 0.0f);
  ASSERT_TRUE(m.textures[XI_TEXTURE_BASE_COLOR].used());
  ASSERT_EQ(s.images.size(), 1u);
  EXPECT_EQ(s.images[0].width, 3);
  EXPECT_TRUE(s.images[0].srgb);
  EXPECT_EQ(material(s, "n").textures[XI_TEXTURE_BASE_COLOR].image, 0);
  expect_vec(material(s, "n").textures[XI_TEXTURE_BASE_COLOR].transform[0], {2, 0, 0}, 0.0f);
}

TEST(ScenePbr, TextureTransformIsKhrTextureTransform) {
  const glm::vec2 offset(0.25f, -0.5f), scale(2.0f, 0.5f);
  const float degrees = 30.0f;
  // The library's matrix on a few points.
  const xi::TextureSlot direct{0, 0, xi::Wrap::Repeat, xi::Wrap::Repeat,
                               xi::texture_transform(offset, glm::radians(degrees), scale)};
  for (glm::vec2 uv : {glm::vec2(0, 0), glm::vec2(1, 0), glm::vec2(0, 1), glm::vec2(0.3f, 0.7f), glm::vec2(-2, 5)}) {
    const glm::vec2 want = khr_transform(uv, offset, glm::radians(degrees), scale), got = apply_slot(direct, uv);
    EXPECT_NEAR(got.x, want.x, 1e-5f);
    EXPECT_NEAR(got.y, want.y, 1e-5f);
  }
  // A positive rotation of 90 degrees takes u = 1 to v = -1: counter-clockwise as drawn with v down.
  const glm::vec2 turned = apply_slot({0, 0, xi::Wrap::Repeat, xi::Wrap::Repeat,
                                       xi::texture_transform({0, 0}, glm::radians(90.0f), {1, 1})},
                                      {1, 0});
  EXPECT_NEAR(turned.x, 0.0f, 1e-6f);
  EXPECT_NEAR(turned.y, -1.0f, 1e-6f);

  // The JSON object's offset, rotation (degrees) and scale give the same matrix.
  const fs::path dir = temp_dir();
  write_test_png(dir / "t.png");
  const xi::Scene s = parse(pbr_scene(R"("m": {"type": "pbr", "base_color_texture": {"file": "t.png",
      "offset": [0.25, -0.5], "rotation": 30, "scale": [2, 0.5]}})"), dir);
  const xi::TextureSlot& slot = material(s, "m").textures[XI_TEXTURE_BASE_COLOR];
  for (int c = 0; c < 3; ++c) expect_vec(slot.transform[c], direct.transform[c], 1e-6f);
  // Without a transform: the identity.
  const xi::Scene plain = parse(pbr_scene(R"("m": {"type": "pbr", "base_color_texture": "t.png"})"), dir);
  for (int c = 0; c < 3; ++c)
    expect_vec(material(plain, "m").textures[XI_TEXTURE_BASE_COLOR].transform[c], glm::mat3(1.0f)[c], 0.0f);
}

TEST(SceneUv, QuadsAndTrianglesMapTheImage) {
  const xi::Scene s = parse(scene_text(kQuad + R"(, {"type": "triangle", "material": "white",
      "vertices": [[0,0,1], [1,0,1], [0,1,1]]})"));
  ASSERT_EQ(s.triangles.size(), 3u);
  // v0..v3 of the quad at (0,0), (1,0), (1,1), (0,1): v0 is the image's top-left corner.
  const glm::vec2 quad[4] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  const glm::vec3 pos[4] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  for (int t = 0; t < 2; ++t)
    for (int k = 0; k < 3; ++k) {
      int corner = 0;
      while (corner < 4 && s.position(s.triangles[t], k) != pos[corner]) ++corner;
      ASSERT_LT(corner, 4);
      for (int set = 0; set < 2; ++set) {
        EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[t]).uv[set][k].x, quad[corner].x);
        EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[t]).uv[set][k].y, quad[corner].y);
      }
    }
  const glm::vec2 tri[3] = {{0, 0}, {1, 0}, {0, 1}};
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[2]).uv[0][k].x, tri[k].x);
    EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[2]).uv[0][k].y, tri[k].y);
  }
}

TEST(SceneUv, MirroringTransformKeepsEachVertexsCoordinates) {
  const xi::Scene s = parse(scene_text(R"({"type": "triangle", "material": "white",
      "vertices": [[0,0,0], [1,0,0], [0,1,0]], "transform": {"scale": [-1, 1, 1]}})"));
  ASSERT_EQ(s.triangles.size(), 1u);
  for (int k = 0; k < 3; ++k) {  // each vertex's (u, v) is the one it had: (0,0) at the origin, (1,0) at x = -1
    const glm::vec3 p = s.position(s.triangles[0], k);
    const glm::vec2 want = p.x < -0.5f ? glm::vec2(1, 0) : p.y > 0.5f ? glm::vec2(0, 1) : glm::vec2(0, 0);
    EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[0]).uv[0][k].x, want.x);
    EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[0]).uv[0][k].y, want.y);
  }
}

TEST(SceneUv, SphereIsEquirectangular) {
  const xi::Scene s = parse(scene_text(R"({"type": "sphere", "material": "white", "center": [0, 0, 0], "radius": 2,
      "subdivisions": 3})"));
  for (const xi::Triangle& t : s.triangles) {
    float lo = 10, hi = -10;
    for (int k = 0; k < 3; ++k) {
      const glm::vec3 d = glm::normalize(s.position(t, k));
      const glm::vec2 uv = xi::texcoords_of(s.texcoords, t).uv[0][k];
      EXPECT_NEAR(uv.y, std::acos(std::clamp(d.y, -1.0f, 1.0f)) / float(M_PI), 1e-5f);
      lo = std::min(lo, uv.x), hi = std::max(hi, uv.x);
      if (std::abs(d.y) < 0.999f) {  // off the poles: u = 0.5 + atan2(x, z) / 2π, maybe + 1 across the seam
        const float u = 0.5f + std::atan2(d.x, d.z) / (2.0f * float(M_PI));
        EXPECT_NEAR(std::fmod(uv.x, 1.0f), std::fmod(u, 1.0f), 1e-5f) << d.x << " " << d.y << " " << d.z;
      }
    }
    EXPECT_LT(hi - lo, 0.5f);  // no triangle spans the whole image across the seam
    EXPECT_GE(lo, 0.0f);
    EXPECT_LT(hi, 1.5f);
  }
}

TEST(SceneLights, EveryTypeWithItsDefaults) {
  const xi::Scene s = parse(pbr_scene(R"("m": {"type": "pbr"})", R"("lights": [
      {"type": "point", "position": [1, 2, 3]},
      {"type": "spot", "name": "key", "position": [0, 5, 0], "direction": [0, -2, 0], "color": [1, 0.5, 0.25],
       "intensity": 100, "inner_angle": 10, "outer_angle": 20},
      {"type": "spot", "position": [0, 5, 0], "direction": [1, 0, 0]},
      {"type": "directional", "direction": [0, 0, -3], "intensity": 2},
      {"type": "sun", "direction": [1, -1, 0], "intensity": 1000},
      {"type": "sun", "direction": [0, -1, 0], "angular_radius": 2}], )"));
  ASSERT_EQ(s.lights.size(), 6u);
  const auto& l = s.lights;
  EXPECT_EQ(l[0].type, xi::LightType::Point);
  expect_vec(l[0].position, {1, 2, 3}, 0.0f);
  expect_vec(l[0].intensity, {1, 1, 1}, 0.0f);
  EXPECT_EQ(l[0].name, "light 0");
  EXPECT_EQ(l[1].type, xi::LightType::Spot);
  EXPECT_EQ(l[1].name, "key");
  expect_vec(l[1].direction, {0, -1, 0}, 0.0f);  // normalised
  expect_vec(l[1].intensity, {100, 50, 25}, 0.0f);
  EXPECT_FLOAT_EQ(l[1].inner_cone, glm::radians(10.0f));
  EXPECT_FLOAT_EQ(l[1].outer_cone, glm::radians(20.0f));
  EXPECT_FLOAT_EQ(l[2].inner_cone, 0.0f);
  EXPECT_FLOAT_EQ(l[2].outer_cone, glm::radians(45.0f));
  EXPECT_EQ(l[3].type, xi::LightType::Directional);
  expect_vec(l[3].direction, {0, 0, -1}, 0.0f);
  expect_vec(l[3].intensity, {2, 2, 2}, 0.0f);
  EXPECT_EQ(l[3].angular_radius, 0.0f);
  EXPECT_EQ(l[4].type, xi::LightType::Directional);
  expect_vec(l[4].direction, glm::normalize(glm::vec3(1, -1, 0)), 1e-6f);
  EXPECT_FLOAT_EQ(l[4].angular_radius, glm::radians(0.27f));
  EXPECT_FLOAT_EQ(l[5].angular_radius, glm::radians(2.0f));
  EXPECT_NO_THROW(xi::check_scene_limits(s));
}

TEST(SceneEnvironment, FileStrengthRotationAndBackground) {
  const fs::path dir = temp_dir();
  write_test_png(dir / "sky.png");
  const xi::Scene s = parse(pbr_scene(R"("m": {"type": "pbr"})",
                                      R"("background": [0.1, 0.2, 0.3], "environment": {"file": "sky.png",
                                          "strength": 2.5, "rotation": -90}, )"),
                            dir);
  ASSERT_TRUE(s.environment.has_value());
  EXPECT_EQ(s.environment->file, dir / "sky.png");
  EXPECT_FLOAT_EQ(s.environment->strength, 2.5f);
  EXPECT_FLOAT_EQ(s.environment->rotation_degrees, -90.0f);
  expect_vec(s.background, {0.1f, 0.2f, 0.3f}, 0.0f);  // kept: the environment replaces it where set
  const xi::Scene d = parse(pbr_scene(R"("m": {"type": "pbr"})", R"("environment": {"file": "sky.png"}, )"), dir);
  EXPECT_FLOAT_EQ(d.environment->strength, 1.0f);
  EXPECT_FLOAT_EQ(d.environment->rotation_degrees, 0.0f);
}

// Each bad input: one error naming the file and the JSON pointer of the value at fault.
TEST(SceneErrors, PbrTexturesLightsAndEnvironment) {
  const fs::path dir = temp_dir();
  write_test_png(dir / "ok.png");
  write_bytes(dir / "corrupt.png", "\x89PNG\r\n\x1a\n not really a png");
  struct Case { std::string materials, extra, needle; };
  const std::string pbr = R"("m": {"type": "pbr")";
  const std::vector<Case> cases = {
      {pbr + R"(, "shiny": 1})", "", "test.json: /materials/m/shiny"},
      {pbr + R"(, "metallic": 1.5})", "", "/materials/m/metallic"},
      {pbr + R"(, "roughness": -0.1})", "", "/materials/m/roughness"},
      {pbr + R"(, "ior": 0.5})", "", "/materials/m/ior"},
      {pbr + R"(, "alpha": 2})", "", "/materials/m/alpha"},
      {pbr + R"(, "alpha_mode": "cutout"})", "", "/materials/m/alpha_mode"},
      {pbr + R"(, "alpha_cutoff": 0.2})", "", "/materials/m/alpha_cutoff"},  // only with "mask"
      {pbr + R"(, "normal_scale": 2})", "", "/materials/m/normal_scale"},    // needs a normal_texture
      {pbr + R"(, "base_color": [1, 2, 0]})", "", "/materials/m/base_color/1"},
      {pbr + R"(, "base_color_texture": "missing.png"})", "", "/materials/m/base_color_texture"},
      {pbr + R"(, "normal_texture": {"file": "corrupt.png"}})", "", "/materials/m/normal_texture/file"},
      {pbr + R"(, "base_color_texture": {"file": "ok.png", "wrap": "tile"}})", "", "/materials/m/base_color_texture/wrap"},
      {pbr + R"(, "base_color_texture": {"file": "ok.png", "wrap_t": "loop"}})", "", "/materials/m/base_color_texture/wrap_t"},
      {pbr + R"(, "base_color_texture": {"file": "ok.png", "texcoord": 2}})", "", "/materials/m/base_color_texture/texcoord"},
      {pbr + R"(, "base_color_texture": {"file": "ok.png", "offset": [1]}})", "", "/materials/m/base_color_texture/offset"},
      {pbr + R"(, "base_color_texture": {"file": "ok.png", "rotate": 3}})", "", "/materials/m/base_color_texture/rotate"},
      {pbr + R"(, "base_color_texture": {"texcoord": 0}})", "", "/materials/m/base_color_texture"},
      {pbr + R"(, "base_color_texture": 3})", "", "/materials/m/base_color_texture"},
      {R"("m": {"type": "diffuse", "albedo": "missing.png"})", "", "/materials/m/albedo"},
      {R"("m": {"type": "plastic"})", "", "/materials/m/type"},
      {pbr + "}", R"("lights": [{"type": "spot", "position": [0,0,0], "direction": [0,-1,0], "inner_angle": 30,
           "outer_angle": 30}], )", "/lights/0/outer_angle"},
      {pbr + "}", R"("lights": [{"type": "spot", "position": [0,0,0], "direction": [0,-1,0], "inner_angle": 50}], )",
       "/lights/0/inner_angle"},
      {pbr + "}", R"("lights": [{"type": "spot", "position": [0,0,0], "direction": [0,-1,0], "outer_angle": 120}], )",
       "/lights/0/outer_angle"},
      {pbr + "}", R"("lights": [{"type": "directional", "direction": [0, 0, 0]}], )", "/lights/0/direction"},
      {pbr + "}", R"("lights": [{"type": "point", "position": [0,0,0], "intensity": -1}], )", "/lights/0/intensity"},
      {pbr + "}", R"("lights": [{"type": "point", "position": [0,0,2e9]}], )", "/lights/0/position"},
      {pbr + "}", R"("lights": [{"type": "point", "position": [0,0,0], "direction": [0,0,1]}], )", "/lights/0/direction"},
      {pbr + "}", R"("lights": [{"type": "point"}], )", "/lights/0"},
      {pbr + "}", R"("lights": [{"type": "area", "position": [0,0,0]}], )", "/lights/0/type"},
      {pbr + "}", R"("lights": [{"type": "sun", "direction": [0,-1,0], "angular_radius": 60}], )",
       "/lights/0/angular_radius"},
      {pbr + "}", R"("lights": [{"type": "point", "position": [0,0,0], "color": [1, 1, 1.5]}], )", "/lights/0/color/2"},
      {pbr + "}", R"("lights": {}, )", "test.json: /lights"},
      {pbr + "}", R"("environment": {"file": "nosky.hdr"}, )", "/environment/file"},
      {pbr + "}", R"("environment": {"file": "ok.png", "strength": -1}, )", "/environment/strength"},
      {pbr + "}", R"("environment": {"file": "ok.png", "rotate": 5}, )", "/environment/rotate"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.materials + " | " + c.extra);
    try {
      parse(pbr_scene(c.materials, c.extra), dir);
      ADD_FAILURE() << "no error";
    } catch (const xi::Error& e) {
      EXPECT_NE(std::string(e.what()).find(c.needle), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
    }
  }
  // The image's errors name the file, too.
  expect_error([&] { parse(pbr_scene(pbr + R"(, "base_color_texture": "missing.png"})"), dir); }, "missing.png");
  expect_error([&] { parse(pbr_scene(pbr + R"(, "normal_texture": "corrupt.png"})"), dir); }, "corrupt.png");
  expect_error([&] { parse(pbr_scene(pbr + R"(, "normal_texture": "corrupt.png"})"), dir); }, "cannot decode");
  expect_error([&] { parse(pbr_scene(pbr + "}", R"("environment": {"file": "nosky.hdr"}, )"), dir); }, "nosky.hdr");
}
