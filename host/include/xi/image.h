// Linear RGB float images and their files: OpenEXR (float channels, layers, attributes) and PNG.
// Writers go through a temporary file in the same folder and rename it, so a failure never leaves
// a half-written image behind.
#pragma once
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <variant>
#include <vector>

#include <glm/glm.hpp>

#include "xi/view.h"

namespace xi {

struct Image {
  int width = 0;
  int height = 0;
  std::vector<glm::vec3> pixels;  // row-major, top row first
  Image() = default;
  Image(int w, int h) : width(w), height(h), pixels((size_t)w * h, glm::vec3(0.0f)) {}
  glm::vec3& at(int x, int y) { return pixels[(size_t)y * width + x]; }
  const glm::vec3& at(int x, int y) const { return pixels[(size_t)y * width + x]; }
};

using ExrAttribute = std::variant<int, float, double, std::string>;
using ExrAttributes = std::map<std::string, ExrAttribute>;

// One layer of an EXR file: "" is the main R, G, B; others are written as name.R, name.G, name.B.
struct ExrLayer {
  std::string name;
  const Image* image = nullptr;
};

void write_exr(const std::filesystem::path& path, const std::vector<ExrLayer>& layers,
               const ExrAttributes& attributes = {});
// Reads one layer (default: the main R, G, B). Throws xi::Error naming the file and what is missing.
Image read_exr(const std::filesystem::path& path, const std::string& layer = "");
ExrAttributes read_exr_attributes(const std::filesystem::path& path);

// 8-bit sRGB PNG: each pixel scaled by `exposure`, shown through `view` (View::Standard: clipped
// to [0, 1]), then sRGB-encoded (display_pixel in view.h).
void write_png(const std::filesystem::path& path, const Image& image, float exposure = 1.0f,
               View view = View::Standard);
// 8-bit RGBA PNG of texels as TextureImage holds them (red in the low byte, top row first), the
// bytes unchanged.
void write_png_rgba8(const std::filesystem::path& path, int width, int height, const std::vector<uint32_t>& texels);
// Reads an 8-bit RGB(A) PNG back as sRGB-decoded linear values (for tests and `xi diff`).
Image read_png(const std::filesystem::path& path);

// Writes to a temporary file beside `path` via `write`, then renames it over `path`.
void write_atomically(const std::filesystem::path& path,
                      const std::function<void(const std::filesystem::path& tmp)>& write);

}  // namespace xi
