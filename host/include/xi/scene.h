// The scene as the user described it, in world units, before any device layout.
#pragma once
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <glm/glm.hpp>

#include "layout.h"  // XI_TEXTURE_*: a material's texture slots

namespace xi {

struct Camera {
  glm::vec3 position{0.0f};
  glm::vec3 look_at{0.0f, 0.0f, 1.0f};
  glm::vec3 up{0.0f, 1.0f, 0.0f};
  float vfov_degrees = 45.0f;     // full vertical field of view
  float aperture_radius = 0.0f;   // 0: pinhole
  float focus_distance = 0.0f;    // distance to the plane in focus (thin lens only)
};

enum class MaterialType : uint32_t { Diffuse = 0, Mirror = 1, Dielectric = 2, Pbr = 3 };
enum class AlphaMode : uint32_t { Opaque = 0, Mask = 1, Blend = 2 };
enum class Wrap : uint32_t { Repeat = 0, Clamp = 1, Mirror = 2 };

// An image a material reads, decoded to 8-bit RGBA (red in the low byte of each texel).
struct TextureImage {
  std::string source;  // file, or "<model>: image N" for an embedded one, for messages
  int width = 0, height = 0;
  bool srgb = true;    // colour (sRGB-encoded) or data (metallic-roughness, normals)
  std::vector<uint32_t> texels;  // row 0 first: the top row, where texture coordinate v is 0
};

// One use of an image by a material: which texture coordinates, how they wrap, and glTF's
// KHR_texture_transform, as a matrix applied to (u, v, 1) in the file's convention (v down).
struct TextureSlot {
  int image = -1;  // index into Scene::images; -1: none
  int texcoord = 0;
  Wrap wrap_s = Wrap::Repeat, wrap_t = Wrap::Repeat;
  glm::mat3 transform{1.0f};
  bool used() const { return image >= 0; }
};

// The texture slots, indexed by XI_TEXTURE_*: the key a scene file and `xi export` use for each,
// and whether its image is colour (sRGB) or data.
struct TextureSlotInfo {
  const char* key;
  bool srgb;
};
inline constexpr TextureSlotInfo kTextureSlots[XI_TEXTURE_SLOTS] = {
    {"base_color_texture", true},           // diffuse too
    {"metallic_roughness_texture", false},  // G: roughness, B: metallic
    {"normal_texture", false},              // tangent space
    {"emissive_texture", true},
    {"clearcoat_texture", false},            // R: the coat's weight
    {"clearcoat_roughness_texture", false},  // G: its roughness
    {"sheen_color_texture", true},
    {"sheen_roughness_texture", false},      // A
    {"specular_texture", false},             // A: the specular layer's strength
    {"specular_color_texture", true},
    {"clearcoat_normal_texture", false},     // tangent space: the coat's own normal
    {"anisotropy_texture", false},           // RG: a direction in tangent space, B: the strength
    {"iridescence_texture", false},          // R: the film's weight
    {"iridescence_thickness_texture", false},  // G: the film's thickness from its minimum to its maximum
};

struct Material {
  std::string name;
  MaterialType type = MaterialType::Diffuse;
  glm::vec3 albedo{0.0f};    // diffuse reflectance, the tint of a mirror / glass, the base colour (pbr)
  glm::vec3 emission{0.0f};  // emitted radiance (front face, or both with two_sided); times the emissive texture
  float ior = 1.5f;          // dielectric and pbr
  bool two_sided = false;    // emission from both faces
  // The glTF 2.0 metallic-roughness model (type Pbr): factors, multiplied by their textures.
  float metallic = 0.0f;
  float roughness = 1.0f;    // perceptual: the microfacet distribution's alpha is roughness²
  float transmission = 0.0f;
  float normal_scale = 1.0f;
  // KHR_materials_specular: the dielectric layer's f0 tint and strength (its F0 and F90).
  glm::vec3 specular_color{1.0f};
  float specular = 1.0f;
  // KHR_materials_clearcoat: a dielectric coat (ior 1.5) over the material, its weight and roughness;
  // its normal is the interpolated one, normal-mapped by its own texture only.
  float clearcoat = 0.0f;
  float clearcoat_roughness = 0.0f;
  float clearcoat_normal_scale = 1.0f;
  // KHR_materials_sheen: fibres over the material, their colour (0: none) and roughness.
  glm::vec3 sheen_color{0.0f};
  float sheen_roughness = 0.0f;
  // KHR_materials_anisotropy: the base's microfacets stretched along a direction in the tangent
  // plane, anisotropy_rotation radians counter-clockwise from the tangent (the texture's direction
  // where it has one): the alpha along it rises from roughness² towards 1 with the strength squared.
  float anisotropy_strength = 0.0f;
  float anisotropy_rotation = 0.0f;
  // KHR_materials_iridescence: a thin dielectric film over the base, its weight (0: none), ior and
  // thickness in nanometres (the maximum, or from the minimum to the maximum by the thickness
  // texture's G).
  float iridescence = 0.0f;
  float iridescence_ior = 1.3f;
  float iridescence_thickness_minimum = 100.0f;
  float iridescence_thickness_maximum = 400.0f;
  // KHR_materials_volume: a transmissive mesh's inside absorbs, Beer–Lambert: light that travels
  // attenuation_distance in it keeps attenuation_color of itself (infinite distance: clear).
  glm::vec3 attenuation_color{1.0f};
  float attenuation_distance = std::numeric_limits<float>::infinity();
  // σa per unit length, −ln(attenuation_color) / attenuation_distance (0: no volume).
  glm::vec3 volume_absorption() const {
    if (type != MaterialType::Pbr || transmission <= 0.0f || !std::isfinite(attenuation_distance)) return glm::vec3(0.0f);
    return -glm::log(glm::max(attenuation_color, glm::vec3(1e-6f))) / attenuation_distance;
  }
  float alpha = 1.0f;        // the base colour's alpha factor
  AlphaMode alpha_mode = AlphaMode::Opaque;
  float alpha_cutoff = 0.5f;
  std::array<TextureSlot, XI_TEXTURE_SLOTS> textures;  // indexed by XI_TEXTURE_* (kTextureSlots)
  bool has_textures() const {
    for (const TextureSlot& t : textures)
      if (t.used()) return true;
    return false;
  }
  bool is_emitter() const {
    return emission.x > 0.0f || emission.y > 0.0f || emission.z > 0.0f;
  }
  bool cuts_out() const { return alpha_mode != AlphaMode::Opaque; }
};

// A triangle's texture coordinates, sets 0 and 1, as the file has them (v down), and the file's
// tangents (glTF TANGENT): xyz along increasing u of the normal map's coordinates, w the bitangent's
// sign (bitangent = w · normal × tangent), all 0 where the file has none. Kept beside the triangles
// rather than in them: large scanned meshes have none, and they are four times a triangle's bytes.
struct TriangleTexcoords {
  glm::vec2 uv[2][3] = {};
  glm::vec4 tangent[3] = {};
};
constexpr uint32_t kNoTexcoords = 0xffffffffu;

// A corner of one or more triangles: its position and its shading normal (zero where it has none;
// read for the triangles with has_normals).
struct Vertex {
  glm::vec3 position{0.0f};
  glm::vec3 normal{0.0f};
};

struct Triangle {
  uint32_t v[3] = {0, 0, 0};  // its corners: indices into Mesh::vertices, counter-clockwise from the front
  uint32_t material = 0;      // index into Scene::materials
  // Index into the texcoords beside the triangles (Mesh::texcoords), each entry one triangle's
  // own; kNoTexcoords: all zero.
  uint32_t texcoords = kNoTexcoords;
  bool has_normals = false;   // shaded with its vertices' normals, else flat
};

// Triangles over shared vertices, as mesh files store them: a vertex is held once however many
// triangles meet there.
struct Mesh {
  std::vector<Vertex> vertices;
  std::vector<Triangle> triangles;
  std::vector<TriangleTexcoords> texcoords;  // Triangle::texcoords indexes it

  const glm::vec3& position(const Triangle& t, int corner) const { return vertices[t.v[corner]].position; }
  const glm::vec3& normal(const Triangle& t, int corner) const { return vertices[t.v[corner]].normal; }
  // Appends a triangle over three vertices of its own (with these normals, where given) and
  // returns it (valid until the next triangle is added).
  Triangle& add_triangle(const glm::vec3& a, const glm::vec3& b, const glm::vec3& c, uint32_t material = 0,
                         const glm::vec3* normals = nullptr);
  // Appends another mesh's vertices and triangles (its texture coordinates too), their material
  // indices offset by first_material.
  void append(Mesh&& other, uint32_t first_material = 0);
  // The bounding box of the triangles' corners, {lo, hi} (lo > hi where there are none).
  std::pair<glm::vec3, glm::vec3> bounds() const;
};

// Punctual lights, reached by light sampling only. Units as glTF's KHR_lights_punctual: a point or
// spot light's intensity is radiant intensity (glTF: candela), giving irradiance I / r² facing it;
// a directional light's is irradiance (glTF: lux). A sun is a directional light whose angular
// radius > 0 spreads it over a cone of directions, so its shadows are soft.
enum class LightType : uint32_t { Point = 0, Spot = 1, Directional = 2 };
struct Light {
  std::string name;
  LightType type = LightType::Point;
  glm::vec3 position{0.0f};
  glm::vec3 direction{0.0f, 0.0f, -1.0f};  // where it shines (spot, directional)
  glm::vec3 intensity{1.0f};               // colour × intensity
  float inner_cone = 0.0f, outer_cone = 0.7853982f;  // spot, radians from the axis
  float angular_radius = 0.0f;             // directional: 0 is a delta direction, > 0 a sun
};

// An equirectangular map of radiance around the scene (Mitsuba 3's orientation, +y up), scaled by
// strength and turned about +y by rotation_degrees.
struct Environment {
  std::filesystem::path file;
  float strength = 1.0f;
  float rotation_degrees = 0.0f;
};

// AlbedoScaling: the base gets what the specular layer does not reflect (as Blender's Principled
// BSDF and OpenPBR); FresnelMix: the base weighed by the Fresnel transmittance both ways.
enum class Layering { AlbedoScaling, FresnelMix };
Layering parse_layering(const std::string& name);  // "albedo-scaling" or "fresnel-mix"; throws Error
const char* layering_name(Layering layering);

// Defaults for `xi render`; command-line flags override them.
struct RenderSettings {
  int spp = 64;
  int max_depth = 8;
  uint32_t seed = 0;
  std::string sampler = "sobol";
  // Multiple scattering restored to the metal and the dielectric layer (microfacet.h, Kulla–Conty);
  // false: single-scattering GGX, as Mitsuba 3's and pbrt-v4's.
  bool multiple_scattering = true;
  // How the metallic-roughness material's dielectric layer weighs the diffuse base (microfacet.h).
  Layering layering = Layering::AlbedoScaling;
};

// A scene's geometry is one indexed mesh (its base): every shape's vertices and triangles.
struct Scene : Mesh {
  std::string source;  // the file it came from, for messages
  Camera camera;
  int width = 512;
  int height = 512;
  glm::vec3 background{0.0f};  // radiance of rays that leave the scene
  RenderSettings render;
  std::optional<Environment> environment;  // replaces the background where set
  std::vector<Material> materials;
  std::vector<TextureImage> images;
  std::vector<Light> lights;
  std::vector<std::string> notes;     // what the loader chose for the user (camera, framing, background)
  std::vector<std::string> warnings;  // what xi does not model and how it was mapped, one line per kind
};

// Reads a JSON scene file (format in README.md), or an asset file (.gltf, .glb, .obj, .ply...: see
// is_asset_file) with load_asset's default options. Meshes are resolved relative to the file.
// Throws xi::Error naming the file and the JSON path of the offending field.
Scene load_scene(const std::filesystem::path& path);
// Same, from text already in memory; base_dir resolves mesh paths.
Scene parse_scene(const std::string& json_text, const std::string& source_name,
                  const std::filesystem::path& base_dir);
// A file shipped in xi's scenes/ folder (the Cornell box, the sky): beside the program, where it
// is installed, or in the source tree. Throws xi::Error naming the file if it is in none.
std::filesystem::path bundled_scene_file(const std::string& name);
// Throws xi::Error if the scene breaks the limits within which single precision stays finite: a
// vertex not finite or beyond +-1e9, geometry spanning less than 1e-6, a negative or non-finite
// radiance (emitters, background); or a triangle names a vertex or texture coordinates it does not
// have. The loaders check these where they read them; compile_scene checks them again for scenes
// built in code.
void check_scene_limits(const Scene& scene);

// Triangle t's texture coordinates and tangents in `pool` (zero where it has none; its index is
// within the pool, as check_scene_limits makes sure).
const TriangleTexcoords& texcoords_of(const std::vector<TriangleTexcoords>& pool, const Triangle& t);

}  // namespace xi
