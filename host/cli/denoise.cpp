// `xi denoise IN.exr OUT.exr`: an EXR's R, G, B denoised with its albedo and normal layers, every
// other channel and attribute copied through, the colour read kept as layer `noisy`.
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfDoubleAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfPartType.h>
#include <OpenEXR/ImfStringAttribute.h>

#include "cli.h"
#include "xi/denoise.h"
#include "xi/device.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/metrics.h"

namespace xi::cli {
namespace {

namespace fs = std::filesystem;

// One channel of the file in its own pixel type, to be written back unchanged.
struct Channel {
  std::string name;
  Imf::Channel format;
  std::vector<char> data;  // width × height values of format.type
};

size_t value_bytes(Imf::PixelType type) { return type == Imf::HALF ? sizeof(Imath::half) : 4; }

float value_at(const Channel& c, size_t i) {
  const char* p = c.data.data() + i * value_bytes(c.format.type);
  if (c.format.type == Imf::HALF) return float(*reinterpret_cast<const Imath::half*>(p));
  if (c.format.type == Imf::UINT) return float(*reinterpret_cast<const uint32_t*>(p));
  return *reinterpret_cast<const float*>(p);
}

// The file as read: its header, every channel, and R, G, B, albedo and normal as images.
struct ExrContents {
  Imf::Header header;
  Imath::Box2i window;
  int width = 0, height = 0;
  std::vector<Channel> channels;
  Image color;
  std::optional<Image> albedo, normal;

  const Channel* find(const std::string& name) const {
    for (const Channel& c : channels)
      if (c.name == name) return &c;
    return nullptr;
  }
  // A layer's three channels ("" is R, G, B) as an image; none unless all three are there.
  std::optional<Image> layer(const std::string& prefix) const {
    const Channel* rgb[3];
    for (int c = 0; c < 3; ++c)
      if (!(rgb[c] = find(prefix + "RGB"[c]))) return std::nullopt;
    Image image(width, height);
    for (size_t i = 0; i < image.pixels.size(); ++i)
      for (int c = 0; c < 3; ++c) image.pixels[i][c] = value_at(*rgb[c], i);
    return image;
  }
};

// A slice of `channel` for a frame buffer: OpenEXR addresses pixels by their data-window coordinates.
Imf::Slice slice(const Imath::Box2i& window, int width, Imf::PixelType type, char* data) {
  const size_t xs = value_bytes(type), ys = xs * (size_t)width;
  return Imf::Slice(type, data - window.min.x * (ptrdiff_t)xs - window.min.y * (ptrdiff_t)ys, xs, ys);
}

ExrContents read_contents(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw Error("no such EXR file", path.string());
  ExrContents in;
  try {
    Imf::InputFile file(path.c_str());
    in.header = file.header();
    in.window = in.header.dataWindow();
    in.width = in.window.max.x - in.window.min.x + 1;
    in.height = in.window.max.y - in.window.min.y + 1;
    const Imf::ChannelList& list = in.header.channels();
    for (auto it = list.begin(); it != list.end(); ++it) {
      const Imf::Channel& c = it.channel();
      if (c.xSampling != 1 || c.ySampling != 1)
        throw Error("channel '" + std::string(it.name()) + "' is stored at " + std::to_string(in.width / c.xSampling) +
                        "x" + std::to_string(in.height / c.ySampling) + " but the image is " +
                        std::to_string(in.width) + "x" + std::to_string(in.height) +
                        ": xi denoise needs every layer at the image's size",
                    path.string());
      in.channels.push_back({it.name(), c, std::vector<char>((size_t)in.width * in.height * value_bytes(c.type))});
    }
    Imf::FrameBuffer fb;
    for (Channel& c : in.channels) fb.insert(c.name, slice(in.window, in.width, c.format.type, c.data.data()));
    file.setFrameBuffer(fb);
    file.readPixels(in.window.min.y, in.window.max.y);
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(std::string("cannot read EXR: ") + e.what(), path.string());
  }
  if (in.find("noisy.R"))
    throw Error("already denoised: it has a noisy layer (its R, G, B are denoised)", path.string());
  std::optional<Image> color = in.layer("");
  if (!color) throw Error("the EXR has no R, G, B channels to denoise", path.string());
  in.color = std::move(*color);
  in.albedo = in.layer("albedo.");
  in.normal = in.layer("normal.");
  return in;
}

// The guides the file gives OIDN, and a warning for what it lacks (OIDN takes a normal only with
// an albedo).
void choose_guides(ExrContents& in, const fs::path& path) {
  const char* lack = nullptr;
  if (!in.albedo && !in.normal) lack = "has no albedo and normal layers: denoising its colour alone";
  else if (!in.albedo) lack = "has a normal but no albedo layer: denoising its colour alone (OIDN needs both)";
  else if (!in.normal) lack = "has no normal layer: denoising with its albedo alone";
  if (!in.albedo) in.normal.reset();
  if (lack) std::fprintf(stderr, "xi: warning: %s %s, so the result keeps less detail\n", path.string().c_str(), lack);
}

// OUT: the input's header and channels, R, G, B (float) replaced by the denoised colour, the
// colour read kept bit for bit as noisy.R, noisy.G, noisy.B, and the denoiser's time and name.
void write_contents(const fs::path& path, const ExrContents& in, const Image& denoised, const Denoiser& denoiser) {
  Imf::Header header = in.header;
  // One scan-line part, whatever the input's layout was.
  header.erase("tiles");
  header.erase("chunkCount");
  if (header.hasType()) header.setType(Imf::SCANLINEIMAGE);
  Imf::ChannelList channels;
  Imf::FrameBuffer fb;
  char* base = const_cast<char*>(reinterpret_cast<const char*>(denoised.pixels.data()));
  const size_t xs = sizeof(glm::vec3), ys = xs * (size_t)in.width;
  for (int c = 0; c < 3; ++c) {
    const std::string name(1, "RGB"[c]);
    channels.insert(name, Imf::Channel(Imf::FLOAT));
    fb.insert(name, Imf::Slice(Imf::FLOAT, base + c * sizeof(float) - in.window.min.x * (ptrdiff_t)xs -
                                               in.window.min.y * (ptrdiff_t)ys,
                               xs, ys));
  }
  for (const Channel& c : in.channels) {
    const bool color = c.name == "R" || c.name == "G" || c.name == "B";
    const std::string name = color ? "noisy." + c.name : c.name;
    channels.insert(name, c.format);
    fb.insert(name, slice(in.window, in.width, c.format.type, const_cast<char*>(c.data.data())));
  }
  header.channels() = channels;
  header.insert("denoiseSeconds", Imf::DoubleAttribute(denoiser.last_seconds()));
  header.insert("denoiser", Imf::StringAttribute(denoiser.description()));
  write_atomically(path, [&](const fs::path& tmp) {
    Imf::OutputFile file(tmp.c_str(), header);
    file.setFrameBuffer(fb);
    file.writePixels(in.height);
  });
}

}  // namespace

const Command kDenoise = {
    .name = "denoise",
    .operands = "IN.exr OUT.exr",
    .about = "denoise a render with Intel Open Image Denoise 2 (OIDN), guided\n"
             "by its albedo and normal layers (each denoised first); OUT keeps\n"
             "every layer and attribute, the colour read going to layer noisy.\n"
             "OIDN is loaded at run time: `bash scripts/install-deps.sh --denoise`\n"
             "installs it, or XI_OIDN_PATH names its folder",
    .flags = {
        {"--device", "D",
         "denoise on OIDN's GPU device that is this OpenCL device, if\n"
         "it has one (default: $XI_DEVICE; else OIDN's CPU device)"},
        {"--denoise-quality", "Q", "as for render"},
        {"--denoise-prefilter", "P", "as for render"},
    },
    .run = denoise,
};

int denoise(const std::vector<std::string>& argv) {
  Args args(argv, kDenoise);
  if (args.positional().size() != 2) throw Error("expected IN.exr OUT.exr", "xi denoise");
  const fs::path in_path = args.positional()[0], out_path = args.positional()[1];
  if (out_path.extension() != ".exr") throw Error("the output must be an .exr file", out_path.string());
  const fs::path out_dir = out_path.has_parent_path() ? out_path.parent_path() : fs::path(".");
  if (!fs::is_directory(out_dir)) throw Error("output folder does not exist", out_path.string());
  if (fs::is_directory(out_path)) throw Error("output is a folder", out_path.string());
  DenoiseOptions options = read_denoise_options(args, nullptr);

  ExrContents in = read_contents(in_path);
  check_finite(in.color, "colour of " + in_path.string());
  if (in.albedo) check_finite(*in.albedo, "albedo layer of " + in_path.string());
  if (in.normal) check_finite(*in.normal, "normal layer of " + in_path.string());

  // OIDN's GPU device if the OpenCL device `xi render` would be given (--device, $XI_DEVICE) is
  // one it has; else, as for a render on the default CPU device, OIDN's CPU device.
  const char* env = std::getenv("XI_DEVICE");
  const std::string selector = args.has("--device") ? args.get("--device") : env ? env : "";
  std::optional<Device> device;
  if (!selector.empty()) device.emplace(Device::open(selector));
  options.render_device = device ? &*device : nullptr;
  Denoiser denoiser(options);
  choose_guides(in, in_path);  // its warning only once nothing can fail before the denoising
  const Image denoised = denoiser.run(in.color, in.albedo ? &*in.albedo : nullptr, in.normal ? &*in.normal : nullptr);
  write_contents(out_path, in, denoised, denoiser);
  std::printf("denoised %s with %s in %.2f s: wrote %s\n", in_path.string().c_str(), denoiser.description().c_str(),
              denoiser.last_seconds(), out_path.string().c_str());
  return 0;
}

DenoiseOptions read_denoise_options(const Args& args, Device* device) {
  DenoiseOptions o;
  o.render_device = device;
  o.quality = parse_denoise_quality(args.get("--denoise-quality", "high"));
  o.prefilter = parse_denoise_prefilter(args.get("--denoise-prefilter", "accurate"));
  return o;
}

}  // namespace xi::cli
