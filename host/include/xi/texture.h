// Texture images: decoding (stb_image: PNG, JPEG, BMP, TGA, GIF...) to 8-bit RGBA, the way both
// the glTF reader and JSON scenes load them.
#pragma once
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "xi/scene.h"

namespace xi {

// The largest side of a texture image. Beyond, the texel offsets of one buffer for every image
// near 2^32 bytes, and no real asset needs more.
constexpr int kMaxTextureSide = 16384;

// Decodes an encoded image held in memory. `source` names it in messages. Throws xi::Error naming
// the source and what is wrong (not an image stb_image reads, truncated, too large, empty).
TextureImage decode_image(const std::vector<uint8_t>& bytes, const std::string& source, bool srgb);
// Reads and decodes an image file. Throws xi::Error naming the file.
TextureImage load_image_file(const std::filesystem::path& path, bool srgb);

// KHR_texture_transform as a TextureSlot::transform: translation(offset) · rotation · scale, applied
// to (u, v, 1) in glTF's convention (v down). A positive rotation turns the coordinates
// counter-clockwise as drawn on the image (u right, v down): u' = cos·u + sin·v, v' = −sin·u + cos·v
// before the offset. This is what the extension's sample model (TextureTransformTest), Blender,
// Babylon.js and three.js do; the GLSL listing in the extension's text has the transpose. The glTF
// reader and JSON scenes both build it here.
glm::mat3 texture_transform(glm::vec2 offset, float rotation_radians, glm::vec2 scale);

}  // namespace xi
