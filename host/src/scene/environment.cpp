#include "xi/environment.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <memory>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <stb/stb_image.h>

#include "geometry.h"
#include "xi/error.h"

namespace xi {
namespace {

using scene_detail::lower_extension;

// Every nonzero weight is kept at no less than this share of its CDF's total, so that in float
// (steps of 2^-24 below 1) its CDF difference stays positive (environment.h).
constexpr double kMinShare = 0x1p-20;

void check_size(long long w, long long h, const std::string& where) {
  if (w <= 0 || h <= 0) throw Error("the environment map is empty (" + std::to_string(w) + "×" + std::to_string(h) + ")", where);
  if (w > kEnvironmentMaxWidth || h > kEnvironmentMaxHeight)
    throw Error("the environment map is " + std::to_string(w) + "×" + std::to_string(h) + ", larger than the " +
                    std::to_string(kEnvironmentMaxWidth) + "×" + std::to_string(kEnvironmentMaxHeight) +
                    " accepted (beyond it the texels alone take over 2 GiB of device memory); downscale it",
                where);
}

// stb_image reads past the end of a truncated RGBE file without a word (repeating the last pixel,
// or looping for ever on a zero-length literal run), so the data is walked here first, the way stb
// decodes it: if the first scanline starts with the new-style run-length marker (2, 2, width) and
// 8 ≤ width < 32768, every scanline is run-length encoded; otherwise the file holds 4·W·H flat
// bytes. Throws naming the first row whose data is missing or malformed.
void check_hdr_body(const std::filesystem::path& path, int w, int h) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw Error("cannot open the environment map", path.string());
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> guard(f, std::fclose);
  std::vector<unsigned char> data;
  unsigned char buf[65536];
  for (size_t got; (got = std::fread(buf, 1, sizeof buf, f)) > 0;) data.insert(data.end(), buf, buf + got);
  // The header ends with an empty line; the resolution line follows it.
  size_t at = 0;
  while (at + 1 < data.size() && !(data[at] == '\n' && data[at + 1] == '\n')) ++at;
  at += 2;
  while (at < data.size() && data[at] != '\n') ++at;
  at = std::min(at + 1, data.size());
  auto bad_row = [&](int y) {
    return Error("truncated or corrupt Radiance HDR file: the data of row " + std::to_string(y) + " of " +
                     std::to_string(h) + " is missing or malformed",
                 path.string());
  };
  auto rle_marker = [&] {
    return at + 4 <= data.size() && data[at] == 2 && data[at + 1] == 2 && !(data[at + 2] & 0x80);
  };
  if (w < 8 || w >= 32768 || !rle_marker()) {
    size_t need = (size_t)4 * w * h;
    if (data.size() - at < need) throw bad_row((int)((data.size() - at) / ((size_t)4 * w)));
    return;
  }
  for (int y = 0; y < h; ++y) {
    if (!rle_marker() || (data[at + 2] << 8 | data[at + 3]) != w) throw bad_row(y);
    at += 4;
    for (int c = 0; c < 4; ++c)
      for (int x = 0; x < w;) {
        if (at >= data.size()) throw bad_row(y);
        int count = data[at++];
        size_t bytes = count > 128 ? 1 : (size_t)count;
        count = count > 128 ? count - 128 : count;
        if (count == 0 || x + count > w || data.size() - at < bytes) throw bad_row(y);
        at += bytes;
        x += count;
      }
  }
}

std::vector<glm::vec4> read_hdr(const std::filesystem::path& path, int& w, int& h) {
  const std::string where = path.string();
  int n = 0;
  if (!stbi_is_hdr(path.c_str()))
    throw Error("not a Radiance HDR (RGBE) file: its header is missing or corrupt", where);
  if (!stbi_info(path.c_str(), &w, &h, &n)) {
    const char* why = stbi_failure_reason();
    throw Error(std::string("corrupt Radiance HDR file: ") + (why ? why : "unreadable header"), where);
  }
  check_size(w, h, where);
  check_hdr_body(path, w, h);
  std::unique_ptr<float, void (*)(void*)> data(stbi_loadf(path.c_str(), &w, &h, &n, 3), stbi_image_free);
  if (!data) {
    const char* why = stbi_failure_reason();
    throw Error(std::string("corrupt Radiance HDR file: ") + (why ? why : "cannot decode it"), where);
  }
  std::vector<glm::vec4> texels((size_t)w * h);
  const float* p = data.get();
  for (size_t i = 0; i < texels.size(); ++i) texels[i] = glm::vec4(p[3 * i], p[3 * i + 1], p[3 * i + 2], 0.0f);
  return texels;
}

std::vector<glm::vec4> read_exr_texels(const std::filesystem::path& path, int& w, int& h) {
  const std::string where = path.string();
  try {
    Imf::InputFile file(path.c_str());
    Imath::Box2i dw = file.header().dataWindow();
    long long lw = (long long)dw.max.x - dw.min.x + 1, lh = (long long)dw.max.y - dw.min.y + 1;
    check_size(lw, lh, where);
    w = (int)lw;
    h = (int)lh;
    const Imf::ChannelList& channels = file.header().channels();
    bool rgb = channels.findChannel("R") && channels.findChannel("G") && channels.findChannel("B");
    bool grey = !rgb && channels.findChannel("Y");
    if (!rgb && !grey) throw Error("OpenEXR file has neither R, G, B nor Y channels", where);
    std::vector<glm::vec4> texels((size_t)w * h, glm::vec4(0.0f));
    char* base = reinterpret_cast<char*>(texels.data()) - (dw.min.x + (ptrdiff_t)dw.min.y * w) * (ptrdiff_t)sizeof(glm::vec4);
    const size_t xs = sizeof(glm::vec4), ys = xs * (size_t)w;
    Imf::FrameBuffer fb;
    if (rgb) {
      for (int c = 0; c < 3; ++c) fb.insert(std::string(1, "RGB"[c]), Imf::Slice(Imf::FLOAT, base + c * sizeof(float), xs, ys));
    } else {
      fb.insert("Y", Imf::Slice(Imf::FLOAT, base, xs, ys));
    }
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    if (grey)
      for (auto& t : texels) t = glm::vec4(t.x, t.x, t.x, 0.0f);
    return texels;
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(std::string("corrupt or unreadable OpenEXR file: ") + e.what(), where);
  }
}

void check_texels(int w, int h, const std::vector<glm::vec4>& texels, const std::string& where) {
  check_size(w, h, where);
  if (texels.size() != (size_t)w * h)
    throw Error("the environment map has " + std::to_string(texels.size()) + " texels, not " + std::to_string(w) + "×" + std::to_string(h), where);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const glm::vec4& t = texels[(size_t)y * w + x];
      for (int c = 0; c < 3; ++c) {
        if (!std::isfinite(t[c]) || t[c] < 0.0f) {
          char buf[200];
          const char* channel = c == 0 ? "red" : c == 1 ? "green" : "blue";
          if (std::isnan(t[c]) || std::isinf(t[c]))
            std::snprintf(buf, sizeof buf, "texel x %d, y %d (from the top left) is %s in %s: radiance must be finite", x, y,
                          std::isnan(t[c]) ? "NaN" : "infinite", channel);
          else
            std::snprintf(buf, sizeof buf, "texel x %d, y %d (from the top left) is negative in %s (%g): radiance cannot be negative", x,
                          y, channel, (double)t[c]);
          throw Error(buf, where);
        }
      }
    }
}

double luminance(const glm::vec4& t) { return 0.2126 * t.x + 0.7152 * t.y + 0.0722 * t.z; }

// The running sum of w normalised to a float CDF ending at exactly 1 (total > 0).
void write_cdf(const std::vector<double>& w, double total, float* out) {
  double sum = 0.0;
  for (size_t i = 0; i < w.size(); ++i) {
    sum += w[i];
    out[i] = (float)std::min(sum / total, 1.0);
  }
  out[w.size() - 1] = 1.0f;
}

// The guide table of an n-entry CDF ending at 1: entry k holds, for the first i with
// cdf[i] > k / n, cdf[i − 1] (0 for i = 0), cdf[i], cdf[i + 1] (the last entry for i = n − 1) and
// i, as four floats (the index exact: n ≤ 16384).
void write_guide(const float* cdf, int n, float* guide) {
  int i = 0;
  for (int k = 0; k < n; ++k) {
    const float at = (float)k / (float)n;
    while (i < n - 1 && !(cdf[i] > at)) ++i;
    float* entry = guide + 4 * (size_t)k;
    entry[0] = i > 0 ? cdf[i - 1] : 0.0f;
    entry[1] = cdf[i];
    entry[2] = cdf[std::min(i + 1, n - 1)];
    entry[3] = (float)i;
  }
}

}  // namespace

void build_environment_distribution(EnvironmentMap& map) {
  const int w = map.width, h = map.height;
  map.cdf.clear();
  std::vector<double> lum((size_t)w * h);
  for (size_t i = 0; i < lum.size(); ++i) lum[i] = luminance(map.texels[i]);

  // Mean luminance: each texel over its cell's solid angle, (2π/W)(cos θ0 − cos θ1).
  double power = 0.0;
  for (int y = 0; y < h; ++y) {
    double band = (std::cos(M_PI * y / h) - std::cos(M_PI * (y + 1) / h)) * (2.0 * M_PI / w), row = 0.0;
    for (int x = 0; x < w; ++x) row += lum[(size_t)y * w + x];
    power += row * band;
  }
  map.mean_luminance = power / (4.0 * M_PI);

  // Vertex weights (environment.h): Y·sin θ at the texel centres, a row of zeros at each pole.
  const size_t rows = (size_t)h + 1;  // patch rows
  const size_t guides = XI_ENV_GUIDE_OFFSET((size_t)w, (size_t)h);
  const size_t weights = XI_ENV_WEIGHT_OFFSET((size_t)w, (size_t)h);
  map.cdf.assign(weights + ((size_t)h + 2) * w, 0.0f);
  float* vertex = map.cdf.data() + weights;
  for (int y = 0; y < h; ++y) {
    const double sin_theta = std::sin(M_PI * (y + 0.5) / h);
    for (int x = 0; x < w; ++x) vertex[(size_t)(y + 1) * w + x] = (float)(lum[(size_t)y * w + x] * sin_theta);
  }

  // Patch weights: the integral of the bilinear vertex weights over each patch, (mean of the four
  // corners) × its height in v (a half row at the poles); the width 1/W is common to all.
  std::vector<double> patch(rows * w), row_sum(rows, 0.0);
  for (size_t k = 0; k < rows; ++k) {
    const double height = (k == 0 || k == (size_t)h) ? 0.5 : 1.0;
    const float* upper = vertex + k * w;
    const float* lower = upper + w;
    for (int x = 0; x < w; ++x) {
      const int x1 = x + 1 == w ? 0 : x + 1;
      const double v = 0.25 * ((double)upper[x] + upper[x1] + lower[x] + lower[x1]) * height;
      patch[k * w + x] = v;
      row_sum[k] += v;
    }
  }
  double total = 0.0;
  for (double r : row_sum) total += r;
  if (!(total > 0.0)) {  // black: no distribution
    map.cdf.clear();
    return;
  }

  std::vector<double> row(w);
  for (size_t k = 0; k < rows; ++k) {
    float* out = map.cdf.data() + rows + k * w;
    if (row_sum[k] > 0.0) {
      double least = row_sum[k] * kMinShare, sum = 0.0;
      for (int x = 0; x < w; ++x) {
        double v = patch[k * w + x];
        row[x] = v > 0.0 ? std::max(v, least) : 0.0;
        sum += row[x];
      }
      write_cdf(row, sum, out);
    } else {  // never picked (its marginal probability is 0); uniform keeps the layout whole
      for (int x = 0; x < w; ++x) out[x] = x + 1 == w ? 1.0f : (float)((x + 1.0) / w);
    }
  }
  std::vector<double> marginal(rows);
  double least = total * kMinShare, sum = 0.0;
  for (size_t k = 0; k < rows; ++k) {
    marginal[k] = row_sum[k] > 0.0 ? std::max(row_sum[k], least) : 0.0;
    sum += marginal[k];
  }
  write_cdf(marginal, sum, map.cdf.data());

  // Guide tables (environment.h), four floats per CDF entry.
  write_guide(map.cdf.data(), (int)rows, map.cdf.data() + guides);
  for (size_t k = 0; k < rows; ++k)
    write_guide(map.cdf.data() + rows + k * w, w, map.cdf.data() + guides + 4 * (rows + k * w));
}

EnvironmentMap make_environment(int width, int height, std::vector<glm::vec4> texels, const std::string& source) {
  check_texels(width, height, texels, source);
  EnvironmentMap map;
  map.width = width;
  map.height = height;
  map.texels = std::move(texels);
  for (auto& t : map.texels) t.w = 0.0f;
  map.source = source;
  build_environment_distribution(map);
  return map;
}

EnvironmentMap load_environment(const std::filesystem::path& path) {
  const std::string where = path.string();
  const std::string ext = lower_extension(path);
  static const char* eight_bit[] = {".png", ".jpg", ".jpeg", ".bmp", ".tga", ".gif", ".ppm", ".pgm", ".pnm", ".psd", ".webp", ".tif", ".tiff"};
  if (std::find_if(std::begin(eight_bit), std::end(eight_bit), [&](const char* e) { return ext == e; }) != std::end(eight_bit))
    throw Error("an environment map must be high dynamic range (.hdr or .exr), not an 8-bit image", where);
  if (ext != ".hdr" && ext != ".exr")
    throw Error("unknown environment map format '" + ext + "': use a Radiance .hdr or an OpenEXR .exr file", where);
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw Error("no such environment map file", where);
  if (!std::filesystem::is_regular_file(path, ec)) throw Error("the environment map is not a regular file", where);
  if (std::filesystem::file_size(path, ec) == 0) throw Error("the environment map file is empty", where);
  int w = 0, h = 0;
  std::vector<glm::vec4> texels = ext == ".hdr" ? read_hdr(path, w, h) : read_exr_texels(path, w, h);
  return make_environment(w, h, std::move(texels), where);
}

EnvironmentData make_environment_data(const EnvironmentMap& map, float strength, float rotation_degrees,
                                      float pick_probability) {
  EnvironmentData env{};
  // to_local = R_y(α)ᵀ, R_y(α) = [[c, 0, s], [0, 1, 0], [−s, 0, c]] (Mitsuba's rotate about +y).
  double a = rotation_degrees * (M_PI / 180.0), c = std::cos(a), s = std::sin(a);
  env.to_local[0] = glm::vec4((float)c, 0.0f, (float)-s, 0.0f);
  env.to_local[1] = glm::vec4(0.0f, 1.0f, 0.0f, 0.0f);
  env.to_local[2] = glm::vec4((float)s, 0.0f, (float)c, 0.0f);
  bool sampled = map.has_distribution() && strength > 0.0f;
  env.scale = glm::vec4(strength, strength, strength, sampled ? std::clamp(pick_probability, 0.0f, 1.0f) : 0.0f);
  env.width = (uint)map.width;
  env.height = (uint)map.height;
  return env;
}

}  // namespace xi
