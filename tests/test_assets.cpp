// Asset files as scenes (xi/asset.h, `xi render FILE.gltf`, the JSON "asset" shape): against files
// no one here wrote (Debian's assimp-testmodels: Cameras.gltf, the 2CylinderEngine .glb, the
// glTF-Asset-Generator set) and small glTF files written by the tests, whose expected numbers come
// from the glTF definitions (node TRS, perspective camera), not from xi's code.
//
// The one statistical test (glTF light = JSON light) is a z-test per 8×8 block and channel on the
// block means, with their standard errors from the EXR variance layer, independent seeds, at a
// family-wise α = 0.01 (Šidák over the blocks × channels).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "cli_test.h"
#include "gltf_builder.h"
#include "fixtures.h"
#include "stats.h"
#include "xi/asset.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/scene.h"

namespace {

using xi_test::base64;
using xi_test::json;
namespace fs = std::filesystem;

const fs::path kModels = "/usr/share/assimp/models/glTF2";
const fs::path kCameras = kModels / "cameras/Cameras.gltf";
const fs::path kEngine = kModels / "2CylinderEngine-glTF-Binary/2CylinderEngine.glb";

using xi_test::Gltf;  // gltf_builder.h

json perspective(const std::string& name, double yfov, double aspect) {
  return {{"name", name}, {"type", "perspective"}, {"perspective", {{"yfov", yfov}, {"aspectRatio", aspect}, {"znear", 0.01}}}};
}
json quat_y(double degrees) {  // glTF rotation [x, y, z, w] about +y
  const double h = glm::radians(degrees) / 2.0;
  return {0.0, std::sin(h), 0.0, std::cos(h)};
}
json diffuse(const std::string& name, double albedo) {
  return {{"name", name}, {"pbrMetallicRoughness", {{"baseColorFactor", {albedo, albedo, albedo, 1.0}}, {"metallicFactor", 0.0}}}};
}

fs::path temp_dir() { return xi::test::fresh_test_dir("xi_assets_"); }  // fixtures.h

// The glTF file's own JSON (a .glb's JSON chunk), read here to get the true numbers.
json gltf_json(const fs::path& p) {
  std::string text = xi_test::read_text(p);
  if (p.extension() == ".glb") {
    uint32_t length = 0;
    std::memcpy(&length, text.data() + 12, 4);
    text = text.substr(20, length);
  }
  return json::parse(text);
}

bool contains(const std::vector<std::string>& lines, const std::string& needle) {
  return std::any_of(lines.begin(), lines.end(), [&](const std::string& l) { return l.find(needle) != std::string::npos; });
}

template <class F>
void expect_error(F&& call, const std::vector<std::string>& needles) {
  try {
    call();
    ADD_FAILURE() << "no exception";
  } catch (const xi::Error& e) {
    for (const auto& n : needles) EXPECT_NE(std::string(e.what()).find(n), std::string::npos) << e.what();
  }
}

// Where a world point lands on a W×H film under a glTF perspective camera placed by `world` (the
// camera node's global matrix), by the glTF definitions: the camera looks down its -z, +y up, yfov
// the full vertical angle, aspectRatio = width / height. Pixel coordinates, (0, 0) the top-left.
glm::dvec2 gltf_project(const glm::dmat4& world, double yfov, double aspect, glm::dvec3 p, int w, int h) {
  const glm::dvec3 c = glm::dvec3(glm::inverse(world) * glm::dvec4(p, 1.0));
  const double t = std::tan(yfov / 2.0);
  const double nx = c.x / -c.z / (t * aspect), ny = c.y / -c.z / t;
  return {(nx + 1.0) / 2.0 * w, (1.0 - ny) / 2.0 * h};
}

// An automatically framed camera: at `centre` + distance * `toward_camera` (a unit vector), the
// distance putting the bounding sphere's edge at 1/1.1 of the half-height of the 40-degree frame
// (distance = 1.1 r / sin 20°, r half the box's diagonal); looking at the centre, up +y; every
// vertex inside the square frame, the farthest from its centre beyond half of it.
void expect_framed(const xi::Scene& s, glm::dvec3 centre, glm::dvec3 toward_camera) {
  glm::dvec3 lo(INFINITY), hi(-INFINITY);
  for (const xi::Triangle& t : s.triangles)
    for (int k = 0; k < 3; ++k) lo = glm::min(lo, glm::dvec3(s.position(t, k))), hi = glm::max(hi, glm::dvec3(s.position(t, k)));
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(0.5 * (lo[k] + hi[k]), centre[k], 1e-5) << "the test's centre";
  const double radius = 0.5 * glm::length(hi - lo), distance = 1.1 * radius / std::sin(glm::radians(20.0));
  const glm::dvec3 want = centre + distance * toward_camera;
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(s.camera.position[k], want[k], 1e-4 * distance) << "camera position, axis " << k;
    EXPECT_NEAR(s.camera.look_at[k], centre[k], 1e-4) << "look_at, axis " << k;
  }
  EXPECT_EQ(s.camera.up, glm::vec3(0, 1, 0));
  EXPECT_EQ(s.camera.vfov_degrees, 40.0f);
  EXPECT_EQ(s.width, s.height);
  const glm::dvec3 pos(s.camera.position), forward = glm::normalize(centre - pos);
  const glm::dvec3 right = glm::normalize(glm::cross(forward, glm::dvec3(0, 1, 0))), up = glm::cross(right, forward);
  const double t = std::tan(glm::radians(20.0));
  double farthest = 0.0;
  for (const xi::Triangle& tri : s.triangles)
    for (int k = 0; k < 3; ++k) {
      const glm::dvec3 c = glm::dvec3(s.position(tri, k)) - pos;
      const double x = glm::dot(c, right) / glm::dot(c, forward) / t, y = glm::dot(c, up) / glm::dot(c, forward) / t;
      EXPECT_LT(std::abs(x), 1.0) << "vertex outside the frame";
      EXPECT_LT(std::abs(y), 1.0) << "vertex outside the frame";
      farthest = std::max({farthest, std::abs(x), std::abs(y)});
    }
  EXPECT_GT(farthest, 0.5) << "framed far too loosely";
}

}  // namespace

// Assimp 5.2 reads Cameras.gltf's perspective camera with mHorizontalFOV = yfov (× aspectRatio) and
// the node translation in mPosition as well as in the node: the camera must match the .gltf itself.
TEST(AssetCamera, CamerasGltfMatchesItsJson) {
  const json j = gltf_json(kCameras);
  const double yfov = j["cameras"][0]["perspective"]["yfov"], aspect = j["cameras"][0]["perspective"]["aspectRatio"];
  const glm::dvec3 t(j["nodes"][1]["translation"][0], j["nodes"][1]["translation"][1], j["nodes"][1]["translation"][2]);
  ASSERT_EQ(j["nodes"][1]["camera"], 0);
  const xi::Scene s = xi::load_asset(kCameras);
  EXPECT_NEAR(s.camera.vfov_degrees, glm::degrees(yfov), 1e-4);
  EXPECT_NEAR(s.camera.position.x, t.x, 1e-6);
  EXPECT_NEAR(s.camera.position.y, t.y, 1e-6);
  EXPECT_NEAR(s.camera.position.z, t.z, 1e-6);
  const glm::vec3 dir = glm::normalize(s.camera.look_at - s.camera.position);
  EXPECT_NEAR(dir.z, -1.0f, 1e-6);  // the node has no rotation: down -z
  EXPECT_NEAR(s.camera.up.y, 1.0f, 1e-6);
  EXPECT_EQ(s.height, 512);
  EXPECT_EQ(s.width, int(std::lround(512 * aspect)));
  EXPECT_TRUE(contains(s.notes, "camera 0 'nodes[1]' of 2")) << s.notes.at(0);
  // No material in the file: glTF's default material (spec 3.9.6: base colour 1, metallic 1,
  // roughness 1, a rough white metal), unwarned.
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_EQ(s.materials[0].type, xi::MaterialType::Pbr);
  EXPECT_EQ(s.materials[0].albedo, glm::vec3(1.0f));
  EXPECT_EQ(s.materials[0].metallic, 1.0f);
  EXPECT_EQ(s.materials[0].roughness, 1.0f);
  EXPECT_EQ(s.materials[0].transmission, 0.0f);
  EXPECT_FALSE(s.materials[0].is_emitter());
  EXPECT_TRUE(s.warnings.empty()) << s.warnings.at(0);
  // Camera 1 is orthographic: chosen by index or name, one error that lists both.
  for (const char* which : {"1", "nodes[2]"})
    expect_error([&] { xi::load_asset(kCameras, {which}); }, {"orthographic", "0 'nodes[1]'", "1 'nodes[2]' (orthographic)"});
  expect_error([&] { xi::load_asset(kCameras, {"5"}); }, {"no camera '5'", "0 'nodes[1]', 1 'nodes[2]'"});
}

// Cameras.gltf has aspectRatio 1, where yfov × aspect and yfov agree: a file with aspect 2 and a
// rotated, nested camera node tells them apart.
TEST(AssetCamera, AspectAndNodeRotation) {
  const fs::path dir = temp_dir();
  Gltf g;
  g.mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, -1);
  g.node({{"mesh", 0}});
  g.add("cameras", perspective("wide", 0.5, 2.0));
  g.add("cameras", perspective("tall", 0.9, 0.5));
  const int cam = g.node({{"name", "rig"}, {"camera", 0}, {"translation", {0.0, 0.0, 2.0}}, {"rotation", quat_y(30)}}, false);
  g.node({{"name", "base"}, {"translation", {1.0, 2.0, 3.0}}, {"children", {cam}}});
  g.node({{"name", "other"}, {"camera", 1}, {"translation", {0.0, 0.0, 5.0}}});
  g.write(dir / "cam.gltf");
  const xi::Scene s = xi::load_asset(dir / "cam.gltf");
  EXPECT_NEAR(s.camera.vfov_degrees, glm::degrees(0.5), 1e-4);
  EXPECT_EQ(s.width, 1024);
  EXPECT_EQ(s.height, 512);
  // World matrix by the glTF definitions: base T · rig T · rig R.
  const glm::dmat4 world = glm::translate(glm::dmat4(1.0), {1, 2, 3}) * glm::translate(glm::dmat4(1.0), {0, 0, 2}) *
                           glm::rotate(glm::dmat4(1.0), glm::radians(30.0), {0, 1, 0});
  const glm::dvec3 pos = world[3], fwd = -glm::dvec3(world[2]);
  EXPECT_NEAR(s.camera.position.x, pos.x, 1e-5);
  EXPECT_NEAR(s.camera.position.y, pos.y, 1e-5);
  EXPECT_NEAR(s.camera.position.z, pos.z, 1e-5);
  const glm::vec3 look = glm::normalize(s.camera.look_at - s.camera.position);
  EXPECT_NEAR(look.x, fwd.x, 1e-5);
  EXPECT_NEAR(look.y, fwd.y, 1e-5);
  EXPECT_NEAR(look.z, fwd.z, 1e-5);
  const xi::Scene tall = xi::load_asset(dir / "cam.gltf", {"other"});  // Assimp names cameras after their nodes
  EXPECT_NEAR(tall.camera.vfov_degrees, glm::degrees(0.9), 1e-4);
  EXPECT_EQ(tall.width, 256);
  EXPECT_NEAR(tall.camera.position.z, 5.0f, 1e-6);  // once, not twice
  EXPECT_EQ(xi::load_asset(dir / "cam.gltf", {"1"}).width, 256);
}

// The engine (not written here): its camera node is a matrix; the camera must sit at the matrix's
// translation, look down its -z, with the file's yfov; and every triangle is placed by its nodes.
TEST(AssetCamera, EngineCameraFromTheFile) {
  const json j = gltf_json(kEngine);
  const json& node = j["nodes"][81];
  ASSERT_EQ(node["camera"], 0);
  std::vector<double> m = node["matrix"];  // column-major
  const xi::Scene s = xi::load_asset(kEngine);
  EXPECT_NEAR(s.camera.vfov_degrees, glm::degrees(double(j["cameras"][0]["perspective"]["yfov"])), 1e-4);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(s.camera.position[k], m[12 + k], 1e-3);
  const glm::dvec3 fwd = -glm::normalize(glm::dvec3(m[8], m[9], m[10]));
  const glm::vec3 dir = glm::normalize(s.camera.look_at - s.camera.position);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(dir[k], fwd[k], 1e-4);  // the file's matrix is float, nearly orthonormal
  EXPECT_TRUE(s.warnings.empty()) << s.warnings.at(0);  // plain metallic-roughness: nothing lost
  // Each material as the file gives it: baseColorFactor, metallicFactor 0, roughnessFactor absent (1).
  for (const json& fm : j["materials"]) {
    const auto m = std::find_if(s.materials.begin(), s.materials.end(), [&](const xi::Material& x) { return x.name == fm["name"]; });
    if (m == s.materials.end()) continue;  // materials no mesh uses are dropped
    SCOPED_TRACE(m->name);
    EXPECT_EQ(m->type, xi::MaterialType::Pbr);
    for (int k = 0; k < 3; ++k) EXPECT_FLOAT_EQ(m->albedo[k], float(fm["pbrMetallicRoughness"]["baseColorFactor"][k]));
    EXPECT_EQ(m->metallic, 0.0f);
    EXPECT_EQ(m->roughness, 1.0f);
  }
  // No KHR_lights_punctual light (its emissive factors are 0 anyway): lit by the bundled sky.
  EXPECT_TRUE(contains(s.notes, "no light in the file: lit by xi's bundled sky"));
  ASSERT_TRUE(s.environment.has_value());
  EXPECT_EQ(s.environment->file.filename(), "sky.hdr");
  EXPECT_EQ(s.background, glm::vec3(0.0f));
}

// Node transforms are applied exactly once: a translated node's vertices are the transformed ones,
// a nested TRS chain equals the product of the glTF matrices, and the engine's triangles equal what
// Assimp's own pre-transform step gives (the JSON "mesh" shape).
TEST(AssetGeometry, NodeTransformsAppliedOnce) {
  const fs::path dir = temp_dir();
  Gltf g;
  const std::vector<glm::vec3> tri = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  g.add("materials", diffuse("a", 0.5));
  g.mesh(tri, 0);
  g.node({{"mesh", 0}, {"translation", {1.0, 2.0, 3.0}}});
  const int child = g.node({{"mesh", 0}, {"scale", {2.0, 2.0, 2.0}}, {"rotation", quat_y(90)}, {"translation", {0.0, 1.0, 0.0}}}, false);
  g.node({{"translation", {10.0, 0.0, 0.0}}, {"children", {child}}});
  g.write(dir / "nodes.gltf");
  const xi::AssetGeometry a = xi::load_asset_geometry(dir / "nodes.gltf");
  ASSERT_EQ(a.triangles.size(), 2u);
  const glm::dmat4 nested = glm::translate(glm::dmat4(1.0), {10, 0, 0}) * glm::translate(glm::dmat4(1.0), {0, 1, 0}) *
                            glm::rotate(glm::dmat4(1.0), glm::radians(90.0), {0, 1, 0}) * glm::scale(glm::dmat4(1.0), {2, 2, 2});
  int matched = 0;
  for (const xi::Triangle& t : a.triangles) {
    const bool first = std::abs(a.position(t, 0).x - 1.0f) < 1e-4f;  // the translated one starts at (1, 2, 3)
    for (int k = 0; k < 3; ++k) {
      const glm::dvec3 want = first ? glm::dvec3(tri[k]) + glm::dvec3(1, 2, 3) : glm::dvec3(nested * glm::dvec4(tri[k], 1.0));
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(a.position(t, k)[c], want[c], 1e-5) << "triangle " << first << " vertex " << k;
    }
    matched += first;
  }
  EXPECT_EQ(matched, 1);

  // The engine: the same triangles as Assimp's pre-transformed vertices (the JSON "mesh" shape), by
  // order-free moments of the triangle centroids (sum, sum of squares, per axis) and the bounding box.
  const xi::AssetGeometry engine = xi::load_asset_geometry(kEngine);
  const json scene = {{"camera", {{"position", {0, 0, 1000}}, {"look_at", {0, 0, 0}}, {"up", {0, 1, 0}}, {"fov", 40}}},
                      {"materials", {{"m", {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}}}}},
                      {"shapes", {{{"type", "mesh"}, {"material", "m"}, {"file", kEngine.string()}}}}};
  const xi::Scene pre = xi::parse_scene(scene.dump(), "engine.json", dir);
  ASSERT_EQ(engine.triangles.size(), pre.triangles.size());
  struct Moments {
    glm::dvec3 sum{0.0}, sum_sq{0.0}, lo{INFINITY}, hi{-INFINITY};
  };
  auto moments = [](const xi::Mesh& mesh) {
    Moments m;
    for (const auto& t : mesh.triangles) {
      const glm::dvec3 v[3] = {glm::dvec3(mesh.position(t, 0)), glm::dvec3(mesh.position(t, 1)), glm::dvec3(mesh.position(t, 2))};
      const glm::dvec3 c = (v[0] + v[1] + v[2]) / 3.0;
      m.sum += c, m.sum_sq += c * c;
      for (const auto& p : v) m.lo = glm::min(m.lo, p), m.hi = glm::max(m.hi, p);
    }
    return m;
  };
  const Moments ma = moments(engine), mb = moments(pre);
  const double n = double(ma.sum_sq.x + ma.sum_sq.y + ma.sum_sq.z);  // scale of the sums
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(ma.sum[k], mb.sum[k], 1e-6 * std::sqrt(n * engine.triangles.size())) << "axis " << k;
    EXPECT_NEAR(ma.sum_sq[k], mb.sum_sq[k], 1e-6 * n) << "axis " << k;
    EXPECT_NEAR(ma.lo[k], mb.lo[k], 1e-3);
    EXPECT_NEAR(ma.hi[k], mb.hi[k], 1e-3);
  }
  // The box the file's own node matrices give (computed from the .glb by a separate script):
  // x in [-371.69, 371.69], y in [-180.97, 92.04], z in [-140, 128].
  EXPECT_NEAR(ma.lo.x, -371.692, 1e-2);
  EXPECT_NEAR(ma.hi.y, 92.0416, 1e-2);
  EXPECT_NEAR(ma.lo.z, -140.0, 1e-2);
}

// Material mapping: glTF materials are metallic-roughness (Pbr) with the file's factors: emissive ×
// KHR_materials_emissive_strength (which Assimp 5.2 does not read), transmission and ior
// (KHR_materials_transmission, KHR_materials_ior), metallic and roughness as given, nothing warned.
// Emissive materials are not what lights a glTF model: without KHR_lights_punctual lights the
// bundled sky does.
TEST(AssetMaterials, MappingAndOneWarningPerKind) {
  const fs::path dir = temp_dir();
  Gltf g;
  const int lamp = g.add("materials", {{"name", "lamp"}, {"emissiveFactor", {1.0, 0.5, 0.25}}, {"doubleSided", true},
                                       {"extensions", {{"KHR_materials_emissive_strength", {{"emissiveStrength", 7.0}}}}}});
  const int glass = g.add("materials", {{"name", "glass"},
                                        {"pbrMetallicRoughness", {{"baseColorFactor", {0.9, 0.8, 0.7, 1.0}}, {"metallicFactor", 0.0}, {"roughnessFactor", 0.0}}},
                                        {"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}}, {"KHR_materials_ior", {{"ior", 1.33}}}}}});
  const int chrome = g.add("materials", {{"name", "chrome"},
                                         {"pbrMetallicRoughness", {{"baseColorFactor", {0.5, 0.6, 0.7, 1.0}}, {"metallicFactor", 1.0}, {"roughnessFactor", 0.0}}}});
  const int rough1 = g.add("materials", {{"name", "rough1"}, {"pbrMetallicRoughness", {{"metallicFactor", 1.0}, {"roughnessFactor", 0.5}}}});
  const int rough2 = g.add("materials", {{"name", "rough2"}, {"pbrMetallicRoughness", {{"metallicFactor", 0.5}, {"roughnessFactor", 0.2}}}});
  g.doc["extensionsUsed"] = {"KHR_materials_emissive_strength", "KHR_materials_transmission", "KHR_materials_ior"};
  std::vector<glm::vec3> many;  // several triangles per rough material
  for (int i = 0; i < 4; ++i) many.insert(many.end(), {{float(i), 0, 0}, {float(i) + 1, 0, 0}, {float(i), 1, 0}});
  for (int m : {lamp, glass, chrome, rough1, rough2}) g.node({{"mesh", g.mesh(many, m)}});
  g.write(dir / "materials.gltf");
  const xi::Scene s = xi::load_asset(dir / "materials.gltf");
  auto find = [&](const std::string& name) -> const xi::Material& {
    for (const auto& m : s.materials)
      if (m.name == name) return m;
    throw std::runtime_error("no material " + name);
  };
  const xi::Material& l = find("lamp");
  EXPECT_NEAR(l.emission.x, 7.0f, 1e-6);
  EXPECT_NEAR(l.emission.y, 3.5f, 1e-6);
  EXPECT_NEAR(l.emission.z, 1.75f, 1e-6);
  EXPECT_TRUE(l.two_sided);
  EXPECT_EQ(l.type, xi::MaterialType::Pbr);
  EXPECT_EQ(l.albedo, glm::vec3(1.0f));  // no pbrMetallicRoughness: glTF's defaults
  EXPECT_EQ(l.metallic, 1.0f);
  EXPECT_EQ(l.roughness, 1.0f);
  const xi::Material& g_ = find("glass");
  EXPECT_EQ(g_.type, xi::MaterialType::Pbr);
  EXPECT_EQ(g_.transmission, 1.0f);
  EXPECT_NEAR(g_.ior, 1.33f, 1e-6);
  EXPECT_NEAR(g_.albedo.y, 0.8f, 1e-6);
  EXPECT_EQ(g_.metallic, 0.0f);
  EXPECT_EQ(g_.roughness, 0.0f);
  EXPECT_FALSE(g_.is_emitter());
  const xi::Material& c = find("chrome");
  EXPECT_EQ(c.type, xi::MaterialType::Pbr);
  EXPECT_NEAR(c.albedo.z, 0.7f, 1e-6);
  EXPECT_EQ(c.metallic, 1.0f);
  EXPECT_EQ(c.roughness, 0.0f);
  EXPECT_EQ(c.transmission, 0.0f);
  EXPECT_EQ(find("rough1").type, xi::MaterialType::Pbr);
  EXPECT_EQ(find("rough1").metallic, 1.0f);
  EXPECT_EQ(find("rough1").roughness, 0.5f);
  EXPECT_EQ(find("rough2").type, xi::MaterialType::Pbr);
  EXPECT_EQ(find("rough2").metallic, 0.5f);
  EXPECT_NEAR(find("rough2").roughness, 0.2f, 1e-7);
  for (const char* name : {"glass", "chrome", "rough1", "rough2"}) {
    EXPECT_EQ(find(name).alpha_mode, xi::AlphaMode::Opaque) << name;
    EXPECT_FALSE(find(name).textures[XI_TEXTURE_BASE_COLOR].used()) << name;
  }
  EXPECT_TRUE(s.warnings.empty()) << s.warnings.at(0);
  // The emissive lamp glows but is no light for the choice of what lights the file: the sky does.
  EXPECT_EQ(s.background, glm::vec3(0.0f));
  ASSERT_TRUE(s.environment.has_value());
  EXPECT_TRUE(contains(s.notes, "no light in the file: lit by xi's bundled sky"));
}

// An emissive strength beyond float (1e300) is one error naming the material and the file, not an
// infinite light; 2e10 is a light of that radiance.
TEST(AssetMaterials, NonFiniteEmission) {
  const fs::path dir = temp_dir();
  for (const double strength : {1e300, 2e10}) {
    SCOPED_TRACE(strength);
    Gltf g;
    const int lamp = g.add("materials", {{"name", "sun"}, {"emissiveFactor", {1.0, 1.0, 1.0}},
                                         {"extensions", {{"KHR_materials_emissive_strength", {{"emissiveStrength", strength}}}}}});
    g.doc["extensionsUsed"] = {"KHR_materials_emissive_strength"};
    g.node({{"mesh", g.mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, lamp)}});
    g.write(dir / "sun.gltf");
    if (strength > 1e38) {
      try {
        xi::load_asset(dir / "sun.gltf");
        ADD_FAILURE() << "loaded";
      } catch (const xi::Error& e) {
        EXPECT_EQ(std::string(e.what()),
                  "material 'sun' has a non-finite emissive factor x strength (" + (dir / "sun.gltf").string() + ")");
      }
    } else {
      EXPECT_EQ(xi::load_asset(dir / "sun.gltf").materials.at(0).emission.x, 2e10f);
    }
  }
  fs::remove_all(dir);
}

// No camera: the bounding sphere framed as a glTF viewer does (from the front, 15 degrees above),
// said in the notes; no light: the bundled sky (strength 1, not turned), said too; or the
// environment the caller names; or with sky off, nothing but the scene's background.
TEST(AssetScene, NoCameraFramingAndNoLightSky) {
  const fs::path dir = temp_dir();
  Gltf g;
  g.add("materials", diffuse("grey", 0.5));
  g.mesh({{-3, -1, 2}, {5, -1, 2}, {5, 4, -6}, {-3, -1, 2}, {5, 4, -6}, {-3, 4, -6}}, 0);
  g.node({{"mesh", 0}, {"translation", {100.0, 0.0, 0.0}}});
  g.write(dir / "plain.gltf");
  const xi::Scene s = xi::load_asset(dir / "plain.gltf");
  EXPECT_TRUE(contains(s.notes, "no camera in the file: framing its bounding sphere from --orbit 0,15 (")) << s.notes.at(0);
  EXPECT_TRUE(contains(s.notes, "no light in the file: lit by xi's bundled sky (")) << s.notes.back();
  EXPECT_TRUE(contains(s.notes, "--background R,G,B a constant one"));
  ASSERT_TRUE(s.environment.has_value());
  EXPECT_EQ(s.environment->file, xi::bundled_scene_file("sky.hdr"));
  EXPECT_EQ(s.environment->strength, 1.0f);
  EXPECT_EQ(s.environment->rotation_degrees, 0.0f);
  EXPECT_EQ(s.background, glm::vec3(0.0f));
  const xi::Scene own = xi::load_asset(dir / "plain.gltf", xi::AssetOptions{.environment = xi::Environment{dir / "mine.hdr", 2.0f, 30.0f}});
  ASSERT_TRUE(own.environment.has_value());
  EXPECT_EQ(own.environment->file, dir / "mine.hdr");
  EXPECT_EQ(own.environment->strength, 2.0f);
  EXPECT_TRUE(contains(own.notes, "no light in the file: lit by " + (dir / "mine.hdr").string()));
  const xi::Scene bare = xi::load_asset(dir / "plain.gltf", xi::AssetOptions{.sky = false});
  EXPECT_FALSE(bare.environment.has_value());
  EXPECT_EQ(bare.background, glm::vec3(0.0f));
  EXPECT_TRUE(contains(bare.notes, "no light in the file and no environment: the background alone lights it"));
  EXPECT_EQ(s.width, 512);
  EXPECT_EQ(s.height, 512);
  expect_framed(s, {101, 1.5, -2}, {0.0, std::sin(glm::radians(15.0)), std::cos(glm::radians(15.0))});
}

// --orbit YAW,PITCH: yaw turns the framing camera about +y toward +x, pitch raises it; always at
// the same distance, looking at the centre, the bounding sphere filling the frame. Refused when
// the file's own camera is used, and for a pitch outside (-90, 90).
TEST(AssetScene, OrbitTurnsTheFraming) {
  const fs::path dir = temp_dir();
  Gltf g;
  g.add("materials", diffuse("grey", 0.5));
  g.mesh({{-1, 0, 0}, {3, 0, 0}, {3, 2, 0}, {-1, 0, 0}, {3, 2, 0}, {-1, 2, 4}}, 0);
  g.node({{"mesh", 0}});
  g.write(dir / "plain.gltf");
  const glm::dvec3 centre(1, 1, 2);
  const xi::Scene side = xi::load_asset(dir / "plain.gltf", {.orbit = xi::Orbit{90, 0}});
  EXPECT_TRUE(contains(side.notes, "framing its bounding sphere from --orbit 90,0 (")) << side.notes.at(0);
  expect_framed(side, centre, {1, 0, 0});  // on +x, at the centre's height
  EXPECT_NEAR(side.camera.position.y, 1.0f, 1e-5);
  const double yaw = glm::radians(-40.0), pitch = glm::radians(-25.0);
  expect_framed(xi::load_asset(dir / "plain.gltf", {.orbit = xi::Orbit{-40, -25}}), centre,
                {std::sin(yaw) * std::cos(pitch), std::sin(pitch), std::cos(yaw) * std::cos(pitch)});
  for (double bad : {90.0, -90.0, 120.0, double(NAN)})
    expect_error([&] { xi::load_asset(dir / "plain.gltf", {.orbit = xi::Orbit{0, bad}}); }, {"pitch", "(-90, 90)", "--orbit"});
  expect_error([&] { xi::load_asset(kCameras, {.orbit = xi::Orbit{}}); }, {"--orbit", "camera 0 'nodes[1]'", "Cameras.gltf"});
  expect_error([&] { xi::load_asset(kCameras, {.camera = "0", .orbit = xi::Orbit{10, 5}}); }, {"--orbit", "camera 0"});
  fs::remove_all(dir);
}

// An asset whose geometry, after its node transforms, spans less than 1e-6 is refused as a JSON
// scene's is (SceneErrors.GeometryBelowTheSmallestExtent); scaled by 1e-5 instead it loads. (Node
// scales, since Assimp merges vertices closer than about 1e-5 in the file itself.)
TEST(AssetScene, GeometryBelowTheSmallestExtent) {
  const fs::path dir = temp_dir();
  for (const double scale : {4e-7, 1e-5}) {
    SCOPED_TRACE(scale);
    Gltf g;
    g.mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, -1);
    g.node({{"mesh", 0}, {"scale", {scale, scale, scale}}});
    g.write(dir / "small.gltf");
    if (scale < 1e-6) {
      try {
        xi::load_asset(dir / "small.gltf");
        ADD_FAILURE() << "loaded";
      } catch (const xi::Error& e) {
        EXPECT_EQ(std::string(e.what()),
                  "the geometry spans only 4e-07 units (the longest side of its bounding box; at least 1e-6): single "
                  "precision cannot shade so small a scene; scale it up (" + (dir / "small.gltf").string() + ")");
      }
    } else {
      EXPECT_EQ(xi::load_asset(dir / "small.gltf").triangles.size(), 1u);
    }
  }
  fs::remove_all(dir);
}

// The glTF-Asset-Generator's primitive modes (not written here): every file with triangles loads,
// and its triangle count is what its index/position accessors say for the mode.
TEST(AssetScene, AssetGeneratorPrimitiveModes) {
  const fs::path dir = kModels / "glTF-Asset-Generator/Mesh_PrimitiveMode";
  int loaded = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".gltf") continue;
    const json j = gltf_json(e.path());
    const json& prim = j["meshes"][0]["primitives"][0];
    const int mode = prim.value("mode", 4);
    const int count = prim.contains("indices") ? int(j["accessors"][int(prim["indices"])]["count"])
                                               : int(j["accessors"][int(prim["attributes"]["POSITION"])]["count"]);
    const int want = mode == 4 ? count / 3 : (mode == 5 || mode == 6) ? count - 2 : 0;
    if (want == 0) {  // points and lines: nothing to render, one error naming the file
      expect_error([&] { xi::load_asset(e.path()); }, {e.path().filename().string()});
      continue;
    }
    const xi::Scene s = xi::load_asset(e.path());
    EXPECT_EQ(int(s.triangles.size()), want) << e.path();
    ++loaded;
  }
  EXPECT_GT(loaded, 0);
}

// OBJ and PLY files (not written here) go through the same reader, from load_scene too; Assimp's
// corpus of invalid files gives one xi::Error per file naming it (malformed2.obj, which Assimp
// reads, excepted).
TEST(AssetScene, ObjPlyAndInvalidCorpus) {
  const xi::Scene ply = xi::load_scene("/usr/share/assimp/models/PLY/cube.ply");
  EXPECT_EQ(ply.triangles.size(), 12u);
  EXPECT_TRUE(contains(ply.notes, "no camera in the file: framing"));
  EXPECT_TRUE(ply.environment.has_value());  // no emitter: the bundled sky
  EXPECT_TRUE(contains(ply.notes, "no light in the file: lit by xi's bundled sky"));
  EXPECT_EQ(ply.background, glm::vec3(0.0f));
  const xi::Scene obj = xi::load_asset("/usr/share/assimp/models/OBJ/cube_usemtl.obj");
  EXPECT_EQ(obj.triangles.size(), 12u);
  int defined = 0;  // the .obj also uses "mtl3", which its .mtl does not define (Assimp's default, 0.6)
  for (const xi::Material& m : obj.materials) {
    EXPECT_EQ(m.type, xi::MaterialType::Diffuse) << m.name;
    if (m.name == "mtl" || m.name == "mtl2") {
      EXPECT_EQ(m.albedo, glm::vec3(1.0f)) << m.name << ": Kd 1 in the .mtl";
      ++defined;
    }
  }
  EXPECT_EQ(defined, 2);
  int errors = 0;
  for (const auto& e : fs::directory_iterator(XI_ASSIMP_INVALID_DIR)) {
    if (e.path().filename() == "malformed2.obj") continue;
    expect_error([&] { xi::load_asset(e.path()); }, {e.path().filename().string()});
    ++errors;
  }
  EXPECT_GT(errors, 10);
}

// Every scene file but a .json one is read through Assimp. An extension Assimp has no importer for
// gets one error naming the file and listing what xi reads; a file Assimp reads loads, or fails with
// Assimp's own error.
TEST(AssetScene, EveryFormatAssimpReads) {
  EXPECT_FALSE(xi::is_asset_file("scene.json"));
  EXPECT_FALSE(xi::is_asset_file("dir/SCENE.Json"));
  for (const char* p : {"a.3ds", "a.blend", "a.x", "a.ac", "a.ase", "a.irr", "a.md2", "a.gltf", "a.xyz", "noext"})
    EXPECT_TRUE(xi::is_asset_file(p)) << p;
  const std::vector<std::string> known = xi::asset_extensions();
  for (const char* e : {".obj", ".gltf", ".glb", ".ply", ".3ds", ".blend", ".x", ".ac", ".ase", ".irr", ".md2"})
    EXPECT_EQ(std::count(known.begin(), known.end(), e), 1) << e;

  const xi::Scene cube = xi::load_scene("/usr/share/assimp/models/3DS/RotatingCube.3DS");
  EXPECT_EQ(cube.triangles.size(), 12u);
  const xi::Scene ase = xi::load_scene("/usr/share/assimp/models/ASE/RotatingCube.ASE");
  EXPECT_EQ(ase.triangles.size(), 12u);
  // Assimp 5.2's RAW reader leaves a null node in the scene graph: refused, not followed.
  expect_error([&] { xi::load_scene("/usr/share/assimp/models/RAW/WithColor.raw"); },
               {"cannot load asset", "null", "WithColor.raw"});

  const fs::path dir = temp_dir();
  xi_test::write_text(dir / "scene.xyz", xi_test::read_text(xi_test::kCornell));  // JSON inside: still refused
  expect_error([&] { xi::load_scene(dir / "scene.xyz"); },
               {"unknown scene format '.xyz'", "scene.xyz", "xi reads .json scenes and, through Assimp,", " .obj", " .3ds"});
  expect_error([&] { xi::load_asset(dir / "scene.xyz"); }, {"unknown scene format '.xyz'", "scene.xyz"});
  expect_error([&] { xi::load_scene(dir / "missing.xyz"); }, {"unknown scene format '.xyz'", "missing.xyz"});
  xi_test::write_text(dir / "scene", "{}");
  expect_error([&] { xi::load_scene(dir / "scene"); }, {"no file extension", " .gltf"});
  // In a JSON scene's "asset" shape the file must be an asset: the error lists Assimp's formats only.
  expect_error([&] { xi::parse_scene(R"({"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {}, "shapes": [{"type": "asset", "file": "scene.xyz"}]})", "test.json", dir); },
               {"unknown scene format '.xyz': xi reads through Assimp .", "/shapes/0/file"});
}

// Assimp's models (its invalid corpus aside): no file but a .json one is parsed as JSON. Each loads,
// or gives one xi::Error naming it and saying why: Assimp's own error (or, where Assimp gives none,
// xi's words), xi's (no triangles...), or for an extension Assimp does not read the list of what xi
// reads.
TEST(AssetScene, ModelCorpusNeverParsedAsJson) {
  const std::vector<std::string> known = xi::asset_extensions();
  int files = 0, loaded = 0, unknown = 0;
  for (auto it = fs::recursive_directory_iterator("/usr/share/assimp/models"); it != fs::recursive_directory_iterator(); ++it) {
    if (it->path().filename() == "invalid") it.disable_recursion_pending();
    if (!it->is_regular_file()) continue;
    std::string ext = it->path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    if (ext == ".json") continue;
    ++files;
    SCOPED_TRACE(it->path().string());
    EXPECT_TRUE(xi::is_asset_file(it->path()));
    const bool readable = std::count(known.begin(), known.end(), ext) > 0;
    try {
      loaded += xi::load_scene(it->path()).triangles.size() > 0;
    } catch (const xi::Error& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.find("invalid JSON"), std::string::npos) << what;
      EXPECT_NE(what.find(it->path().string()), std::string::npos) << what;
      EXPECT_EQ(what.find(":  ("), std::string::npos) << "no reason given: " << what;  // Assimp's may be empty
      if (!readable) EXPECT_NE(what.find("xi reads .json scenes and, through Assimp, .3d"), std::string::npos) << what;
    }
    unknown += !readable;
  }
  EXPECT_GT(files, 400);
  EXPECT_GT(loaded, 250);
  EXPECT_GT(unknown, 100);  // textures, notes, extensionless files
}

// The JSON "asset" shape: the file's shapes with its own materials, then the shape's transform.
TEST(AssetScene, JsonAssetShape) {
  const fs::path dir = temp_dir();
  Gltf g;
  g.add("materials", {{"name", "chrome"}, {"pbrMetallicRoughness", {{"metallicFactor", 1.0}, {"roughnessFactor", 0.0}}}});
  const std::vector<glm::vec2> uv = {{0.125f, 0.25f}, {0.375f, 0.5f}, {0.625f, 0.75f}};
  g.mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {}, uv, {}, 0);
  g.node({{"mesh", 0}, {"translation", {1.0, 0.0, 0.0}}});
  g.write(dir / "thing.gltf");
  const std::string text = R"({"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [{"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]]},
               {"type": "asset", "file": "thing.gltf", "transform": {"scale": 2, "translate": [0, 0, -3]}}]})";
  const xi::Scene s = xi::parse_scene(text, "test.json", dir);
  ASSERT_EQ(s.triangles.size(), 3u);
  ASSERT_EQ(s.materials.size(), 2u);
  const xi::Triangle& t = s.triangles[2];
  EXPECT_EQ(s.materials[t.material].type, xi::MaterialType::Pbr);
  EXPECT_EQ(s.materials[t.material].metallic, 1.0f);
  EXPECT_EQ(s.materials[t.material].roughness, 0.0f);
  EXPECT_EQ(s.materials[t.material].name, "thing.gltf:chrome");
  EXPECT_FALSE(s.environment.has_value()) << "a JSON scene's asset shape brings no sky";
  // node translation (1, 0, 0), then scale 2 and translate (0, 0, -3): (0,0,0) -> (2, 0, -3)
  EXPECT_NEAR(s.position(t, 0).x, 2.0f, 1e-6);
  EXPECT_NEAR(s.position(t, 0).z, -3.0f, 1e-6);
  EXPECT_NEAR(s.position(t, 1).x, 4.0f, 1e-6);
  EXPECT_NEAR(s.position(t, 2).y, 2.0f, 1e-6);
  // Its texture coordinates as the file has them, after the quad's own (each triangle its entry).
  const glm::vec2 quad_corners[3] = {{0, 0}, {1, 0}, {1, 1}};
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(xi::texcoords_of(s.texcoords, t).uv[0][k], uv[k]) << k;
    EXPECT_EQ(xi::texcoords_of(s.texcoords, s.triangles[0]).uv[0][k], quad_corners[k]) << k;
  }
  expect_error([&] { xi::parse_scene(R"({"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {}, "shapes": [{"type": "asset", "file": "missing.glb"}]})", "test.json", dir); },
               {"asset file not found", "/shapes/0/file"});
  expect_error([&] { xi::parse_scene(R"({"camera": {"position": [0, 0, 5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {}, "shapes": [{"type": "asset", "file": "thing.gltf", "material": "white"}]})", "test.json", dir); },
               {"unknown key 'material'", "/shapes/0/material"});
}

namespace {

class AssetCli : public xi_test::CliTest {
 protected:
  // A small emissive square (double-sided, radiance 1) under a nested node, seen by a rotated
  // camera with aspect 2: returns the world centre of the square.
  glm::dvec3 write_framing(const fs::path& p, glm::dmat4* camera_world) {
    Gltf g;
    g.add("materials", {{"name", "glow"}, {"emissiveFactor", {1.0, 1.0, 1.0}}, {"doubleSided", true}});
    const float h = 0.05f;
    g.mesh({{-h, -h, 0}, {h, -h, 0}, {h, h, 0}, {-h, -h, 0}, {h, h, 0}, {-h, h, 0}}, 0);
    const int child = g.node({{"mesh", 0}, {"translation", {0.2, 0.1, 0.0}}}, false);
    g.node({{"translation", {0.3, 0.0, -1.0}}, {"children", {child}}});
    g.add("cameras", perspective("front", 0.6, 2.0));
    g.add("cameras", perspective("side", 0.8, 1.0));
    g.node({{"name", "front-node"}, {"camera", 0}, {"translation", {1.0, 0.5, 4.0}}, {"rotation", quat_y(20)}});
    g.node({{"name", "side-node"}, {"camera", 1}, {"translation", {2.0, 0.6, 2.0}}, {"rotation", quat_y(45)}});
    g.write(p);
    *camera_world = glm::translate(glm::dmat4(1.0), {1.0, 0.5, 4.0}) * glm::rotate(glm::dmat4(1.0), glm::radians(20.0), {0, 1, 0});
    return {0.5, 0.1, -1.0};
  }
};

// Intensity-weighted centroid of channel 0, in pixel coordinates (pixel centres at +0.5).
glm::dvec2 centroid(const xi::Image& img) {
  double sx = 0, sy = 0, sw = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const double w = img.at(x, y).x;
      sx += w * (x + 0.5), sy += w * (y + 0.5), sw += w;
    }
  return {sx / sw, sy / sw};
}

}  // namespace

// `xi render FILE.gltf`: the square's bright pixels are centred where the glTF camera definition
// projects its centre (to within half a pixel at 128×64), through the default camera and by name.
// `--background 0`: the file has no light (its emissive square is no light for that choice), so it
// would be lit by the sky; on black the square alone is seen.
TEST_F(AssetCli, CameraFramingRendered) {
  glm::dmat4 world;
  const glm::dvec3 centre = write_framing(work_ / "frame.gltf", &world);
  const auto r = run_xi({"render", "frame.gltf", "--spp", "16", "--resolution", "128x64", "--max-depth", "1", "--background", "0"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("camera 0 'front-node' of 2"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("film: 128x64 (--resolution)"), std::string::npos) << r.out;
  EXPECT_EQ(r.err, "");
  const xi::Image img = xi::read_exr(work_ / "frame.exr");
  const glm::dvec2 want = gltf_project(world, 0.6, 2.0, centre, 128, 64);
  const glm::dvec2 got = centroid(img);
  EXPECT_NEAR(got.x, want.x, 0.5);
  EXPECT_NEAR(got.y, want.y, 0.5);
  EXPECT_GT(want.x, 70.0) << "the test's square should be off-centre";

  // By name: the side camera at (2, 0.6, 2), turned 45 degrees, sees the square obliquely.
  const auto side = run_xi({"render", "frame.gltf", "--camera", "side-node", "--spp", "16", "--max-depth", "1", "--resolution", "33x33", "--background", "0", "-o", "side.exr"});
  ASSERT_EQ(side.code, 0) << side.err;
  EXPECT_NE(side.out.find("camera 1 'side-node' of 2"), std::string::npos) << side.out;
  const glm::dvec2 s = centroid(xi::read_exr(work_ / "side.exr"));
  const glm::dmat4 side_world = glm::translate(glm::dmat4(1.0), {2.0, 0.6, 2.0}) * glm::rotate(glm::dmat4(1.0), glm::radians(45.0), {0, 1, 0});
  const glm::dvec2 sw = gltf_project(side_world, 0.8, 1.0, centre, 33, 33);
  EXPECT_NEAR(s.x, sw.x, 0.5);
  EXPECT_NEAR(s.y, sw.y, 0.5);
}

TEST_F(AssetCli, CameraByIndexFilmFromAspectAndBadCamera) {
  glm::dmat4 world;
  write_framing(work_ / "frame.gltf", &world);
  // Default film: height 512, width from the aspect ratio (2): checked without rendering 1024x512
  // by the note; rendered small with --camera 1.
  const auto r = run_xi({"render", "frame.gltf", "--camera", "1", "--spp", "1", "--resolution", "16x16", "-o", "one.exr"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("camera 1 'side-node' of 2 (vertical fov 45.84 degrees, aspect 1)"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(work_ / "one.exr"));

  auto before = files();
  const auto bad = run_xi(xi_test::concat({"render", "frame.gltf", "--camera", "7"}, xi_test::kFast));
  expect_user_error(bad, {"no camera '7'", "0 'front-node', 1 'side-node'", "--camera"}, before);
  const auto name = run_xi(xi_test::concat({"render", "frame.gltf", "--camera", "back"}, xi_test::kFast));
  expect_user_error(name, {"no camera 'back'", "0 'front-node'"}, before);
  const auto json_scene = run_xi(xi_test::concat({"render", xi_test::kCornell.string(), "--camera", "0"}, xi_test::kFast));
  expect_user_error(json_scene, {"--camera chooses among an asset file's cameras"}, before);
}

// `xi render --orbit`: the framing's direction from the flag, said in the note; one error (and no
// file) for a file whose camera is used, a JSON scene, and a malformed or out-of-range value.
TEST_F(AssetCli, OrbitFlag) {
  Gltf g;
  g.mesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, -1);
  g.node({{"mesh", 0}});
  g.write(work_ / "plain.gltf");
  const auto r = run_xi({"render", "plain.gltf", "--orbit", "90,0", "--spp", "1", "--resolution", "8x8"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("no camera in the file: framing its bounding sphere from --orbit 90,0 ("), std::string::npos) << r.out;
  const auto plain = run_xi({"render", "plain.gltf", "--spp", "1", "--resolution", "8x8", "-o", "default.exr"});
  EXPECT_NE(plain.out.find("framing its bounding sphere from --orbit 0,15 ("), std::string::npos) << plain.out;

  glm::dmat4 world;
  write_framing(work_ / "frame.gltf", &world);
  const auto before = files();
  expect_user_error(run_xi(xi_test::concat({"render", "frame.gltf", "--orbit", "0,10"}, xi_test::kFast)),
                    {"--orbit", "camera 0 'front-node'"}, before);
  expect_user_error(run_xi(xi_test::concat({"render", "frame.gltf", "--camera", "side-node", "--orbit", "0,10"}, xi_test::kFast)),
                    {"--orbit", "camera 1 'side-node'"}, before);
  expect_user_error(run_xi(xi_test::concat({"render", xi_test::kCornell.string(), "--orbit", "0,10"}, xi_test::kFast)),
                    {"--orbit 0,10", "a JSON scene has its own camera"}, before);
  for (const char* bad : {"10", "a,b", "10,", "1,2,3", "nan,0"})
    expect_user_error(run_xi(xi_test::concat({"render", "plain.gltf", "--orbit", bad}, xi_test::kFast)),
                      {"expected YAW,PITCH", std::string("--orbit ") + bad}, before);
  expect_user_error(run_xi(xi_test::concat({"render", "plain.gltf", "--orbit", "0,90"}, xi_test::kFast)),
                    {"pitch", "(-90, 90)", "--orbit"}, before);
}

// `xi render` on the engine .glb as shipped: works, says which camera, what lights it (no light in
// the file: the bundled sky; with --background 1 a white background) and film.
TEST_F(AssetCli, RendersTheEngineGlb) {
  fs::copy_file(kEngine, work_ / "engine.glb");
  const auto lit = run_xi({"render", "engine.glb", "--spp", "1", "--max-depth", "2", "--resolution", "32x32", "-o", "sky.exr"});
  ASSERT_EQ(lit.code, 0) << lit.err;
  EXPECT_NE(lit.out.find("no light in the file: lit by xi's bundled sky"), std::string::npos) << lit.out;
  EXPECT_EQ(lit.err, "");
  const auto r = run_xi({"render", "engine.glb", "--spp", "1", "--max-depth", "2", "--background", "1"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("camera 0 'nodes[81]' of 1"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("no light in the file and no environment: the background alone lights it"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("film: 512x512 (height 512, width from the camera's aspect ratio)"), std::string::npos) << r.out;
  const xi::Image img = xi::read_exr(work_ / "engine.exr");
  EXPECT_EQ(img.width, 512);
  // The engine fills part of the frame: some pixels see the white sky (1), some the engine (< 1).
  int sky = 0, engine = 0;
  for (const auto& p : img.pixels) (p.x > 0.999f ? sky : engine) += 1;
  EXPECT_GT(sky, 512 * 512 / 20);
  EXPECT_GT(engine, 512 * 512 / 20);
}

// `xi render` reads any format Assimp reads (not as JSON), and refuses an extension it does not
// read with one error naming the file and listing the formats.
TEST_F(AssetCli, AnyAssimpFormatAndUnknownExtension) {
  fs::copy_file("/usr/share/assimp/models/3DS/RotatingCube.3DS", work_ / "cube.3ds");
  const auto r = run_xi(xi_test::concat({"render", "cube.3ds", "-o", "cube.exr"}, xi_test::kFast));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(xi::read_exr(work_ / "cube.exr").width, 32);

  fs::copy_file(xi_test::kCornell, work_ / "scene.xyz");
  const auto before = files();
  expect_user_error(run_xi(xi_test::concat({"render", "scene.xyz", "-o", "out.exr"}, xi_test::kFast)),
                    {"unknown scene format '.xyz'", "(scene.xyz)", ".json", " .obj", " .3ds", " .blend"}, before);
  const auto help = run_xi({"help"});
  EXPECT_NE(help.out.find("render [SCENE]"), std::string::npos) << help.out;
}

// Warnings: one line per kind on stderr, whatever the number of materials and triangles that have
// it: three materials with KHR_materials_unlit, two with KHR_materials_dispersion (unmodelled, one
// line each), and rough partial transmission (modelled: no warning).
TEST_F(AssetCli, OneWarningLinePerKind) {
  Gltf g;
  for (int i = 0; i < 5; ++i) {
    const char* ext = i < 3 ? "KHR_materials_unlit" : "KHR_materials_dispersion";
    const int m = g.add("materials", {{"name", "coated" + std::to_string(i)}, {"pbrMetallicRoughness", {{"metallicFactor", 1.0}, {"roughnessFactor", 0.3}}},
                                      {"extensions", {{ext, json::object()}}}});
    g.node({{"mesh", g.mesh({{float(i), 0, 0}, {float(i) + 1, 0, 0}, {float(i), 1, 0}, {float(i), 0, 1}, {float(i) + 1, 0, 1}, {float(i), 1, 1}}, m)}});
  }
  const int glass = g.add("materials", {{"name", "frosted"}, {"pbrMetallicRoughness", {{"metallicFactor", 0.0}, {"roughnessFactor", 0.5}}},
                                        {"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", 0.5}}}}}});
  g.node({{"mesh", g.mesh({{0, 2, 0}, {1, 2, 0}, {0, 3, 0}}, glass)}});
  g.doc["extensionsUsed"] = {"KHR_materials_transmission", "KHR_materials_unlit", "KHR_materials_dispersion"};
  g.write(work_ / "warn.gltf");
  const auto r = run_xi(xi_test::concat({"render", "warn.gltf"}, xi_test::kFast));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 2) << r.err;
  auto lines_with = [&](const std::string& needle) {
    int n = 0;
    for (size_t p = r.err.find(needle); p != std::string::npos; p = r.err.find(needle, p + 1)) ++n;
    return n;
  };
  EXPECT_EQ(lines_with("xi: warning: unlit materials are not modelled"), 1) << r.err;
  EXPECT_EQ(lines_with("xi: warning: dispersion needs spectral rendering"), 1) << r.err;
  EXPECT_EQ(lines_with("transmission"), 0) << r.err;
}

// An emissive glTF triangle over a plane renders as the same light written in JSON (the glTF
// materials as the pbr materials they are: the plane baseColor 0.8, metallic 0, roughness 1; the
// lamp base colour 0; on a black background: an emissive material is no light for the choice of
// the sky, so the glTF render is given `--background 0`): per 8×8 block and channel, |mean_a − mean_b| / sqrt(se_a² + se_b²) below the Šidák critical value for
// α = 0.01 over all blocks × channels (standard errors from the EXR variance layer; seeds 1 and 2).
TEST_F(AssetCli, EmissiveTriangleMatchesJsonLight) {
  Gltf g;
  const int plane = g.add("materials", diffuse("plane", 0.8));
  const int lamp = g.add("materials", {{"name", "lamp"}, {"emissiveFactor", {1.0, 0.8, 0.6}}, {"pbrMetallicRoughness", {{"baseColorFactor", {0.0, 0.0, 0.0, 1.0}}, {"metallicFactor", 0.0}}},
                                       {"extensions", {{"KHR_materials_emissive_strength", {{"emissiveStrength", 5.0}}}}}});
  g.doc["extensionsUsed"] = {"KHR_materials_emissive_strength"};
  const std::vector<glm::vec3> plane_v = {{-2, 0, 1}, {2, 0, 1}, {2, 0, -4}, {-2, 0, 1}, {2, 0, -4}, {-2, 0, -4}};
  const std::vector<glm::vec3> lamp_v = {{-0.5f, 1.5f, -1}, {0, 1.5f, -2}, {0.5f, 1.5f, -1}};  // facing down
  g.node({{"mesh", g.mesh(plane_v, plane)}});
  g.node({{"mesh", g.mesh(lamp_v, lamp)}});
  g.add("cameras", perspective("cam", 0.9, 1.0));
  g.node({{"camera", 0}, {"translation", {0.0, 1.0, 3.0}}});
  g.write(work_ / "light.gltf");
  auto vertices = [](const std::vector<glm::vec3>& v, size_t first) {
    return json::array({{v[first].x, v[first].y, v[first].z}, {v[first + 1].x, v[first + 1].y, v[first + 1].z},
                        {v[first + 2].x, v[first + 2].y, v[first + 2].z}});
  };
  const json scene = {
      {"camera", {{"position", {0, 1, 3}}, {"look_at", {0, 1, 2}}, {"up", {0, 1, 0}}, {"fov", glm::degrees(0.9)}}},
      {"materials", {{"plane", {{"type", "pbr"}, {"base_color", {0.8, 0.8, 0.8}}, {"metallic", 0.0}, {"roughness", 1.0}}},
                     {"lamp", {{"type", "pbr"}, {"base_color", {0.0, 0.0, 0.0}}, {"metallic", 0.0}, {"roughness", 1.0}, {"radiance", {5.0, 4.0, 3.0}}}}}},
      {"shapes", {{{"type", "triangle"}, {"material", "plane"}, {"vertices", vertices(plane_v, 0)}},
                  {{"type", "triangle"}, {"material", "plane"}, {"vertices", vertices(plane_v, 3)}},
                  {{"type", "triangle"}, {"material", "lamp"}, {"vertices", vertices(lamp_v, 0)}}}}};
  xi_test::write_text(work_ / "light.json", scene.dump());
  const std::vector<std::string> common = {"--spp", "256", "--resolution", "64x64", "--max-depth", "3", "--sampler", "random", "--quiet"};
  const auto a = run_xi(xi_test::concat({"render", "light.gltf", "--seed", "1", "--background", "0", "-o", "a.exr"}, common));
  ASSERT_EQ(a.code, 0) << a.err;
  const auto b = run_xi(xi_test::concat({"render", "light.json", "--seed", "2", "-o", "b.exr"}, common));
  ASSERT_EQ(b.code, 0) << b.err;
  const xi::Image ma = xi::read_exr(work_ / "a.exr"), va = xi::read_exr(work_ / "a.exr", "variance");
  const xi::Image mb = xi::read_exr(work_ / "b.exr"), vb = xi::read_exr(work_ / "b.exr", "variance");
  const int blocks = 8 * 8, channels = 3;
  const double zc = xi::stats::sidak_critical_z(0.01, blocks * channels);
  int lit = 0;
  for (int by = 0; by < 8; ++by)
    for (int bx = 0; bx < 8; ++bx)
      for (int c = 0; c < channels; ++c) {
        double sa = 0, sb = 0, qa = 0, qb = 0;
        for (int y = by * 8; y < by * 8 + 8; ++y)
          for (int x = bx * 8; x < bx * 8 + 8; ++x)
            sa += ma.at(x, y)[c], sb += mb.at(x, y)[c], qa += va.at(x, y)[c], qb += vb.at(x, y)[c];
        const double se = std::sqrt(qa + qb) / 64.0, d = (sa - sb) / 64.0;
        if (se == 0.0) {
          EXPECT_EQ(sa, sb) << "block " << bx << "," << by << " channel " << c;
          continue;
        }
        lit += sa > 0.0;
        EXPECT_LT(std::abs(d) / se, zc) << "block " << bx << "," << by << " channel " << c << ": " << sa / 64 << " vs " << sb / 64;
      }
  EXPECT_GT(lit, blocks * channels / 3) << "most blocks see the lit plane";
}
