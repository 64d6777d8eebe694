#include "xi/texture.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <memory>

#include <stb/stb_image.h>

#include "xi/error.h"

namespace xi {

TextureImage decode_image(const std::vector<uint8_t>& bytes, const std::string& source, bool srgb) {
  if (bytes.empty()) throw Error("texture image is empty", source);
  if (bytes.size() > size_t(INT32_MAX)) throw Error("texture image is over 2 GiB", source);
  int w = 0, h = 0, channels = 0;
  if (!stbi_info_from_memory(bytes.data(), int(bytes.size()), &w, &h, &channels))
    throw Error(std::string("cannot decode texture image: ") + stbi_failure_reason() +
                    " (xi reads PNG, JPEG, BMP, TGA, GIF, PSD, PIC and PNM images)",
                source);
  if (w < 1 || h < 1 || w > kMaxTextureSide || h > kMaxTextureSide)
    throw Error("texture image is " + std::to_string(w) + "x" + std::to_string(h) + "; xi takes sides of 1 to " +
                    std::to_string(kMaxTextureSide) + " texels",
                source);
  std::unique_ptr<stbi_uc, void (*)(void*)> pixels(
      stbi_load_from_memory(bytes.data(), int(bytes.size()), &w, &h, &channels, 4), stbi_image_free);
  if (!pixels) throw Error(std::string("cannot decode texture image: ") + stbi_failure_reason(), source);
  TextureImage img;
  img.source = source;
  img.width = w;
  img.height = h;
  img.srgb = srgb;
  img.texels.resize(size_t(w) * h);
  std::memcpy(img.texels.data(), pixels.get(), img.texels.size() * 4);  // RGBA bytes: red lowest on little-endian
  return img;
}

TextureImage load_image_file(const std::filesystem::path& path, bool srgb) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  if (!in || !std::filesystem::is_regular_file(path, ec)) throw Error("texture image not found", path.string());
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return decode_image(bytes, path.string(), srgb);
}

glm::mat3 texture_transform(glm::vec2 offset, float rotation_radians, glm::vec2 scale) {
  const float c = std::cos(rotation_radians), s = std::sin(rotation_radians);
  // Columns of a glm::mat3, as GLSL writes them.
  const glm::mat3 translation(1, 0, 0, 0, 1, 0, offset.x, offset.y, 1);
  const glm::mat3 rotation(c, -s, 0, s, c, 0, 0, 0, 1);
  const glm::mat3 scaling(scale.x, 0, 0, 0, scale.y, 0, 0, 0, 1);
  return translation * rotation * scaling;
}

}  // namespace xi
