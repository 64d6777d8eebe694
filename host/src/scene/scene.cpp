// JSON scene reader: turns a scene file into xi::Scene, checking every field on the way so that
// each error names the file and the JSON path (RFC 6901 pointer) of the value at fault.
#include "xi/scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string_view>
#include <unordered_map>

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <glm/gtc/matrix_transform.hpp>
#include <nlohmann/json.hpp>

#include "geometry.h"
#include "mesh_check.h"
#include "xi/asset.h"
#include "xi/error.h"

namespace xi {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
constexpr float kInf = INFINITY;
using namespace scene_detail;  // kMaxCoordinate, Transform, apply, within_range, degenerate (geometry.h)

// Keys may contain '/' or '~' (material names); escape them as RFC 6901 says.
std::string escape(std::string_view key) {
  std::string out;
  for (char c : key) out += c == '~' ? "~0" : c == '/' ? "~1" : std::string(1, c);
  return out;
}

// Keys, names and file names come from the user and may hold any character: errors are one line,
// so control characters are written as escapes (a key "a\nb" shows as 'a\nb').
std::string one_line(std::string_view s) {
  std::string out;
  for (unsigned char c : s) {
    if (c == '\n') out += "\\n";
    else if (c == '\t') out += "\\t";
    else if (c < 0x20 || c == 0x7f) out += "\\x" + std::string(1, "0123456789abcdef"[c >> 4]) + "0123456789abcdef"[c & 15];
    else out += char(c);
  }
  return out;
}

// A JSON value plus where it lives, so that each check is one line and each error says where.
class Node {
 public:
  Node(const json& j, std::string path, const std::string& file)
      : j_(j), path_(std::move(path)), file_(file) {}

  [[noreturn]] void fail(const std::string& what) const {
    throw Error(one_line(what), one_line(file_ + ": " + (path_.empty() ? "/" : path_)));
  }
  const json& raw() const { return j_; }
  bool has(const std::string& key) const { return j_.is_object() && j_.contains(key); }

  // An object whose keys all come from `allowed`: an unknown key is most likely a typo.
  void expect_object(std::initializer_list<std::string_view> allowed) const {
    if (!j_.is_object()) fail("expected an object");
    for (const auto& item : j_.items())
      if (std::find(allowed.begin(), allowed.end(), item.key()) == allowed.end())
        at(item.key()).fail("unknown key '" + item.key() + "'");
  }
  Node at(const std::string& key) const {
    if (!j_.is_object()) fail("expected an object");
    auto it = j_.find(key);
    if (it == j_.end()) fail("missing required key '" + key + "'");
    return Node(*it, path_ + "/" + escape(key), file_);
  }
  // The elements of an array, optionally of an exact length.
  std::vector<Node> elements(size_t count = 0) const {
    if (!j_.is_array()) fail("expected an array");
    if (count && j_.size() != count) fail("expected an array of " + std::to_string(count) + " elements");
    std::vector<Node> out;
    for (size_t i = 0; i < j_.size(); ++i) out.emplace_back(j_[i], path_ + "/" + std::to_string(i), file_);
    return out;
  }

  // nlohmann reads 1e999 as inf, and a finite double may still overflow a float: reject both.
  float number() const {
    if (!j_.is_number()) fail("expected a number");
    const double d = j_.get<double>();
    if (!std::isfinite(d) || !std::isfinite(static_cast<float>(d))) fail("number is not finite in single precision");
    return static_cast<float>(d);
  }
  float number(const std::string& key, float def) const { return has(key) ? at(key).number() : def; }

  int64_t integer(int64_t lo, int64_t hi) const {
    const std::string range = "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    if (!j_.is_number_integer()) fail(range);
    // Non-negative literals are stored unsigned and may exceed int64: compare before converting.
    if (j_.is_number_unsigned() && j_.get<uint64_t>() > uint64_t(hi)) fail(range);
    const int64_t v = j_.get<int64_t>();
    if (v < lo || v > hi) fail(range);
    return v;
  }
  int64_t integer(const std::string& key, int64_t def, int64_t lo, int64_t hi) const {
    return has(key) ? at(key).integer(lo, hi) : def;
  }

  std::string string() const {
    if (!j_.is_string()) fail("expected a string");
    return j_.get<std::string>();
  }
  bool boolean(const std::string& key, bool def) const {
    if (!has(key)) return def;
    const Node n = at(key);
    if (!n.raw().is_boolean()) n.fail("expected true or false");
    return n.raw().get<bool>();
  }

  glm::vec3 vec3() const {
    auto e = elements(3);
    return {e[0].number(), e[1].number(), e[2].number()};
  }
  // An RGB triple with every component in [0, max] (max = 1 for reflectances, inf for radiance).
  glm::vec3 rgb(float max) const {
    auto e = elements(3);
    glm::vec3 c;
    for (int i = 0; i < 3; ++i) {
      c[i] = e[i].number();
      if (c[i] < 0.0f || c[i] > max) e[i].fail(max == kInf ? "must be >= 0" : "must be in [0, 1]");
    }
    return c;
  }
  glm::vec3 rgb(const std::string& key, glm::vec3 def, float max) const { return has(key) ? at(key).rgb(max) : def; }

 private:
  const json& j_;
  std::string path_;
  const std::string& file_;
};

Camera read_camera(const Node& n) {
  n.expect_object({"position", "look_at", "up", "fov", "focal_length_mm", "film_height_mm", "aperture_radius",
                   "focus_distance"});
  Camera c;
  c.position = n.at("position").vec3();
  c.look_at = n.at("look_at").vec3();
  c.up = n.at("up").vec3();
  if (!within_range(c.position)) n.at("position").fail("coordinate beyond +-1e9");
  if (!within_range(c.look_at)) n.at("look_at").fail("coordinate beyond +-1e9");
  const glm::vec3 dir = c.look_at - c.position;
  if (!(glm::length(dir) > 0.0f)) n.at("look_at").fail("look_at must differ from position");
  if (!(glm::length(glm::cross(glm::normalize(dir), c.up)) > 1e-6f * glm::length(c.up)))
    n.at("up").fail("up must be non-zero and not parallel to the view direction");

  const bool lens = n.has("focal_length_mm") || n.has("film_height_mm");
  if (n.has("fov") && lens) n.fail("give either fov or focal_length_mm + film_height_mm, not both");
  if (n.has("fov")) {
    c.vfov_degrees = n.at("fov").number();
    if (!(c.vfov_degrees > 0.0f && c.vfov_degrees < 180.0f)) n.at("fov").fail("fov must be in (0, 180) degrees");
  } else if (lens) {
    const float focal = n.at("focal_length_mm").number(), film = n.at("film_height_mm").number();
    if (!(focal > 0.0f)) n.at("focal_length_mm").fail("must be > 0");
    if (!(film > 0.0f)) n.at("film_height_mm").fail("must be > 0");
    c.vfov_degrees = glm::degrees(2.0f * std::atan(film / 2.0f / focal));
  } else {
    n.fail("camera needs fov or focal_length_mm + film_height_mm");
  }

  c.aperture_radius = n.number("aperture_radius", 0.0f);
  if (!(c.aperture_radius >= 0.0f)) n.at("aperture_radius").fail("must be >= 0");
  if (c.aperture_radius > kMaxCoordinate) n.at("aperture_radius").fail("must be <= 1e9");
  c.focus_distance = n.number("focus_distance", glm::length(dir));
  if (!(c.focus_distance > 0.0f)) n.at("focus_distance").fail("must be > 0");
  if (c.focus_distance > 4.0f * kMaxCoordinate)  // the default, the distance to look_at, is below 3.5e9
    n.at("focus_distance").fail("must be <= 4e9");
  return c;
}

Material read_material(const Node& n, const std::string& name) {
  if (!n.raw().is_object()) n.fail("expected an object");
  Material m;
  m.name = name;
  const std::string type = n.at("type").string();
  if (type == "diffuse" || type == "emitter") {
    // An emitter is a diffuse surface (black unless given an albedo) with required radiance.
    n.expect_object({"type", "albedo", "radiance", "two_sided"});
    const bool emitter = type == "emitter";
    m.albedo = emitter ? n.rgb("albedo", glm::vec3(0.0f), 1.0f) : n.at("albedo").rgb(1.0f);
    if (emitter || n.has("radiance")) m.emission = n.at("radiance").rgb(kInf);
    m.two_sided = n.boolean("two_sided", false);
  } else if (type == "mirror") {
    n.expect_object({"type", "albedo"});
    m.type = MaterialType::Mirror;
    m.albedo = n.rgb("albedo", glm::vec3(1.0f), 1.0f);
  } else if (type == "glass") {
    n.expect_object({"type", "ior", "albedo"});
    m.type = MaterialType::Dielectric;
    m.albedo = n.rgb("albedo", glm::vec3(1.0f), 1.0f);
    m.ior = n.number("ior", 1.5f);
    if (!(m.ior >= 1.0f && m.ior <= 4.0f)) n.at("ior").fail("ior must be in [1, 4]");
  } else {
    n.at("type").fail("unknown material type '" + type + "' (expected diffuse, emitter, mirror or glass)");
  }
  return m;
}

Transform read_transform(const Node& n) {
  n.expect_object({"translate", "scale", "rotate", "matrix"});
  glm::dmat4 m(1.0);
  if (n.has("matrix")) {
    if (n.has("translate") || n.has("scale") || n.has("rotate"))
      n.fail("'matrix' cannot be combined with translate, scale or rotate");
    const Node mat = n.at("matrix");
    auto e = mat.elements(16);
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) m[c][r] = e[r * 4 + c].number();  // row-major text, column-major glm
    if (m[0][3] != 0.0 || m[1][3] != 0.0 || m[2][3] != 0.0 || m[3][3] != 1.0)
      mat.fail("last row must be 0 0 0 1 (an affine matrix, row-major)");
  } else {
    glm::dvec3 s(1.0), t(0.0);
    glm::dmat4 r(1.0);
    if (n.has("scale")) {
      const Node sc = n.at("scale");
      s = sc.raw().is_array() ? glm::dvec3(sc.vec3()) : glm::dvec3(sc.number());
    }
    if (n.has("rotate")) {
      const Node rot = n.at("rotate");
      rot.expect_object({"axis", "degrees"});
      const glm::dvec3 axis = rot.at("axis").vec3();
      if (!(glm::length(axis) > 0.0)) rot.at("axis").fail("rotation axis must be non-zero");
      r = glm::rotate(glm::dmat4(1.0), glm::radians(double(rot.at("degrees").number())), glm::normalize(axis));
    }
    if (n.has("translate")) t = n.at("translate").vec3();
    m = glm::translate(glm::dmat4(1.0), t) * r * glm::scale(glm::dmat4(1.0), s);  // scale, rotate, translate
  }
  const glm::dmat3 linear(m);
  const double det = glm::determinant(linear);
  double size = 0.0;  // Frobenius norm, to make the singularity test scale-free
  for (int c = 0; c < 3; ++c) size += glm::dot(linear[c], linear[c]);
  size = std::sqrt(size);
  if (!(std::abs(det) > 1e-12 * size * size * size)) n.fail("transform matrix is singular");
  return make_transform(m);
}

Triangle flat(glm::vec3 a, glm::vec3 b, glm::vec3 c) {
  Triangle t{};  // zeroed: glm vectors are not initialised by default
  t.v[0] = a, t.v[1] = b, t.v[2] = c;
  return t;
}

// Icosahedron subdivided `levels` times, every vertex pushed onto the unit sphere.
std::vector<Triangle> icosphere(glm::vec3 center, float radius, int levels) {
  const double g = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<glm::dvec3> p = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                               {0, -1, -g}, {0, 1, -g}, {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
  for (auto& v : p) v = glm::normalize(v);
  std::vector<std::array<uint32_t, 3>> faces = {
      {0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
      {3, 8, 9},  {4, 9, 5},  {2, 4, 11},  {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int level = 0; level < levels; ++level) {
    std::unordered_map<uint64_t, uint32_t> midpoints;  // edge (low, high) → its midpoint: shared edges split once
    auto mid = [&](uint32_t a, uint32_t b) {
      auto [it, added] = midpoints.try_emplace(uint64_t(std::min(a, b)) << 32 | std::max(a, b), uint32_t(p.size()));
      if (added) p.push_back(glm::normalize(p[a] + p[b]));
      return it->second;
    };
    std::vector<std::array<uint32_t, 3>> next;
    next.reserve(faces.size() * 4);
    for (auto [a, b, c] : faces) {
      const uint32_t ab = mid(a, b), bc = mid(b, c), ca = mid(c, a);
      next.insert(next.end(), {{a, ab, ca}, {b, bc, ab}, {c, ca, bc}, {ab, bc, ca}});
    }
    faces = std::move(next);
  }
  std::vector<Triangle> out;
  out.reserve(faces.size());
  for (auto [a, b, c] : faces) {
    // Outward winding whatever the table says: the face normal must agree with the position.
    if (glm::dot(glm::cross(p[b] - p[a], p[c] - p[a]), p[a] + p[b] + p[c]) < 0.0) std::swap(b, c);
    Triangle t{};
    const uint32_t idx[3] = {a, b, c};
    for (int k = 0; k < 3; ++k) {
      t.n[k] = glm::vec3(p[idx[k]]);
      t.v[k] = center + radius * t.n[k];
    }
    t.has_normals = true;
    out.push_back(t);
  }
  return out;
}

std::vector<Triangle> load_mesh(const Node& file_node, const fs::path& base_dir) {
  const fs::path path = base_dir / file_node.string();
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) file_node.fail("mesh file not found: " + path.string());
  // Before Assimp allocates what the header claims (it would exhaust memory, not fail).
  if (auto why = implausible_mesh_counts(path)) file_node.fail("cannot load mesh " + path.string() + ": " + *why);
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(
      path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_PreTransformVertices);
  if (!scene || (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) || !scene->mRootNode)
    file_node.fail("cannot load mesh " + path.string() + ": " + importer.GetErrorString());
  std::vector<Triangle> out;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    const std::vector<Triangle> tris = mesh_triangles(*scene->mMeshes[i]);
    out.insert(out.end(), tris.begin(), tris.end());
  }
  return out;
}

void read_shape(const Node& n, const std::map<std::string, uint32_t>& materials, const fs::path& base_dir,
                std::vector<Triangle>& out) {
  const std::string type = n.at("type").string();
  if (type == "quad" || type == "triangle")
    n.expect_object({"type", "material", "transform", "vertices"});
  else if (type == "mesh")
    n.expect_object({"type", "material", "transform", "file"});
  else if (type == "sphere")
    n.expect_object({"type", "material", "transform", "center", "radius", "subdivisions"});
  else
    n.at("type").fail("unknown shape type '" + type + "' (expected quad, triangle, mesh, sphere or asset)");

  const Node mat = n.at("material");
  const std::string name = mat.string();
  const auto found = materials.find(name);
  if (found == materials.end()) mat.fail("unknown material '" + name + "'");
  const Transform xf = n.has("transform") ? read_transform(n.at("transform")) : Transform{};

  std::vector<Triangle> tris;
  if (type == "quad" || type == "triangle") {
    const Node verts = n.at("vertices");
    std::vector<glm::vec3> v;
    for (const Node& e : verts.elements(type == "quad" ? 4 : 3)) v.push_back(e.vec3());
    tris.push_back(flat(v[0], v[1], v[2]));
    if (type == "quad") tris.push_back(flat(v[0], v[2], v[3]));
    for (Triangle& t : tris) {
      apply(xf, t);
      if (!within_range(t)) verts.fail(type + " has a vertex coordinate beyond +-1e9 (after its transform)");
      if (degenerate(t)) verts.fail(type + " has zero area");
    }
  } else if (type == "sphere") {
    const glm::vec3 center = n.at("center").vec3();
    const float radius = n.at("radius").number();
    if (!(radius > 0.0f)) n.at("radius").fail("radius must be > 0");
    tris = icosphere(center, radius, int(n.integer("subdivisions", 4, 0, 8)));
    for (Triangle& t : tris) {
      apply(xf, t);
      if (!within_range(t)) n.fail("sphere reaches a vertex coordinate beyond +-1e9 (after its transform)");
    }
  } else {
    const Node file = n.at("file");
    tris = load_mesh(file, base_dir);
    const long long bad = place_mesh(xf, tris);
    if (bad >= 0)  // NaN or Inf in the file's data, or overflow in the transform
      file.fail("mesh " + file.string() + ": triangle " + std::to_string(bad) +
                " has a non-finite vertex coordinate or one beyond +-1e9 (after its transform)");
    if (tris.empty()) file.fail("mesh has no triangles (after dropping degenerate ones)");
  }
  for (Triangle& t : tris) t.material = found->second;
  out.insert(out.end(), tris.begin(), tris.end());
}

// {"type": "asset", "file": ..., "transform": ...}: an asset file's shapes with its own materials
// (named "<file>:<material>"), node transforms first, then the shape's transform.
void read_asset_shape(const Node& n, const fs::path& base_dir, Scene& s) {
  n.expect_object({"type", "file", "transform"});
  const Node file = n.at("file");
  const fs::path path = base_dir / file.string();
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) file.fail("asset file not found: " + path.string());
  AssetGeometry g;
  try {
    g = load_asset_geometry(path);
  } catch (const Error& e) {
    file.fail(e.message());
  }
  const Transform xf = n.has("transform") ? read_transform(n.at("transform")) : Transform{};
  const long long bad = place_mesh(xf, g.triangles);
  if (bad >= 0)
    file.fail("asset " + file.string() + ": triangle " + std::to_string(bad) +
              " has a coordinate beyond +-1e9 (after its transform)");
  if (g.triangles.empty()) file.fail("asset has no triangles (after dropping degenerate ones)");
  const uint32_t first = uint32_t(s.materials.size());
  const int first_image = int(s.images.size());
  for (Material& m : g.materials) {
    m.name = file.string() + ":" + m.name;
    for (TextureSlot* slot : {&m.base_color_texture, &m.metallic_roughness_texture, &m.normal_texture, &m.emissive_texture})
      if (slot->used()) slot->image += first_image;
    s.materials.push_back(std::move(m));
  }
  s.images.insert(s.images.end(), g.images.begin(), g.images.end());
  for (Light light : g.lights) {
    light.position = glm::vec3(xf.m * glm::dvec4(light.position, 1.0));
    light.direction = glm::vec3(glm::normalize(glm::dmat3(xf.m) * glm::dvec3(light.direction)));
    s.lights.push_back(light);
  }
  for (Triangle& t : g.triangles) t.material += first;
  s.triangles.insert(s.triangles.end(), g.triangles.begin(), g.triangles.end());
  for (const std::string& w : g.warnings)
    if (std::find(s.warnings.begin(), s.warnings.end(), w) == s.warnings.end()) s.warnings.push_back(w);
}

}  // namespace

fs::path bundled_scene_file(const std::string& name) {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec).parent_path();
  for (const fs::path& dir : {exe.parent_path() / "scenes", exe.parent_path() / "share/xi/scenes",
                              fs::path(XI_INSTALL_SCENE_DIR), fs::path(XI_SOURCE_SCENE_DIR)})
    if (fs::is_regular_file(dir / name, ec)) return dir / name;
  throw Error("cannot find xi's bundled " + name + " (looked beside the program, in " XI_INSTALL_SCENE_DIR
              " and in " XI_SOURCE_SCENE_DIR ")");
}

Scene parse_scene(const std::string& json_text, const std::string& source_name, const fs::path& base_dir) {
  // nlohmann rejects numbers beyond double range (1e999) during parsing, so follow the JSON path
  // while it parses: at each point `stack` holds the object key or array index being read.
  struct Level { bool array; size_t index; std::string key; };
  std::vector<Level> stack;
  auto track = [&stack](int, json::parse_event_t event, json& parsed) {
    using E = json::parse_event_t;
    if (event == E::object_start || event == E::array_start) stack.push_back({event == E::array_start, 0, {}});
    if (event == E::key) stack.back().key = parsed.get<std::string>();
    if (event == E::object_end || event == E::array_end) stack.pop_back();
    if ((event == E::value || event == E::object_end || event == E::array_end) && !stack.empty() && stack.back().array)
      ++stack.back().index;  // an array element is complete
    return true;
  };
  auto message = [](const json::exception& e) {  // without nlohmann's "[json.exception.xxx.nnn] " prefix
    std::string msg = e.what();
    const auto p = msg.find("] ");
    return msg.rfind("[json.exception", 0) == 0 && p != std::string::npos ? msg.substr(p + 2) : msg;
  };
  json doc;
  try {
    doc = json::parse(json_text, track);
  } catch (const json::parse_error& e) {
    throw Error("invalid JSON: " + one_line(message(e)), one_line(source_name) + ": byte " + std::to_string(e.byte));
  } catch (const json::exception& e) {
    std::string path;
    for (const Level& l : stack) path += "/" + (l.array ? std::to_string(l.index) : escape(l.key));
    throw Error("invalid JSON: " + one_line(message(e)), one_line(source_name + ": " + (path.empty() ? "/" : path)));
  }

  Scene s;
  s.source = source_name;
  const Node root(doc, "", source_name);
  root.expect_object({"camera", "film", "render", "background", "materials", "shapes"});
  s.camera = read_camera(root.at("camera"));

  if (root.has("film")) {
    const Node film = root.at("film");
    film.expect_object({"width", "height"});
    s.width = int(film.integer("width", s.width, 1, 16384));
    s.height = int(film.integer("height", s.height, 1, 16384));
  }
  if (root.has("render")) {
    const Node r = root.at("render");
    r.expect_object({"spp", "max_depth", "seed", "sampler"});
    s.render.spp = int(r.integer("spp", s.render.spp, 1, INT32_MAX));
    s.render.max_depth = int(r.integer("max_depth", s.render.max_depth, 1, 64));
    s.render.seed = uint32_t(r.integer("seed", s.render.seed, 0, INT32_MAX));  // 31 bits: the EXR attribute is a signed int
    if (r.has("sampler")) {
      s.render.sampler = r.at("sampler").string();
      if (s.render.sampler != "random" && s.render.sampler != "grid" && s.render.sampler != "stratified" &&
          s.render.sampler != "sobol")
        r.at("sampler").fail("unknown sampler '" + s.render.sampler + "' (expected random, grid, stratified or sobol)");
    }
  }
  s.background = root.rgb("background", s.background, kInf);

  // Material indices follow the key order of the materials object (alphabetical in nlohmann::json).
  std::map<std::string, uint32_t> index;
  const Node materials = root.at("materials");
  if (!materials.raw().is_object()) materials.fail("expected an object mapping names to materials");
  for (const auto& item : materials.raw().items()) {
    index[item.key()] = uint32_t(s.materials.size());
    s.materials.push_back(read_material(materials.at(item.key()), item.key()));
  }

  const Node shapes = root.at("shapes");
  const auto list = shapes.elements();
  if (list.empty()) shapes.fail("scene has no shapes");
  for (const Node& shape : list) {
    if (shape.has("type") && shape.at("type").raw() == "asset") read_asset_shape(shape, base_dir, s);
    else read_shape(shape, index, base_dir, s.triangles);
  }
  if (const std::string small = too_small(s.triangles); !small.empty()) shapes.fail(small + " with a transform");
  return s;
}

void check_scene_limits(const Scene& scene) {
  for (size_t i = 0; i < scene.triangles.size(); ++i)
    if (!within_range(scene.triangles[i]))
      throw Error("triangle " + std::to_string(i) + " has a non-finite vertex coordinate or one beyond +-1e9",
                  scene.source);
  if (const std::string small = too_small(scene.triangles); !small.empty()) throw Error(small, scene.source);
  auto radiance_ok = [](glm::vec3 c) {  // (false for NaN)
    return c.x >= 0.0f && c.y >= 0.0f && c.z >= 0.0f && std::isfinite(c.x + c.y + c.z);
  };
  for (const Material& m : scene.materials)
    if (!radiance_ok(m.emission))
      throw Error("material '" + m.name + "' has a negative or non-finite radiance", scene.source);
  if (!radiance_ok(scene.background)) throw Error("the background radiance is negative or not finite", scene.source);
}

Scene load_scene(const fs::path& path) {
  if (is_asset_file(path)) return load_asset(path);
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  if (!in || fs::is_directory(path, ec)) throw Error("cannot open scene file", one_line(path.string()));
  std::stringstream text;
  text << in.rdbuf();
  return parse_scene(text.str(), path.string(), path.parent_path());
}

}  // namespace xi
