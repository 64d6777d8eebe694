// The scene as the user described it, in world units, before any device layout.
#pragma once
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <glm/glm.hpp>

namespace xi {

struct Camera {
  glm::vec3 position{0.0f};
  glm::vec3 look_at{0.0f, 0.0f, 1.0f};
  glm::vec3 up{0.0f, 1.0f, 0.0f};
  float vfov_degrees = 45.0f;     // full vertical field of view
  float aperture_radius = 0.0f;   // 0: pinhole
  float focus_distance = 0.0f;    // distance to the plane in focus (thin lens only)
};

enum class MaterialType : uint32_t { Diffuse = 0, Mirror = 1, Dielectric = 2 };

struct Material {
  std::string name;
  MaterialType type = MaterialType::Diffuse;
  glm::vec3 albedo{0.0f};    // diffuse reflectance, or the tint of a mirror / glass
  glm::vec3 emission{0.0f};  // emitted radiance (front face, or both with two_sided)
  float ior = 1.5f;          // dielectric only
  bool two_sided = false;    // emission from both faces
  bool is_emitter() const { return emission.x > 0.0f || emission.y > 0.0f || emission.z > 0.0f; }
};

struct Triangle {
  glm::vec3 v[3];
  glm::vec3 n[3];            // per-vertex shading normals, valid when has_normals
  bool has_normals = false;
  uint32_t material = 0;     // index into Scene::materials
};

// Defaults for `xi render`; command-line flags override them.
struct RenderSettings {
  int spp = 64;
  int max_depth = 8;
  uint32_t seed = 0;
  std::string sampler = "sobol";
};

struct Scene {
  std::string source;  // the file it came from, for messages
  Camera camera;
  int width = 512;
  int height = 512;
  glm::vec3 background{0.0f};  // radiance of rays that leave the scene
  RenderSettings render;
  std::vector<Material> materials;
  std::vector<Triangle> triangles;
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
// Throws xi::Error if the scene breaks the limits within which single precision stays finite: a
// vertex not finite or beyond +-1e9, geometry spanning less than 1e-6, a negative or non-finite
// radiance (emitters, background). The loaders check these where they read them; compile_scene
// checks them again for scenes built in code.
void check_scene_limits(const Scene& scene);

}  // namespace xi
