// `xi warp`: points of a sample set warped by a map, drawn as a PNG (like the lecture's pictures)
// or written as CSV. The points come from the same kernel code the renderer uses.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <numeric>

#include "cli.h"
#include "sampling.h"
#include "warps.h"
#include "xi/kernel_config.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/warp.h"

namespace xi::cli {
namespace {

constexpr int kCanvas = 512;
constexpr int kStrata = 8;  // colours: an 8×8 grid of the unit square

// A colour per cell of the 8×8 grid over (ξ₁, ξ₂): hue walks the cells, brightness alternates like
// a checkerboard, so neighbouring strata stay distinguishable after the warp.
glm::vec3 stratum_colour(glm::vec2 u) {
  int cx = std::min(kStrata - 1, (int)(u.x * kStrata)), cy = std::min(kStrata - 1, (int)(u.y * kStrata));
  float h = (float)(cx * kStrata + cy) / (kStrata * kStrata) * 6.0f;
  glm::vec3 rgb = glm::clamp(glm::vec3(std::fabs(h - 3.0f) - 1.0f, 2.0f - std::fabs(h - 2.0f), 2.0f - std::fabs(h - 4.0f)),
                             0.0f, 1.0f);
  return rgb * (((cx + cy) & 1) ? 0.55f : 0.9f);
}

void dot(Image& img, float sx, float sy, glm::vec3 c, int radius) {
  int px = (int)std::lround(sx), py = (int)std::lround(sy);
  for (int y = py - radius; y <= py + radius; ++y)
    for (int x = px - radius; x <= px + radius; ++x)
      if (x >= 0 && y >= 0 && x < img.width && y < img.height) img.at(x, y) = c;
}

// Maps a domain coordinate in [lo, hi]² to the canvas with a margin, y up.
struct View2D {
  float lo, hi;
  float sx(float x) const { return 24.0f + (x - lo) / (hi - lo) * (kCanvas - 48); }
  float sy(float y) const { return kCanvas - 24.0f - (y - lo) / (hi - lo) * (kCanvas - 48); }
};

// An oblique view of the unit sphere: turned 35° about z, seen from 25° above the horizon.
struct View3D {
  float c = std::cos(0.61f), s = std::sin(0.61f), ce = std::cos(0.44f), se = std::sin(0.44f);
  glm::vec3 project(glm::vec3 p) const {  // screen x, screen y (up), depth (away from the viewer)
    float x1 = c * p.x - s * p.y, y1 = s * p.x + c * p.y;
    return {x1, y1 * se + p.z * ce, y1 * ce - p.z * se};
  }
  float sx(float x) const { return kCanvas * 0.5f + x * kCanvas * 0.42f; }
  float sy(float y) const { return kCanvas * 0.5f - y * kCanvas * 0.42f; }
};

Image draw(int map, const WarpedSamples& w) {
  Image img(kCanvas, kCanvas);
  for (auto& p : img.pixels) p = glm::vec3(1.0f);
  const glm::vec3 outline(0.6f);
  const int radius = w.points.size() > 4096 ? 0 : 1;
  if (!warp_map_is_3d(map)) {
    bool disc = map == XI_MAP_DISC || map == XI_MAP_CONCENTRIC_DISC || map == XI_MAP_DISC_NAIVE;
    View2D v{disc ? -1.0f : 0.0f, 1.0f};
    for (int i = 0; i < 2048; ++i) {  // the domain's outline
      float t = (float)i / 2048;
      if (disc) {
        dot(img, v.sx(std::cos(6.2831853f * t)), v.sy(std::sin(6.2831853f * t)), outline, 0);
      } else {
        dot(img, v.sx(t), v.sy(0.0f), outline, 0);
        dot(img, v.sx(0.0f), v.sy(t), outline, 0);
        if (map == XI_MAP_TRIANGLE) {
          dot(img, v.sx(t), v.sy(1.0f - t), outline, 0);
        } else {
          dot(img, v.sx(t), v.sy(1.0f), outline, 0);
          dot(img, v.sx(1.0f), v.sy(t), outline, 0);
        }
      }
    }
    for (size_t i = 0; i < w.points.size(); ++i)
      dot(img, v.sx(w.points[i].x), v.sy(w.points[i].y), stratum_colour(w.squares[i]), radius);
    return img;
  }
  View3D v;
  for (int i = 0; i < 2048; ++i) {  // the equator
    float a = 6.2831853f * i / 2048;
    glm::vec3 q = v.project({std::cos(a), std::sin(a), 0.0f});
    dot(img, v.sx(q.x), v.sy(q.y), outline, 0);
  }
  // Far points first, and paler, so the near side reads on top.
  std::vector<size_t> order(w.points.size());
  std::iota(order.begin(), order.end(), 0);
  std::vector<glm::vec3> proj(w.points.size());
  for (size_t i = 0; i < proj.size(); ++i) proj[i] = v.project(w.points[i]);
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return proj[a].z > proj[b].z; });
  for (size_t i : order) {
    float fade = 0.45f * glm::clamp(proj[i].z, 0.0f, 1.0f);
    glm::vec3 c = glm::mix(stratum_colour(w.squares[i]), glm::vec3(1.0f), fade);
    dot(img, v.sx(proj[i].x), v.sy(proj[i].y), c, radius);
  }
  return img;
}

}  // namespace

const Command kWarp = {
    .name = "warp",
    .about = "draw a sample set warped by a map (as PNG) or write it as CSV",
    .flags = {
        {"--map", "NAME",
         "square | sphere | hemisphere | cosine-hemisphere | disc |\n"
         "concentric-disc | triangle | disc-naive"},
        {"--sampler", "NAME", "random | grid | stratified | sobol (default stratified)"},
        {"-n", "N", "number of points (default 1024)"},
        {"--seed", "S", "random seed"},
        {"--device", "D", "OpenCL device (as for render)"},
        {"-o", "FILE.png|FILE.csv", "output: a picture, or one x,y,z line per point"},
    },
    .run = warp,
};

int warp(const std::vector<std::string>& argv) {
  Args args(argv, kWarp);
  if (!args.positional().empty()) throw Error("unexpected argument '" + args.positional()[0] + "'", "xi warp");
  int map = parse_warp_map(args.get("--map", "square"));
  int sampler = parse_sampler(args.get("--sampler", "stratified"));
  int n = args.get_int("-n", 1024, 1, 1 << 24);
  uint32_t seed = (uint32_t)args.get_int("--seed", 0, 0, INT32_MAX);
  if (!args.has("-o")) throw Error("missing output file (FILE.png or FILE.csv)", "-o");
  std::filesystem::path out = args.get("-o");
  std::string ext = out.extension().string();
  if (ext != ".png" && ext != ".csv") throw Error("the output must end in .png or .csv", "-o " + out.string());
  auto dir = out.has_parent_path() ? out.parent_path() : std::filesystem::path(".");
  if (!std::filesystem::is_directory(dir)) throw Error("output folder does not exist", dir.string());

  Device device = Device::open(args.get("--device"));
  WarpedSamples w = warp_samples(device, map, sampler, (uint32_t)n, seed);
  if (ext == ".png") {
    write_png(out, draw(map, w));
  } else {
    write_atomically(out, [&](const std::filesystem::path& tmp) {
      std::FILE* f = std::fopen(tmp.c_str(), "w");
      if (!f) throw Error("cannot open file for writing", tmp.string());
      for (auto& p : w.points) std::fprintf(f, "%.9g,%.9g,%.9g\n", p.x, p.y, p.z);
      if (std::fclose(f) != 0) throw Error("cannot write file", tmp.string());
    });
  }
  std::printf("wrote %d %s points (%s sampler) to %s\n", n, warp_map_name(map), sampler_name(sampler),
              out.string().c_str());
  return 0;
}

}  // namespace xi::cli
