// `xi export`: a scene's triangles as xi renders them (quads split, spheres as icospheres, meshes
// cleaned, every transform applied), in world space, as binary little-endian PLY files, one per
// material, and a JSON manifest naming each file's material. Other renderers read these to see
// exactly xi's geometry. In each file the `flat_triangles` (manifest) that have no vertex normals
// come first, their face normal at their three vertices; the rest carry their own vertex normals.
// A material with textures also gets texture coordinates (set 0), and each image goes as a PNG; the
// manifest also holds every material's parameters and texture slots, the lights and the environment.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include "cli.h"
#include "xi/asset.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/scene.h"

namespace xi::cli {
namespace {

namespace fs = std::filesystem;

void put_u32(std::string& out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out += char((v >> (8 * i)) & 0xff);  // little-endian whatever the host
}

void put_float(std::string& out, float f) {
  uint32_t bits = 0;
  static_assert(sizeof bits == sizeof f);
  std::memcpy(&bits, &f, sizeof f);
  put_u32(out, bits);
}

// The normal at each vertex: the triangle's own, or its face normal (the same at all three, so that
// interpolating them keeps the triangle flat). The face normal follows the winding, as xi's does.
void vertex_normals(const Mesh& mesh, const Triangle& t, glm::vec3 out[3]) {
  if (t.has_normals) {
    for (int k = 0; k < 3; ++k) out[k] = mesh.normal(t, k);
    return;
  }
  const glm::dvec3 a(mesh.position(t, 0)), b(mesh.position(t, 1)), c(mesh.position(t, 2));
  const glm::vec3 n(glm::normalize(glm::cross(b - a, c - a)));
  for (int k = 0; k < 3; ++k) out[k] = n;
}

// One material's triangles as a PLY: three vertices of its own per triangle (x y z nx ny nz: a flat
// triangle's face normal is its own), and with `uv` the texture coordinates of set 0 (u v, as the
// file has them: v down the image).
std::string ply(const Mesh& mesh, const std::vector<const Triangle*>& tris, const std::string& material, bool uv) {
  const size_t n = tris.size();
  if (3 * n > (size_t)INT32_MAX) throw Error("too many triangles for a PLY file's int indices", material);
  std::string out =
      "ply\nformat binary_little_endian 1.0\ncomment xi export\nelement vertex " + std::to_string(3 * n) +
      "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
      "property float nz\n" + std::string(uv ? "property float u\nproperty float v\n" : "") +
      "element face " + std::to_string(n) + "\nproperty list uchar int vertex_indices\nend_header\n";
  out.reserve(out.size() + n * (3 * (uv ? 8 : 6) * 4 + 1 + 3 * 4));
  for (const Triangle* t : tris) {
    glm::vec3 normals[3];
    vertex_normals(mesh, *t, normals);
    for (int k = 0; k < 3; ++k) {
      for (int c = 0; c < 3; ++c) put_float(out, mesh.position(*t, k)[c]);
      for (int c = 0; c < 3; ++c) put_float(out, normals[k][c]);
      if (uv)
        for (int c = 0; c < 2; ++c) put_float(out, texcoords_of(mesh.texcoords, *t).uv[0][k][c]);
    }
  }
  for (size_t i = 0; i < n; ++i) {
    out += char(3);
    for (uint32_t k = 0; k < 3; ++k) put_u32(out, uint32_t(3 * i + k));
  }
  return out;
}

nlohmann::json vec(const glm::vec3& v) { return {v.x, v.y, v.z}; }

const char* wrap_name(Wrap w) {
  switch (w) {
    case Wrap::Clamp: return "clamp";
    case Wrap::Mirror: return "mirror";
    default: return "repeat";
  }
}

// A texture slot: the PNG `xi export` wrote for its image, its coordinate set, wrap modes and the
// KHR_texture_transform matrix (row-major, applied to (u, v, 1) with v down, as xi applies it).
nlohmann::json slot_json(const TextureSlot& s) {
  nlohmann::json m = nlohmann::json::array();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m.push_back(s.transform[c][r]);
  return {{"file", "texture-" + std::to_string(s.image) + ".png"}, {"image", s.image}, {"texcoord", s.texcoord},
          {"wrap_s", wrap_name(s.wrap_s)}, {"wrap_t", wrap_name(s.wrap_t)}, {"transform", m}};
}

nlohmann::json material_json(const Material& m) {
  static const char* types[] = {"diffuse", "mirror", "glass", "pbr"};
  static const char* alpha_modes[] = {"opaque", "mask", "blend"};
  nlohmann::json j = {{"name", m.name}, {"type", types[(uint32_t)m.type]}, {"albedo", vec(m.albedo)},
                      {"emission", vec(m.emission)}, {"two_sided", m.two_sided}, {"ior", m.ior},
                      {"metallic", m.metallic}, {"roughness", m.roughness}, {"transmission", m.transmission},
                      {"normal_scale", m.normal_scale}, {"alpha", m.alpha},
                      {"alpha_mode", alpha_modes[(uint32_t)m.alpha_mode]}, {"alpha_cutoff", m.alpha_cutoff},
                      {"specular", m.specular}, {"specular_color", vec(m.specular_color)},
                      {"clearcoat", m.clearcoat}, {"clearcoat_roughness", m.clearcoat_roughness},
                      {"sheen_color", vec(m.sheen_color)}, {"sheen_roughness", m.sheen_roughness},
                      {"anisotropy_strength", m.anisotropy_strength}, {"anisotropy_rotation", m.anisotropy_rotation},
                      {"iridescence", m.iridescence}, {"iridescence_ior", m.iridescence_ior},
                      {"iridescence_thickness_minimum", m.iridescence_thickness_minimum},
                      {"iridescence_thickness_maximum", m.iridescence_thickness_maximum},
                      {"absorption", vec(m.volume_absorption())}};
  nlohmann::json textures = nlohmann::json::object();
  for (int k = 0; k < XI_TEXTURE_SLOTS; ++k)
    if (m.textures[k].used()) textures[kTextureSlots[k].key] = slot_json(m.textures[k]);
  j["textures"] = textures;
  return j;
}

nlohmann::json light_json(const Light& l) {
  static const char* types[] = {"point", "spot", "directional"};
  nlohmann::json j = {{"name", l.name}, {"type", types[(uint32_t)l.type]}, {"intensity", vec(l.intensity)}};
  if (l.type != LightType::Directional) j["position"] = vec(l.position);
  if (l.type != LightType::Point) j["direction"] = vec(l.direction);
  if (l.type == LightType::Spot) {
    j["inner_cone_degrees"] = glm::degrees(l.inner_cone);
    j["outer_cone_degrees"] = glm::degrees(l.outer_cone);
  }
  if (l.type == LightType::Directional) j["angular_radius_degrees"] = glm::degrees(l.angular_radius);
  return j;
}

void write_file(const fs::path& path, const std::string& bytes) {
  write_atomically(path, [&](const fs::path& tmp) {
    std::FILE* f = std::fopen(tmp.c_str(), "wb");
    if (!f) throw Error("cannot open file for writing", tmp.string());
    const bool wrote = std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size();
    if (std::fclose(f) != 0 || !wrote) throw Error("cannot write file", tmp.string());
  });
}

}  // namespace

const Command kExport = {
    .name = "export",
    .operands = "SCENE OUT_DIR",
    .about = "write the scene's triangles as xi renders them, in world space, for\n"
             "other renderers: one binary PLY per material (x y z nx ny nz; its\n"
             "flat triangles first, each with its face normal at its three\n"
             "vertices) and manifest.json naming each file's material and its\n"
             "count of flat triangles; OUT_DIR is made if its parent exists",
    .run = export_scene,
};

int export_scene(const std::vector<std::string>& argv) {
  Args args(argv, kExport);
  if (args.positional().size() != 2) throw Error("expected SCENE OUT_DIR", "xi export");
  const fs::path scene_path = args.positional()[0], out_dir = args.positional()[1];

  // The output folder: an existing folder, or a new one whose parent exists. Checked before the
  // scene loads (a mesh may take a while), created only once the scene has loaded.
  std::error_code ec;
  const bool existed = fs::exists(out_dir, ec);
  if (existed && !fs::is_directory(out_dir, ec)) throw Error("the output exists and is not a folder", out_dir.string());
  const fs::path parent = out_dir.has_parent_path() ? out_dir.parent_path() : fs::path(".");
  if (!existed && !fs::is_directory(parent, ec))
    throw Error("the output folder's parent folder does not exist", out_dir.string());

  const Scene scene = is_asset_file(scene_path) ? load_asset(scene_path) : load_scene(scene_path);

  // Per material, the triangles without vertex normals first (xi shades them flat), then those with
  // (xi interpolates their normals), each in the scene's order; the manifest says where the first end.
  std::vector<std::vector<const Triangle*>> by_material(scene.materials.size());
  std::vector<size_t> flat(scene.materials.size(), 0);
  for (bool smooth : {false, true})
    for (const Triangle& t : scene.triangles)
      if (t.has_normals == smooth) by_material.at(t.material).push_back(&t);
  for (const Triangle& t : scene.triangles) flat.at(t.material) += !t.has_normals;

  if (!existed && !fs::create_directory(out_dir, ec))
    throw Error("cannot create the output folder: " + ec.message(), out_dir.string());
  std::vector<fs::path> written;
  try {
    // An earlier export's manifest goes first: from here until the new one is written, none means
    // the folder is incomplete.
    if (fs::exists(out_dir / "manifest.json", ec)) fs::remove(out_dir / "manifest.json");
    nlohmann::json meshes = nlohmann::json::array();
    for (size_t m = 0; m < by_material.size(); ++m) {
      if (by_material[m].empty()) continue;
      const std::string file = "material-" + std::to_string(m) + ".ply";
      const bool uv = scene.materials[m].has_textures();
      write_file(out_dir / file, ply(scene, by_material[m], scene.materials[m].name, uv));
      written.push_back(out_dir / file);
      meshes.push_back({{"file", file}, {"material", scene.materials[m].name}, {"material_index", m},
                        {"triangles", by_material[m].size()}, {"flat_triangles", flat[m]}, {"texcoords", uv}});
    }
    // Every image the materials read, as an 8-bit RGBA PNG of xi's decoded texels (top row first).
    nlohmann::json images = nlohmann::json::array();
    for (size_t i = 0; i < scene.images.size(); ++i) {
      const TextureImage& im = scene.images[i];
      const std::string file = "texture-" + std::to_string(i) + ".png";
      write_png_rgba8(out_dir / file, im.width, im.height, im.texels);
      written.push_back(out_dir / file);
      images.push_back({{"file", file}, {"source", im.source}, {"width", im.width}, {"height", im.height},
                        {"srgb", im.srgb}});
    }
    nlohmann::json materials = nlohmann::json::array(), lights = nlohmann::json::array();
    for (const Material& m : scene.materials) materials.push_back(material_json(m));
    for (const Light& l : scene.lights) lights.push_back(light_json(l));
    nlohmann::json environment = nullptr;
    if (scene.environment)
      environment = {{"file", fs::absolute(scene.environment->file).string()},
                     {"strength", scene.environment->strength}, {"rotation", scene.environment->rotation_degrees}};
    const nlohmann::json manifest = {{"scene", scene.source.empty() ? scene_path.string() : scene.source},
                                     {"triangles", scene.triangles.size()},
                                     {"meshes", meshes},
                                     {"materials", materials},
                                     {"images", images},
                                     {"lights", lights},
                                     {"environment", environment},
                                     {"background", vec(scene.background)}};
    write_file(out_dir / "manifest.json", manifest.dump(2) + "\n");  // last: its presence means complete
  } catch (...) {  // no partial export: what this run wrote goes, and the folder if it made it
    for (const fs::path& p : written) fs::remove(p, ec);
    if (!existed) fs::remove(out_dir, ec);
    throw;
  }
  std::printf("wrote %zu triangles of %s in %zu PLY files and manifest.json to %s\n", scene.triangles.size(),
              scene_path.string().c_str(), written.size(), out_dir.string().c_str());
  return 0;
}

}  // namespace xi::cli
