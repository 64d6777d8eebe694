// Ray–triangle intersection and traversal on hard geometry: needles of aspect ratio down to 1e-5
// must be hit as often as their area says, zero-area triangles never; and ten million rays from
// inside closed meshes, aimed at their edges and vertices, must all hit the shell.
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

#include <random>

#include <glm/glm.hpp>

#include "analytic.h"
#include "brute_force.h"
#include "fixtures.h"
#include "scene_builder.h"
#include "stats.h"
#include "xi/renderer.h"
#include "xi/scene.h"
#include "render/ray_probe.h"

namespace fs = std::filesystem;

namespace {

using namespace xi::test;  // fixtures.h, analytic.h, scene_builder.h (its vector types too)


// Area of a convex polygon clipped to the rectangle [x0, x1] × [y0, y1] (Sutherland–Hodgman).
double clipped_area(std::vector<dvec2> p, double x0, double y0, double x1, double y1) {
  const double limit[4] = {x0, y0, x1, y1};
  for (int e = 0; e < 4 && !p.empty(); ++e) {
    const int axis = e & 1;
    const bool lower = e < 2;
    auto in = [&](dvec2 q) { return lower ? q[axis] >= limit[e] : q[axis] <= limit[e]; };
    std::vector<dvec2> out;
    for (size_t i = 0; i < p.size(); ++i) {
      const dvec2 a = p[i], b = p[(i + 1) % p.size()];
      if (in(a)) out.push_back(a);
      if (in(a) != in(b)) out.push_back(a + (limit[e] - a[axis]) / (b[axis] - a[axis]) * (b - a));
    }
    p = std::move(out);
  }
  double twice = 0.0;
  for (size_t i = 0; i < p.size(); ++i) {
    const dvec2 a = p[i], b = p[(i + 1) % p.size()];
    twice += a.x * b.y - a.y * b.x;
  }
  return std::abs(twice) / 2.0;
}



struct RayTest {
  size_t escaped = 0, off_shell = 0;
  double seconds = 0.0;
};

// aim_into: a triangle over the mesh's vertices (one removed from its triangles: a hole).
RayTest shoot_from_inside(const xi::Mesh& mesh, dvec3 centre, double origin_radius, double r_lo,
                          double r_hi, size_t count, uint64_t seed, const xi::Triangle* aim_into = nullptr) {
  const std::vector<xi::Triangle>& tris = mesh.triangles;
  xi::Scene s;
  s.width = s.height = 512;  // 2^18 paths in flight with one sample per pixel
  s.materials = {xi::Material{}};
  s.vertices = mesh.vertices;
  s.triangles = tris;
  for (xi::Triangle& t : s.triangles) t.texcoords = xi::kNoTexcoords;  // geometry alone
  xi::RenderOptions o;
  o.spp = 1;
  o.paths_in_flight = (size_t)s.width * s.height;
  o.ray_packets = xi::RenderOptions::RayPackets::Off;  // one ray per work item: random origins make no packets
  xi::Renderer renderer(device(), s, o);
  const size_t batch = renderer.paths_in_flight();
  std::vector<dvec3> verts;
  for (const xi::Triangle& t : tris)
    for (int k = 0; k < 3; ++k) verts.push_back(dvec3(mesh.position(t, k)));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g;
  RayTest out;
  xi::RayBatch rays;
  std::vector<glm::vec4> hits;
  for (size_t done = 0; done < count; done += batch) {
    const size_t n = std::min(batch, count - done);
    rays.org.resize(n);
    rays.dir.resize(n);
    for (size_t i = 0; i < n; ++i) {
      dvec3 o;
      do o = dvec3(2 * u(rng) - 1, 2 * u(rng) - 1, 2 * u(rng) - 1);
      while (glm::dot(o, o) > 1.0);
      o = centre + origin_radius * o;
      const vec3 of(o);
      dvec3 target;
      const size_t k = (done + i) % 3;
      if (aim_into) {  // a uniform point of the triangle
        double a = u(rng), b = u(rng);
        if (a + b > 1.0) a = 1.0 - a, b = 1.0 - b;
        const dvec3 p0(mesh.position(*aim_into, 0)), p1(mesh.position(*aim_into, 1)), p2(mesh.position(*aim_into, 2));
        target = p0 + a * (p1 - p0) + b * (p2 - p0);
      } else if (k == 0) {
        target = dvec3(of) + dvec3(g(rng), g(rng), g(rng));
      } else {
        const size_t t = (size_t)(u(rng) * tris.size()) % tris.size(), e = (size_t)(u(rng) * 3) % 3;
        const dvec3 a = verts[3 * t + e], b = verts[3 * t + (e + 1) % 3];
        target = k == 1 ? a + u(rng) * (b - a) : a;
      }
      rays.org[i] = glm::vec4(of, 0.0f);
      rays.dir[i] = glm::vec4(vec3(glm::normalize(target - dvec3(of))), 0.0f);
    }
    out.seconds += xi::RayProbe(renderer).trace_closest(rays, &hits, 1);
    for (size_t i = 0; i < n; ++i) {
      if (hits[i].x < 0.0f) {
        out.escaped++;
        continue;
      }
      const double r = glm::length(dvec3(rays.org[i]) + (double)hits[i].x * dvec3(rays.dir[i]) - centre);
      out.off_shell += !(r >= r_lo * (1 - 1e-3) && r <= r_hi * (1 + 1e-3));
    }
  }
  return out;
}

}  // namespace

// Needles: black triangles 40 pixels long and 1e-2, 1e-3, 1e-4 and 1e-5 of that wide (aspect
// ratios the loader keeps; it drops triangles under 1e-6), in a plane facing the camera, in front
// of a white sky (background 1), loaded from OBJ. Four bands of 16 rows hold 2, 20, 200 and 2000
// parallel, non-overlapping needles of one aspect each, so each band's expected mean is exactly
// 1 − (needle area in it) / (band area): the plane is parallel to the film, so its map to film
// coordinates is affine and the areas are computed exactly by clipping the loaded triangles' film
// images to the band. Per band a z-test (4 tests, family-wise α = 0.01, Šidák, z = 3.02), so
// needles that are missed, or hit too often, fail. The same OBJ holds zero-area triangles (three
// collinear points, a repeated vertex, three equal vertices, and a 1e-7 needle): the loader must
// drop exactly those.
// Finally, zero-area triangles put straight into the scene (bypassing the loader, one of them
// emissive) must change no pixel of the render: never hit, never sampled as a light, no NaN.
TEST(IntersectionRobustness, NeedleAndDegenerateTriangles) {
  xi::Scene cam;
  cam.width = cam.height = 64;
  set_camera(cam, vec3(0.0f), vec3(0, 0, 1), 40.0f);
  const View v(cam);
  const double plane_z = 10.0;
  auto world = [&](double fx, double fy) {  // the film point's place on the plane z = 10
    const dvec3 d = v.fwd + (2.0 * fx / v.w - 1.0) * v.right + (1.0 - 2.0 * fy / v.h) * v.up;
    return v.o + d * (plane_z / d.z);
  };
  const double length = 40.0, angle = glm::radians(20.0);
  const dvec2 along(std::cos(angle), std::sin(angle)), across(-std::sin(angle), std::cos(angle));
  std::vector<std::array<dvec3, 3>> tris;
  int needles = 0;
  for (int band = 0; band < 4; ++band) {
    const double aspect = std::pow(10.0, -2 - band);
    const int n = 2 * (int)std::pow(10.0, band);
    for (int k = 0; k < n; ++k) {
      const dvec2 base(4.0 + k * 18.4 / (n - 1), 16.0 * band + 1.0);
      const dvec2 a = base - across * (aspect * length / 2), b = base + across * (aspect * length / 2),
                  c = base + along * length;
      tris.push_back({world(a.x, a.y), world(b.x, b.y), world(c.x, c.y)});
      needles++;
    }
  }
  const dvec3 p = world(30, 30), q = world(31, 33), r = world(40, 31);
  tris.push_back({p, (p + q) / 2.0, q});                                        // collinear
  tris.push_back({p, q, q});                                                    // a repeated vertex
  tris.push_back({r, r, r});                                                    // one point
  tris.push_back({p, r, r + (p - r) * 0.5 + dvec3(0, 1e-7 * glm::length(r - p), 0)});  // aspect 1e-7
  const fs::path obj = write_obj("needles.obj", tris);

  xi::Scene s = cam;
  s.background = vec3(1.0f);
  static_cast<xi::Mesh&>(s) = load_obj(obj);
  ASSERT_EQ((int)s.triangles.size(), needles) << "the loader keeps every needle and drops every zero-area triangle";
  s.materials = {xi::Material{}};  // black diffuse
  s.materials[0].name = "black";
  for (xi::Triangle& t : s.triangles) t.material = 0;

  const Shot shot = render_shot(s, render_options(256, 91, xi::Strategy::Mis, 4));
  EXPECT_EQ(shot.nonfinite, 0u);
  const double z_max = xi::stats::sidak_critical_z(0.01, 4);
  for (int band = 0; band < 4; ++band) {
    const double y0 = 16.0 * band, y1 = y0 + 16.0;
    double covered = 0.0;
    for (const xi::Triangle& t : s.triangles)
      covered += clipped_area({v.film(dvec3(s.position(t, 0))), v.film(dvec3(s.position(t, 1))),
                               v.film(dvec3(s.position(t, 2)))}, 0, y0, 64, y1);
    const double exact = 1.0 - covered / (64.0 * 16.0);
    const MeanSe m = block_mean(shot, 0, (int)y0, 64, (int)y1);
    std::printf("[ needle ] aspect 1e-%d: coverage %.5f (exact %.5f) ± %.5f, z = %+.2f\n", band + 2, 1.0 - m.mean,
                1.0 - exact, m.se, (m.mean - exact) / m.se);
    EXPECT_GT(m.se, 0.0);
    EXPECT_LE(std::abs(m.mean - exact), z_max * m.se) << "band " << band;
  }

  xi::Scene with = s;
  with.materials.push_back(xi::Material{});
  with.materials[1].name = "zero-area light";
  with.materials[1].emission = vec3(100.0f);
  with.materials[1].two_sided = true;
  const vec3 fp(p), fq(q), fr(r);
  for (uint32_t m : {0u, 1u}) {
    add_triangle(with, m, fp, fq, fq);
    add_triangle(with, m, fr, fr, fr);
    add_triangle(with, m, vec3(-1, -1, 10), vec3(0, 0, 10), vec3(1, 1, 10));  // exactly collinear in float
  }
  s.materials = with.materials;  // the same materials, so the same kernels
  const Shot plain = render_shot(s, render_options(16, 92, xi::Strategy::Mis, 4));
  const Shot degenerate = render_shot(with, render_options(16, 92, xi::Strategy::Mis, 4));
  EXPECT_EQ(degenerate.nonfinite, 0u);
  int differ = 0;
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x) differ += plain.mean.at(x, y) != degenerate.mean.at(x, y);
  EXPECT_EQ(differ, 0) << "pixels changed by adding zero-area triangles";
}

// Watertightness: 1e7 rays from inside each of two closed meshes, none escapes. The extend
// kernel alone (RayProbe::trace_closest) in batches of the 2^18 paths in flight. A third of the rays
// go in uniformly random directions, a third toward a random point of a random mesh edge, a third
// exactly toward a random vertex (where cracks between triangles would be). Meshes: an icosphere
// (5 subdivisions, 20480 triangles) of radius 1 centred at 1e3 (1, −2, 3), where its vertices
// round to a 2.4e-4 grid, with origins uniform in the ball of radius 0.95; and the uneven
// star-shaped mesh (4 subdivisions, 5120 triangles, radii 0.3 to 1.5) loaded from OBJ, with origins
// uniform in a ball about its centre inside every face's plane (half the smallest distance from the
// centre to a face's plane), so each origin sees the inside of every face it can hit. Every ray must
// hit, at a point within the mesh's radii (it hit the shell). Rays from inside start within most of
// the BVH's boxes, a slow case, slowest for the uneven mesh, whose long crossing slivers make the
// boxes large. Fused multiply-adds in the triangle test (triangle.h turns them off) let rays escape
// the uneven mesh. Control: rays aimed into a triangle removed from the uneven mesh all escape.

TEST(IntersectionRobustness, TenMillionRaysFromInsideClosedMeshesNoneEscapes) {
  constexpr size_t kRays = 10'000'000;
  const dvec3 far(1e3, -2e3, 3e3);
  const xi::Scene sphere = xi::parse_scene(
      R"({"camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
          "materials": {"m": {"type": "diffuse", "albedo": [1, 1, 1]}},
          "shapes": [{"type": "sphere", "material": "m", "center": [1000, -2000, 3000], "radius": 1,
                      "subdivisions": 5}]})",
      "icosphere", ".");
  const RayTest a = shoot_from_inside(sphere, far, 0.95, 0.99, 1.0, kRays, 101);
  std::printf("[ watert ] icosphere, %zu triangles at 1e3 (1, -2, 3): %zu rays, %zu escaped, %zu off the shell, %.2f s "
              "in extend\n", sphere.triangles.size(), kRays, a.escaped, a.off_shell, a.seconds);
  EXPECT_EQ(a.escaped, 0u);  // exact
  EXPECT_EQ(a.off_shell, 0u);

  xi::Mesh lumpy = load_obj(write_obj("lumpy-watertight.obj", lumpy_mesh(4)));
  ASSERT_EQ(lumpy.triangles.size(), 5120u);
  double inner = INFINITY;
  for (const xi::Triangle& t : lumpy.triangles) {
    const vec3 &p0 = lumpy.position(t, 0), &p1 = lumpy.position(t, 1), &p2 = lumpy.position(t, 2);
    const dvec3 n = glm::normalize(glm::cross(dvec3(p1 - p0), dvec3(p2 - p0)));
    inner = std::min(inner, std::abs(glm::dot(n, dvec3(p0))));
  }
  ASSERT_GT(inner, 0.01);
  const RayTest b = shoot_from_inside(lumpy, dvec3(0.0), inner / 2, inner, 1.5, kRays, 102);
  std::printf("[ watert ] uneven mesh, %zu triangles (nearest face plane %.3f from the centre): %zu rays, %zu escaped, "
              "%zu off the shell, %.2f s in extend\n", lumpy.triangles.size(), inner, kRays, b.escaped, b.off_shell,
              b.seconds);
  EXPECT_EQ(b.escaped, 0u);  // exact
  EXPECT_EQ(b.off_shell, 0u);

  // Control: a hole. Remove the triangle with the largest solid angle seen from the centre.
  size_t hole = 0;
  double best = 0.0;
  for (size_t i = 0; i < lumpy.triangles.size(); ++i) {
    const xi::Triangle& t = lumpy.triangles[i];
    const dvec3 p0(lumpy.position(t, 0)), p1(lumpy.position(t, 1)), p2(lumpy.position(t, 2));
    const double omega = glm::length(glm::cross(p1 - p0, p2 - p0)) / std::pow(glm::length((p0 + p1 + p2) / 3.0), 2);
    if (omega > best) best = omega, hole = i;
  }
  const xi::Triangle removed = lumpy.triangles[hole];  // its vertices stay, shared with its neighbours
  lumpy.triangles.erase(lumpy.triangles.begin() + (long)hole);
  const RayTest c = shoot_from_inside(lumpy, dvec3(0.0), inner / 2, inner, 1.5, 10000, 103, &removed);
  std::printf("[ watert ] control, one triangle removed: %zu of 10000 rays aimed into the hole escaped\n", c.escaped);
  EXPECT_GE(c.escaped, 9900u);
}

// The shadow rays a render queues, recorded by the probe (RayProbe::recorded_shadow) and traced by
// the shadow stage alone (RayProbe::trace_shadow, as bench/ceiling.cpp does): each is occluded
// exactly where a brute-force search over the scene's triangles finds a hit before its end.
// mirror.json (hundreds of 8-wide nodes): bounce 0's shadow rays go in hybrid packets, bounce 1's
// alone. Rays with a hit within 1e-4 of their end are left out (rounding there may go either way).
TEST(IntersectionRobustness, RecordedShadowRaysAreOccludedAsBruteForceFinds) {
  xi::Scene scene = xi::load_scene(fs::path(XI_SCENE_DIR) / "mirror.json");
  scene.width = scene.height = 48;
  const BruteForce brute(scene);
  for (int bounce : {0, 1}) {
    SCOPED_TRACE(testing::Message() << "bounce " << bounce);
    xi::RenderOptions o;
    o.spp = 1;
    o.bvh_width = 8;
    o.paths_in_flight = (size_t)scene.width * scene.height;
    xi::Renderer renderer(device(), scene, o);
    ASSERT_TRUE(renderer.kernels().hybrid_packets);
    xi::RayProbe probe(renderer);
    probe.record(bounce);
    renderer.run_pass();
    const xi::RayBatch& rays = probe.recorded_shadow();
    ASSERT_GT(rays.org.size(), (size_t)scene.width * scene.height / 4);
    std::vector<bool> occluded;
    probe.trace_shadow(rays, &occluded, bounce);
    ASSERT_EQ(occluded.size(), rays.org.size());
    size_t blocked = 0, unclear = 0, wrong = 0;
    for (size_t i = 0; i < rays.org.size(); ++i) {
      const float tmax = rays.org[i].w;
      const std::vector<HostHit> hits = brute.hits(vec3(rays.org[i]), vec3(rays.dir[i]), INFINITY);
      if (!hits.empty() && std::abs(hits[0].t - tmax) < 1e-4f * tmax) {
        unclear++;
        continue;
      }
      const bool want = !hits.empty() && hits[0].t < tmax;
      blocked += want;
      if (occluded[i] != want && ++wrong <= 5)
        ADD_FAILURE() << "shadow ray " << i << ": traced " << (occluded[i] ? "occluded" : "clear") << ", brute force "
                      << (want ? "occluded" : "clear");
    }
    EXPECT_EQ(wrong, 0u);
    EXPECT_LT(unclear, rays.org.size() / 100);
    EXPECT_GT(blocked, 0u);  // both outcomes, so that agreeing says something
    EXPECT_LT(blocked, rays.org.size() - unclear);
  }
}

// A bounce that no path reaches (every camera ray escaped, say) hands the probe an empty batch: it
// traces nothing and says so, where an empty OpenCL transfer would be an error.
TEST(IntersectionRobustness, ProbeOfAnEmptyBatchTracesNothing) {
  xi::Scene scene = xi::load_scene(fs::path(XI_SCENE_DIR) / "cornell-box.json");
  scene.width = scene.height = 16;
  xi::RenderOptions o;
  o.spp = 1;
  xi::Renderer renderer(device(), scene, o);
  xi::RayProbe probe(renderer);
  const xi::RayBatch none;
  std::vector<glm::vec4> hits(3);
  std::vector<bool> occluded(3);
  EXPECT_EQ(probe.trace_closest(none, &hits, 1), 0.0);
  EXPECT_TRUE(hits.empty());
  EXPECT_EQ(probe.trace_shadow(none, &occluded, 1), 0.0);
  EXPECT_TRUE(occluded.empty());
}
