#include <cmath>
#include <cstdio>
#include <memory>
#include <unistd.h>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfDoubleAttribute.h>
#include <OpenEXR/ImfFloatAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfIntAttribute.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <png.h>

#include "xi/error.h"
#include "xi/image.h"

namespace xi {
namespace {

std::string channel(const std::string& layer, char c) {
  return layer.empty() ? std::string(1, c) : layer + "." + c;
}

float srgb_decode(float v) {
  return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
}

}  // namespace

void write_atomically(const std::filesystem::path& path,
                      const std::function<void(const std::filesystem::path& tmp)>& write) {
  auto tmp = path;
  tmp += ".tmp" + std::to_string(::getpid());
  try {
    write(tmp);
    std::filesystem::rename(tmp, path);
  } catch (const Error&) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  } catch (const std::exception& e) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw Error(std::string("cannot write file: ") + e.what(), path.string());
  }
}

void write_exr(const std::filesystem::path& path, const std::vector<ExrLayer>& layers,
               const ExrAttributes& attributes) {
  if (layers.empty() || !layers[0].image) throw Error("no image to write", path.string());
  const int w = layers[0].image->width, h = layers[0].image->height;
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    Imf::Header header(w, h);
    header.compression() = Imf::ZIP_COMPRESSION;
    Imf::FrameBuffer fb;
    for (auto& layer : layers) {
      if (layer.image->width != w || layer.image->height != h)
        throw Error("EXR layers differ in size", path.string() + ": layer " + layer.name);
      auto* base = const_cast<char*>(reinterpret_cast<const char*>(layer.image->pixels.data()));
      const size_t xs = sizeof(glm::vec3), ys = xs * (size_t)w;
      for (int c = 0; c < 3; ++c) {
        std::string name = channel(layer.name, "RGB"[c]);
        header.channels().insert(name, Imf::Channel(Imf::FLOAT));
        fb.insert(name, Imf::Slice(Imf::FLOAT, base + c * sizeof(float), xs, ys));
      }
    }
    for (auto& [name, value] : attributes) {
      if (auto* i = std::get_if<int>(&value)) header.insert(name, Imf::IntAttribute(*i));
      else if (auto* f = std::get_if<float>(&value)) header.insert(name, Imf::FloatAttribute(*f));
      else if (auto* d = std::get_if<double>(&value)) header.insert(name, Imf::DoubleAttribute(*d));
      else header.insert(name, Imf::StringAttribute(std::get<std::string>(value)));
    }
    Imf::OutputFile file(tmp.c_str(), header);
    file.setFrameBuffer(fb);
    file.writePixels(h);
  });
}

Image read_exr(const std::filesystem::path& path, const std::string& layer) {
  if (!std::filesystem::exists(path)) throw Error("no such EXR file", path.string());
  try {
    Imf::InputFile file(path.c_str());
    Imath::Box2i dw = file.header().dataWindow();
    Image img(dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1);
    Imf::FrameBuffer fb;
    char* base = reinterpret_cast<char*>(img.pixels.data()) -
                 (dw.min.x + (ptrdiff_t)dw.min.y * img.width) * (ptrdiff_t)sizeof(glm::vec3);
    for (int c = 0; c < 3; ++c) {
      std::string name = channel(layer, "RGB"[c]);
      if (!file.header().channels().findChannel(name))
        throw Error("EXR file has no channel '" + name + "'", path.string());
      fb.insert(name, Imf::Slice(Imf::FLOAT, base + c * sizeof(float), sizeof(glm::vec3),
                                 sizeof(glm::vec3) * (size_t)img.width));
    }
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    return img;
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(std::string("cannot read EXR: ") + e.what(), path.string());
  }
}

ExrAttributes read_exr_attributes(const std::filesystem::path& path) {
  ExrAttributes out;
  try {
    Imf::InputFile file(path.c_str());
    for (auto it = file.header().begin(); it != file.header().end(); ++it) {
      const Imf::Attribute& a = it.attribute();
      if (auto* i = dynamic_cast<const Imf::IntAttribute*>(&a)) out[it.name()] = i->value();
      else if (auto* f = dynamic_cast<const Imf::FloatAttribute*>(&a)) out[it.name()] = f->value();
      else if (auto* d = dynamic_cast<const Imf::DoubleAttribute*>(&a)) out[it.name()] = d->value();
      else if (auto* s = dynamic_cast<const Imf::StringAttribute*>(&a)) out[it.name()] = s->value();
    }
  } catch (const std::exception& e) {
    throw Error(std::string("cannot read EXR: ") + e.what(), path.string());
  }
  return out;
}

void write_png(const std::filesystem::path& path, const Image& image, float exposure, View view) {
  std::vector<unsigned char> rgb((size_t)image.width * image.height * 3);
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    const glm::u8vec3 shown = display_pixel(view, image.pixels[i], exposure);
    for (int c = 0; c < 3; ++c) rgb[3 * i + c] = shown[c];
  }
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    png_image img{};
    img.version = PNG_IMAGE_VERSION;
    img.width = (png_uint_32)image.width;
    img.height = (png_uint_32)image.height;
    img.format = PNG_FORMAT_RGB;
    if (!png_image_write_to_file(&img, tmp.c_str(), 0, rgb.data(), 0, nullptr))
      throw Error(std::string("cannot write PNG: ") + img.message, path.string());
  });
}

void write_png_rgba8(const std::filesystem::path& path, int width, int height, const std::vector<uint32_t>& texels) {
  if (width <= 0 || height <= 0 || texels.size() != (size_t)width * height)
    throw Error("cannot write PNG: texel count does not match its size", path.string());
  std::vector<unsigned char> rgba(texels.size() * 4);
  for (size_t i = 0; i < texels.size(); ++i)
    for (int c = 0; c < 4; ++c) rgba[4 * i + c] = (unsigned char)((texels[i] >> (8 * c)) & 0xff);
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    png_image img{};
    img.version = PNG_IMAGE_VERSION;
    img.width = (png_uint_32)width;
    img.height = (png_uint_32)height;
    img.format = PNG_FORMAT_RGBA;
    if (!png_image_write_to_file(&img, tmp.c_str(), 0, rgba.data(), 0, nullptr))
      throw Error(std::string("cannot write PNG: ") + img.message, path.string());
  });
}

Image read_png(const std::filesystem::path& path) {
  png_image img{};
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&img, path.c_str()))
    throw Error(std::string("cannot read PNG: ") + img.message, path.string());
  img.format = PNG_FORMAT_RGB;
  std::vector<unsigned char> rgb(PNG_IMAGE_SIZE(img));
  if (!png_image_finish_read(&img, nullptr, rgb.data(), 0, nullptr))
    throw Error(std::string("cannot read PNG: ") + img.message, path.string());
  Image out((int)img.width, (int)img.height);
  for (size_t i = 0; i < out.pixels.size(); ++i)
    for (int c = 0; c < 3; ++c) out.pixels[i][c] = srgb_decode(rgb[3 * i + c] / 255.0f);
  return out;
}

}  // namespace xi
