// End to end, through the scene parsers and the device: textures (bilinear filtering, wrap modes,
// KHR_texture_transform, texture coordinate sets), the metallic-roughness material in a white
// furnace, punctual lights, alpha MASK and BLEND in shadows, environment importance sampling, glTF
// files written here and Debian's assimp-testmodels, and bad texture input.
//
// Every expectation is computed here from the definitions (glTF 2.0 and its extensions, the
// README's scene format): texture lookups by an independent host sampler, pixel rays from the
// camera's definition, irradiance in closed form or by quadrature, and the BSDF's directional
// albedo by brute-force quadrature of microfacet.h's f (the function the kernels call).
//
// Exact comparisons render with the grid sampler at 1 spp: every dimension of the one sample is a
// cell centre, so the camera ray goes through the pixel centre and the comparison is against that
// point alone. Statistical checks are z-tests on block means with their standard errors from the
// film's variance, fixed seeds, each test's family at the significance level stated beside it
// (Šidák-corrected over the family's checks).
#include <gtest/gtest.h>
#include <png.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <type_traits>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "cli_test.h"
#include "gltf_builder.h"
#include "fixtures.h"
#include "microfacet.h"
#include "sampling.h"
#include "stats.h"
#include "xi/asset.h"
#include "xi/compiled_scene.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using xi_test::base64;
using glm::dvec2;
using glm::dvec3;
using glm::dvec4;

const fs::path kModels = "/usr/share/assimp/models/glTF2";

fs::path temp_dir() { return xi::test::fresh_test_dir("xi_materials_"); }

// Every render here compiles all features in: one shading program per sampler and strategy.
xi::RenderOptions options(int spp, uint32_t seed, int sampler, int max_depth = 1,
                          xi::Strategy strategy = xi::Strategy::Mis) {
  xi::RenderOptions o = xi::test::render_options(spp, seed, strategy, max_depth, sampler);
  o.all_features = true;
  return o;
}
// One sample per pixel through its centre (see the top of the file).
xi::RenderOptions exact() { return options(1, 1, XI_SAMPLER_GRID); }

// --- 8-bit RGBA images, written as PNG here (libpng), read back by xi's decoder

struct Rgba {
  int w = 0, h = 0;
  std::vector<uint8_t> px;  // 4 bytes per texel, row 0 the top
  uint8_t& at(int x, int y, int c) { return px[(size_t(y) * w + x) * 4 + c]; }
  uint8_t at(int x, int y, int c) const { return px[(size_t(y) * w + x) * 4 + c]; }
};

// A 4×4 image of unrelated texel values (no two neighbours alike), opaque.
Rgba pattern4() {
  Rgba t{4, 4, std::vector<uint8_t>(64)};
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) {
      t.at(x, y, 0) = uint8_t((x * 67 + y * 151 + 13) % 256);
      t.at(x, y, 1) = uint8_t((x * 29 + y * 97 + 200) % 256);
      t.at(x, y, 2) = uint8_t((x * 181 + y * 43 + 77) % 256);
      t.at(x, y, 3) = 255;
    }
  return t;
}

std::string png_bytes(const Rgba& img) {
  png_image im;
  std::memset(&im, 0, sizeof im);
  im.version = PNG_IMAGE_VERSION;
  im.width = uint32_t(img.w);
  im.height = uint32_t(img.h);
  im.format = PNG_FORMAT_RGBA;
  png_alloc_size_t size = 0;
  if (!png_image_write_to_memory(&im, nullptr, &size, 0, img.px.data(), 0, nullptr)) return {};
  std::string out(size, '\0');
  if (!png_image_write_to_memory(&im, out.data(), &size, 0, img.px.data(), 0, nullptr)) return {};
  out.resize(size);
  return out;
}
void write_png(const fs::path& p, const Rgba& img) {
  const std::string bytes = png_bytes(img);
  ASSERT_FALSE(bytes.empty());
  xi_test::write_text(p, bytes);
}

// --- the reference texture sampler: glTF 2.0 / OpenGL's definitions, written independently

enum class Wrap { Repeat, Clamp, Mirror };

// OpenGL 4.6 §8.14.2: the texel index i along an axis of n texels after the wrap mode.
int wrap_index(int i, int n, Wrap w) {
  if (w == Wrap::Clamp) return std::clamp(i, 0, n - 1);
  if (w == Wrap::Repeat) return ((i % n) + n) % n;
  const int a = ((i % (2 * n)) + 2 * n) % (2 * n) - n;  // MIRRORED_REPEAT: (n−1) − mirror((i mod 2n) − n)
  return (n - 1) - (a >= 0 ? a : -(1 + a));
}
double srgb_to_linear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

// Bilinear between texel centres (at half-integers), colour decoded from sRGB first; (u, v) with
// v down the image. Returns RGB and alpha (linear).
dvec4 sample(const Rgba& t, dvec2 uv, Wrap ws, Wrap wt, bool srgb = true) {
  const double x = uv.x * t.w - 0.5, y = uv.y * t.h - 0.5;
  const double x0 = std::floor(x), y0 = std::floor(y), fx = x - x0, fy = y - y0;
  dvec4 sum(0.0);
  for (int dy = 0; dy < 2; ++dy)
    for (int dx = 0; dx < 2; ++dx) {
      const int ix = wrap_index(int(x0) + dx, t.w, ws), iy = wrap_index(int(y0) + dy, t.h, wt);
      const double w = (dx ? fx : 1.0 - fx) * (dy ? fy : 1.0 - fy);
      dvec4 c;
      for (int k = 0; k < 3; ++k) c[k] = srgb ? srgb_to_linear(t.at(ix, iy, k) / 255.0) : t.at(ix, iy, k) / 255.0;
      c[3] = t.at(ix, iy, 3) / 255.0;
      sum += w * c;
    }
  return sum;
}

// KHR_texture_transform: scale, then rotate (u' = cos u + sin v, v' = −sin u + cos v: the
// extension's rotation matrix rows), then offset.
dvec2 khr_transform(dvec2 uv, dvec2 offset, double rotation, dvec2 scale) {
  const dvec2 s = uv * scale;
  const double c = std::cos(rotation), n = std::sin(rotation);
  return {c * s.x + n * s.y + offset.x, -n * s.x + c * s.y + offset.y};
}

// --- rays and films

struct Ray {
  dvec3 o, d;
};
// The pinhole camera's ray through film point (fx, fy) in pixels ((0, 0) the top-left corner), as
// the README defines the camera: vertical fov, right = forward × up.
Ray camera_ray(dvec3 pos, dvec3 look_at, dvec3 up, double vfov_degrees, int w, int h, double fx, double fy) {
  const dvec3 fwd = glm::normalize(look_at - pos), right = glm::normalize(glm::cross(fwd, up)), u = glm::cross(right, fwd);
  const double t = std::tan(glm::radians(vfov_degrees) / 2.0), aspect = double(w) / h;
  const double sx = 2.0 * fx / w - 1.0, sy = 1.0 - 2.0 * fy / h;
  return {pos, glm::normalize(fwd + right * (t * aspect * sx) + u * (t * sy))};
}
Ray camera_ray(const xi::Scene& s, int w, int h, double fx, double fy) {
  return camera_ray(dvec3(s.camera.position), dvec3(s.camera.look_at), dvec3(s.camera.up), s.camera.vfov_degrees, w, h, fx, fy);
}
// Where a ray meets the plane p·axis = c (axis 0, 1, 2); false if it does not (ahead).
bool hit_plane(const Ray& r, int axis, double c, dvec3* p) {
  if (r.d[axis] == 0.0) return false;
  const double t = (c - r.o[axis]) / r.d[axis];
  if (!(t > 0.0)) return false;
  *p = r.o + t * r.d;
  return true;
}

bool all_finite(const xi::Image& img) {
  for (const glm::vec3& p : img.pixels)
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) return false;
  return true;
}

xi::Scene load_json(const fs::path& dir, const json& scene) {
  xi_test::write_text(dir / "scene.json", scene.dump(1));
  return xi::load_scene(dir / "scene.json");
}

json camera_json(dvec3 pos, dvec3 look, dvec3 up, double fov) {
  return {{"position", {pos.x, pos.y, pos.z}}, {"look_at", {look.x, look.y, look.z}}, {"up", {up.x, up.y, up.z}}, {"fov", fov}};
}

// A diffuse quad y = 0, |x|, |z| ≤ half, facing +y.
json floor_quad(const std::string& material, double half) {
  return {{"type", "quad"}, {"material", material},
          {"vertices", {{-half, 0, -half}, {-half, 0, half}, {half, 0, half}, {half, 0, -half}}}};
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// a. A diffuse quad whose albedo is a 4×4 image, lit only by a constant background of radiance 1,
// one bounce: each sample's value is exactly the albedo at its hit (the bounce escapes, weight =
// albedo). At each pixel centre the render must equal the host sampler at the hit's texture
// coordinates (the quad's v0..v3 get (0,0), (1,0), (1,1), (0,1); v runs down the image) within
// 1e-3: the reference reads the same 8-bit texels, so what is left is float rounding of the hit
// point and of the device's pow (< 1e-5 here). Variants: transforms taking the coordinates
// outside [0, 1] under each wrap mode, texture coordinate set 1, a rotation. Must-fail: the same
// reference with v not flipped, with the wrong wrap mode, or with the transposed rotation (the
// extension text's GLSL listing) misses by more than 0.1 somewhere.
TEST(MaterialTextures, DiffuseQuadShowsItsTextureExactly) {
  const fs::path dir = temp_dir();
  const Rgba tex = pattern4();
  write_png(dir / "tex.png", tex);
  struct Variant {
    const char* name;
    dvec2 offset, scale;
    double degrees;
    Wrap ws, wt;
    int set;
  };
  const Variant variants[] = {
      {"plain", {0, 0}, {1, 1}, 0, Wrap::Repeat, Wrap::Repeat, 0},
      {"repeat", {-0.3, -0.6}, {2.5, 1.75}, 0, Wrap::Repeat, Wrap::Repeat, 0},
      {"clamp", {-0.3, -0.6}, {2.5, 1.75}, 0, Wrap::Clamp, Wrap::Clamp, 0},
      {"mirror", {-0.3, -0.6}, {2.5, 1.75}, 0, Wrap::Mirror, Wrap::Mirror, 0},
      {"mirror-clamp-set1", {0.2, -0.45}, {1.6, 2.2}, 0, Wrap::Mirror, Wrap::Clamp, 1},
      {"rotated", {0.1, 0.35}, {1.3, 0.8}, 30, Wrap::Repeat, Wrap::Repeat, 0},
  };
  auto wrap_name = [](Wrap w) { return w == Wrap::Clamp ? "clamp" : w == Wrap::Mirror ? "mirror" : "repeat"; };
  const int W = 48, H = 48;
  for (const Variant& v : variants) {
    SCOPED_TRACE(v.name);
    const json texture = {{"file", "tex.png"}, {"wrap_s", wrap_name(v.ws)}, {"wrap_t", wrap_name(v.wt)},
                          {"offset", {v.offset.x, v.offset.y}}, {"scale", {v.scale.x, v.scale.y}},
                          {"rotation", v.degrees}, {"texcoord", v.set}};
    const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 40)},
                        {"film", {{"width", W}, {"height", H}}},
                        {"background", {1, 1, 1}},
                        {"materials", {{"tex", {{"type", "diffuse"}, {"albedo", texture}}}}},
                        {"shapes", {{{"type", "quad"}, {"material", "tex"}, {"vertices", {{-1, 1, 0}, {1, 1, 0}, {1, -1, 0}, {-1, -1, 0}}}}}}};
    const xi::Scene s = load_json(dir, scene);
    const xi::test::Shot shot = xi::test::render_shot(s, exact());
    ASSERT_EQ(shot.nonfinite, 0u);
    double err = 0.0, err_v_up = 0.0, err_wrap = 0.0, err_transposed = 0.0;
    int compared = 0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        dvec3 p;
        if (!hit_plane(camera_ray(s, W, H, x + 0.5, y + 0.5), 2, 0.0, &p) || std::abs(p.x) > 0.97 || std::abs(p.y) > 0.97) continue;
        const dvec2 uv((p.x + 1.0) / 2.0, (1.0 - p.y) / 2.0);
        const double rad = glm::radians(v.degrees);
        const dvec4 want = sample(tex, khr_transform(uv, v.offset, rad, v.scale), v.ws, v.wt);
        const dvec4 v_up = sample(tex, khr_transform({uv.x, 1.0 - uv.y}, v.offset, rad, v.scale), v.ws, v.wt);
        const Wrap other = v.ws == Wrap::Repeat ? Wrap::Mirror : Wrap::Repeat;
        const dvec4 wrong_wrap = sample(tex, khr_transform(uv, v.offset, rad, v.scale), other, other);
        const dvec4 transposed = sample(tex, khr_transform(uv, v.offset, -rad, v.scale), v.ws, v.wt);
        for (int c = 0; c < 3; ++c) {
          const double got = shot.mean.at(x, y)[c];
          err = std::max(err, std::abs(got - want[c]));
          err_v_up = std::max(err_v_up, std::abs(got - v_up[c]));
          err_wrap = std::max(err_wrap, std::abs(got - wrong_wrap[c]));
          err_transposed = std::max(err_transposed, std::abs(got - transposed[c]));
        }
        ++compared;
      }
    EXPECT_GT(compared, W * H / 2);
    EXPECT_LT(err, 1e-3) << "largest difference from the reference sampler";
    EXPECT_GT(err_v_up, 0.1) << "the test cannot tell v up from v down";
    if (v.offset != dvec2(0.0) || v.scale != dvec2(1.0)) EXPECT_GT(err_wrap, 0.1) << "the test cannot tell the wrap mode";
    if (v.degrees != 0.0) EXPECT_GT(err_transposed, 0.1) << "the test cannot tell the rotation's sense";
  }
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// b. White furnace: a pbr icosphere (subdivision 5, vertex normals) under radiance 1 from every
// direction, one bounce (the sphere is convex: every reflected ray escapes). A pixel's mean is the
// directional albedo ∫ f(wo, wi) cos θi dωi at the points it sees, computed here by quadrature of
// microfacet.h's xi_pbr_eval over the half-vector hemisphere (dense around the normal, where the
// narrow lobes are), with wo from the pixel's ray and the exact sphere's normal, averaged over 2×2
// points of the pixel. Checks, at a family-wise α = 0.01 per test (Šidák over the checks):
//  - every pixel ≤ 1 (a z-test of each pixel's mean against 1), but those of the white dielectric,
//    whose albedo is 1 itself;
//  - at three pixels per material (cos θo about 0.95, 0.7, 0.45): |mean − albedo| within the z
//    bound plus 2e-3 for the reference's own error (the 2×2 footprint average and the facets).
// Cases: roughness {0.05, 0.5, 1} × metallic {0, 1} × base colour {1, 0.5}. Must-fail: the albedo
// with α = roughness (not squared) is rejected at some roughness-0.5 pixel.
namespace {

// ∫ f(wo, wi) max(wi.z, 0) dωi over wi by the half vector h: wi = 2 (wo·h) h − wo, dωi = 4 (wo·h) dωh.
double directional_albedo(const PbrLobes& m, glm::vec3 wo) {
  const double a = std::max(double(m.alpha), 1e-4);
  const double theta_c = std::min(std::atan(25.0 * a), 1.5);
  const int n1 = 256, n2 = 512, nphi = 128;
  double sum = 0.0;
  for (int region = 0; region < 2; ++region) {
    const double t0 = region ? theta_c : 0.0, t1 = region ? M_PI / 2 : theta_c;
    const int n = region ? n2 : n1;
    const double dt = (t1 - t0) / n, dp = 2.0 * M_PI / nphi;
    for (int i = 0; i < n; ++i) {
      const double th = t0 + (i + 0.5) * dt;
      for (int j = 0; j < nphi; ++j) {
        const double ph = (j + 0.5) * dp;
        const dvec3 h(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
        const double oh = glm::dot(dvec3(wo), h);
        if (oh <= 0.0) continue;
        const dvec3 wi = 2.0 * oh * h - dvec3(wo);
        if (wi.z <= 0.0) continue;
        const glm::vec3 f = xi_pbr_eval(m, wo, glm::vec3(glm::normalize(wi)));
        sum += double(f.x) * wi.z * 4.0 * oh * std::sin(th) * dt * dp;
      }
    }
  }
  return sum;
}

}  // namespace

TEST(MaterialFurnace, MetallicRoughnessSphereAlbedo) {
  const fs::path dir = temp_dir();
  const int W = 32, H = 32, spp = 512;
  const dvec3 eye(0, 0, 4);
  const double fov = 33.0;
  struct Case {
    double roughness, metallic, base;
    bool multiple_scattering = true;
  };
  std::vector<Case> cases;
  for (double r : {0.05, 0.5, 1.0})
    for (double m : {0.0, 1.0})
      for (double b : {1.0, 0.5}) cases.push_back({r, m, b});
  // The scene's switch: single-scattering GGX, a white metal at roughness 1 well below 1.
  cases.push_back({1.0, 1.0, 1.0, false});
  // The pixels along row 15 whose centres see cos θo nearest 0.95, 0.7, 0.45.
  auto cos_at = [&](double fx, double fy, dvec3* n) {
    const Ray r = camera_ray(eye, {0, 0, 0}, {0, 1, 0}, fov, W, H, fx, fy);
    const double b = glm::dot(r.o, r.d), c = glm::dot(r.o, r.o) - 1.0, disc = b * b - c;
    if (disc <= 0.0) return -1.0;
    *n = glm::normalize(r.o + (-b - std::sqrt(disc)) * r.d);
    return -glm::dot(r.d, *n);
  };
  std::vector<std::pair<int, int>> pixels;
  for (double target : {0.95, 0.7, 0.45}) {
    int best = -1;
    double gap = 1e9;
    for (int x = W / 2; x < W; ++x) {
      dvec3 n;
      const double c = cos_at(x + 0.5, 15.5, &n);
      if (c > 0.3 && std::abs(c - target) < gap) gap = std::abs(c - target), best = x;
    }
    ASSERT_GE(best, 0);
    pixels.push_back({best, 15});
  }
  const double z_pix = xi::stats::sidak_critical_z(0.01, int(cases.size()) * W * H);
  const double z_alb = xi::stats::sidak_critical_z(0.01, int(cases.size() * pixels.size()));
  const double ref_tol = 2e-3;
  int wrong_rejected = 0;
  for (const Case& k : cases) {
    SCOPED_TRACE("roughness " + std::to_string(k.roughness) + " metallic " + std::to_string(k.metallic) + " base " +
                 std::to_string(k.base) + (k.multiple_scattering ? "" : " single scattering"));
    const json scene = {{"camera", camera_json(eye, {0, 0, 0}, {0, 1, 0}, fov)},
                        {"film", {{"width", W}, {"height", H}}},
                        {"render", {{"multiple_scattering", k.multiple_scattering}}},
                        {"background", {1, 1, 1}},
                        {"materials", {{"m", {{"type", "pbr"}, {"base_color", {k.base, k.base, k.base}}, {"metallic", k.metallic}, {"roughness", k.roughness}}}}},
                        {"shapes", {{{"type", "sphere"}, {"material", "m"}, {"center", {0, 0, 0}}, {"radius", 1}, {"subdivisions", 5}}}}};
    const xi::Scene s = load_json(dir, scene);
    const xi::test::Shot shot = xi::test::render_shot(s, options(spp, 11, XI_SAMPLER_RANDOM));
    ASSERT_EQ(shot.nonfinite, 0u);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        // A white dielectric's albedo is 1 itself (the layer's albedo scaling): whether a pixel's
        // mean passes it is up to its noise, heavy-tailed at roughness 1, whose variance 512
        // samples underestimate; the pixels below compare it with quadrature instead.
        if (k.metallic == 0.0 && k.base == 1.0) continue;
        const double mean = shot.mean.at(x, y).x, se = std::sqrt(double(shot.variance.at(x, y).x));
        // A metal's multiple-scattering tables are interpolated: its albedo may pass 1 by a little.
        EXPECT_LE(mean, 1.0 + z_pix * se + (k.metallic > 0.0 ? 1e-3 : 1e-5)) << "pixel " << x << "," << y;
      }
    for (const auto& [px, py] : pixels) {
      double albedo = 0.0, wrong = 0.0;
      for (double sy : {0.25, 0.75})
        for (double sx : {0.25, 0.75}) {
          dvec3 n;
          const double c = cos_at(px + sx, py + sy, &n);
          ASSERT_GT(c, 0.0);
          // Local frame: n = +z; wo = (sin θo, 0, cos θo) (the lobes are isotropic).
          const glm::vec3 wo(float(std::sqrt(std::max(0.0, 1.0 - c * c))), 0.0f, float(c));
          PbrLobes m = xi_plain_pbr_lobes(glm::vec3(float(k.base)));
          m.metallic = float(k.metallic);
          m.alpha = float(k.roughness * k.roughness);
          m.multiple_scattering = k.multiple_scattering ? 1.0f : 0.0f;
          m.albedo_scaling = 1.0f;  // the scene's default layering
          albedo += directional_albedo(m, wo) / 4.0;
          m.alpha = float(k.roughness);
          wrong += directional_albedo(m, wo) / 4.0;
        }
      const xi::test::MeanSe got = xi::test::block_mean(shot, px, py, px + 1, py + 1);
      EXPECT_LT(std::abs(got.mean - albedo), z_alb * got.se + ref_tol)
          << "pixel " << px << "," << py << ": mean " << got.mean << " ± " << got.se << ", albedo " << albedo;
      if (k.roughness == 0.5 && std::abs(got.mean - wrong) > z_alb * got.se + ref_tol) ++wrong_rejected;
      std::printf("furnace r=%.2f m=%.0f b=%.1f%s pixel %2d: mean %.5f se %.5f albedo %.5f (alpha=r: %.5f)\n",
                  k.roughness, k.metallic, k.base, k.multiple_scattering ? "" : " single", px, got.mean, got.se, albedo,
                  wrong);
      if (!k.multiple_scattering) EXPECT_LT(got.mean, 0.85);  // what the multiple scattering restores
    }
  }
  EXPECT_GT(wrong_rejected, 0) << "the test cannot tell alpha = roughness² from alpha = roughness";
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// c. Punctual lights over a diffuse floor (albedo ρ = 0.5), one bounce, black background. With a
// point, spot or directional light, light sampling is exact per sample: a pixel centre's value is
// ρ/π · I · cos θ / r² (point), times glTF's smooth cone falloff squared (spot: full inside the
// inner cone, 0 outside the outer), ρ/π · E cos θ (directional); compared within 1e-4 relative
// (float rounding), the spot's cone region within 1e-3 (its falloff divides by cos differences).
// A sun (angular radius 5°) gives the directional's value on average (the cap's mean of cos θ is
// cos of its axis' angle times 1, exactly: ∫cap ω dω = π sin²θmax · axis): z-tests over 16 blocks
// and the whole image at α = 0.01 (Šidák over the 17). Two lights at once (point + directional,
// picked by power): each block's mean is the sum, z-tests at α = 0.01 over 16 blocks. BSDF sampling
// alone never reaches a punctual light: the image is black. Must-fail: 1/r instead of 1/r², and the
// falloff unsquared, miss by more than 5%.
TEST(MaterialLights, PunctualLightsOverAFloor) {
  const fs::path dir = temp_dir();
  const int W = 32, H = 32;
  const double rho = 0.5;
  const dvec3 eye(0, 3, 0);
  auto scene_with = [&](const json& lights) {
    return json{{"camera", camera_json(eye, {0, 0, 0}, {0, 0, -1}, 80)},
                {"film", {{"width", W}, {"height", H}}},
                {"lights", lights},
                {"materials", {{"floor", {{"type", "diffuse"}, {"albedo", {rho, rho, rho}}}}}},
                {"shapes", {floor_quad("floor", 4)}}};
  };
  // Each pixel centre's floor point.
  auto floor_point = [&](const xi::Scene& s, int x, int y) {
    dvec3 p(0.0);
    EXPECT_TRUE(hit_plane(camera_ray(s, W, H, x + 0.5, y + 0.5), 1, 0.0, &p));
    return p;
  };
  auto rel = [](double got, double want) { return std::abs(got - want) / std::max(std::abs(want), 1e-6); };

  {  // Point light.
    SCOPED_TRACE("point");
    const dvec3 lp(0.3, 1.5, -0.2), color(1.0, 0.8, 0.6);
    const double I = 5.0;
    const xi::Scene s = load_json(dir, scene_with({{{"type", "point"}, {"position", {lp.x, lp.y, lp.z}}, {"color", {color.x, color.y, color.z}}, {"intensity", I}}}));
    const xi::test::Shot shot = xi::test::render_shot(s, exact());
    double err = 0.0, err_wrong = 0.0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const dvec3 p = floor_point(s, x, y), to = lp - p;
        const double r = glm::length(to), cos_t = to.y / r;
        for (int c = 0; c < 3; ++c) {
          const double want = rho / M_PI * I * color[c] * cos_t / (r * r), got = shot.mean.at(x, y)[c];
          err = std::max(err, rel(got, want));
          err_wrong = std::max(err_wrong, rel(got, want * r));
        }
      }
    EXPECT_LT(err, 1e-4);
    EXPECT_GT(err_wrong, 0.05);
    // BSDF sampling alone cannot reach it (README: punctual lights are reached by light sampling only).
    const xi::test::Shot bsdf = xi::test::render_shot(s, options(4, 1, XI_SAMPLER_RANDOM, 1, xi::Strategy::Bsdf));
    for (const glm::vec3& px : bsdf.mean.pixels) ASSERT_EQ(px, glm::vec3(0.0f));
  }
  {  // Spot light straight down: inner 20°, outer 35°.
    SCOPED_TRACE("spot");
    const dvec3 lp(0, 2, 0);
    const double I = 4.0, inner = glm::radians(20.0), outer = glm::radians(35.0);
    const xi::Scene s = load_json(dir, scene_with({{{"type", "spot"}, {"position", {0, 2, 0}}, {"direction", {0, -1, 0}}, {"intensity", I}, {"inner_angle", 20}, {"outer_angle", 35}}}));
    const xi::test::Shot shot = xi::test::render_shot(s, exact());
    double err_in = 0.0, err_cone = 0.0, err_unsquared = 0.0, out_max = 0.0;
    int n_in = 0, n_cone = 0, n_out = 0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const dvec3 p = floor_point(s, x, y), to = lp - p;
        const double r = glm::length(to), cos_t = to.y / r, angle = std::acos(cos_t);
        const double t = std::clamp((cos_t - std::cos(outer)) / (std::cos(inner) - std::cos(outer)), 0.0, 1.0);
        const double full = rho / M_PI * I * cos_t / (r * r), got = shot.mean.at(x, y).x;
        if (angle < inner - 0.01) err_in = std::max(err_in, rel(got, full)), ++n_in;
        else if (angle > outer + 0.01) out_max = std::max(out_max, got), ++n_out;
        else if (angle > inner + 0.01 && angle < outer - 0.01) {
          err_cone = std::max(err_cone, rel(got, full * t * t));
          err_unsquared = std::max(err_unsquared, rel(got, full * t));
          ++n_cone;
        }
      }
    EXPECT_GT(n_in, 20);
    EXPECT_GT(n_cone, 20);
    EXPECT_GT(n_out, 20);
    EXPECT_LT(err_in, 1e-4);
    EXPECT_LT(err_cone, 1e-3);
    EXPECT_EQ(out_max, 0.0);
    EXPECT_GT(err_unsquared, 0.05);
  }
  const dvec3 sun_dir = glm::normalize(dvec3(-1, -2, 1));
  const double E = 3.0, directional = rho / M_PI * E * -sun_dir.y;
  {  // Directional light.
    SCOPED_TRACE("directional");
    const xi::Scene s = load_json(dir, scene_with({{{"type", "directional"}, {"direction", {-1, -2, 1}}, {"intensity", E}}}));
    const xi::test::Shot shot = xi::test::render_shot(s, exact());
    double err = 0.0;
    for (const glm::vec3& px : shot.mean.pixels) err = std::max(err, rel(px.y, directional));
    EXPECT_LT(err, 1e-4);
  }
  {  // Sun: the same on average.
    SCOPED_TRACE("sun");
    const xi::Scene s = load_json(dir, scene_with({{{"type", "sun"}, {"direction", {-1, -2, 1}}, {"intensity", E}, {"angular_radius", 5}}}));
    const xi::test::Shot shot = xi::test::render_shot(s, options(64, 3, XI_SAMPLER_RANDOM));
    const double zc = xi::stats::sidak_critical_z(0.01, 17);
    for (int by = 0; by < 4; ++by)
      for (int bx = 0; bx < 4; ++bx) {
        const auto b = xi::test::block_mean(shot, bx * 8, by * 8, bx * 8 + 8, by * 8 + 8);
        ASSERT_GT(b.se, 0.0);
        EXPECT_LT(std::abs(b.mean - directional) / b.se, zc) << "block " << bx << "," << by << ": " << b.mean << " vs " << directional;
      }
    const auto all = xi::test::block_mean(shot, 0, 0, W, H);
    EXPECT_LT(std::abs(all.mean - directional) / all.se, zc) << all.mean << " ± " << all.se << " vs " << directional;
  }
  {  // A point and a directional light together, picked by power.
    SCOPED_TRACE("point + directional");
    const dvec3 lp(-0.5, 1.0, 0.4);
    const double I = 2.0;
    const xi::Scene s = load_json(dir, scene_with({{{"type", "point"}, {"position", {lp.x, lp.y, lp.z}}, {"intensity", I}},
                                                   {{"type", "directional"}, {"direction", {-1, -2, 1}}, {"intensity", E}}}));
    const xi::test::Shot shot = xi::test::render_shot(s, options(64, 5, XI_SAMPLER_RANDOM));
    const double zc = xi::stats::sidak_critical_z(0.01, 16);
    for (int by = 0; by < 4; ++by)
      for (int bx = 0; bx < 4; ++bx) {
        double want = 0.0;
        for (int y = by * 8; y < by * 8 + 8; ++y)
          for (int x = bx * 8; x < bx * 8 + 8; ++x) {
            // The mean over the pixel's area: 4×4 points.
            for (int j = 0; j < 4; ++j)
              for (int i = 0; i < 4; ++i) {
                dvec3 p;
                hit_plane(camera_ray(s, W, H, x + (i + 0.5) / 4, y + (j + 0.5) / 4), 1, 0.0, &p);
                const dvec3 to = lp - p;
                const double r = glm::length(to);
                want += (rho / M_PI * I * (to.y / r) / (r * r) + directional) / (64.0 * 16.0);
              }
          }
        const auto b = xi::test::block_mean(shot, bx * 8, by * 8, bx * 8 + 8, by * 8 + 8);
        EXPECT_LT(std::abs(b.mean - want) / b.se, zc) << "block " << bx << "," << by << ": " << b.mean << " vs " << want;
      }
  }
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// d. Cut-outs in shadows. A directional light (E = 2, 45° from the vertical, towards +x) over a
// diffuse floor (ρ = 0.5); a quad at height 1.5, x and z in [−0.5, 0.5], whose base colour texture
// keeps its u < ½ half (alpha 1) and cuts out the rest (alpha 0), alphaMode MASK (cutoff 0.5). Its
// shadow falls 1.5 further along +x: the kept half's on x ∈ [1, 1.5], the cut-out half's place,
// x ∈ [1.5, 2], stays lit. One sample through each pixel centre (exact): floor points 0.05 inside
// the kept half's shadow read exactly 0; points 0.05 clear of it read ρ/π E cos 45° within 1e-4
// relative. Must-fail: the same quad opaque darkens the cut-out half's place (the test can tell).
// BLEND with alpha 0.3 and no texture: the shadow lets 70% through on average: a z-test of the
// shadow's block mean at α = 0.01 (one test).
TEST(MaterialAlpha, MaskAndBlendShadows) {
  const fs::path dir = temp_dir();
  Rgba mask{8, 8, std::vector<uint8_t>(256)};
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      for (int c = 0; c < 3; ++c) mask.at(x, y, c) = 200;
      mask.at(x, y, 3) = x < 4 ? 255 : 0;
    }
  write_png(dir / "mask.png", mask);
  const int W = 32, H = 32;
  const double rho = 0.5, E = 2.0, lit = rho / M_PI * E * std::sqrt(0.5);
  auto scene_with = [&](const json& occluder) {
    return json{{"camera", camera_json({1.5, 4, 0}, {1.5, 0, 0}, {0, 0, -1}, 20)},
                {"film", {{"width", W}, {"height", H}}},
                {"lights", {{{"type", "directional"}, {"direction", {1, -1, 0}}, {"intensity", E}}}},
                {"materials", {{"floor", {{"type", "diffuse"}, {"albedo", {rho, rho, rho}}}}, {"occluder", occluder}}},
                {"shapes", {floor_quad("floor", 3),
                            {{"type", "quad"}, {"material", "occluder"},
                             {"vertices", {{-0.5, 1.5, -0.5}, {0.5, 1.5, -0.5}, {0.5, 1.5, 0.5}, {-0.5, 1.5, 0.5}}}}}}};
  };
  enum Where { kShadow, kCutOut, kLit, kEdge };
  auto where = [](dvec3 p) {
    const double m = 0.05;
    if (std::abs(p.z) > 0.5 + m || p.x < 1.0 - m || p.x > 2.0 + m) return kLit;
    if (std::abs(p.z) < 0.5 - m && p.x > 1.0 + m && p.x < 1.5 - m) return kShadow;
    if (std::abs(p.z) < 0.5 - m && p.x > 1.5 + m && p.x < 2.0 - m) return kCutOut;
    return kEdge;
  };
  auto run = [&](const std::string& mode, double* shadow_max, double* cut_err, double* lit_err, int counts[3]) {
    json occluder = {{"type", "pbr"}, {"base_color_texture", "mask.png"}, {"alpha_mode", mode}};
    if (mode == "mask") occluder["alpha_cutoff"] = 0.5;
    const xi::Scene s = load_json(dir, scene_with(occluder));
    const xi::test::Shot shot = xi::test::render_shot(s, exact());
    *shadow_max = *cut_err = *lit_err = 0.0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        dvec3 p;
        ASSERT_TRUE(hit_plane(camera_ray(s, W, H, x + 0.5, y + 0.5), 1, 0.0, &p));
        const double got = shot.mean.at(x, y).x;
        switch (where(p)) {
          case kShadow: *shadow_max = std::max(*shadow_max, got), ++counts[0]; break;
          case kCutOut: *cut_err = std::max(*cut_err, std::abs(got - lit) / lit), ++counts[1]; break;
          case kLit: *lit_err = std::max(*lit_err, std::abs(got - lit) / lit), ++counts[2]; break;
          case kEdge: break;
        }
      }
  };
  double shadow_max, cut_err, lit_err;
  int counts[3] = {0, 0, 0};
  run("mask", &shadow_max, &cut_err, &lit_err, counts);
  EXPECT_GT(counts[0], 50);
  EXPECT_GT(counts[1], 50);
  EXPECT_GT(counts[2], 100);
  EXPECT_EQ(shadow_max, 0.0) << "light inside the kept half's shadow";
  EXPECT_LT(cut_err, 1e-4) << "the cut-out half must cast no shadow";
  EXPECT_LT(lit_err, 1e-4);
  int opaque_counts[3] = {0, 0, 0};
  run("opaque", &shadow_max, &cut_err, &lit_err, opaque_counts);
  EXPECT_GT(cut_err, 0.99) << "opaque, the cut-out half should shadow too (the test could not tell)";

  // BLEND, alpha 0.3: 70% of the light passes on average.
  const xi::Scene s = load_json(dir, scene_with({{"type", "pbr"}, {"alpha", 0.3}, {"alpha_mode", "blend"}}));
  const xi::test::Shot shot = xi::test::render_shot(s, options(256, 9, XI_SAMPLER_RANDOM));
  double sum = 0.0, var = 0.0;
  int n = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      dvec3 p;
      hit_plane(camera_ray(s, W, H, x + 0.5, y + 0.5), 1, 0.0, &p);
      if (where(p) != kShadow && where(p) != kCutOut) continue;
      sum += shot.mean.at(x, y).x, var += shot.variance.at(x, y).x, ++n;
    }
  ASSERT_GT(n, 100);
  const double mean = sum / n, se = std::sqrt(var) / n, want = 0.7 * lit;
  EXPECT_LT(std::abs(mean - want) / se, xi::stats::sidak_critical_z(0.01, 1)) << mean << " ± " << se << " vs " << want;
  std::printf("blend shadow: %.5f ± %.5f, expected %.5f (unshadowed %.5f)\n", mean, se, want, lit);
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// e. A diffuse floor (ρ = 0.5) under an environment map written here (512×256 OpenEXR): a constant
// sky of radiance 0.2 and a 2×2-texel sun (about 4.6e-4 sr) of 5e4 holding about 90% of the power.
// Every floor point sees the whole upper hemisphere, so every pixel's expectation is ρ/π · E with E
// the map's irradiance on an up-facing plane: 0.2π from the sky plus the sun's excess, integrated
// here over the bilinearly filtered map (16×16 points per texel around the sun; Mitsuba's
// equirectangular directions, +y up). At equal spp (16) the relMSE of MIS (default) must be at
// least 10× below BSDF sampling's. Then z-tests at α = 0.01 (Šidák over the 3): the image means of
// MIS at 256 spp and of BSDF sampling at 1024 spp each against E, and against each other.
TEST(MaterialEnvironment, ImportanceSamplingPays) {
  const fs::path dir = temp_dir();
  const int EW = 512, EH = 256;
  const double sky = 0.2, sun = 5e4;
  xi::Image env(EW, EH);
  for (glm::vec3& p : env.pixels) p = glm::vec3(float(sky));
  for (int y = 70; y < 72; ++y)
    for (int x = 100; x < 102; ++x) env.at(x, y) = glm::vec3(float(sun));
  xi::write_exr(dir / "sky.exr", {{"", &env}});
  // Irradiance on an up-facing plane: the bilinear map (wrap in u, clamp in v) against cos⁺θ.
  auto lookup = [&](double u, double v) {
    const double s = u * EW - 0.5, t = v * EH - 0.5, s0 = std::floor(s), t0 = std::floor(t);
    double sum = 0.0;
    for (int dy = 0; dy < 2; ++dy)
      for (int dx = 0; dx < 2; ++dx) {
        const int x = ((int(s0) + dx) % EW + EW) % EW, y = std::clamp(int(t0) + dy, 0, EH - 1);
        sum += (dx ? s - s0 : 1.0 - (s - s0)) * (dy ? t - t0 : 1.0 - (t - t0)) * env.at(x, y).x;
      }
    return sum;
  };
  double excess = 0.0;  // ∫ (L − sky) cos⁺θ dω, dω = 2π² sin θ du dv, θ = πv (the direction's y is cos θ)
  const int sub = 16;
  for (int y = 66; y < 76; ++y)
    for (int x = 96; x < 106; ++x)
      for (int j = 0; j < sub; ++j)
        for (int i = 0; i < sub; ++i) {
          const double u = (x + (i + 0.5) / sub) / EW, v = (y + (j + 0.5) / sub) / EH, th = M_PI * v;
          excess += (lookup(u, v) - sky) * std::max(std::cos(th), 0.0) * 2.0 * M_PI * M_PI * std::sin(th) / (double(EW) * EH * sub * sub);
        }
  const double E = sky * M_PI + excess, rho = 0.5, want = rho / M_PI * E;
  std::printf("environment: irradiance %.5f (sky %.5f, sun %.5f): radiance %.6f\n", E, sky * M_PI, excess, want);
  ASSERT_GT(excess, 8.0 * sky * M_PI);  // the sun dominates

  const int W = 32, H = 32;
  const json scene = {{"camera", camera_json({0, 2, 3}, {0, 0, 0}, {0, 1, 0}, 40)},
                      {"film", {{"width", W}, {"height", H}}},
                      {"environment", {{"file", "sky.exr"}}},
                      {"materials", {{"floor", {{"type", "diffuse"}, {"albedo", {rho, rho, rho}}}}}},
                      {"shapes", {floor_quad("floor", 50)}}};
  const xi::Scene s = load_json(dir, scene);
  auto rel_mse = [&](const xi::Image& img) {
    double sum = 0.0;
    for (const glm::vec3& p : img.pixels) sum += (p.x - want) * (p.x - want) / (want * want);
    return sum / img.pixels.size();
  };
  const xi::test::Shot mis16 = xi::test::render_shot(s, options(16, 21, XI_SAMPLER_RANDOM));
  const xi::test::Shot bsdf16 = xi::test::render_shot(s, options(16, 22, XI_SAMPLER_RANDOM, 1, xi::Strategy::Bsdf));
  const double r_mis = rel_mse(mis16.mean), r_bsdf = rel_mse(bsdf16.mean);
  std::printf("environment: relMSE at 16 spp: mis %.4g, bsdf %.4g (ratio %.1f)\n", r_mis, r_bsdf, r_bsdf / r_mis);
  EXPECT_GT(r_bsdf, 10.0 * r_mis);

  const xi::test::Shot mis = xi::test::render_shot(s, options(256, 23, XI_SAMPLER_RANDOM));
  const xi::test::Shot bsdf = xi::test::render_shot(s, options(1024, 24, XI_SAMPLER_RANDOM, 1, xi::Strategy::Bsdf));
  ASSERT_EQ(mis.nonfinite + bsdf.nonfinite, 0u);
  const auto a = xi::test::block_mean(mis, 0, 0, W, H), b = xi::test::block_mean(bsdf, 0, 0, W, H);
  const double zc = xi::stats::sidak_critical_z(0.01, 3);
  std::printf("environment: mis %.6f ± %.6f, bsdf %.6f ± %.6f, expected %.6f\n", a.mean, a.se, b.mean, b.se, want);
  EXPECT_LT(std::abs(a.mean - want) / a.se, zc);
  EXPECT_LT(std::abs(b.mean - want) / b.se, zc);
  EXPECT_LT(std::abs(a.mean - b.mean) / std::hypot(a.se, b.se), zc);
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------
// f–h. glTF files.
namespace {

using xi_test::Gltf;  // gltf_builder.h

// The quad |x|, |y| ≤ 1 at z = 0 facing +z (counter-clockwise seen from +z), as two triangles, with
// texture coordinates set 0 (u = (x + 1)/2, v = (1 − y)/2: the image upright seen from +z) and set 1
// = set 0 mirrored in u.
struct Quad {
  std::vector<glm::vec3> pos, normals;
  std::vector<glm::vec2> uv0, uv1;
  Quad() {
    for (glm::vec2 p : {glm::vec2(-1, 1), glm::vec2(1, -1), glm::vec2(1, 1), glm::vec2(-1, 1), glm::vec2(-1, -1), glm::vec2(1, -1)}) {
      pos.push_back({p.x, p.y, 0.0f});
      normals.push_back({0, 0, 1});
      uv0.push_back({(p.x + 1) / 2, (1 - p.y) / 2});
      uv1.push_back({1 - (p.x + 1) / 2, (1 - p.y) / 2});
    }
  }
};

bool contains(const std::vector<std::string>& lines, const std::string& needle) {
  return std::any_of(lines.begin(), lines.end(), [&](const std::string& l) { return l.find(needle) != std::string::npos; });
}
int count_containing(const std::vector<std::string>& lines, const std::string& needle) {
  return int(std::count_if(lines.begin(), lines.end(), [&](const std::string& l) { return l.find(needle) != std::string::npos; }));
}

// A chrome quad (metallic 1, roughness 0: a mirror whose reflectance is Schlick's with f0 = the base
// colour) seen head-on by the file's camera (yfov 0.7, at (0, 0, 3)), under radiance 1: the pixel
// is exactly f0 + (1 − f0)(1 − cos θ)⁵, f0 = factor × texture at the hit.
const double kYfov = 0.7;
void add_chrome_quad(Gltf& g, json material) {
  const Quad q;
  material["name"] = "chrome";
  material["pbrMetallicRoughness"]["metallicFactor"] = 1.0;
  material["pbrMetallicRoughness"]["roughnessFactor"] = 0.0;
  const int m = g.add("materials", material);
  g.node({{"mesh", g.mesh(q.pos, q.normals, q.uv0, q.uv1, m)}});
  g.add("cameras", {{"type", "perspective"}, {"perspective", {{"yfov", kYfov}, {"aspectRatio", 1.0}, {"znear", 0.01}}}});
  g.node({{"name", "eye"}, {"camera", 0}, {"translation", {0.0, 0.0, 3.0}}});
}

// Renders a chrome-quad file at W×W under radiance 1 (no sky) and returns the largest difference
// from f0(uv) + (1 − f0)(1 − cos)⁵, f0 from `base` at the pixel centre's hit.
double chrome_error(const fs::path& file, int W, const std::function<dvec3(dvec2 uv0)>& base, xi::Image* out = nullptr) {
  xi::Scene s = xi::load_asset(file, xi::AssetOptions{.sky = false});
  s.background = glm::vec3(1.0f);
  const xi::test::Shot shot = xi::test::render_shot(s, W, W, exact());
  EXPECT_EQ(shot.nonfinite, 0u);
  double err = 0.0;
  int compared = 0;
  for (int y = 0; y < W; ++y)
    for (int x = 0; x < W; ++x) {
      const Ray r = camera_ray({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, glm::degrees(kYfov), W, W, x + 0.5, y + 0.5);
      dvec3 p;
      if (!hit_plane(r, 2, 0.0, &p) || std::abs(p.x) > 0.97 || std::abs(p.y) > 0.97) continue;
      const double cos_t = -r.d.z;
      const dvec3 f0 = base({(p.x + 1) / 2, (1 - p.y) / 2});
      for (int c = 0; c < 3; ++c)
        err = std::max(err, std::abs(shot.mean.at(x, y)[c] - (f0[c] + (1 - f0[c]) * std::pow(1 - cos_t, 5.0))));
      ++compared;
    }
  EXPECT_GT(compared, W * W / 3);
  if (out) *out = shot.mean;
  return err;
}

}  // namespace

// f. A textured chrome quad in a .gltf, its PNG once as a file beside it and once as a data URI:
// texture coordinate set 1, sampler wrapS MIRRORED_REPEAT / wrapT CLAMP_TO_EDGE and a
// KHR_texture_transform (offset, rotation, scale). Both load the image texel for texel, the slot
// as the file says, the triangles' texture coordinates as the accessors hold them, and render
// identically: at each pixel centre within 1e-3 of the mirror's reflectance with f0 the host
// sampler's value there (1 sample through the centre, exact; 1e-3 covers float rounding).
TEST(MaterialGltf, TexturedChromeFromFileAndDataUri) {
  const fs::path dir = temp_dir();
  const Rgba tex = pattern4();
  write_png(dir / "checker.png", tex);
  const dvec2 offset(-0.2, 0.1), scale(1.5, 1.25);
  const double rotation = 0.3;
  xi::Image renders[2];
  for (int k = 0; k < 2; ++k) {
    SCOPED_TRACE(k ? "data URI" : "file");
    Gltf g;
    g.doc["extensionsUsed"] = {"KHR_texture_transform"};
    g.add("samplers", {{"wrapS", 33648}, {"wrapT", 33071}});
    g.add("images", {{"uri", k ? "data:image/png;base64," + base64(png_bytes(tex)) : "checker.png"}});
    g.add("textures", {{"source", 0}, {"sampler", 0}});
    add_chrome_quad(g, {{"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}, {"texCoord", 1},
        {"extensions", {{"KHR_texture_transform", {{"offset", {offset.x, offset.y}}, {"rotation", rotation}, {"scale", {scale.x, scale.y}}}}}}}}}}});
    const fs::path file = dir / (k ? "uri.gltf" : "file.gltf");
    g.write(file);

    const xi::Scene s = xi::load_asset(file, xi::AssetOptions{.sky = false});
    ASSERT_EQ(s.images.size(), 1u);
    const xi::TextureImage& img = s.images[0];
    EXPECT_EQ(img.width, 4);
    EXPECT_EQ(img.height, 4);
    EXPECT_TRUE(img.srgb);
    ASSERT_EQ(img.texels.size(), 16u);
    for (int i = 0; i < 16; ++i) {
      const uint32_t want = tex.px[4 * i] | tex.px[4 * i + 1] << 8 | tex.px[4 * i + 2] << 16 | uint32_t(tex.px[4 * i + 3]) << 24;
      EXPECT_EQ(img.texels[i], want) << "texel " << i;
    }
    ASSERT_EQ(s.materials.size(), 1u);
    const xi::Material& m = s.materials[0];
    EXPECT_EQ(m.type, xi::MaterialType::Pbr);
    EXPECT_EQ(m.metallic, 1.0f);
    EXPECT_EQ(m.roughness, 0.0f);
    EXPECT_EQ(m.albedo, glm::vec3(1.0f));
    EXPECT_EQ(m.textures[XI_TEXTURE_BASE_COLOR].image, 0);
    EXPECT_EQ(m.textures[XI_TEXTURE_BASE_COLOR].texcoord, 1);
    EXPECT_EQ(m.textures[XI_TEXTURE_BASE_COLOR].wrap_s, xi::Wrap::Mirror);
    EXPECT_EQ(m.textures[XI_TEXTURE_BASE_COLOR].wrap_t, xi::Wrap::Clamp);
    for (const dvec2 uv : {dvec2(0.3, 0.9), dvec2(-1.2, 2.5)}) {
      const glm::vec3 t = m.textures[XI_TEXTURE_BASE_COLOR].transform * glm::vec3(glm::vec2(uv), 1.0f);
      const dvec2 want = khr_transform(uv, offset, rotation, scale);
      EXPECT_NEAR(t.x, want.x, 1e-5);
      EXPECT_NEAR(t.y, want.y, 1e-5);
    }
    EXPECT_FALSE(s.environment.has_value());
    EXPECT_TRUE(contains(s.notes, "no light in the file and no environment"));
    ASSERT_EQ(s.triangles.size(), 2u);
    const Quad q;
    for (const xi::Triangle& t : s.triangles)
      for (int v = 0; v < 3; ++v) {
        const glm::vec2 want0((s.position(t, v).x + 1) / 2, (1 - s.position(t, v).y) / 2);
        EXPECT_NEAR(xi::texcoords_of(s.texcoords, t).uv[0][v].x, want0.x, 1e-6);
        EXPECT_NEAR(xi::texcoords_of(s.texcoords, t).uv[0][v].y, want0.y, 1e-6);
        EXPECT_NEAR(xi::texcoords_of(s.texcoords, t).uv[1][v].x, 1 - want0.x, 1e-6);
        EXPECT_NEAR(xi::texcoords_of(s.texcoords, t).uv[1][v].y, want0.y, 1e-6);
      }
    const double err = chrome_error(file, 32, [&](dvec2 uv0) {
      const dvec2 uv1(1 - uv0.x, uv0.y);
      return dvec3(sample(tex, khr_transform(uv1, offset, rotation, scale), Wrap::Mirror, Wrap::Clamp));
    }, &renders[k]);
    EXPECT_LT(err, 1e-3);
    // Must-fail: texture coordinate set 0 instead.
    const double err0 = chrome_error(file, 32, [&](dvec2 uv0) {
      return dvec3(sample(tex, khr_transform(uv0, offset, rotation, scale), Wrap::Mirror, Wrap::Clamp));
    });
    EXPECT_GT(err0, 0.1);
  }
  EXPECT_EQ(renders[0].pixels, renders[1].pixels);
  fs::remove_all(dir);
}

// Normal maps: the tangent frame is the file's TANGENT where it has one, else the triangle's
// direction of increasing u. A floor quad (normal +y) whose constant normal map tilts the normal
// along both tangent and bitangent, under a directional light and a black background (one bounce:
// every pixel is its light sample, no noise). Its texture coordinates run u along +z in one file
// and along +x in the others, which carry TANGENT +z with w = 1 (the same frame as the first: the
// image must be the same), w = -1 (the bitangent reversed) or no TANGENT (u's frame): those must
// differ. A node that mirrors x turns the file's frame (+z, +x) into its mirror image (+z, -x): w
// flips with the mirroring, and the (symmetric, evenly lit) quad renders as with w = -1.
TEST(MaterialNormalMap, TangentsFromTheFileOrTheTriangle) {
  const fs::path dir = temp_dir();
  Rgba tilt{1, 1, {179, 166, 238, 255}};  // (0.40, 0.30, 0.87) in tangent space
  const std::string png = "data:image/png;base64," + base64(png_bytes(tilt));
  auto write = [&](const std::string& name, bool u_along_z, std::vector<glm::vec4> tangents, double mirror_x) {
    Gltf g;
    g.add("images", {{"uri", png}});
    g.add("textures", {{"source", 0}});
    g.add("materials", {{"name", "bumpy"}, {"normalTexture", {{"index", 0}}},
                        {"pbrMetallicRoughness", {{"baseColorFactor", {0.8, 0.8, 0.8, 1.0}}, {"metallicFactor", 0.0},
                                                  {"roughnessFactor", 0.7}}}});
    const std::vector<glm::vec3> corners = {{-1, 0, -1}, {-1, 0, 1}, {1, 0, 1}, {-1, 0, -1}, {1, 0, 1}, {1, 0, -1}};
    std::vector<glm::vec3> normals(6, glm::vec3(0, 1, 0));
    std::vector<glm::vec2> uv;
    for (const glm::vec3& c : corners) uv.push_back(u_along_z ? glm::vec2((c.z + 1) / 2, (c.x + 1) / 2)
                                                              : glm::vec2((c.x + 1) / 2, (1 - c.z) / 2));
    g.mesh(corners, normals, uv, {}, 0, tangents);
    g.node({{"mesh", 0}, {"scale", {mirror_x, 1.0, 1.0}}});
    g.write(dir / (name + ".gltf"));
    return dir / (name + ".gltf");
  };
  auto render = [&](const fs::path& model) {
    const json scene = {{"camera", camera_json({0.3, 2.5, 0.2}, {0, 0, 0}, {0, 0, -1}, 40)},
                        {"film", {{"width", 24}, {"height", 24}}},
                        {"background", {0, 0, 0}},
                        {"lights", {{{"type", "directional"}, {"direction", {-0.5, -1.0, -0.7}}, {"intensity", 3}}}},
                        {"materials", json::object()},
                        {"shapes", {{{"type", "asset"}, {"file", model.filename().string()}}}}};
    return xi::test::render_shot(load_json(dir, scene), options(2, 3, XI_SAMPLER_RANDOM)).mean;
  };
  auto max_rel = [](const xi::Image& a, const xi::Image& b) {
    double m = 0.0;
    for (size_t i = 0; i < a.pixels.size(); ++i)
      for (int c = 0; c < 3; ++c)
        m = std::max(m, std::abs(double(a.pixels[i][c]) - b.pixels[i][c]) / std::max(double(b.pixels[i][c]), 1e-3));
    return m;
  };
  const glm::vec4 along_z(0, 0, 1, 1), along_z_reversed(0, 0, 1, -1);
  const xi::Image from_u = render(write("u-along-z", true, {}, 1.0));
  const xi::Image file = render(write("tangent", false, std::vector<glm::vec4>(6, along_z), 1.0));
  const xi::Image reversed = render(write("reversed", false, std::vector<glm::vec4>(6, along_z_reversed), 1.0));
  const xi::Image without = render(write("no-tangent", false, {}, 1.0));
  size_t lit = 0;
  for (const glm::vec3& p : from_u.pixels) lit += p.x > 0.01f;
  EXPECT_GT(lit, from_u.pixels.size() / 2);
  const double same = max_rel(file, from_u), flipped = max_rel(reversed, from_u), derived = max_rel(without, from_u);
  std::printf("[ tangents ] file vs u's frame: %.2e; w = -1: %.3f; no TANGENT: %.3f\n", same, flipped, derived);
  EXPECT_LT(same, 1e-4);
  EXPECT_GT(flipped, 0.05);
  EXPECT_GT(derived, 0.05);
  const xi::Image mirrored = render(write("mirrored", false, std::vector<glm::vec4>(6, along_z), -1.0));
  EXPECT_LT(max_rel(mirrored, reversed), 1e-4);
  EXPECT_GT(max_rel(mirrored, file), 0.05);  // w kept through the mirroring
  fs::remove_all(dir);
}

// f. KHR_lights_punctual (a point light placed by its node's translation, a directional light
// turned by its node's rotation), alphaMode MASK with a texture's alpha, KHR_materials_transmission
// with KHR_materials_ior: read as the file says; a file with lights is not given the sky; it renders
// with no non-finite sample, the floor lit.
TEST(MaterialGltf, LightsMaskAndTransmission) {
  const fs::path dir = temp_dir();
  Rgba half{2, 1, std::vector<uint8_t>(8, 255)};
  half.at(1, 0, 3) = 0;
  Gltf g;
  g.doc["extensionsUsed"] = {"KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_ior"};
  g.add("images", {{"uri", "data:image/png;base64," + base64(png_bytes(half))}});
  g.add("textures", {{"source", 0}});
  const int floor = g.add("materials", {{"name", "floor"}, {"pbrMetallicRoughness", {{"baseColorFactor", {0.8, 0.8, 0.8, 1.0}}, {"metallicFactor", 0.0}, {"roughnessFactor", 1.0}}}});
  const int cutout = g.add("materials", {{"name", "cutout"}, {"alphaMode", "MASK"}, {"alphaCutoff", 0.4}, {"doubleSided", true},
                                         {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0.0}}}});
  const int glass = g.add("materials", {{"name", "glass"}, {"pbrMetallicRoughness", {{"metallicFactor", 0.0}, {"roughnessFactor", 0.1}}},
                                        {"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}}, {"KHR_materials_ior", {{"ior", 1.4}}}}}});
  const Quad q;
  std::vector<glm::vec3> floor_pos;  // the quad turned to y = 0, facing +y, 4 wide
  for (const glm::vec3& p : q.pos) floor_pos.push_back({2 * p.x, 0.0f, -2 * p.y});
  g.node({{"mesh", g.mesh(floor_pos, {}, q.uv0, {}, floor)}});
  g.node({{"mesh", g.mesh(q.pos, q.normals, q.uv0, {}, cutout)}, {"translation", {-0.8, 1.0, 0.0}}, {"scale", {0.5, 0.5, 0.5}}});
  g.node({{"mesh", g.mesh(q.pos, q.normals, q.uv0, {}, glass)}, {"translation", {0.8, 1.0, 0.0}}, {"scale", {0.5, 0.5, 0.5}}});
  g.doc["extensions"]["KHR_lights_punctual"]["lights"] = {
      {{"name", "bulb"}, {"type", "point"}, {"color", {1.0, 0.5, 0.25}}, {"intensity", 20.0}},
      {{"name", "sun"}, {"type", "directional"}, {"intensity", 2.0}}};
  g.node({{"name", "bulb"}, {"translation", {0.0, 2.0, 1.0}}, {"extensions", {{"KHR_lights_punctual", {{"light", 0}}}}}});
  g.node({{"name", "sun"}, {"rotation", {-std::sqrt(0.5), 0.0, 0.0, std::sqrt(0.5)}},  // −90° about x: −z turns to −y
          {"extensions", {{"KHR_lights_punctual", {{"light", 1}}}}}});
  g.add("cameras", {{"type", "perspective"}, {"perspective", {{"yfov", 0.9}, {"aspectRatio", 1.0}, {"znear", 0.01}}}});
  g.node({{"camera", 0}, {"translation", {0.0, 1.2, 4.0}}});
  g.write(dir / "lights.gltf");

  const xi::Scene s = xi::load_asset(dir / "lights.gltf");
  ASSERT_EQ(s.lights.size(), 2u);
  for (const xi::Light& l : s.lights) {
    SCOPED_TRACE(l.name);
    if (l.name == "bulb") {
      EXPECT_EQ(l.type, xi::LightType::Point);
      EXPECT_NEAR(l.position.x, 0.0f, 1e-6);
      EXPECT_NEAR(l.position.y, 2.0f, 1e-6);
      EXPECT_NEAR(l.position.z, 1.0f, 1e-6);
      EXPECT_NEAR(l.intensity.x, 20.0f, 1e-4);  // colour × intensity (candela: W/sr in xi)
      EXPECT_NEAR(l.intensity.y, 10.0f, 1e-4);
      EXPECT_NEAR(l.intensity.z, 5.0f, 1e-4);
    } else {
      EXPECT_EQ(l.name, "sun");
      EXPECT_EQ(l.type, xi::LightType::Directional);
      EXPECT_NEAR(l.direction.x, 0.0f, 1e-5);
      EXPECT_NEAR(l.direction.y, -1.0f, 1e-5);
      EXPECT_NEAR(l.direction.z, 0.0f, 1e-5);
      EXPECT_NEAR(l.intensity.x, 2.0f, 1e-5);
      EXPECT_EQ(l.angular_radius, 0.0f);
    }
  }
  EXPECT_FALSE(s.environment.has_value()) << "a file with lights is lit by them, not the sky";
  EXPECT_FALSE(contains(s.notes, "no light in the file"));
  auto find = [&](const std::string& name) -> const xi::Material& {
    for (const auto& m : s.materials)
      if (m.name == name) return m;
    throw std::runtime_error("no material " + name);
  };
  EXPECT_EQ(find("cutout").alpha_mode, xi::AlphaMode::Mask);
  EXPECT_NEAR(find("cutout").alpha_cutoff, 0.4f, 1e-6);
  EXPECT_TRUE(find("cutout").textures[XI_TEXTURE_BASE_COLOR].used());
  EXPECT_EQ(find("glass").type, xi::MaterialType::Pbr);
  EXPECT_EQ(find("glass").transmission, 1.0f);
  EXPECT_NEAR(find("glass").ior, 1.4f, 1e-6);
  EXPECT_NEAR(find("glass").roughness, 0.1f, 1e-6);
  EXPECT_EQ(find("floor").alpha_mode, xi::AlphaMode::Opaque);
  ASSERT_EQ(s.images.size(), 1u);
  EXPECT_EQ(s.images[0].texels[1] >> 24, 0u);
  EXPECT_EQ(s.images[0].texels[0] >> 24, 255u);

  const xi::test::Shot shot = xi::test::render_shot(s, 32, 32, options(4, 1, XI_SAMPLER_RANDOM, 4));
  EXPECT_EQ(shot.nonfinite, 0u);
  EXPECT_TRUE(all_finite(shot.mean));
  double brightest = 0.0;
  for (const glm::vec3& p : shot.mean.pixels) brightest = std::max(brightest, double(p.x));
  EXPECT_GT(brightest, 0.05);
  fs::remove_all(dir);
}

// g. Debian's assimp-testmodels (not written here).
TEST(MaterialGltf, AssimpTestModels) {
  // BoxTextured as .gltf with a .bin and a PNG, as .glb, and embedded: one image each, the same.
  std::vector<xi::Scene> boxes;
  for (const char* f : {"BoxTextured-glTF/BoxTextured.gltf", "BoxTextured-glTF-Binary/BoxTextured.glb",
                        "BoxTextured-glTF-Embedded/BoxTextured.gltf"}) {
    SCOPED_TRACE(f);
    boxes.push_back(xi::load_asset(kModels / f, xi::AssetOptions{.height = 32}));
    const xi::Scene& s = boxes.back();
    ASSERT_EQ(s.images.size(), 1u);
    EXPECT_GT(s.images[0].width, 0);
    ASSERT_FALSE(s.materials.empty());
    EXPECT_EQ(s.materials[0].type, xi::MaterialType::Pbr);
    EXPECT_EQ(s.materials[0].textures[XI_TEXTURE_BASE_COLOR].image, 0);
    EXPECT_TRUE(s.environment.has_value()) << "no light in the file: the bundled sky";
  }
  for (size_t i = 1; i < boxes.size(); ++i) {
    EXPECT_EQ(boxes[i].images[0].width, boxes[0].images[0].width);
    EXPECT_EQ(boxes[i].images[0].height, boxes[0].images[0].height);
    EXPECT_TRUE(boxes[i].images[0].texels == boxes[0].images[0].texels) << "image " << i << " differs";
  }

  // TextureTransformTest: every textureInfo with KHR_texture_transform gives that matrix.
  const fs::path tt = kModels / "textureTransform/TextureTransformTest.gltf";
  const json doc = json::parse(xi_test::read_text(tt));
  const xi::Scene t = xi::load_asset(tt, xi::AssetOptions{.height = 32});
  int transformed = 0;
  for (const json& m : doc["materials"]) {
    const json& info = m["pbrMetallicRoughness"]["baseColorTexture"];
    if (!info.contains("extensions") || !info["extensions"].contains("KHR_texture_transform")) continue;
    const json& x = info["extensions"]["KHR_texture_transform"];
    const dvec2 offset = x.contains("offset") ? dvec2(x["offset"][0], x["offset"][1]) : dvec2(0.0);
    const dvec2 scale = x.contains("scale") ? dvec2(x["scale"][0], x["scale"][1]) : dvec2(1.0);
    const double rotation = x.value("rotation", 0.0);
    const std::string name = m["name"];
    SCOPED_TRACE(name);
    const auto found = std::find_if(t.materials.begin(), t.materials.end(), [&](const xi::Material& mm) { return mm.name == name; });
    ASSERT_NE(found, t.materials.end());
    ASSERT_TRUE(found->textures[XI_TEXTURE_BASE_COLOR].used());
    for (const dvec2 uv : {dvec2(0.25, 0.5), dvec2(1.0, 0.0)}) {
      const glm::vec3 got = found->textures[XI_TEXTURE_BASE_COLOR].transform * glm::vec3(glm::vec2(uv), 1.0f);
      const dvec2 want = khr_transform(uv, offset, rotation, scale);
      EXPECT_NEAR(got.x, want.x, 1e-5);
      EXPECT_NEAR(got.y, want.y, 1e-5);
    }
    ++transformed;
  }
  EXPECT_GE(transformed, 5);
  EXPECT_FALSE(t.images.empty());

  // ClearCoatTest: its coats' factors and textures are read, their own normal maps among them.
  const xi::Scene cc = xi::load_asset(kModels / "ClearCoat-glTF/ClearCoatTest.gltf", xi::AssetOptions{.height = 32});
  EXPECT_EQ(count_containing(cc.warnings, "clearcoat"), 0);
  int coated = 0;
  for (const xi::Material& m : cc.materials) {
    const bool should = m.name.size() > 7 && m.name.substr(m.name.size() - 7) == "_Coated";
    EXPECT_EQ(m.clearcoat, should ? 1.0f : 0.0f) << m.name;
    if (m.name == "Simple_Coated") EXPECT_FLOAT_EQ(m.clearcoat_roughness, 0.03f);
    if (m.name == "RoughVariations_Coated") EXPECT_FLOAT_EQ(m.clearcoat_roughness, 1.0f);
    EXPECT_EQ(m.textures[XI_TEXTURE_CLEARCOAT].used(), m.name == "Partial_Coated") << m.name;
    EXPECT_EQ(m.textures[XI_TEXTURE_CLEARCOAT_ROUGHNESS].used(), m.name == "RoughVariations_Coated") << m.name;
    EXPECT_EQ(m.textures[XI_TEXTURE_CLEARCOAT_NORMAL].used(), m.name == "CoatNorm_Coated" || m.name == "SharedNorm_Coated")
        << m.name;
    coated += should;
  }
  EXPECT_EQ(coated, 6);
  for (size_t i = 0; i < cc.warnings.size(); ++i)
    for (size_t j = i + 1; j < cc.warnings.size(); ++j) EXPECT_NE(cc.warnings[i], cc.warnings[j]);

  const xi::Scene engine = xi::load_asset(kModels / "2CylinderEngine-glTF-Binary/2CylinderEngine.glb", xi::AssetOptions{.height = 32});
  EXPECT_GT(engine.triangles.size(), 1000u);

  for (const xi::Scene* s : std::vector<const xi::Scene*>{&boxes[0], &boxes[1], &boxes[2], &t, &cc, &engine}) {
    SCOPED_TRACE(s->source);
    const xi::test::Shot shot = xi::test::render_shot(*s, 32, 32, options(2, 1, XI_SAMPLER_RANDOM, 4));
    EXPECT_EQ(shot.nonfinite, 0u);
    EXPECT_TRUE(all_finite(shot.mean));
  }
}

// h. Bad texture input. In a glTF file: an image file that is missing, one that is not an image:
// one warning each, naming the material and the image file, and the chrome quad renders with its
// base colour factor alone (f0 = 0.6, exactly). A texture index out of range is refused by Assimp
// 5.2's glTF reader before xi reads the materials: one error naming the file (gltf.cpp's warning
// for it is only reached where Assimp lets the file through). In a JSON scene a missing image is
// one error naming the JSON path and the file.
TEST(MaterialGltf, BadTexturesFallBackToTheFactor) {
  const fs::path dir = temp_dir();
  xi_test::write_text(dir / "corrupt.png", "\x89PNG\r\n\x1a\nthis is not a png");
  struct Bad {
    const char* name;
    const char* uri;
    int index;
    const char* warning;
  };
  {
    Gltf g;
    g.add("images", {{"uri", "none.png"}});
    g.add("textures", {{"source", 0}});
    add_chrome_quad(g, {{"pbrMetallicRoughness", {{"baseColorFactor", {0.6, 0.6, 0.6, 1.0}}, {"baseColorTexture", {{"index", 5}}}}}});
    g.write(dir / "index.gltf");
    try {
      xi::load_asset(dir / "index.gltf");
      ADD_FAILURE() << "loaded";
    } catch (const xi::Error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find((dir / "index.gltf").string()), std::string::npos) << what;
      EXPECT_NE(what.find("out of bounds"), std::string::npos) << what;
    }
  }
  for (const Bad& b : {Bad{"missing", "missing.png", 0, "missing.png"},
                       Bad{"corrupt", "corrupt.png", 0, "corrupt.png"}}) {
    SCOPED_TRACE(b.name);
    Gltf g;
    g.add("images", {{"uri", b.uri}});
    g.add("textures", {{"source", 0}});
    add_chrome_quad(g, {{"pbrMetallicRoughness", {{"baseColorFactor", {0.6, 0.6, 0.6, 1.0}}, {"baseColorTexture", {{"index", b.index}}}}}});
    const fs::path file = dir / (std::string(b.name) + ".gltf");
    g.write(file);
    const xi::Scene s = xi::load_asset(file, xi::AssetOptions{.sky = false});
    EXPECT_EQ(count_containing(s.warnings, b.warning), 1) << (s.warnings.empty() ? "no warning" : s.warnings[0]);
    EXPECT_EQ(s.warnings.size(), 1u);
    EXPECT_TRUE(contains(s.warnings, "chrome")) << "the warning names the material";
    EXPECT_FALSE(s.materials.at(0).textures[XI_TEXTURE_BASE_COLOR].used());
    EXPECT_LT(chrome_error(file, 16, [](dvec2) { return dvec3(0.6); }), 1e-4);
  }
  const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 40)},
                      {"materials", {{"tex", {{"type", "diffuse"}, {"albedo", {{"file", "gone.png"}}}}}}},
                      {"shapes", {{{"type", "quad"}, {"material", "tex"}, {"vertices", {{-1, 1, 0}, {1, 1, 0}, {1, -1, 0}, {-1, -1, 0}}}}}}};
  xi_test::write_text(dir / "scene.json", scene.dump());
  try {
    xi::load_scene(dir / "scene.json");
    ADD_FAILURE() << "loaded";
  } catch (const xi::Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("/materials/tex/albedo/file"), std::string::npos) << what;
    EXPECT_NE(what.find("gone.png"), std::string::npos) << what;
    EXPECT_EQ(std::count(what.begin(), what.end(), '\n'), 0) << what;
  }
  fs::remove_all(dir);
}

// A BLEND surface's pass-through decision for a shadow ray draws on the path's own stream (seed,
// pixel, sample, bounce): two renders with the same seed are bitwise the same (README: the image
// does not depend on threads or pass size), and a pixel in the shadow, 64 passes of one sample,
// has a variance near p(1 − p)·lit²/64, not the zero of a decision repeated every pass.
TEST(MaterialAlpha, BlendShadowIsDeterministicAndSeeded) {
  const fs::path dir = temp_dir();
  const json scene = {{"camera", camera_json({1.5, 4, 0}, {1.5, 0, 0}, {0, 0, -1}, 20)},
                      {"film", {{"width", 32}, {"height", 32}}},
                      {"lights", {{{"type", "directional"}, {"direction", {1, -1, 0}}, {"intensity", 2.0}}}},
                      {"materials", {{"floor", {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}}},
                                     {"occluder", {{"type", "pbr"}, {"alpha", 0.3}, {"alpha_mode", "blend"}}}}},
                      {"shapes", {floor_quad("floor", 3),
                                  {{"type", "quad"}, {"material", "occluder"},
                                   {"vertices", {{-0.5, 1.5, -0.5}, {0.5, 1.5, -0.5}, {0.5, 1.5, 0.5}, {-0.5, 1.5, 0.5}}}}}}};
  const xi::Scene s = load_json(dir, scene);
  xi::RenderOptions o = options(64, 9, XI_SAMPLER_RANDOM);
  o.samples_per_pass = 1;
  const xi::test::Shot a = xi::test::render_shot(s, o), b = xi::test::render_shot(s, o);
  EXPECT_TRUE(a.mean.pixels == b.mean.pixels) << "same seed, different images";
  int frozen = 0, shadowed = 0;
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 32; ++x) {
      dvec3 p;
      hit_plane(camera_ray(s, 32, 32, x + 0.5, y + 0.5), 1, 0.0, &p);
      if (std::abs(p.z) > 0.45 || p.x < 1.05 || p.x > 1.95) continue;
      ++shadowed;
      frozen += a.variance.at(x, y).x == 0.0f;
    }
  std::printf("blend shadow, one sample per pass: %d of %d shadowed pixels have zero variance\n", frozen, shadowed);
  EXPECT_LT(frozen, shadowed / 100 + 1);
  fs::remove_all(dir);
}

// KHR_materials_volume: Beer–Lambert through a slab. The camera looks through two parallel faces a
// distance L apart (ior 1, smooth, transmission 1: no refraction and, near the axis, no Fresnel)
// at a background of 1; inside, σa = −ln(c) / d. Each channel of the centre pixels must be c^(L/d)
// within the Šidák-corrected z (α = 0.01 over 3 channels) standard errors plus 1e-4 (the path is
// L / cos θ long, θ under 0.3° there). Must-fail: the clear slab (1) and absorption counted twice
// (c^(2L/d)) are rejected. A ray leaving the slab returns to the outside: were it still inside,
// the escaped path would be absorbed (0).
TEST(MaterialVolume, BeerLambertThroughASlab) {
  const fs::path dir = temp_dir();
  const double L = 0.5, d = 0.8;
  const dvec3 c(0.3, 0.6, 0.9);
  const int W = 16, H = 16;
  const json pbr = {{"type", "pbr"}, {"base_color", {1, 1, 1}}, {"metallic", 0}, {"roughness", 0}, {"ior", 1.0},
                    {"transmission", 1}, {"attenuation_color", {c.x, c.y, c.z}}, {"attenuation_distance", d}};
  const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 10)},
                      {"film", {{"width", W}, {"height", H}}},
                      {"background", {1, 1, 1}},
                      {"materials", {{"slab", pbr}}},
                      {"shapes", {{{"type", "quad"}, {"material", "slab"}, {"vertices", {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}}}},
                                  {{"type", "quad"}, {"material", "slab"}, {"vertices", {{-2, -2, -L}, {-2, 2, -L}, {2, 2, -L}, {2, -2, -L}}}}}}};
  const xi::Scene s = load_json(dir, scene);
  ASSERT_GT(s.materials[0].volume_absorption().x, 0.0f);
  const xi::test::Shot shot = xi::test::render_shot(s, options(256, 5, XI_SAMPLER_RANDOM, 4));
  ASSERT_EQ(shot.nonfinite, 0u);
  const double z = xi::stats::sidak_critical_z(0.01, 3);
  int clear_rejected = 0, twice_rejected = 0;
  for (int ch = 0; ch < 3; ++ch) {
    const xi::test::MeanSe got = xi::test::block_mean(shot, W / 2 - 2, H / 2 - 2, W / 2 + 2, H / 2 + 2, ch);
    const double want = std::pow(c[ch], L / d), tol = z * got.se + 1e-4;
    std::printf("[ volume   ] channel %d: %.5f ± %.1e, Beer–Lambert %.5f\n", ch, got.mean, got.se, want);
    EXPECT_NEAR(got.mean, want, tol) << "channel " << ch;
    clear_rejected += std::abs(got.mean - 1.0) > tol;
    twice_rejected += std::abs(got.mean - std::pow(c[ch], 2.0 * L / d)) > tol;
  }
  EXPECT_EQ(clear_rejected, 3);
  EXPECT_EQ(twice_rejected, 3);
}

// The layers' glTF extensions are read as the spec defines them: KHR_materials_clearcoat's factors
// (default 0), KHR_materials_specular's (default 1, white), KHR_materials_sheen's (default 0),
// KHR_materials_pbrSpecularGlossiness as a specular tint, KHR_materials_anisotropy's strength
// (default 0), rotation and texture, KHR_materials_volume's absorption
// −ln(attenuationColor) / attenuationDistance where thicknessFactor > 0 (0: thin-walled, none; an
// infinite distance: clear), none without transmission. Each turns on its kernel feature only.
TEST(MaterialGltf, LayerExtensions) {
  const fs::path dir = temp_dir();
  Gltf g;
  g.doc["extensionsUsed"] = {"KHR_materials_clearcoat", "KHR_materials_specular", "KHR_materials_volume",
                             "KHR_materials_transmission"};
  g.add("images", {{"uri", "data:image/png;base64," + base64(png_bytes(pattern4()))}});
  g.add("textures", {{"source", 0}});
  const json tex = {{"index", 0}};
  const json plain = {{"metallicFactor", 0.0}, {"roughnessFactor", 0.5}};
  const json glass = {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}}};
  auto with = [&](json ext, const json& more) {
    for (auto& [k, v] : more.items()) ext[k] = v;
    return ext;
  };
  const json clearcoat = {{"clearcoatFactor", 0.7}, {"clearcoatRoughnessFactor", 0.2}, {"clearcoatTexture", tex},
                          {"clearcoatRoughnessTexture", tex}};
  const int coat = g.add("materials", {{"name", "coat"}, {"pbrMetallicRoughness", plain},
                                       {"extensions", {{"KHR_materials_clearcoat", clearcoat}}}});
  const json specular = {{"specularFactor", 0.4}, {"specularColorFactor", {1.0, 0.5, 2.0}}, {"specularTexture", tex},
                         {"specularColorTexture", tex}};
  const int spec = g.add("materials", {{"name", "spec"}, {"pbrMetallicRoughness", plain},
                                       {"extensions", {{"KHR_materials_specular", specular}}}});
  const int vol = g.add("materials", {{"name", "vol"}, {"pbrMetallicRoughness", plain},
                                      {"extensions", with(glass, {{"KHR_materials_volume", {{"thicknessFactor", 1.0}, {"attenuationColor", {0.5, 0.25, 1.0}}, {"attenuationDistance", 2.0}}}})}});
  const int thin = g.add("materials", {{"name", "thin"}, {"pbrMetallicRoughness", plain},
                                       {"extensions", with(glass, {{"KHR_materials_volume", {{"thicknessFactor", 0.0}, {"attenuationColor", {0.5, 0.5, 0.5}}, {"attenuationDistance", 1.0}}}})}});
  const int opaque = g.add("materials", {{"name", "opaque"}, {"pbrMetallicRoughness", plain},
                                         {"extensions", {{"KHR_materials_volume", {{"thicknessFactor", 1.0}, {"attenuationColor", {0.5, 0.5, 0.5}}, {"attenuationDistance", 1.0}}}}}});
  const json sg = {{"diffuseFactor", {0.5, 0.25, 0.125, 1.0}}, {"specularFactor", {0.2, 0.1, 0.04}}, {"glossinessFactor", 0.75}};
  const int gloss = g.add("materials", {{"name", "gloss"}, {"pbrMetallicRoughness", {{"metallicFactor", 1.0}}},
                                        {"extensions", {{"KHR_materials_pbrSpecularGlossiness", sg}}}});
  const json fibres = {{"sheenColorFactor", {0.9, 0.5, 0.1}}, {"sheenRoughnessFactor", 0.4}, {"sheenColorTexture", tex},
                       {"sheenRoughnessTexture", tex}};
  const int sheen = g.add("materials", {{"name", "sheen"}, {"pbrMetallicRoughness", plain},
                                        {"extensions", {{"KHR_materials_sheen", fibres}}}});
  const json brushed = {{"anisotropyStrength", 0.6}, {"anisotropyRotation", 1.25}, {"anisotropyTexture", tex}};
  const int aniso = g.add("materials", {{"name", "aniso"}, {"pbrMetallicRoughness", plain},
                                        {"extensions", {{"KHR_materials_anisotropy", brushed}}}});
  const json film = {{"iridescenceFactor", 0.8}, {"iridescenceIor", 1.6}, {"iridescenceThicknessMinimum", 250.0},
                     {"iridescenceThicknessMaximum", 650.0}, {"iridescenceTexture", tex}, {"iridescenceThicknessTexture", tex}};
  const int irid = g.add("materials", {{"name", "irid"}, {"pbrMetallicRoughness", plain},
                                       {"extensions", {{"KHR_materials_iridescence", film}}}});
  const int bare = g.add("materials", {{"name", "bare"}, {"pbrMetallicRoughness", plain},
                                       {"extensions", {{"KHR_materials_iridescence", json::object()}}}});
  int i = 0;
  for (int m : {coat, spec, vol, thin, opaque, gloss, sheen, aniso, irid, bare}) {
    const float x = float(2 * i++);
    g.node({{"mesh", g.mesh({{x, 0, 0}, {x + 1, 0, 0}, {x, 1, 0}}, m)}});
  }
  g.write(dir / "layers.gltf");
  const xi::Scene s = xi::load_asset(dir / "layers.gltf");
  for (const std::string& w : s.warnings) EXPECT_EQ(w.find("not modelled"), std::string::npos) << w;
  auto material = [&](const std::string& name) -> const xi::Material& {
    for (const xi::Material& m : s.materials)
      if (m.name == name) return m;
    throw std::runtime_error("no material " + name);
  };
  EXPECT_FLOAT_EQ(material("coat").clearcoat, 0.7f);
  EXPECT_FLOAT_EQ(material("coat").clearcoat_roughness, 0.2f);
  EXPECT_EQ(material("spec").clearcoat, 0.0f);
  EXPECT_FLOAT_EQ(material("spec").specular, 0.4f);
  EXPECT_EQ(material("spec").specular_color, glm::vec3(1.0f, 0.5f, 2.0f));
  EXPECT_EQ(material("coat").specular, 1.0f);
  EXPECT_EQ(material("coat").specular_color, glm::vec3(1.0f));
  const glm::vec3 sigma = material("vol").volume_absorption();
  EXPECT_NEAR(sigma.x, std::log(2.0) / 2.0, 1e-6);
  EXPECT_NEAR(sigma.y, std::log(4.0) / 2.0, 1e-6);
  EXPECT_EQ(sigma.z, 0.0f);
  EXPECT_EQ(material("thin").volume_absorption(), glm::vec3(0.0f));
  EXPECT_EQ(material("opaque").volume_absorption(), glm::vec3(0.0f));
  EXPECT_EQ(material("sheen").sheen_color, glm::vec3(0.9f, 0.5f, 0.1f));
  EXPECT_FLOAT_EQ(material("sheen").sheen_roughness, 0.4f);
  EXPECT_EQ(material("coat").sheen_color, glm::vec3(0.0f));
  EXPECT_FLOAT_EQ(material("aniso").anisotropy_strength, 0.6f);
  EXPECT_FLOAT_EQ(material("aniso").anisotropy_rotation, 1.25f);
  EXPECT_EQ(material("coat").anisotropy_strength, 0.0f);
  EXPECT_FLOAT_EQ(material("irid").iridescence, 0.8f);
  EXPECT_FLOAT_EQ(material("irid").iridescence_ior, 1.6f);
  EXPECT_FLOAT_EQ(material("irid").iridescence_thickness_minimum, 250.0f);
  EXPECT_FLOAT_EQ(material("irid").iridescence_thickness_maximum, 650.0f);
  // glTF's defaults: no film (factor 0), ior 1.3, 100 to 400 nm.
  EXPECT_EQ(material("bare").iridescence, 0.0f);
  EXPECT_FLOAT_EQ(material("bare").iridescence_ior, 1.3f);
  EXPECT_FLOAT_EQ(material("bare").iridescence_thickness_minimum, 100.0f);
  EXPECT_FLOAT_EQ(material("bare").iridescence_thickness_maximum, 400.0f);
  // Their textures, each in its slot (colour ones sRGB-decoded).
  const std::pair<const char*, int> slots[] = {{"coat", XI_TEXTURE_CLEARCOAT}, {"coat", XI_TEXTURE_CLEARCOAT_ROUGHNESS},
                                               {"spec", XI_TEXTURE_SPECULAR}, {"spec", XI_TEXTURE_SPECULAR_COLOR},
                                               {"sheen", XI_TEXTURE_SHEEN_COLOR}, {"sheen", XI_TEXTURE_SHEEN_ROUGHNESS},
                                               {"aniso", XI_TEXTURE_ANISOTROPY}, {"irid", XI_TEXTURE_IRIDESCENCE},
                                               {"irid", XI_TEXTURE_IRIDESCENCE_THICKNESS}};
  for (const auto& [name, k] : slots) {
    EXPECT_TRUE(material(name).textures[k].used()) << name << " slot " << k;
    EXPECT_FALSE(material("vol").textures[k].used()) << "slot " << k;
  }
  // Specular-glossiness, preferred to the metallic-roughness beside it: F0 = the specular colour.
  const xi::Material& sgm = material("gloss");
  EXPECT_EQ(sgm.albedo, glm::vec3(0.5f, 0.25f, 0.125f));
  EXPECT_EQ(sgm.metallic, 0.0f);
  EXPECT_FLOAT_EQ(sgm.roughness, 0.25f);
  const glm::vec3 f0 = sgm.specular_color * 0.04f * sgm.specular;
  EXPECT_NEAR(f0.x, 0.2f, 1e-6f);
  EXPECT_NEAR(f0.y, 0.1f, 1e-6f);
  EXPECT_NEAR(f0.z, 0.04f, 1e-6f);
  const xi::Features f = xi::compile_scene(s).features;
  EXPECT_TRUE(f.clearcoat && f.specular && f.volume && f.sheen && f.anisotropy && f.iridescence);
  const xi::Features box = xi::compile_scene(xi::load_asset(kModels / "BoxTextured-glTF/BoxTextured.gltf")).features;
  EXPECT_FALSE(box.clearcoat || box.anisotropy || box.iridescence);
}

// Transmission is tinted by √base_color at each crossing: through the slab of MaterialVolume (ior 1,
// no absorption) a background of 1 comes out as the base colour itself, within the Šidák z
// standard errors plus 1e-4. Must-fail: the base colour at each crossing (its square) is rejected
// in the channels below 1.
TEST(MaterialVolume, BaseColourTintsOncePerObject) {
  const fs::path dir = temp_dir();
  const dvec3 base(0.25, 0.5, 1.0);
  const int W = 16, H = 16;
  const json pbr = {{"type", "pbr"}, {"base_color", {base.x, base.y, base.z}}, {"metallic", 0}, {"roughness", 0},
                    {"ior", 1.0}, {"transmission", 1}};
  const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 10)},
                      {"film", {{"width", W}, {"height", H}}},
                      {"background", {1, 1, 1}},
                      {"materials", {{"slab", pbr}}},
                      {"shapes", {{{"type", "quad"}, {"material", "slab"}, {"vertices", {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}}}},
                                  {{"type", "quad"}, {"material", "slab"}, {"vertices", {{-2, -2, -0.5}, {-2, 2, -0.5}, {2, 2, -0.5}, {2, -2, -0.5}}}}}}};
  const xi::test::Shot shot = xi::test::render_shot(load_json(dir, scene), options(256, 7, XI_SAMPLER_RANDOM, 4));
  ASSERT_EQ(shot.nonfinite, 0u);
  const double z = xi::stats::sidak_critical_z(0.01, 3);
  for (int ch = 0; ch < 3; ++ch) {
    const xi::test::MeanSe got = xi::test::block_mean(shot, W / 2 - 2, H / 2 - 2, W / 2 + 2, H / 2 + 2, ch);
    const double tol = z * got.se + 1e-4;
    EXPECT_NEAR(got.mean, base[ch], tol) << "channel " << ch;
    if (base[ch] < 1.0) EXPECT_GT(std::abs(got.mean - base[ch] * base[ch]), tol) << "channel " << ch;
  }
}

// The layers' textures multiply their factors: a black clearcoat_texture takes the coat away, pixel
// for pixel (every feature compiled in, so one program), and a white one leaves it whole (within
// 1e-5: the bilinear weights' sum); a specular_texture whose alpha is 0 takes the specular layer
// away as a specular factor of 0 does.
TEST(MaterialLayers, TexturesScaleTheirFactors) {
  const fs::path dir = temp_dir();
  write_png(dir / "black.png", Rgba{1, 1, {0, 0, 0, 0}});
  write_png(dir / "white.png", Rgba{1, 1, {255, 255, 255, 255}});
  auto render = [&](json material) {
    material["type"] = "pbr";
    material["base_color"] = {0.6, 0.3, 0.2};
    material["roughness"] = 0.4;
    const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 40)},
                        {"film", {{"width", 24}, {"height", 24}}},
                        {"environment", {{"file", (fs::path(XI_SCENE_DIR) / "sky.hdr").string()}}},
                        {"materials", {{"m", material}}},
                        {"shapes", {{{"type", "sphere"}, {"material", "m"}, {"center", {0, 0, 0}}, {"radius", 1}}}}};
    return xi::test::render_shot(load_json(dir, scene), options(4, 3, XI_SAMPLER_RANDOM, 3)).mean;
  };
  auto same = [](const xi::Image& a, const xi::Image& b) { return a.pixels == b.pixels; };
  // A white texel is 1 up to the rounding of the bilinear weights' sum.
  auto close = [](const xi::Image& a, const xi::Image& b) {
    for (size_t i = 0; i < a.pixels.size(); ++i)
      if (glm::any(glm::greaterThan(glm::abs(a.pixels[i] - b.pixels[i]), 1e-5f * (glm::abs(a.pixels[i]) + 1.0f))))
        return false;
    return true;
  };
  const xi::Image plain = render(json::object());
  const xi::Image coated = render({{"clearcoat", 1.0}, {"clearcoat_roughness", 0.1}});
  EXPECT_FALSE(same(plain, coated));
  EXPECT_TRUE(same(plain, render({{"clearcoat", 1.0}, {"clearcoat_roughness", 0.1}, {"clearcoat_texture", "black.png"}})));
  EXPECT_TRUE(close(coated, render({{"clearcoat", 1.0}, {"clearcoat_roughness", 0.1}, {"clearcoat_texture", "white.png"}})));
  const xi::Image weak = render({{"specular", 0.0}});
  EXPECT_FALSE(same(plain, weak));
  EXPECT_TRUE(same(weak, render({{"specular_texture", "black.png"}})));
}

// What two renders' means over one part of an image may differ by: the Šidák z of their standard
// errors plus 1e-4 (float accumulation).
double allowed(const xi::test::MeanSe& a, const xi::test::MeanSe& b, double z) { return z * std::hypot(a.se, b.se) + 1e-4; }
// f(quarter, channel, mean) over the four quarters of a W × H image and its three channels, mean(shot)
// that shot's mean and standard error there.
template <class F>
void for_each_quarter(int W, int H, F f) {
  for (int q = 0; q < 4; ++q)
    for (int ch = 0; ch < 3; ++ch) {
      const int x = (q % 2) * W / 2, y = (q / 2) * H / 2;
      f(q, ch, [=](const xi::test::Shot& s) { return xi::test::block_mean(s, x, y, x + W / 2, y + H / 2, ch); });
    }
}

// The coat keeps its own normal (glTF: the interpolated one with clearcoat_normal_texture only): a
// base normal map (a constant 30° tilt) leaves a smooth coat over a black base with no specular
// layer as it was, on a square facing the camera under the sky (the coat's reflections stay above
// the tilted base's horizon, where the renderer keeps them): the four quarters' means of the image,
// per channel, agree with those without the map within the Šidák z of their standard errors plus
// 1e-4. Must-fail: the same map as the coat's own moves its reflections, and some quarter differs
// by more than that.
TEST(MaterialLayers, CoatKeepsItsOwnNormal) {
  const fs::path dir = temp_dir();
  write_png(dir / "tilt.png", Rgba{1, 1, {191, 128, 238, 255}});  // (0.5, 0, 0.87) in tangent space
  const int W = 24, H = 24;
  auto render = [&](json material) {
    material.update({{"type", "pbr"}, {"base_color", {0, 0, 0}}, {"metallic", 0}, {"specular", 0.0},
                     {"clearcoat", 1.0}, {"clearcoat_roughness", 0.0}});
    const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 30)},
                        {"film", {{"width", W}, {"height", H}}},
                        {"environment", {{"file", (fs::path(XI_SCENE_DIR) / "sky.hdr").string()}}},
                        {"materials", {{"m", material}}},
                        {"shapes", {{{"type", "quad"}, {"material", "m"}, {"vertices", {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}}}}}}};
    return xi::test::render_shot(load_json(dir, scene), options(64, 5, XI_SAMPLER_RANDOM, 3));
  };
  const xi::test::Shot plain = render(json::object()), based = render({{"normal_texture", "tilt.png"}}),
                       own = render({{"clearcoat_normal_texture", "tilt.png"}});
  const double z = xi::stats::sidak_critical_z(0.01, 12);
  int moved = 0;
  for_each_quarter(W, H, [&](int q, int ch, auto mean) {
    const xi::test::MeanSe a = mean(plain), b = mean(based), c = mean(own);
    EXPECT_NEAR(b.mean, a.mean, allowed(a, b, z)) << "quarter " << q << " channel " << ch;
    moved += std::abs(c.mean - a.mean) > allowed(a, c, z);
  });
  EXPECT_GT(moved, 0) << "the coat's own normal map changes nothing";
}

// KHR_materials_anisotropy's direction is the tangent (the direction of increasing u) turned by the
// rotation towards the bitangent n × tangent. A brushed metal square seen obliquely under the sky,
// twice: u along +x with rotation 0, and u along +y with rotation π/2 (its direction n × y = −x, the
// same axis), then u along +x with rotation π/2 and u along +y with rotation 0 (both along y). Each
// pair's four quarters' means, per channel, agree within the Šidák z of their standard errors plus
// 1e-4. Must-fail: a direction along x against one along y differs in some quarter by more.
TEST(MaterialAnisotropy, DirectionIsTheTangentTurnedByTheRotation) {
  const fs::path dir = temp_dir();
  const int W = 24, H = 24;
  const json along_x = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};  // a quad's u runs from its first corner to its second
  const json along_y = {{1, -1, 0}, {1, 1, 0}, {-1, 1, 0}, {-1, -1, 0}};
  auto render = [&](const json& corners, double rotation) {
    const json brushed = {{"type", "pbr"}, {"base_color", {0.9, 0.9, 0.9}}, {"metallic", 1}, {"roughness", 0.25},
                          {"anisotropy_strength", 0.8}, {"anisotropy_rotation", rotation}};
    const json scene = {{"camera", camera_json({0, 1.5, 3}, {0, 0, 0}, {0, 1, 0}, 40)},
                        {"film", {{"width", W}, {"height", H}}},
                        {"environment", {{"file", (fs::path(XI_SCENE_DIR) / "sky.hdr").string()}}},
                        {"materials", {{"m", brushed}}},
                        {"shapes", {{{"type", "quad"}, {"material", "m"}, {"vertices", corners}}}}};
    return xi::test::render_shot(load_json(dir, scene), options(64, 11, XI_SAMPLER_RANDOM, 3));
  };
  const double quarter_turn = 1.5707963267948966;
  const xi::test::Shot x0 = render(along_x, 0.0), x1 = render(along_y, quarter_turn);
  const xi::test::Shot y0 = render(along_x, quarter_turn), y1 = render(along_y, 0.0);
  const double z = xi::stats::sidak_critical_z(0.01, 24);
  int differ = 0;
  for_each_quarter(W, H, [&](int q, int ch, auto mean) {
    const xi::test::MeanSe a = mean(x0), b = mean(x1), c = mean(y0), d = mean(y1);
    EXPECT_NEAR(b.mean, a.mean, allowed(a, b, z)) << "along x: quarter " << q << " channel " << ch;
    EXPECT_NEAR(d.mean, c.mean, allowed(c, d, z)) << "along y: quarter " << q << " channel " << ch;
    differ += std::abs(c.mean - a.mean) > allowed(a, c, z);
  });
  std::printf("[ aniso    ] a direction along x against one along y: %d of 12 quarter-channels differ\n", differ);
  EXPECT_GT(differ, 0) << "the anisotropy direction changes nothing";
}

// KHR_materials_iridescence through the renderer: a smooth metal square (base colour 0.8, 0.5, 0.2)
// seen head-on through a 4° field against a white background reflects its Fresnel at normal
// incidence, Schlick's f0, which the film replaces in its share: every pixel (one sample through its
// centre) within 3e-3 of f0 + (film − f0) · weight per channel, the film's reflectance at cosine 1
// over the base colour's ior (thin_film.h, whose own accuracy test_microfacet.cpp checks). Once a
// film of weight 1, 450 nm; once weight 0.8 times the texture's R, thickness 200 to 600 nm by its G.
// Must-fail: the first image against a 400 nm film's reflectance.
TEST(MaterialIridescence, FilmReplacesTheFresnelByItsWeightAndThickness) {
  const fs::path dir = temp_dir();
  write_png(dir / "film.png", Rgba{1, 1, {128, 64, 0, 255}});
  const int W = 8, H = 8;
  const glm::vec3 base(0.8f, 0.5f, 0.2f);
  auto render = [&](json film) {
    film.update({{"type", "pbr"}, {"base_color", {base.x, base.y, base.z}}, {"metallic", 1}, {"roughness", 0}});
    const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 4)},
                        {"film", {{"width", W}, {"height", H}}},
                        {"background", {1, 1, 1}},
                        {"materials", {{"m", film}}},
                        {"shapes", {{{"type", "quad"}, {"material", "m"}, {"vertices", {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}}}}}}};
    return xi::test::render_shot(load_json(dir, scene), options(1, 1, XI_SAMPLER_GRID, 3));
  };
  auto expected = [&](float weight, float thickness) {
    return base + (xi_thin_film_fresnel(1.0f, 1.3f, thickness, xi_ior_of_f0(base)) - base) * weight;
  };
  auto worst = [&](const xi::test::Shot& shot, glm::vec3 want) {
    double d = 0.0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        for (int ch = 0; ch < 3; ++ch) d = std::max(d, std::abs((double)shot.mean.at(x, y)[ch] - want[ch]));
    return d;
  };
  const xi::test::Shot plain = render({{"iridescence", 1.0}, {"iridescence_thickness_maximum", 450}});
  const xi::test::Shot mapped = render({{"iridescence", 0.8}, {"iridescence_thickness_minimum", 200},
                                        {"iridescence_thickness_maximum", 600}, {"iridescence_texture", "film.png"},
                                        {"iridescence_thickness_texture", "film.png"}});
  const double r = 128.0 / 255.0, g = 64.0 / 255.0;
  EXPECT_LT(worst(plain, expected(1.0f, 450.0f)), 3e-3);
  EXPECT_LT(worst(mapped, expected(float(0.8 * r), float(200.0 + 400.0 * g))), 3e-3);
  const double wrong = worst(plain, expected(1.0f, 400.0f));
  std::printf("[ film     ] a 450 nm film against a 400 nm one's reflectance: largest difference %.4f\n", wrong);
  EXPECT_GT(wrong, 3e-3);
}

// An opaque metallic-roughness surface's back face is the same surface seen from the other side
// (glTF's double-sided surfaces, Cycles' Principled BSDF): a rough red dielectric square seen at 70°
// under the sky looks the same wound towards the camera and away from it: the four quarters' means
// per channel agree within the Šidák z of their standard errors plus 1e-4. Must-fail: with
// transmission 0.5, light can be inside, so the back face is the inside of glass (eta 1/ior), and
// some quarter differs by more.
TEST(MaterialBackFaces, OpaqueSurfaceLooksTheSameFromBehind) {
  const fs::path dir = temp_dir();
  const int W = 24, H = 24;
  const json towards = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}}, away = {{-1, -1, 0}, {-1, 1, 0}, {1, 1, 0}, {1, -1, 0}};
  auto render = [&](const json& corners, double transmission) {
    const json red = {{"type", "pbr"}, {"base_color", {0.8, 0.1, 0.05}}, {"metallic", 0}, {"roughness", 0.3},
                      {"transmission", transmission}};
    const json scene = {{"camera", camera_json({0, -2.75, 1}, {0, 0, 0}, {0, 0, 1}, 30)},
                        {"film", {{"width", W}, {"height", H}}},
                        {"environment", {{"file", (fs::path(XI_SCENE_DIR) / "sky.hdr").string()}}},
                        {"materials", {{"m", red}}},
                        {"shapes", {{{"type", "quad"}, {"material", "m"}, {"vertices", corners}}}}};
    return xi::test::render_shot(load_json(dir, scene), options(64, 13, XI_SAMPLER_RANDOM, 3));
  };
  const double z = xi::stats::sidak_critical_z(0.01, 24);
  const xi::test::Shot front = render(towards, 0.0), back = render(away, 0.0);
  const xi::test::Shot glass_front = render(towards, 0.5), glass_back = render(away, 0.5);
  int differ = 0;
  for_each_quarter(W, H, [&](int q, int ch, auto mean) {
    const xi::test::MeanSe a = mean(front), b = mean(back), c = mean(glass_front), d = mean(glass_back);
    EXPECT_NEAR(b.mean, a.mean, allowed(a, b, z)) << "quarter " << q << " channel " << ch;
    differ += std::abs(d.mean - c.mean) > allowed(c, d, z);
  });
  std::printf("[ backface ] half-transmissive, front against back: %d of 12 quarter-channels differ\n", differ);
  EXPECT_GT(differ, 0) << "a transmissive surface's inside looks like its outside";
}

// Volumes inside one another (ice in a drink in a glass in a tank), as deep as a path follows them
// (XI_VOLUME_LEVELS, 4): slabs of σ_k, k = 1..4, each inside the one before ([0, −1], [−0.2, −0.8],
// [−0.3, −0.7], [−0.4, −0.6]; ior 1, smooth, transmission 1). Through them all,
// exp(−0.4 σ_1 − 0.2 σ_2 − 0.2 σ_3 − 0.2 σ_4) within the Šidák z standard errors plus 1e-4; must-fail:
// a path that forgot the outermost (three levels) absorbs nothing on its way out of the first
// slab's last 0.2, and is rejected.
TEST(MaterialVolume, VolumesNestFourDeep) {
  const fs::path dir = temp_dir();
  const dvec3 colours[4] = {{0.2, 0.3, 0.4}, {0.9, 0.4, 0.2}, {0.6, 0.8, 0.3}, {0.3, 0.5, 0.7}};  // distance 1
  const double fronts[4] = {0.0, -0.2, -0.3, -0.4}, backs[4] = {-1.0, -0.8, -0.7, -0.6};
  const double inside[4] = {0.4, 0.2, 0.2, 0.2};  // how far the ray travels with slab k innermost
  const int W = 16, H = 16;
  auto pbr = [](dvec3 c) {
    return json{{"type", "pbr"}, {"base_color", {1, 1, 1}}, {"metallic", 0}, {"roughness", 0}, {"ior", 1.0},
                {"transmission", 1}, {"attenuation_color", {c.x, c.y, c.z}}, {"attenuation_distance", 1}};
  };
  json shapes = json::array(), materials = json::object();
  for (int k = 0; k < 4; ++k) {
    const std::string name = "slab" + std::to_string(k);
    materials[name] = pbr(colours[k]);
    const double z0 = fronts[k], z1 = backs[k];  // the front face faces +z, the back one −z
    shapes.push_back({{"type", "quad"}, {"material", name}, {"vertices", {{-2, -2, z0}, {2, -2, z0}, {2, 2, z0}, {-2, 2, z0}}}});
    shapes.push_back({{"type", "quad"}, {"material", name}, {"vertices", {{-2, -2, z1}, {-2, 2, z1}, {2, 2, z1}, {2, -2, z1}}}});
  }
  const json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 10)},
                      {"film", {{"width", W}, {"height", H}}},
                      {"background", {1, 1, 1}},
                      {"materials", materials},
                      {"shapes", shapes}};
  const xi::test::Shot shot = xi::test::render_shot(load_json(dir, scene), options(1024, 9, XI_SAMPLER_RANDOM, 10));
  ASSERT_EQ(shot.nonfinite, 0u);
  const double z = xi::stats::sidak_critical_z(0.01, 3);
  for (int ch = 0; ch < 3; ++ch) {
    const xi::test::MeanSe got = xi::test::block_mean(shot, W / 2 - 2, H / 2 - 2, W / 2 + 2, H / 2 + 2, ch);
    double optical = 0.0;
    for (int k = 0; k < 4; ++k) optical += inside[k] * -std::log(colours[k][ch]);
    const double want = std::exp(-optical), forgot = std::exp(-optical - 0.2 * std::log(colours[0][ch]));
    const double tol = z * got.se + 1e-4;
    std::printf("[ volume   ] four deep, channel %d: %.5f ± %.1e, Beer–Lambert %.5f\n", ch, got.mean, got.se, want);
    EXPECT_NEAR(got.mean, want, tol) << "channel " << ch;
    EXPECT_GT(std::abs(got.mean - forgot), tol) << "channel " << ch;
  }
}

// A scene may hold XI_MAX_VOLUMES materials with a volume (a path names each in 8 bits): one more is
// one error naming the limit, before anything renders.
TEST(MaterialVolume, TooManyVolumesIsOneError) {
  const fs::path dir = temp_dir();
  json shapes = json::array(), materials = json::object();
  // (Appended, not "v" + to_string(k): GCC 12 warns falsely of an overflow in that operator+.)
  const auto volume_name = [](int k) { return std::string("v").append(std::to_string(k)); };
  for (int k = 0; k <= XI_MAX_VOLUMES; ++k) {
    const std::string name = volume_name(k);
    materials[name] = {{"type", "pbr"}, {"transmission", 1}, {"attenuation_color", {0.5, 0.5, 0.5}},
                       {"attenuation_distance", 1}};
    const double x = k;
    shapes.push_back({{"type", "triangle"}, {"material", name}, {"vertices", {{x, 0, 0}, {x + 1, 0, 0}, {x, 1, 0}}}});
  }
  json scene = {{"camera", camera_json({0, 0, 3}, {0, 0, 0}, {0, 1, 0}, 40)},
                {"film", {{"width", 8}, {"height", 8}}},
                {"materials", materials},
                {"shapes", shapes}};
  try {
    xi::compile_scene(load_json(dir, scene));
    FAIL() << "no error";
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find("at most 255 materials with a volume, not 256"), std::string::npos) << e.what();
  }
  // One fewer compiles.
  scene["shapes"].erase(scene["shapes"].size() - 1);
  scene["materials"].erase(volume_name(XI_MAX_VOLUMES));
  EXPECT_NO_THROW(xi::compile_scene(load_json(dir, scene)));
}
