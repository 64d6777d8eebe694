// Scenes from asset files (glTF, GLB, OBJ, PLY, 3DS...: whatever Assimp reads) read through
// Assimp's scene graph: node transforms, cameras and materials as the file gives them. Format notes
// in README.md.
#pragma once
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "xi/scene.h"

namespace xi {

// Where the automatic framing of a file without a camera looks from, in degrees: yaw about +y (0:
// from +z, the glTF front; 90: from +x), pitch the elevation above the horizontal (within (-90, 90)).
struct Orbit {
  double yaw = 0.0;
  double pitch = 15.0;  // as model-viewer's default orbit, 75 degrees from the pole
};

struct AssetOptions {
  std::string camera;  // a camera's name or index; empty: the file's first perspective camera
  // The automatic framing's direction (default: Orbit{}); an error when the file's camera is used.
  std::optional<Orbit> orbit;
  int height = 512;  // film height; the width follows the camera's aspect ratio
  // What lights a file with no light of its own: this map, else the bundled sky unless `sky` is
  // false (then the scene's constant background alone, black unless the caller sets it).
  std::optional<Environment> environment;
  bool sky = true;
};

// Whether a scene file is read through Assimp: every one but a .json scene (any case). load_asset
// refuses an extension Assimp has no importer for, naming the file and listing asset_extensions().
bool is_asset_file(const std::filesystem::path& path);
// The extensions Assimp reads (".3ds", ".obj", ...), in its order.
std::vector<std::string> asset_extensions();

// A whole scene from an asset file. Camera: the chosen one, or without one, the bounding sphere
// framed from AssetOptions::orbit (looking at its centre, up +y, vfov 40, the sphere filling the
// frame's height). No light of any kind (emissive material, punctual light): lit by
// AssetOptions::environment, else the bundled sky (unless AssetOptions::sky is false).
// Both decisions are stated in Scene::notes; what xi does not model is in Scene::warnings.
// Throws xi::Error naming the file (and, for an unknown camera, listing the file's cameras).
Scene load_asset(const std::filesystem::path& path, const AssetOptions& options = {});

// An asset's shapes and materials in the file's world space (node transforms applied once), for
// the JSON scene's "asset" shape. Triangle::material indexes `materials` (only the used ones).
struct AssetGeometry : Mesh {
  std::vector<Material> materials;
  std::vector<TextureImage> images;  // the materials' textures (TextureSlot::image indexes them)
  std::vector<Light> lights;  // punctual lights (glTF's KHR_lights_punctual, through Assimp's aiLight)
  std::vector<std::string> warnings;  // one line per kind of thing xi does not model
};
AssetGeometry load_asset_geometry(const std::filesystem::path& path);

}  // namespace xi
