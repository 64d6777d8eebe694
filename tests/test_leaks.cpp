// Light where none belongs, and none missing where some belongs: spawned rays must neither hit
// their own surface again nor be caught by geometry that touches it, and no ray may slip through
// the junctions of touching or closed geometry: grazing rays over a huge plane, a light set into a
// wall, lights inside a closed box, a camera inside a closed mesh.
//
// Every case has an exact or a statistical expectation; each statistical test states its
// significance next to the assertion, Šidák-corrected over its own family (one test = one family),
// and uses fixed seeds and the random sampler (whose per-pixel variance of the mean is unbiased, so
// a z-test with the film's variance layer is exact in the large-sample limit). Scenes are built in
// C++ (scene_builder.h), so that each expectation can be derived from the very geometry.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "analytic.h"
#include "fixtures.h"
#include "scene_builder.h"
#include "stats.h"
#include "xi/renderer.h"
#include "xi/scene.h"

namespace {

using namespace xi::test;  // fixtures.h, analytic.h, scene_builder.h (its vector types too)

// A rigid motion applied to a whole scene (every vertex and the camera), in double precision.
struct Rigid {
  glm::dmat3 r{1.0};
  dvec3 t{0.0};
  dvec3 operator()(dvec3 p) const { return r * p + t; }
};
Rigid rotation(dvec3 axis, double degrees, dvec3 translate = dvec3(0.0)) {
  axis = glm::normalize(axis);
  const double a = glm::radians(degrees), c = std::cos(a), s = std::sin(a);
  const glm::dmat3 k(0, axis.z, -axis.y, -axis.z, 0, axis.x, axis.y, -axis.x, 0);  // column-major cross matrix
  return {glm::dmat3(1.0) + s * k + (1.0 - c) * k * k, translate};
}
xi::Scene moved(xi::Scene s, const Rigid& m) {
  for (xi::Vertex& v : s.vertices) v.position = vec3(m(dvec3(v.position)));
  s.camera.position = vec3(m(dvec3(s.camera.position)));
  s.camera.look_at = vec3(m(dvec3(s.camera.look_at)));
  s.camera.up = vec3(m.r * dvec3(s.camera.up));
  return s;
}

void add_wall_with_light(xi::Scene& s, uint32_t wall, uint32_t light) {
  auto piece = [&](uint32_t m, float x0, float y0, float x1, float y1) {
    add_quad(s, m, vec3(x0, y0, 0), vec3(x0, y1, 0), vec3(x1, y1, 0), vec3(x1, y0, 0));  // front face: −z
  };
  piece(light, -0.5f, 0, 0.5f, 1);
  piece(wall, -4, 0, -0.5f, 1);
  piece(wall, -4, 1, -0.5f, 2);
  piece(wall, -0.5f, 1, 0.5f, 2);
  piece(wall, 0.5f, 0, 4, 1);
  piece(wall, 0.5f, 1, 4, 2);
}

// The floor y = 0, x and z in [−4, 4] (or only its front half, z ≤ 0), in pieces whose edges along
// z = 0 are the wall's and the light's bottom edges, with the same vertices.
void add_conforming_floor(xi::Scene& s, uint32_t m, float y, bool behind = true) {
  const float xs[] = {-4, -0.5f, 0.5f, 4};
  for (int i = 0; i < 3; ++i)
    for (float z0 : {-4.0f, 0.0f})
      if (z0 < 0.0f || behind)
        add_quad(s, m, vec3(xs[i], y, z0), vec3(xs[i], y, z0 + 4), vec3(xs[i + 1], y, z0 + 4), vec3(xs[i + 1], y, z0));
}

// The turn the wall scenes are given, so that no edge is axis-aligned.
const Rigid kTurn = rotation(dvec3(1, 2, 3), 23.0, dvec3(0.25, -0.5, 0.75));

// Grazing camera rays over a huge plane. The camera is a hair above an enormous diffuse plane
// (albedo 1/2) under a uniform sky (background B), looking at the horizon through a 0.5° field of
// view, so every ray that hits the plane meets it at less than 0.26° (at 0.008° in the first row
// below the horizon). The plane sees only sky, so its radiance is exactly ρB: a hit sample is
// ρ·B (the bounce ray escapes), a miss is B, with no noise at all. With ρ and B powers of two every
// sum is exact, so each pixel whose whole footprint lands on the plane must average exactly ρB with
// zero variance, and each pixel whose footprint sees only sky exactly B. One self-intersection
// (a bounce ray re-hitting the plane, giving ρ²B, or leaving from below it) in any of the 64
// samples of such a pixel breaks the equality. Two configurations, each with the camera 1e-6 of the
// plane's half-width above it: height 1e-3 over half-width 1e3 (hits 0.2 to 7 away), and 0.1 over
// 1e5 (hits 23 to 700 away, coordinates where a float's spacing is 0.008). Pixels that the horizon
// crosses are mixed and only checked to lie between the two values.
// Not tested, a known limit: the triangle test refuses hits closer than pbrt's bound on the error
// of t, which grows with the triangle's size over the ray's height above it (its terms for the
// sheared x, y take |z| where |d_x z|, |d_y z| would do): once the half-width is about 2e6 times
// the height, the bound exceeds the hit distance at every angle, and a camera 1e-3 above a plane
// of half-width 1e4 sees through it (every pixel: sky).
TEST(Leaks, GrazingRaysOverAHugePlaneSeeExactlyAlbedoTimesSky) {
  struct Config {
    float height, half_width;
  };
  for (const Config& c : {Config{1e-3f, 1e3f}, Config{0.1f, 1e5f}}) {
    SCOPED_TRACE("camera height " + std::to_string(c.height) + ", plane half-width " + std::to_string(c.half_width));
    xi::Scene s;
    s.width = s.height = 64;
    s.background = vec3(1.0f, 0.25f, 2.0f);
    set_camera(s, vec3(0, c.height, 0), vec3(0, c.height, 1), 0.5f);
    const float r = c.half_width;
    add_quad(s, add_material(s, "plane", vec3(0.5f)), vec3(-r, 0, -r), vec3(-r, 0, r), vec3(r, 0, r), vec3(r, 0, -r));
    const Shot shot = render_shot(s, render_options(64, 11, xi::Strategy::Mis, 8));
    EXPECT_EQ(shot.nonfinite, 0u);
    const View v(s);
    auto on_plane = [&](dvec3 d) {
      if (d.y >= 0.0) return false;
      const dvec3 p = v.o + (-v.o.y / d.y) * d;
      return std::abs(p.x) < r && std::abs(p.z) < r;
    };
    const glm::vec3 ground = 0.5f * s.background, sky = s.background;
    int n_ground = 0, n_sky = 0, bad = 0;
    for (int y = 0; y < s.height; ++y)
      for (int x = 0; x < s.width; ++x) {
        // Corner rays on the plane (the directions that meet a convex polygon form a convex cone, so
        // four corners on it put the whole footprint on it) and above the horizon (a half-space).
        int corners = 0, up = 0;
        for (int k = 0; k < 4; ++k) {
          const dvec3 d = v.ray(x + (k & 1), y + (k >> 1));
          corners += on_plane(d);
          up += d.y > 0.0;
        }
        if (up == 4) corners = -1;
        const glm::vec3 m = shot.mean.at(x, y), var = shot.variance.at(x, y);
        ASSERT_TRUE(std::isfinite(m.x + m.y + m.z));
        bool ok;
        if (corners == 4) ok = m == ground && var == glm::vec3(0.0f);  // exact: every sample is ρB
        else if (corners == -1) ok = m == sky && var == glm::vec3(0.0f);
        else ok = glm::all(glm::greaterThanEqual(m, ground)) && glm::all(glm::lessThanEqual(m, sky));
        if (!ok && ++bad <= 5)
          ADD_FAILURE() << "pixel " << x << ", " << y << " (" << corners << " corners on the plane): " << m.x << " "
                        << m.y << " " << m.z << ", variance " << var.x;
        n_ground += corners == 4;
        n_sky += corners == -1;
      }
    std::printf("[ graze  ] height %g over %g: %d pixels on the plane, %d sky, all exact: %s\n", c.height, c.half_width,
                n_ground, n_sky, bad ? "no" : "yes");
    EXPECT_EQ(bad, 0);
    EXPECT_GE(n_ground, 24 * 64);  // the case must actually contain grazing hits
    EXPECT_GE(n_sky, 24 * 64);
  }
}

// A light coplanar with a wall and touching it. In a local frame: a floor y = 0 (x, z in
// [−4, 4], albedo 1/2); a wall in the plane z = 0 (x in [−4, 4], y in [0, 2]) made of pieces around
// the light, the rectangle x in [−0.5, 0.5], y in [0, 1] of the same plane: its sides and top are
// edges of wall pieces and its bottom edge an edge of floor pieces, with the same vertices (so the
// junctions are conforming: watertight). The light is one-sided, facing −z. The whole scene, camera
// included, is turned by 23° about (1, 2, 3) and moved, so that no edge is axis-aligned.
//
// The lit side: with a black wall (albedo 0) and a black light, the floor in front of the light is
// lit only directly, so its radiance is ρ/π · E with E from Lambert's polygon formula (the light is
// whole in view of every floor point in front of it). 5 × 5 pixel blocks at three spots: right in
// front of the light's foot (shadow rays graze the floor and end beside the wall's edges), just
// outside its side edge, and off to the side; MIS and light sampling alone: 6 z-tests at family-wise
// α = 0.01 (Šidák, z = 2.87). A shadow ray caught by the wall piece that shares the light's edge,
// or by the floor it stands on, darkens the first two spots by more than a few standard errors.
TEST(Leaks, LightInAWallLightsTheFloorAsLambertsFormulaSays) {
  xi::Scene local;
  local.width = local.height = 64;
  const uint32_t floor_m = add_material(local, "floor", vec3(0.5f));
  const uint32_t wall = add_material(local, "wall", vec3(0.0f));
  const uint32_t light = add_material(local, "light", vec3(0.0f), vec3(4.0f));
  add_conforming_floor(local, floor_m, 0.0f);
  add_wall_with_light(local, wall, light);
  set_camera(local, vec3(0.3f, 1.4f, -2.4f), vec3(0.0f, 0.0f, -0.4f), 45.0f);
  const xi::Scene scene = moved(local, kTurn);

  const std::vector<dvec3> light_polygon = {{-0.5, 0, 0}, {-0.5, 1, 0}, {0.5, 1, 0}, {0.5, 0, 0}};
  const View v(local);
  auto radiance = [&](dvec3 d) {  // in the local frame; NaN off the floor's lit half
    if (d.y >= 0.0) return (double)NAN;
    const double t = -v.o.y / d.y;
    const dvec3 p = v.o + t * d;
    if (!(p.z < 0.0 && std::abs(p.x) < 4.0 && p.z > -4.0)) return (double)NAN;
    return 0.5 / M_PI * lambert_irradiance(light_polygon, 4.0, p, dvec3(0, 1, 0));
  };
  struct Spot {
    const char* name;
    dvec3 p;
  };
  const Spot spots[] = {
      {"light's foot", {0.0, 0, -0.2}}, {"beside its edge", {0.56, 0, -0.2}}, {"off to the side", {-0.7, 0, -0.9}}};
  const double z_max = xi::stats::sidak_critical_z(0.01, 6);
  uint32_t seed = 21;
  for (xi::Strategy strategy : {xi::Strategy::Mis, xi::Strategy::Nee}) {
    const Shot shot = render_shot(scene, render_options(512, seed++, strategy, 4));
    EXPECT_EQ(shot.nonfinite, 0u);
    for (const Spot& s : spots) {
      const dvec2 f = v.film(s.p);
      const int cx = (int)std::floor(f.x), cy = (int)std::floor(f.y);
      ASSERT_TRUE(cx >= 2 && cy >= 2 && cx + 2 < local.width && cy + 2 < local.height) << s.name;
      double exact = 0.0;
      for (int y = cy - 2; y <= cy + 2; ++y)
        for (int x = cx - 2; x <= cx + 2; ++x) exact += footprint_mean(v, x, y, radiance) / 25.0;
      ASSERT_TRUE(std::isfinite(exact)) << s.name << ": the block must lie on the lit floor";
      const MeanSe m = block_mean(shot, cx - 2, cy - 2, cx + 3, cy + 3);
      std::printf("[ wall   ] %-4s %-16s %.5f ± %.5f, exact %.5f, z = %+.2f\n", xi::strategy_name(strategy), s.name,
                  m.mean, m.se, exact, (m.mean - exact) / m.se);
      EXPECT_GT(m.se, 0.0);
      EXPECT_LE(std::abs(m.mean - exact), z_max * m.se) << xi::strategy_name(strategy) << ", " << s.name;
    }
  }
}

// The other side: the same wall and light above a grey floor (albedo 1/2) in front of the wall only,
// whose back edges are the wall's bottom edges (same vertices), the light bright (radiance 50),
// seen from behind the wall. Nothing lit can reach the back: light leaving the front goes up and
// over the wall, away from it, and a one-sided light sends nothing backward. Camera rays that
// slipped through a crack between light and wall or wall and floor would reach the lit floor (a
// sample of ≥ 1e-2 of Le), and a light sample that counted the light's front from behind would light
// the wall. Axis-aligned, every pixel is exactly 0 with zero variance. Turned (23° about (1, 2, 3)),
// the light and the wall are coplanar only up to the rounding of their vertices, so points of the
// wall's back may lie a few 1e-7 in front of the light's plane and see its front at such grazing
// angles (≈ 1e-14 of Le, measured ≤ 1e-11): there every pixel must stay below 1e-6 of Le. Control:
// a two-sided light does light the wall's back.
// Not tested, a known limit: with a floor behind the wall as well, paths in the back room that
// bounce off the floor within ~1e-5 of the wall's foot can pass through the wall (see CameraInsideAClosedMesh).
TEST(Leaks, LightInAWallLeaksNothingBehindIt) {
  enum { kAxisAligned, kTurned, kControl };
  const float le = 50.0f;
  for (int variant : {kAxisAligned, kTurned, kControl}) {
    const bool two_sided = variant == kControl;
    SCOPED_TRACE(variant == kAxisAligned ? "axis-aligned" : variant == kTurned ? "turned" : "control: two-sided light");
    xi::Scene local;
    local.width = local.height = two_sided ? 16 : 48;
    const uint32_t grey = add_material(local, "grey", vec3(0.5f));
    const uint32_t light = add_material(local, "light", vec3(0.0f), vec3(le), two_sided);
    add_conforming_floor(local, grey, 0.0f, false);
    add_wall_with_light(local, grey, light);
    set_camera(local, vec3(0.7f, 1.3f, 2.5f), vec3(0.0f, 0.5f, 0.0f), 60.0f);
    const Shot shot = render_shot(variant == kAxisAligned ? local : moved(local, kTurn),
                                  render_options(two_sided ? 16 : 64, 31, xi::Strategy::Mis, 16));
    EXPECT_EQ(shot.nonfinite, 0u);
    double sum = 0.0, brightest = 0.0;
    int lit = 0;
    for (int y = 0; y < local.height; ++y)
      for (int x = 0; x < local.width; ++x) {
        const glm::vec3 m = shot.mean.at(x, y), var = shot.variance.at(x, y);
        sum += m.x + m.y + m.z;
        brightest = std::max<double>(brightest, std::max({m.x, m.y, m.z}));
        lit += !(m == glm::vec3(0.0f) && var == glm::vec3(0.0f));
      }
    std::printf("[ wall   ] behind it, %-12s: %4d of %4d pixels not black, mean %.3g, brightest %.3g\n",
                variant == kAxisAligned ? "axis-aligned" : variant == kTurned ? "turned" : "control", lit,
                local.width * local.height, sum / (3.0 * local.width * local.height), brightest);
    if (variant == kAxisAligned) EXPECT_EQ(lit, 0);           // exact
    if (variant == kTurned) EXPECT_LE(brightest, 1e-6 * le);  // grazing light through rounded coplanarity only
    if (variant == kControl) EXPECT_GT(lit, local.width * local.height / 4);  // its back lights the wall
  }
}

// Lights inside a closed box: a cube (six quads, 12 triangles, every edge shared with identical
// vertices), turned by 37° about (1, −2, 0.5), diffuse inside and out (albedo 0.8), holding a
// two-sided emitter quad across its middle and a one-sided one near its floor, above an outside
// floor, seen from outside. Every camera path either stays outside the box (where no light can
// arrive without crossing a wall) or is stopped by it, and every shadow ray from outside toward a
// light inside must be blocked by a wall: each pixel is exactly 0 with zero variance. Control: the
// same box without its bottom lights the floor.
TEST(Leaks, LightsInsideAClosedBoxLightNothingOutside) {
  for (bool closed : {true, false}) {
    SCOPED_TRACE(closed ? "closed box" : "control: box without its bottom");
    xi::Scene s;
    s.width = s.height = closed ? 48 : 16;
    const uint32_t grey = add_material(s, "grey", vec3(0.8f));
    add_floor(s, add_material(s, "floor", vec3(0.5f)), -2.0f, 8.0f);
    const size_t first = s.vertices.size();  // the box's and the lights' vertices follow
    add_box(s, grey, vec3(-1.0f), vec3(1.0f), closed);
    add_quad(s, add_material(s, "lamp", vec3(0.0f), vec3(20.0f), true), vec3(-0.6f, -0.3f, -0.5f),
             vec3(-0.5f, 0.4f, 0.6f), vec3(0.6f, 0.3f, 0.5f), vec3(0.5f, -0.4f, -0.6f));
    add_quad(s, add_material(s, "spot", vec3(0.0f), vec3(50.0f)), vec3(-0.3f, -0.9f, -0.3f), vec3(-0.3f, -0.9f, 0.3f),
             vec3(0.3f, -0.9f, 0.3f), vec3(0.3f, -0.9f, -0.3f));  // faces up
    const Rigid turn = rotation(dvec3(1, -2, 0.5), 37.0, dvec3(0.0, 0.1, 0.0));
    for (size_t i = first; i < s.vertices.size(); ++i)
      s.vertices[i].position = vec3(turn(dvec3(s.vertices[i].position)));
    set_camera(s, vec3(3.5f, 2.0f, -4.5f), vec3(0.0f, -0.3f, 0.0f), 50.0f);
    const Shot shot = render_shot(s, render_options(closed ? 64 : 16, 41, xi::Strategy::Mis, 12));
    EXPECT_EQ(shot.nonfinite, 0u);
    int lit = 0;
    double sum = 0.0;
    for (int y = 0; y < s.height; ++y)
      for (int x = 0; x < s.width; ++x) {
        const glm::vec3 m = shot.mean.at(x, y), var = shot.variance.at(x, y);
        sum += m.x;
        if (!(m == glm::vec3(0.0f) && var == glm::vec3(0.0f)) && ++lit <= 5 && closed)
          ADD_FAILURE() << "pixel " << x << ", " << y << " is lit: " << m.x;
      }
    std::printf("[ box    ] %s: %d of %d pixels lit, mean %.4g\n", closed ? "closed" : "no bottom (control)", lit,
                s.width * s.height, sum / (s.width * s.height));
    if (closed) EXPECT_EQ(lit, 0);  // exact
    else EXPECT_GT(lit, s.width * s.height / 4);
  }
}

// A camera inside a closed mesh. With no light and a bright sky outside (background 1), the inside
// of a closed mesh is exactly black: every path stays inside, and any ray that escapes through a
// crack, or starts on the wrong side of a wall, sees the sky. An icosphere (4 subdivisions, vertex
// normals) and an ellipsoid (the same mesh scaled by (1.5, 0.6, 0.3), loaded from OBJ, no normals),
// diffuse albedo 0.8, 16 bounces: every pixel 0 with zero variance. Then the uneven star-shaped mesh
// made an emitter (Le = 1, two-sided, albedo 1/2): a closed cavity of any shape with uniform
// emission and albedo has radiance Le / (1 − ρ) = 2 everywhere (truncation at depth 64: 2^−64):
// image mean and three column bands, 4 z-tests at family-wise α = 0.01 (Šidák, z = 3.02).
// Not tested, a known limit: rays spawned within ~1e-5 (relative to the triangles' size) of an
// inside edge, toward the face across it, meet that face closer than the triangle test's
// conservative bound on the error of t, which refuses the hit, and leave the mesh: rare inside a
// cube (a few in a million bounce rays), more frequent inside the uneven mesh with its sharp creases,
// whose inside is then not exactly black; the furnace below loses far less than its standard error
// through them.
TEST(Leaks, CameraInsideAClosedMesh) {
  std::vector<std::array<dvec3, 3>> ellipsoid = lumpy_mesh(4, 1.0, 1.0);
  for (auto& t : ellipsoid)
    for (dvec3& p : t) p *= dvec3(1.5, 0.6, 0.3);
  write_obj("ellipsoid.obj", ellipsoid);
  write_obj("lumpy.obj", lumpy_mesh(4));
  const char* shapes[] = {R"({"type": "sphere", "material": "m", "center": [0, 0, 0], "radius": 1})",
                          R"({"type": "mesh", "material": "m", "file": "ellipsoid.obj"})"};
  for (int which = 0; which < 2; ++which) {
    const std::string json = R"({
      "camera": {"position": [0.05, 0.02, -0.03], "look_at": [1, 0.3, 0.2], "up": [0, 1, 0], "fov": 100},
      "film": {"width": 48, "height": 48}, "background": [1, 1, 1],
      "materials": {"m": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}},
      "shapes": [)" + std::string(shapes[which]) + "]}";
    const xi::Scene s = xi::parse_scene(json, which == 0 ? "icosphere" : "ellipsoid", mesh_dir());
    const Shot shot = render_shot(s, render_options(32, 81 + which, xi::Strategy::Mis, 16));
    EXPECT_EQ(shot.nonfinite, 0u);
    int lit = 0;
    for (int y = 0; y < s.height; ++y)
      for (int x = 0; x < s.width; ++x)
        if (!(shot.mean.at(x, y) == glm::vec3(0.0f) && shot.variance.at(x, y) == glm::vec3(0.0f)) && ++lit <= 5)
          ADD_FAILURE() << s.source << ": pixel " << x << ", " << y << " sees " << shot.mean.at(x, y).x;
    std::printf("[ inside ] %-9s (%zu triangles): %d pixels not black\n", s.source.c_str(), s.triangles.size(), lit);
    EXPECT_EQ(lit, 0);  // exact
  }
  const std::string json = R"({
    "camera": {"position": [0.05, 0.02, -0.03], "look_at": [1, 0.3, 0.2], "up": [0, 1, 0], "fov": 100},
    "film": {"width": 32, "height": 32}, "background": [1, 1, 1],
    "materials": {"m": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5], "radiance": [1, 1, 1], "two_sided": true}},
    "shapes": [{"type": "mesh", "material": "m", "file": "lumpy.obj"}]})";
  const xi::Scene s = xi::parse_scene(json, "lumpy furnace", mesh_dir());
  for (const xi::Triangle& t : s.triangles) ASSERT_FALSE(t.has_normals);
  const Shot shot = render_shot(s, render_options(64, 83, xi::Strategy::Mis, 64));
  EXPECT_EQ(shot.nonfinite, 0u);
  const double z_max = xi::stats::sidak_critical_z(0.01, 4);
  const int bands[4][2] = {{0, 32}, {0, 11}, {11, 22}, {22, 32}};
  for (const auto& b : bands) {
    const MeanSe m = block_mean(shot, b[0], 0, b[1], 32);
    std::printf("[ inside ] lumpy furnace, columns %2d..%2d: %.4f ± %.4f, exact 2, z = %+.2f\n", b[0], b[1], m.mean,
                m.se, (m.mean - 2.0) / m.se);
    EXPECT_GT(m.se, 0.0);
    EXPECT_LE(std::abs(m.mean - 2.0), z_max * m.se) << "columns " << b[0] << ".." << b[1];
  }
}

}  // namespace
