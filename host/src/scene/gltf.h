// glTF 2.0 materials, textures and images read from the file's JSON, which Assimp 5.2 reads only in
// part (no KHR_materials_emissive_strength, a texture transform in its own convention, no
// samplers per texture). Meshes, nodes, cameras and lights still come through Assimp.
#pragma once
#include <algorithm>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "xi/scene.h"

namespace xi::scene_detail {

// One line per kind of thing xi does not model (or a file gets wrong), in the order first met.
struct Warnings {
  std::vector<std::string> lines;
  void add(const std::string& line) {
    if (std::find(lines.begin(), lines.end(), line) == lines.end()) lines.push_back(line);
  }
};

struct GltfFile {
  std::filesystem::path path;
  nlohmann::json doc;
  std::string bin;  // a .glb's binary chunk
};
// The file's JSON (a .gltf's text or a .glb's JSON chunk) and a .glb's binary chunk; nullopt when
// it cannot be read here (Assimp has read the file already, so that is not an error).
std::optional<GltfFile> read_gltf(const std::filesystem::path& path);

struct GltfMaterials {
  std::vector<Material> materials;  // one per entry of the file's "materials", in order
  std::vector<TextureImage> images;        // what their TextureSlot::image index
};
// Every material of the file as xi's metallic-roughness material (or glass, or an emitter), with
// its textures decoded. A texture that cannot be used (missing or corrupt image, index out of
// range, an image format xi does not decode) is a warning, and the material uses its factor alone,
// as glTF viewers do.
GltfMaterials gltf_materials(const GltfFile& file, Warnings& warn);

}  // namespace xi::scene_detail
