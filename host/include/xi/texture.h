// Texture images: decoding (stb_image: PNG, JPEG, BMP, TGA, GIF...) to 8-bit RGBA, the way both
// the glTF reader and JSON scenes load them.
#pragma once
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

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

}  // namespace xi
