// JSON scene reader: turns a scene file into xi::Scene, checking every field on the way so that
// each error names the file and the JSON path (RFC 6901 pointer) of the value at fault.
#include "xi/scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <fstream>
#include <map>
#include <span>
#include <sstream>
#include <string_view>
#include <thread>
#include <unordered_map>

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <glm/gtc/matrix_transform.hpp>
#include <nlohmann/json.hpp>

#include "geometry.h"
#include "mesh_check.h"
#include "ply.h"
#include "xi/asset.h"
#include "xi/error.h"
#include "xi/texture.h"

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

std::string short_number(float v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", double(v));
  return buf;
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
    expect_object(std::span(allowed.begin(), allowed.size()));
  }
  void expect_object(std::span<const std::string_view> allowed) const {
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

  glm::vec2 vec2() const {
    auto e = elements(2);
    return {e[0].number(), e[1].number()};
  }
  glm::vec3 vec3() const {
    auto e = elements(3);
    return {e[0].number(), e[1].number(), e[2].number()};
  }
  // A number in [lo, hi], or `def` when the key is absent.
  float number_in(const std::string& key, float def, float lo, float hi) const {
    if (!has(key)) return def;
    const float v = at(key).number();
    if (!(v >= lo && v <= hi)) at(key).fail(key + " must be in [" + short_number(lo) + ", " + short_number(hi) + "]");
    return v;
  }
  // One of `names` (the key's value), or `def` when the key is absent.
  std::string choice(const std::string& key, const std::string& def, std::initializer_list<std::string_view> names) const {
    if (!has(key)) return def;
    const std::string v = at(key).string();
    if (std::find(names.begin(), names.end(), v) == names.end()) {
      std::string list;
      for (auto it = names.begin(); it != names.end(); ++it)
        list += (it == names.begin() ? "" : std::next(it) == names.end() ? " or " : ", ") + std::string(*it);
      at(key).fail("unknown " + key + " '" + v + "' (expected " + list + ")");
    }
    return v;
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

// The texture images a scene file names, each (file, colour or data) decoded once.
class ImageFiles {
 public:
  ImageFiles(const fs::path& base_dir, std::vector<TextureImage>& images) : base_dir_(base_dir), images_(images) {}

  // The index in Scene::images of the image file `file` (a string node, relative to the scene file).
  int load(const Node& file, bool srgb) {
    const fs::path path = (base_dir_ / file.string()).lexically_normal();
    const auto key = std::make_pair(path.string(), srgb);
    if (auto found = loaded_.find(key); found != loaded_.end()) return found->second;
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) file.fail("texture image not found: " + path.string());
    try {
      images_.push_back(load_image_file(path, srgb));
    } catch (const Error& e) {
      file.fail(e.message() + ": " + path.string());
    }
    return loaded_[key] = int(images_.size()) - 1;
  }

 private:
  fs::path base_dir_;
  std::vector<TextureImage>& images_;
  std::map<std::pair<std::string, bool>, int> loaded_;
};

// A texture input: an image file name, or {"file", "texcoord", "wrap" (or "wrap_s", "wrap_t"),
// "offset", "rotation" (degrees), "scale"}, the last three as KHR_texture_transform.
// srgb: a colour (base colour, emission) rather than data (metallic-roughness, normals).
TextureSlot read_texture(const Node& n, bool srgb, ImageFiles& images) {
  TextureSlot slot;
  if (n.raw().is_string()) {
    slot.image = images.load(n, srgb);
    return slot;
  }
  if (!n.raw().is_object()) n.fail("expected an image file name or an object with \"file\"");
  n.expect_object({"file", "texcoord", "wrap", "wrap_s", "wrap_t", "offset", "rotation", "scale"});
  slot.image = images.load(n.at("file"), srgb);
  slot.texcoord = int(n.integer("texcoord", 0, 0, 1));
  if (n.has("wrap") && (n.has("wrap_s") || n.has("wrap_t")))
    n.at("wrap").fail("give either wrap or wrap_s / wrap_t, not both");
  auto wrap = [&](const std::string& key) {
    const std::string w = n.choice(key, n.has("wrap") ? n.at("wrap").string() : "repeat", {"repeat", "clamp", "mirror"});
    return w == "clamp" ? Wrap::Clamp : w == "mirror" ? Wrap::Mirror : Wrap::Repeat;
  };
  slot.wrap_s = wrap(n.has("wrap") ? "wrap" : "wrap_s");
  slot.wrap_t = wrap(n.has("wrap") ? "wrap" : "wrap_t");
  const glm::vec2 offset = n.has("offset") ? n.at("offset").vec2() : glm::vec2(0.0f);
  const glm::vec2 scale = n.has("scale") ? n.at("scale").vec2() : glm::vec2(1.0f);
  const float degrees = n.number("rotation", 0.0f);
  slot.transform = texture_transform(offset, glm::radians(degrees), scale);
  for (int c = 0; c < 3; ++c)  // e.g. an offset near FLT_MAX
    for (int r = 0; r < 3; ++r)
      if (!std::isfinite(slot.transform[c][r])) n.fail("texture transform is not finite in single precision");
  return slot;
}

// glTF 2.0's metallic-roughness material (type "pbr").
void read_pbr(const Node& n, Material& m, ImageFiles& images) {
  std::vector<std::string_view> keys = {"type", "base_color", "metallic", "roughness", "ior", "transmission",
                                        "normal_scale", "radiance", "two_sided", "alpha", "alpha_mode", "alpha_cutoff",
                                        "specular", "specular_color", "clearcoat", "clearcoat_roughness",
                                        "attenuation_color", "attenuation_distance", "sheen_color", "sheen_roughness",
                                        "clearcoat_normal_scale", "anisotropy_strength", "anisotropy_rotation",
                                        "iridescence", "iridescence_ior", "iridescence_thickness_minimum",
                                        "iridescence_thickness_maximum"};
  for (const TextureSlotInfo& slot : kTextureSlots) keys.push_back(slot.key);
  n.expect_object(keys);
  m.type = MaterialType::Pbr;
  m.albedo = n.rgb("base_color", glm::vec3(1.0f), 1.0f);
  m.metallic = n.number_in("metallic", 0.0f, 0.0f, 1.0f);
  m.roughness = n.number_in("roughness", 0.5f, 0.0f, 1.0f);
  m.ior = n.number_in("ior", 1.5f, 1.0f, 4.0f);
  m.transmission = n.number_in("transmission", 0.0f, 0.0f, 1.0f);
  m.specular = n.number_in("specular", 1.0f, 0.0f, 1.0f);
  m.specular_color = n.rgb("specular_color", glm::vec3(1.0f), 1e3f);
  m.clearcoat = n.number_in("clearcoat", 0.0f, 0.0f, 1.0f);
  m.clearcoat_roughness = n.number_in("clearcoat_roughness", 0.0f, 0.0f, 1.0f);
  m.sheen_color = n.rgb("sheen_color", glm::vec3(0.0f), 1.0f);
  m.sheen_roughness = n.number_in("sheen_roughness", 0.0f, 0.0f, 1.0f);
  m.anisotropy_strength = n.number_in("anisotropy_strength", 0.0f, 0.0f, 1.0f);
  m.anisotropy_rotation = n.number_in("anisotropy_rotation", 0.0f, -1e3f, 1e3f);
  m.iridescence = n.number_in("iridescence", 0.0f, 0.0f, 1.0f);
  m.iridescence_ior = n.number_in("iridescence_ior", 1.3f, 1.0f, 4.0f);
  m.iridescence_thickness_minimum = n.number_in("iridescence_thickness_minimum", 100.0f, 0.0f, 1e5f);
  m.iridescence_thickness_maximum = n.number_in("iridescence_thickness_maximum", 400.0f, 0.0f, 1e5f);
  m.attenuation_color = n.rgb("attenuation_color", glm::vec3(1.0f), 1.0f);
  m.attenuation_distance = n.number_in("attenuation_distance", m.attenuation_distance, 1e-30f, kInf);
  if ((n.has("attenuation_color") || n.has("attenuation_distance")) && m.transmission <= 0.0f)
    n.at(n.has("attenuation_color") ? "attenuation_color" : "attenuation_distance")
        .fail("a volume's absorption needs transmission > 0 (light must get in)");
  m.two_sided = n.boolean("two_sided", false);
  m.alpha = n.number_in("alpha", 1.0f, 0.0f, 1.0f);
  const std::string mode = n.choice("alpha_mode", "opaque", {"opaque", "mask", "blend"});
  m.alpha_mode = mode == "mask" ? AlphaMode::Mask : mode == "blend" ? AlphaMode::Blend : AlphaMode::Opaque;
  if (n.has("alpha_cutoff") && m.alpha_mode != AlphaMode::Mask)
    n.at("alpha_cutoff").fail("alpha_cutoff applies to alpha_mode \"mask\" only");
  m.alpha_cutoff = n.number_in("alpha_cutoff", 0.5f, 0.0f, 1.0f);
  for (int k = 0; k < XI_TEXTURE_SLOTS; ++k) {
    const TextureSlotInfo& slot = kTextureSlots[k];
    if (n.has(slot.key)) m.textures[k] = read_texture(n.at(slot.key), slot.srgb, images);
    if (k == XI_TEXTURE_NORMAL) {  // here, before the emissive texture: the order errors are reported in
      if (n.has("normal_scale") && !m.textures[k].used())
        n.at("normal_scale").fail("normal_scale needs a normal_texture");
      m.normal_scale = n.number_in("normal_scale", 1.0f, -1e3f, 1e3f);
    }
    if (k == XI_TEXTURE_CLEARCOAT_NORMAL) {
      if (n.has("clearcoat_normal_scale") && !m.textures[k].used())
        n.at("clearcoat_normal_scale").fail("clearcoat_normal_scale needs a clearcoat_normal_texture");
      m.clearcoat_normal_scale = n.number_in("clearcoat_normal_scale", 1.0f, -1e3f, 1e3f);
    }
  }
  // The emissive texture is multiplied by the radiance: white unless given.
  m.emission = n.rgb("radiance", glm::vec3(m.textures[XI_TEXTURE_EMISSIVE].used() ? 1.0f : 0.0f), kInf);
}

Material read_material(const Node& n, const std::string& name, ImageFiles& images) {
  if (!n.raw().is_object()) n.fail("expected an object");
  Material m;
  m.name = name;
  const std::string type = n.at("type").string();
  if (type == "diffuse" || type == "emitter") {
    // An emitter is a diffuse surface (black unless given an albedo) with required radiance.
    n.expect_object({"type", "albedo", "radiance", "two_sided"});
    const bool emitter = type == "emitter";
    if (n.has("albedo") && !n.at("albedo").raw().is_array()) {  // an image: the albedo is the texture's
      m.albedo = glm::vec3(1.0f);
      m.textures[XI_TEXTURE_BASE_COLOR] = read_texture(n.at("albedo"), true, images);
    } else {
      m.albedo = emitter ? n.rgb("albedo", glm::vec3(0.0f), 1.0f) : n.at("albedo").rgb(1.0f);
    }
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
  } else if (type == "pbr") {
    read_pbr(n, m, images);
  } else {
    n.at("type").fail("unknown material type '" + type + "' (expected diffuse, emitter, mirror, glass or pbr)");
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

// Appends a flat triangle whose texture coordinates (both sets) are ta, tb, tc.
void add_flat(Mesh& mesh, glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec2 ta, glm::vec2 tb, glm::vec2 tc) {
  Triangle& t = mesh.add_triangle(a, b, c);
  t.texcoords = uint32_t(mesh.texcoords.size());
  for (auto& set : mesh.texcoords.emplace_back().uv) set[0] = ta, set[1] = tb, set[2] = tc;
}

// Equirectangular texture coordinates of the unit direction d: v = θ/π from the +y pole (v = 0) to
// the −y pole, u = φ/2π with u = 0.5 facing +z and growing towards +x there, the seam facing −z.
glm::vec2 sphere_uv(glm::dvec3 d) {
  const double pi = 3.14159265358979323846;
  return {float(0.5 + std::atan2(d.x, d.z) / (2.0 * pi)), float(std::acos(std::clamp(d.y, -1.0, 1.0)) / pi)};
}

// Appends an icosahedron subdivided `levels` times, every vertex pushed onto the sphere, with
// the sphere's normals and equirectangular texture coordinates.
void add_icosphere(Mesh& mesh, glm::vec3 center, float radius, int levels) {
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
  const uint32_t base = uint32_t(mesh.vertices.size());
  for (const glm::dvec3& d : p) {
    const glm::vec3 n(d);
    mesh.vertices.push_back({center + radius * n, n});
  }
  for (auto [a, b, c] : faces) {
    // Outward winding whatever the table says: the face normal must agree with the position.
    if (glm::dot(glm::cross(p[b] - p[a], p[c] - p[a]), p[a] + p[b] + p[c]) < 0.0) std::swap(b, c);
    Triangle t;
    const uint32_t idx[3] = {a, b, c};
    glm::vec2 uv[3];
    for (int k = 0; k < 3; ++k) {
      t.v[k] = base + idx[k];
      uv[k] = sphere_uv(p[idx[k]]);
    }
    // A triangle across the seam takes u beyond 1 on its far side (repeat wrapping reads it right);
    // a vertex on a pole, where u is undefined, takes the mean u of the other two.
    bool pole[3];
    float lo = 1.0f, hi = 0.0f;
    for (int k = 0; k < 3; ++k) {
      pole[k] = std::abs(p[idx[k]].y) > 1.0 - 1e-9;
      if (!pole[k]) lo = std::min(lo, uv[k].x), hi = std::max(hi, uv[k].x);
    }
    if (hi - lo > 0.5f)
      for (auto& q : uv)
        if (q.x < 0.5f) q.x += 1.0f;
    for (int k = 0; k < 3; ++k)
      if (pole[k]) uv[k].x = 0.5f * (uv[(k + 1) % 3].x + uv[(k + 2) % 3].x);
    t.texcoords = uint32_t(mesh.texcoords.size());
    for (auto& set : mesh.texcoords.emplace_back().uv) std::copy(uv, uv + 3, set);
    t.has_normals = true;
    mesh.triangles.push_back(t);
  }
}

// Appends the mesh file's vertices and triangles to `out`, read where they land: a large mesh is
// never copied.
void load_mesh(const Node& file_node, const fs::path& base_dir, Mesh& out) {
  const fs::path path = base_dir / file_node.string();
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) file_node.fail("mesh file not found: " + path.string());
  // Before Assimp allocates what the header claims (it would exhaust memory, not fail).
  if (auto why = implausible_mesh_counts(path)) file_node.fail("cannot load mesh " + path.string() + ": " + *why);
  // Binary PLY files of triangles without Assimp (Assimp picks its reader by the extension).
  if (lower_extension(path) == ".ply" && read_binary_ply(path, true, out)) return;
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(
      path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_PreTransformVertices);
  if (!scene || (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) || !scene->mRootNode)
    file_node.fail("cannot load mesh " + path.string() + ": " + importer.GetErrorString());
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    // Assimp puts every format's texture origin at the bottom left (it flips glTF's); xi's v runs down.
    mesh_triangles(*scene->mMeshes[i], 0, true, out);
  }
}

void read_shape(const Node& n, const std::map<std::string, uint32_t>& materials, const fs::path& base_dir,
                Mesh& out) {
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

  // Straight into `out`: a mesh of millions of triangles is neither copied nor held twice.
  const size_t first_vertex = out.vertices.size(), first = out.triangles.size();
  if (type == "quad" || type == "triangle") {
    const Node verts = n.at("vertices");
    std::vector<glm::vec3> v;
    for (const Node& e : verts.elements(type == "quad" ? 4 : 3)) v.push_back(e.vec3());
    // The image's top-left corner at v0; a quad's corners (0,0), (1,0), (1,1), (0,1) at v0..v3.
    const glm::vec2 t0(0, 0), t1(1, 0), t2(1, 1), t3(0, 1);
    if (type == "quad") {
      add_flat(out, v[0], v[1], v[2], t0, t1, t2);
      add_flat(out, v[0], v[2], v[3], t0, t2, t3);
    } else {
      add_flat(out, v[0], v[1], v[2], t0, t1, t3);
    }
    transform_mesh(xf, out, first_vertex, first);
    for (size_t i = first; i < out.triangles.size(); ++i) {
      if (!within_range(out, out.triangles[i]))
        verts.fail(type + " has a vertex coordinate beyond +-1e9 (after its transform)");
      if (degenerate(out, out.triangles[i])) verts.fail(type + " has zero area");
    }
  } else if (type == "sphere") {
    const glm::vec3 center = n.at("center").vec3();
    const float radius = n.at("radius").number();
    if (!(radius > 0.0f)) n.at("radius").fail("radius must be > 0");
    add_icosphere(out, center, radius, int(n.integer("subdivisions", 4, 0, 8)));
    transform_mesh(xf, out, first_vertex, first);
    for (size_t i = first; i < out.triangles.size(); ++i)
      if (!within_range(out, out.triangles[i]))
        n.fail("sphere reaches a vertex coordinate beyond +-1e9 (after its transform)");
  } else {
    const Node file = n.at("file");
    load_mesh(file, base_dir, out);
    const long long bad = place_mesh(xf, out, first_vertex, first);
    if (bad >= 0)  // NaN or Inf in the file's data, or overflow in the transform
      file.fail("mesh " + file.string() + ": triangle " + std::to_string(bad) +
                " has a non-finite vertex coordinate or one beyond +-1e9 (after its transform)");
    if (out.triangles.size() == first) file.fail("mesh has no triangles (after dropping degenerate ones)");
  }
  for (size_t i = first; i < out.triangles.size(); ++i) out.triangles[i].material = found->second;
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
  const long long bad = place_mesh(xf, g);
  if (bad >= 0)
    file.fail("asset " + file.string() + ": triangle " + std::to_string(bad) +
              " has a coordinate beyond +-1e9 (after its transform)");
  if (g.triangles.empty()) file.fail("asset has no triangles (after dropping degenerate ones)");
  const uint32_t first = uint32_t(s.materials.size());
  const int first_image = int(s.images.size());
  for (Material& m : g.materials) {
    m.name = file.string() + ":" + m.name;
    for (TextureSlot& slot : m.textures)
      if (slot.used()) slot.image += first_image;
    s.materials.push_back(std::move(m));
  }
  s.images.insert(s.images.end(), g.images.begin(), g.images.end());
  for (Light light : g.lights) {
    light.position = glm::vec3(xf.m * glm::dvec4(light.position, 1.0));
    light.direction = glm::vec3(glm::normalize(glm::dmat3(xf.m) * glm::dvec3(light.direction)));
    s.lights.push_back(light);
  }
  s.append(std::move(g), first);
  for (const std::string& w : g.warnings)
    if (std::find(s.warnings.begin(), s.warnings.end(), w) == s.warnings.end()) s.warnings.push_back(w);
}

// A punctual light: point, spot, directional, or a sun (a directional light of angular radius > 0).
Light read_light(const Node& n, size_t index) {
  if (!n.raw().is_object()) n.fail("expected an object");
  const std::string type = n.at("type").string();
  if (type == "point") n.expect_object({"type", "name", "position", "color", "intensity"});
  else if (type == "spot") n.expect_object({"type", "name", "position", "direction", "color", "intensity", "inner_angle", "outer_angle"});
  else if (type == "directional") n.expect_object({"type", "name", "direction", "color", "intensity"});
  else if (type == "sun") n.expect_object({"type", "name", "direction", "color", "intensity", "angular_radius"});
  else n.at("type").fail("unknown light type '" + type + "' (expected point, spot, directional or sun)");
  Light l;
  l.name = n.has("name") ? n.at("name").string() : "light " + std::to_string(index);
  l.type = type == "point" ? LightType::Point : type == "spot" ? LightType::Spot : LightType::Directional;
  if (l.type != LightType::Directional) {
    l.position = n.at("position").vec3();
    if (!within_range(l.position)) n.at("position").fail("coordinate beyond +-1e9");
  }
  if (l.type != LightType::Point) {
    const glm::vec3 d = n.at("direction").vec3();
    if (!within_range(d)) n.at("direction").fail("coordinate beyond +-1e9");
    const double length = glm::length(glm::dvec3(d));
    if (!(length > 1e-30)) n.at("direction").fail("direction must be non-zero");
    l.direction = glm::vec3(glm::dvec3(d) / length);
  }
  const glm::vec3 color = n.rgb("color", glm::vec3(1.0f), 1.0f);
  const float intensity = n.number_in("intensity", 1.0f, 0.0f, 1e30f);
  l.intensity = color * intensity;
  if (type == "spot") {
    const float inner = n.number_in("inner_angle", 0.0f, 0.0f, 90.0f);
    const float outer = n.number_in("outer_angle", 45.0f, 0.0f, 90.0f);
    if (!(outer > inner))
      (n.has("outer_angle") ? n.at("outer_angle") : n.at("inner_angle"))
          .fail("outer_angle (" + short_number(outer) + ") must exceed inner_angle (" + short_number(inner) + ")");
    l.inner_cone = glm::radians(inner);
    l.outer_cone = glm::radians(outer);
  }
  if (type == "sun") l.angular_radius = glm::radians(n.number_in("angular_radius", 0.27f, 0.0f, 45.0f));
  return l;
}

// {"file", "strength", "rotation"}: an equirectangular map around the scene, the file relative to
// the scene file (decoded when the scene is compiled).
Environment read_environment(const Node& n, const fs::path& base_dir) {
  n.expect_object({"file", "strength", "rotation"});
  Environment e;
  const Node file = n.at("file");
  e.file = base_dir / file.string();
  std::error_code ec;
  if (!fs::is_regular_file(e.file, ec)) file.fail("environment map not found: " + e.file.string());
  e.strength = n.number_in("strength", 1.0f, 0.0f, 1e30f);
  e.rotation_degrees = n.number_in("rotation", 0.0f, -1e6f, 1e6f);
  return e;
}

}  // namespace

Layering parse_layering(const std::string& name) {
  if (name == layering_name(Layering::AlbedoScaling)) return Layering::AlbedoScaling;
  if (name == layering_name(Layering::FresnelMix)) return Layering::FresnelMix;
  throw Error("unknown layering '" + name + "' (expected albedo-scaling or fresnel-mix)");
}

const char* layering_name(Layering layering) {
  return layering == Layering::AlbedoScaling ? "albedo-scaling" : "fresnel-mix";
}

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
  root.expect_object({"camera", "film", "render", "background", "environment", "lights", "materials", "shapes"});
  s.camera = read_camera(root.at("camera"));

  if (root.has("film")) {
    const Node film = root.at("film");
    film.expect_object({"width", "height"});
    s.width = int(film.integer("width", s.width, 1, 16384));
    s.height = int(film.integer("height", s.height, 1, 16384));
  }
  if (root.has("render")) {
    const Node r = root.at("render");
    r.expect_object({"spp", "max_depth", "seed", "sampler", "multiple_scattering", "layering"});
    s.render.spp = int(r.integer("spp", s.render.spp, 1, INT32_MAX));
    s.render.max_depth = int(r.integer("max_depth", s.render.max_depth, 1, 64));
    s.render.seed = uint32_t(r.integer("seed", s.render.seed, 0, INT32_MAX));  // 31 bits: the EXR attribute is a signed int
    s.render.multiple_scattering = r.boolean("multiple_scattering", s.render.multiple_scattering);
    if (r.has("layering")) {
      try {
        s.render.layering = parse_layering(r.at("layering").string());
      } catch (const Error& e) {
        r.at("layering").fail(e.message());
      }
    }
    if (r.has("sampler")) {
      s.render.sampler = r.at("sampler").string();
      if (s.render.sampler != "random" && s.render.sampler != "grid" && s.render.sampler != "stratified" &&
          s.render.sampler != "sobol")
        r.at("sampler").fail("unknown sampler '" + s.render.sampler + "' (expected random, grid, stratified or sobol)");
    }
  }
  s.background = root.rgb("background", s.background, kInf);
  if (root.has("environment")) s.environment = read_environment(root.at("environment"), base_dir);
  if (root.has("lights")) {
    const auto lights = root.at("lights").elements();
    for (size_t i = 0; i < lights.size(); ++i) s.lights.push_back(read_light(lights[i], i));
  }

  // Material indices follow the key order of the materials object (alphabetical in nlohmann::json).
  std::map<std::string, uint32_t> index;
  ImageFiles images(base_dir, s.images);
  const Node materials = root.at("materials");
  if (!materials.raw().is_object()) materials.fail("expected an object mapping names to materials");
  for (const auto& item : materials.raw().items()) {
    index[item.key()] = uint32_t(s.materials.size());
    s.materials.push_back(read_material(materials.at(item.key()), item.key(), images));
  }

  const Node shapes = root.at("shapes");
  const auto list = shapes.elements();
  if (list.empty()) shapes.fail("scene has no shapes");
  for (const Node& shape : list) {
    if (shape.has("type") && shape.at("type").raw() == "asset") read_asset_shape(shape, base_dir, s);
    else read_shape(shape, index, base_dir, s);
  }
  if (const std::string small = too_small(s); !small.empty()) shapes.fail(small + " with a transform");
  return s;
}

const TriangleTexcoords& texcoords_of(const std::vector<TriangleTexcoords>& pool, const Triangle& t) {
  static const TriangleTexcoords none;
  return t.texcoords == kNoTexcoords ? none : pool[t.texcoords];
}

Triangle& Mesh::add_triangle(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c, uint32_t material,
                             const glm::vec3* normals) {
  const uint32_t first = uint32_t(vertices.size());
  const glm::vec3 corners[3] = {a, b, c};
  for (int k = 0; k < 3; ++k) vertices.push_back({corners[k], normals ? normals[k] : glm::vec3(0.0f)});
  Triangle& t = triangles.emplace_back();
  t.v[0] = first, t.v[1] = first + 1, t.v[2] = first + 2;
  t.material = material;
  t.has_normals = normals != nullptr;
  return t;
}

std::pair<glm::vec3, glm::vec3> Mesh::bounds() const {
  const unsigned parts = parts_for(triangles.size());
  std::vector<std::pair<glm::vec3, glm::vec3>> part_bounds(parts, {glm::vec3(INFINITY), glm::vec3(-INFINITY)});
  parallel_chunks(triangles.size(), parts, [&](size_t begin, size_t end, unsigned part) {
    glm::vec3 lo(INFINITY), hi(-INFINITY);
    for (size_t i = begin; i < end; ++i)
      for (int k = 0; k < 3; ++k) {
        const glm::vec3& v = position(triangles[i], k);
        lo = glm::min(lo, v), hi = glm::max(hi, v);
      }
    part_bounds[part] = {lo, hi};
  });
  glm::vec3 lo(INFINITY), hi(-INFINITY);
  for (const auto& [l, h] : part_bounds) lo = glm::min(lo, l), hi = glm::max(hi, h);
  return {lo, hi};
}

void Mesh::append(Mesh&& other, uint32_t first_material) {
  const uint32_t first_vertex = uint32_t(vertices.size()), first_texcoords = uint32_t(texcoords.size());
  for (Triangle& t : other.triangles) {
    for (uint32_t& v : t.v) v += first_vertex;
    t.material += first_material;
    if (t.texcoords != kNoTexcoords) t.texcoords += first_texcoords;
  }
  // Moved where this mesh is empty (the common case: one asset): no copy.
  auto join = [](auto& to, auto& from) {
    if (to.empty()) to = std::move(from);
    else to.insert(to.end(), from.begin(), from.end());
  };
  join(vertices, other.vertices);
  join(triangles, other.triangles);
  join(texcoords, other.texcoords);
}

void check_scene_limits(const Scene& scene) {
  const size_t n = scene.triangles.size(), vertices = scene.vertices.size();
  if (size_t i = first_where(n, [&](size_t i) {
        const uint32_t* v = scene.triangles[i].v;
        return v[0] >= vertices || v[1] >= vertices || v[2] >= vertices;
      });
      i != SIZE_MAX) {
    const uint32_t* v = scene.triangles[i].v;
    const uint32_t beyond = v[0] >= vertices ? v[0] : v[1] >= vertices ? v[1] : v[2];
    throw Error("triangle " + std::to_string(i) + " names vertex " + std::to_string(beyond) + " of " +
                    std::to_string(vertices),
                scene.source);
  }
  if (size_t i = first_where(n, [&](size_t i) { return !within_range(scene, scene.triangles[i]); }); i != SIZE_MAX)
    throw Error("triangle " + std::to_string(i) + " has a non-finite vertex coordinate or one beyond +-1e9",
                scene.source);
  if (const std::string small = too_small(scene); !small.empty()) throw Error(small, scene.source);
  const size_t texcoords = scene.texcoords.size();
  if (size_t i = first_where(n, [&](size_t i) {
        const uint32_t k = scene.triangles[i].texcoords;
        return k != kNoTexcoords && k >= texcoords;
      });
      i != SIZE_MAX)
    throw Error("triangle " + std::to_string(i) + " names texture coordinates " +
                    std::to_string(scene.triangles[i].texcoords) + " of " + std::to_string(texcoords),
                scene.source);
  auto radiance_ok = [](glm::vec3 c) {  // (false for NaN)
    return c.x >= 0.0f && c.y >= 0.0f && c.z >= 0.0f && std::isfinite(c.x + c.y + c.z);
  };
  for (const Material& m : scene.materials)
    if (!radiance_ok(m.emission))
      throw Error("material '" + m.name + "' has a negative or non-finite radiance", scene.source);
  if (!radiance_ok(scene.background)) throw Error("the background radiance is negative or not finite", scene.source);
  for (const Light& l : scene.lights)
    if (!radiance_ok(l.intensity) || !within_range(l.position) || !(glm::length(l.direction) > 0.0f))
      throw Error("light '" + l.name + "' has a negative or non-finite intensity, a position beyond +-1e9 or no direction",
                  scene.source);
  if (scene.environment && !(scene.environment->strength >= 0.0f && std::isfinite(scene.environment->strength)))
    throw Error("the environment's strength is negative or not finite", scene.source);
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
