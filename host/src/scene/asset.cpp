// Asset files as scenes: Assimp's scene graph walked with its node transforms, its cameras (with
// the corrections Assimp 5.2's glTF importer needs) and its materials mapped onto xi's.
#include "xi/asset.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>

#include <assimp/Importer.hpp>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <nlohmann/json.hpp>

#include "geometry.h"
#include "gltf.h"
#include "mesh_check.h"
#include "xi/error.h"

namespace xi {

namespace scene_detail {

void mesh_triangles(const aiMesh& mesh, uint32_t material, bool flip_v, Mesh& out) {
  const uint32_t base = uint32_t(out.vertices.size());
  make_room(out.vertices, mesh.mNumVertices);
  for (unsigned i = 0; i < mesh.mNumVertices; ++i) {
    Vertex& v = out.vertices.emplace_back();
    v.position = {mesh.mVertices[i].x, mesh.mVertices[i].y, mesh.mVertices[i].z};
    if (mesh.HasNormals()) v.normal = {mesh.mNormals[i].x, mesh.mNormals[i].y, mesh.mNormals[i].z};
  }
  make_room(out.triangles, mesh.mNumFaces);
  const bool tangents = mesh.HasNormals() && mesh.HasTangentsAndBitangents();
  const bool has_texcoords = tangents || mesh.HasTextureCoords(0) || mesh.HasTextureCoords(1);
  if (has_texcoords) make_room(out.texcoords, mesh.mNumFaces);
  for (unsigned f = 0; f < mesh.mNumFaces; ++f) {
    const aiFace& face = mesh.mFaces[f];
    if (face.mNumIndices != 3) continue;  // points and lines survive triangulation; skip them
    Triangle& t = out.triangles.emplace_back();
    t.has_normals = mesh.HasNormals();
    t.material = material;
    TriangleTexcoords* tc = nullptr;
    if (has_texcoords) t.texcoords = uint32_t(out.texcoords.size()), tc = &out.texcoords.emplace_back();
    for (int k = 0; k < 3; ++k) {
      const unsigned i = face.mIndices[k];
      t.v[k] = base + i;
      if (tangents) {  // Assimp gives glTF's w as bitangent = w · normal × tangent
        const aiVector3D& n = mesh.mNormals[i];
        const aiVector3D& tg = mesh.mTangents[i];
        const aiVector3D& b = mesh.mBitangents[i];
        const glm::vec3 tv(tg.x, tg.y, tg.z), bv(b.x, b.y, b.z);
        const float w = glm::dot(glm::cross(glm::vec3(n.x, n.y, n.z), tv), bv) < 0.0f ? -1.0f : 1.0f;
        if (std::isfinite(tv.x + tv.y + tv.z) && glm::dot(tv, tv) > 0.0f) tc->tangent[k] = glm::vec4(tv, w);
      }
      for (int set = 0; set < 2; ++set)
        if (mesh.HasTextureCoords(set)) {
          const aiVector3D& uv = mesh.mTextureCoords[set][i];
          tc->uv[set][k] = {uv.x, flip_v ? 1.0f - uv.y : uv.y};
        }
    }
  }
}

long long place_mesh(const Transform& xf, Mesh& mesh, size_t first_vertex, size_t first_triangle) {
  // On every core for a large mesh (in double precision: most of a large mesh's load after reading
  // it); then the kept triangles moved together, in order. Vertices of dropped triangles stay.
  transform_mesh(xf, mesh, first_vertex, first_triangle);
  std::vector<Triangle>& tris = mesh.triangles;
  const size_t n = tris.size() - first_triangle;
  std::vector<uint8_t> keep(n);
  // One pass: each triangle within range is checked as it is reached (a part stops at its first
  // out of range, which is then the error).
  const size_t bad = first_where(n, [&](size_t i) {
    Triangle& t = tris[first_triangle + i];
    if (!within_range(mesh, t)) return true;
    keep[i] = !degenerate(mesh, t);  // common in real meshes and harmless to drop
    for (int k = 0; k < 3 && t.has_normals; ++k) {
      const glm::vec3& nv = mesh.normal(t, k);
      t.has_normals = std::isfinite(nv.x + nv.y + nv.z) && glm::dot(nv, nv) > 0.0f;
    }
    return false;
  });
  if (bad != SIZE_MAX) return (long long)bad;
  size_t kept = first_triangle;
  for (size_t i = 0; i < n; ++i)
    if (keep[i]) {
      if (kept != first_triangle + i) tris[kept] = tris[first_triangle + i];
      kept++;
    }
  tris.resize(kept);
  return -1;
}

}  // namespace scene_detail

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace scene_detail;

bool is_gltf(const fs::path& path) {
  const std::string ext = lower_extension(path);
  return ext == ".gltf" || ext == ".glb";
}

glm::dmat4 to_glm(const aiMatrix4x4& a) {  // Assimp is row-major (a1..a4 the first row)
  glm::dmat4 m;
  const float* r = &a.a1;
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col) m[col][row] = r[row * 4 + col];
  return m;
}

glm::dmat4 global_transform(const aiNode* node) {
  glm::dmat4 m(1.0);
  for (; node; node = node->mParent) m = to_glm(node->mTransformation) * m;
  return m;
}

float get_float(const aiMaterial& m, const char* key, unsigned type, unsigned index, float def) {
  float v = def;
  return m.Get(key, type, index, v) == aiReturn_SUCCESS && std::isfinite(v) ? v : def;
}

glm::vec3 get_color(const aiMaterial& m, const char* key, unsigned type, unsigned index, glm::vec3 def) {
  aiColor4D c;
  if (m.Get(key, type, index, c) != aiReturn_SUCCESS) return def;
  const glm::vec3 v(c.r, c.g, c.b);
  return std::isfinite(v.x + v.y + v.z) ? v : def;
}

bool has_property(const aiMaterial& m, const char* key) {
  const aiMaterialProperty* p = nullptr;
  return aiGetMaterialProperty(&m, key, 0, 0, &p) == aiReturn_SUCCESS;
}

// A material of a format other than glTF (whose materials gltf.cpp reads from the file itself), as
// Assimp hands it over: metallic-roughness factors where the file has them, else a diffuse surface
// with the diffuse colour; transmission makes it transmissive with the file's ior. Textures and
// opacity are warnings.
Material convert_material(const aiMaterial& am, size_t index, Warnings& warn) {
  Material m;
  m.name = am.GetName().length ? am.GetName().C_Str() : "material " + std::to_string(index);
  const glm::vec3 diffuse = get_color(am, AI_MATKEY_COLOR_DIFFUSE, glm::vec3(0.8f));
  const glm::vec3 base = glm::clamp(get_color(am, AI_MATKEY_BASE_COLOR, diffuse), 0.0f, 1.0f);
  const glm::vec3 emissive = glm::max(get_color(am, AI_MATKEY_COLOR_EMISSIVE, glm::vec3(0.0f)), 0.0f);
  const float transmission = std::clamp(get_float(am, AI_MATKEY_TRANSMISSION_FACTOR, 0.0f), 0.0f, 1.0f);
  const bool pbr = has_property(am, "$mat.metallicFactor");
  const float opacity = get_float(am, AI_MATKEY_OPACITY, 1.0f);
  int two_sided = 0;
  am.Get(AI_MATKEY_TWOSIDED, two_sided);

  for (aiTextureType t : {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE, aiTextureType_EMISSIVE,
                          aiTextureType_METALNESS, aiTextureType_DIFFUSE_ROUGHNESS, aiTextureType_NORMALS,
                          aiTextureType_TRANSMISSION, aiTextureType_SPECULAR})
    if (am.GetTextureCount(t) > 0)
      warn.add("textures are read from glTF files only: other formats' materials use their constant factors");
  if (opacity < 1.0f) warn.add("opacity below 1 is read from glTF files only: such surfaces are opaque");

  m.albedo = base;
  m.emission = emissive;
  m.two_sided = two_sided != 0;
  if (pbr || transmission > 0.0f) {
    m.type = MaterialType::Pbr;
    m.metallic = std::clamp(get_float(am, AI_MATKEY_METALLIC_FACTOR, 0.0f), 0.0f, 1.0f);
    m.roughness = std::clamp(get_float(am, AI_MATKEY_ROUGHNESS_FACTOR, 1.0f), 0.0f, 1.0f);
    m.transmission = transmission;
    m.ior = std::clamp(get_float(am, AI_MATKEY_REFRACTI, 1.5f), 1.0f, 4.0f);
  }
  return m;
}

struct Loaded {
  Assimp::Importer importer;
  const aiScene* scene = nullptr;
};

// Some of Assimp's readers leave null entries behind (5.2's RAW reader: a null child node), which
// the walks below would follow. (aiProcess_ValidateDataStructure would catch them, but also refuses
// files read well, e.g. an OpenGEX light without a node.)
std::optional<std::string> null_entry(const aiScene& scene) {
  for (unsigned i = 0; i < scene.mNumMeshes; ++i)
    if (!scene.mMeshes[i]) return "a null mesh";
  for (unsigned i = 0; i < scene.mNumMaterials; ++i)
    if (!scene.mMaterials[i]) return "a null material";
  std::vector<const aiNode*> stack = {scene.mRootNode};
  while (!stack.empty()) {
    const aiNode* node = stack.back();
    stack.pop_back();
    for (unsigned c = 0; c < node->mNumChildren; ++c) {
      if (!node->mChildren[c]) return "a null node in the scene graph";
      stack.push_back(node->mChildren[c]);
    }
  }
  return std::nullopt;
}

// Assimp picks its importer by the extension, so one it has no importer for is refused here, with
// the list of those it has (JSON scenes too where the file was given as a whole scene).
void check_format(const fs::path& path, const Assimp::Importer& importer, bool whole_scene) {
  const std::string ext = lower_extension(path);
  if (!ext.empty() && importer.IsExtensionSupported(ext)) return;
  std::string known;
  for (const std::string& e : asset_extensions()) known += " " + e;
  throw Error((ext.empty() ? std::string("no file extension to tell the format by")
                           : "unknown scene format '" + path.extension().string() + "'") +
                  ": xi reads " + (whole_scene ? ".json scenes and, through Assimp," : "through Assimp") + known,
              path.string());
}

void read_file(const fs::path& path, Loaded& l, bool whole_scene) {
  check_format(path, l.importer, whole_scene);
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw Error("asset file not found", path.string());
  // Before Assimp allocates what the header claims (it would exhaust memory, not fail).
  if (auto why = implausible_mesh_counts(path)) throw Error("cannot load asset: " + *why, path.string());
  l.scene = l.importer.ReadFile(path.string(), aiProcess_Triangulate | aiProcess_JoinIdenticalVertices);
  if (!l.scene || (l.scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) || !l.scene->mRootNode) {
    const std::string why = l.importer.GetErrorString();
    // Assimp marks some files incomplete without a reason (a glTF scene that lists no nodes).
    throw Error("cannot load asset: " + (why.empty() ? std::string("Assimp read no complete scene from it (it gave "
                                                                   "no reason; a scene without nodes is one cause)")
                                                     : why),
                path.string());
  }
  if (auto what = null_entry(*l.scene)) throw Error("cannot load asset: Assimp's reader left " + *what, path.string());
}

// The file's point, spot and directional lights, placed by their nodes (glTF: KHR_lights_punctual,
// whose node holds the light at its origin, shining down its -z). Assimp gives colour × intensity.
std::vector<Light> punctual_lights(const fs::path& path, const aiScene& scene, Warnings& warn) {
  std::vector<Light> out;
  for (unsigned i = 0; i < scene.mNumLights; ++i) {
    const aiLight* l = scene.mLights[i];
    if (!l) continue;
    Light light;
    light.name = l->mName.C_Str();
    switch (l->mType) {
      case aiLightSource_POINT: light.type = LightType::Point; break;
      case aiLightSource_SPOT: light.type = LightType::Spot; break;
      case aiLightSource_DIRECTIONAL: light.type = LightType::Directional; break;
      default: warn.add("area and ambient lights of asset files are not read: model them as emissive meshes"); continue;
    }
    const aiNode* node = scene.mRootNode->FindNode(l->mName);
    const glm::dmat4 m = node ? global_transform(node) : glm::dmat4(1.0);
    const glm::dvec3 pos(l->mPosition.x, l->mPosition.y, l->mPosition.z), dir(l->mDirection.x, l->mDirection.y, l->mDirection.z);
    light.position = glm::vec3(m * glm::dvec4(pos, 1.0));
    const glm::dvec3 d = glm::dmat3(m) * (glm::length(dir) > 0.0 ? dir : glm::dvec3(0, 0, -1));
    light.direction = glm::vec3(glm::normalize(d));
    light.intensity = glm::max(glm::vec3(l->mColorDiffuse.r, l->mColorDiffuse.g, l->mColorDiffuse.b), 0.0f);
    light.outer_cone = std::clamp(l->mAngleOuterCone, 1e-4f, 1.5707963f);
    light.inner_cone = std::clamp(l->mAngleInnerCone, 0.0f, light.outer_cone);
    if (!within_range(light.position) || !std::isfinite(light.intensity.x + light.intensity.y + light.intensity.z) ||
        !std::isfinite(light.direction.x + light.direction.y + light.direction.z))
      throw Error("light '" + light.name + "' has a non-finite or out-of-range position, direction or intensity",
                  path.string());
    out.push_back(light);
  }
  return out;
}

AssetGeometry geometry(const fs::path& path, const aiScene& scene) {
  AssetGeometry g;
  Warnings warn;
  const bool gltf = is_gltf(path);
  std::optional<GltfMaterials> file_materials;
  if (gltf)
    if (const auto file = read_gltf(path)) file_materials = gltf_materials(*file, warn);
  std::vector<int> remap(scene.mNumMaterials, -1);  // Assimp's index -> ours (only used materials)
  auto material = [&](unsigned i) -> uint32_t {
    if (i >= scene.mNumMaterials) throw Error("mesh names material " + std::to_string(i) + ", which does not exist", path.string());
    if (remap[i] < 0) {
      remap[i] = int(g.materials.size());
      // Assimp keeps a glTF file's material order and appends its default material, for
      // primitives without one: glTF's default, a rough white metal.
      if (file_materials && i >= file_materials->materials.size()) {
        Material m;
        m.name = "default";
        m.type = MaterialType::Pbr;
        m.albedo = glm::vec3(1.0f);
        m.metallic = 1.0f;
        g.materials.push_back(m);
      } else {
        g.materials.push_back(file_materials ? file_materials->materials[i] : convert_material(*scene.mMaterials[i], i, warn));
        const glm::vec3 e = g.materials.back().emission;
        if (!std::isfinite(e.x + e.y + e.z))
          throw Error("material '" + g.materials.back().name + "' has a non-finite emissive colour", path.string());
      }
    }
    return uint32_t(remap[i]);
  };
  // Every node's meshes, through the node's global transform (applied here, once).
  std::vector<std::pair<const aiNode*, glm::dmat4>> stack = {{scene.mRootNode, to_glm(scene.mRootNode->mTransformation)}};
  while (!stack.empty()) {
    auto [node, m] = stack.back();
    stack.pop_back();
    for (unsigned c = 0; c < node->mNumChildren; ++c)
      stack.push_back({node->mChildren[c], m * to_glm(node->mChildren[c]->mTransformation)});
    for (unsigned k = 0; k < node->mNumMeshes; ++k) {
      if (node->mMeshes[k] >= scene.mNumMeshes) throw Error("node names a mesh that does not exist", path.string());
      const aiMesh& mesh = *scene.mMeshes[node->mMeshes[k]];
      const size_t first_vertex = g.vertices.size(), first = g.triangles.size();
      mesh_triangles(mesh, material(mesh.mMaterialIndex), gltf, g);
      if (place_mesh(make_transform(m), g, first_vertex, first) >= 0)
        throw Error("mesh '" + std::string(mesh.mName.C_Str()) +
                        "' has a non-finite vertex coordinate or one beyond +-1e9 (after its node transforms)",
                    path.string());
    }
  }
  if (g.triangles.empty()) throw Error("asset has no triangles (after dropping degenerate ones)", path.string());
  if (file_materials) g.images = std::move(file_materials->images);
  g.lights = punctual_lights(path, scene, warn);
  g.warnings = std::move(warn.lines);
  return g;
}

struct CameraInfo {
  std::string name;
  bool perspective = true;
  Camera camera;
  float aspect = 1.0f;
};

// A file's cameras in world space. Assimp 5.2's glTF2 importer (checked against glTF2/cameras/
// Cameras.gltf and files written by the tests) gets two things wrong, corrected here:
//  - aiCamera::mHorizontalFOV is documented as half the horizontal angle, but holds yfov x aspectRatio
//    (yfov being glTF's full vertical angle): the vertical fov is mHorizontalFOV / mAspect (mAspect 0,
//    for a file without aspectRatio, multiplies by 1);
//  - aiCamera::mPosition holds the camera node's translation although the node's transform (which the
//    camera, named after its node, is placed by) has it too: used as documented it would count twice.
//    For glTF the camera sits at its node's origin, looking down its -z with +y up.
// Other formats are read as aiCamera documents them.
std::vector<CameraInfo> cameras(const fs::path& path, const aiScene& scene) {
  std::vector<CameraInfo> out;
  const bool gltf = is_gltf(path);
  for (unsigned i = 0; i < scene.mNumCameras; ++i) {
    const aiCamera& c = *scene.mCameras[i];
    CameraInfo info;
    info.name = c.mName.C_Str();
    const aiNode* node = scene.mRootNode->FindNode(c.mName);
    const glm::dmat4 m = node ? global_transform(node) : glm::dmat4(1.0);
    info.perspective = c.mHorizontalFOV > 0.0f;
    info.aspect = c.mAspect > 0.0f ? c.mAspect : 1.0f;
    const glm::dvec3 local_pos = gltf ? glm::dvec3(0.0) : glm::dvec3(c.mPosition.x, c.mPosition.y, c.mPosition.z);
    const glm::dvec3 local_dir = gltf ? glm::dvec3(0, 0, -1) : glm::dvec3(c.mLookAt.x, c.mLookAt.y, c.mLookAt.z);
    const glm::dvec3 local_up = gltf ? glm::dvec3(0, 1, 0) : glm::dvec3(c.mUp.x, c.mUp.y, c.mUp.z);
    const glm::dvec3 pos = glm::dvec3(m * glm::dvec4(local_pos, 1.0));
    const glm::dvec3 dir = glm::dmat3(m) * local_dir, up = glm::dmat3(m) * local_up;
    info.camera.position = glm::vec3(pos);
    info.camera.look_at = glm::vec3(pos + glm::normalize(dir));
    info.camera.up = glm::vec3(glm::normalize(up));
    info.camera.focus_distance = 1.0f;
    const double vfov = gltf ? double(c.mHorizontalFOV) / info.aspect  // see above
                             : 2.0 * std::atan(std::tan(double(c.mHorizontalFOV)) / info.aspect);
    info.camera.vfov_degrees = float(glm::degrees(vfov));
    out.push_back(info);
  }
  return out;
}

std::string describe(const std::vector<CameraInfo>& list) {
  std::string s;
  for (size_t i = 0; i < list.size(); ++i)
    s += (i ? ", " : "") + std::to_string(i) + " '" + list[i].name + "'" + (list[i].perspective ? "" : " (orthographic)");
  return s.empty() ? "none" : s;
}

}  // namespace

bool is_asset_file(const fs::path& path) { return lower_extension(path) != ".json"; }

std::vector<std::string> asset_extensions() {
  std::string list;  // "*.3d;*.3ds;*.3mf;..."
  Assimp::Importer().GetExtensionList(list);
  std::vector<std::string> out;
  for (size_t at = 0; at < list.size();) {
    const size_t end = std::min(list.find(';', at), list.size());
    std::string e = list.substr(at, end - at);
    if (e.rfind("*", 0) == 0) e.erase(0, 1);
    if (!e.empty()) out.push_back(e);
    at = end + 1;
  }
  return out;
}

AssetGeometry load_asset_geometry(const fs::path& path) {
  Loaded l;
  read_file(path, l, false);
  return geometry(path, *l.scene);
}

Scene load_asset(const fs::path& path, const AssetOptions& options) {
  Loaded l;
  read_file(path, l, true);
  AssetGeometry g = geometry(path, *l.scene);
  Scene s;
  s.source = path.string();
  s.materials = std::move(g.materials);
  static_cast<Mesh&>(s) = std::move(static_cast<Mesh&>(g));
  s.warnings = std::move(g.warnings);
  if (const std::string small = too_small(s); !small.empty()) throw Error(small, path.string());
  if (options.height < 1 || options.height > 16384) throw Error("film height must be in [1, 16384]", path.string());

  const std::vector<CameraInfo> list = cameras(path, *l.scene);
  int chosen = -1;
  if (!options.camera.empty()) {
    const std::string& want = options.camera;
    if (want.find_first_not_of("0123456789") == std::string::npos && want.size() < 9) {
      const size_t i = std::stoul(want);
      if (i < list.size()) chosen = int(i);
    }
    for (size_t i = 0; chosen < 0 && i < list.size(); ++i)
      if (list[i].name == want) chosen = int(i);
    if (chosen < 0)
      throw Error("no camera '" + want + "' in " + path.filename().string() + " (its cameras: " + describe(list) + ")",
                  "--camera");
    if (!list[chosen].perspective)
      throw Error("camera " + std::to_string(chosen) + " '" + list[chosen].name +
                      "' is orthographic; xi renders perspective cameras (the file's cameras: " + describe(list) + ")",
                  "--camera");
  } else {
    for (size_t i = 0; chosen < 0 && i < list.size(); ++i)
      if (list[i].perspective) chosen = int(i);
  }

  float aspect = 1.0f;
  if (chosen >= 0 && options.orbit)
    throw Error("--orbit turns the framing of a file without a camera, but this render uses camera " +
                    std::to_string(chosen) + " '" + list[chosen].name + "' of " + path.filename().string(),
                "--orbit");
  if (chosen >= 0) {
    const CameraInfo& c = list[chosen];
    const glm::vec3 dir = c.camera.look_at - c.camera.position;
    if (!within_range(c.camera.position) || !within_range(c.camera.look_at) || !(glm::length(dir) > 0.0f) ||
        !(glm::length(glm::cross(glm::normalize(dir), c.camera.up)) > 1e-6f) ||
        !(c.camera.vfov_degrees > 0.0f && c.camera.vfov_degrees < 180.0f))
      throw Error("camera " + std::to_string(chosen) + " '" + c.name + "' cannot be used (degenerate transform or fov)",
                  path.string());
    s.camera = c.camera;
    aspect = c.aspect;
    char buf[160];
    std::snprintf(buf, sizeof buf, "camera %d '%s' of %zu (vertical fov %.2f degrees, aspect %.4g)", chosen,
                  c.name.c_str(), list.size(), c.camera.vfov_degrees, c.aspect);
    s.notes.push_back(buf);
  } else {
    // Frame the bounding sphere of the box as glTF viewers do: from the front (+z, the glTF front
    // view), a little above, looking at its centre, up +y, the sphere filling the frame's height.
    const Orbit orbit = options.orbit.value_or(Orbit{});
    if (!std::isfinite(orbit.yaw) || !(std::abs(orbit.pitch) < 90.0)) {
      char buf[120];
      std::snprintf(buf, sizeof buf,
                    "the framing's pitch must be within (-90, 90) degrees and its yaw finite, got %g,%g", orbit.yaw,
                    orbit.pitch);
      throw Error(buf, "--orbit");
    }
    const auto [box_lo, box_hi] = s.bounds();
    const glm::dvec3 lo(box_lo), hi(box_hi);
    const glm::dvec3 centre = 0.5 * (lo + hi);
    const double radius = std::max(0.5 * glm::length(hi - lo), 1e-6);
    const double vfov = 40.0, distance = 1.1 * radius / std::sin(glm::radians(vfov / 2.0));
    const double yaw = glm::radians(orbit.yaw), pitch = glm::radians(orbit.pitch);
    const glm::dvec3 toward_camera(std::sin(yaw) * std::cos(pitch), std::sin(pitch), std::cos(yaw) * std::cos(pitch));
    s.camera.position = glm::vec3(centre + distance * toward_camera);
    s.camera.look_at = glm::vec3(centre);
    s.camera.up = {0.0f, 1.0f, 0.0f};
    s.camera.vfov_degrees = float(vfov);
    s.camera.focus_distance = float(distance);
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  ": framing its bounding sphere from --orbit %g,%g (yaw about +y from the front, pitch above "
                  "the horizontal, in degrees; looking at its centre, up +y, vertical fov 40 degrees)",
                  orbit.yaw, orbit.pitch);
    s.notes.push_back(std::string(list.empty() ? "no camera in the file" : "no perspective camera in the file") + buf);
  }
  s.height = options.height;
  s.width = int(std::clamp(std::lround(options.height * double(aspect)), 1L, 16384L));

  s.images = std::move(g.images);
  s.lights = std::move(g.lights);
  // A glTF file's lights are its KHR_lights_punctual ones: emissive materials there are glowing
  // surfaces (labels, screens), not what lights the model. Other formats have no such convention.
  const bool emitters =
      std::any_of(s.materials.begin(), s.materials.end(), [](const Material& m) { return m.is_emitter(); });
  const bool lit = !s.lights.empty() || (emitters && !is_gltf(path));
  if (!lit && options.environment) {
    s.environment = options.environment;
    s.notes.push_back("no light in the file: lit by " + s.environment->file.string());
  } else if (!lit && !options.sky) {
    s.notes.push_back("no light in the file and no environment: the background alone lights it");
  } else if (!lit) {
    // As glTF viewers light a model without lights: by an environment.
    s.environment = Environment{bundled_scene_file("sky.hdr"), 1.0f, 0.0f};
    s.notes.push_back("no light in the file: lit by xi's bundled sky (" + s.environment->file.string() +
                      "); --env FILE names another, --background R,G,B a constant one");
  }
  return s;
}

}  // namespace xi
