// Closed-form results the tests compare renders against, computed on the host in double (or long
// double) precision, independently of the renderer: the camera's rays and its map from world to
// film, a pixel's expected value as the average over its footprint, and Lambert's formula for the
// irradiance from a polygonal Lambertian emitter.
#pragma once
#include <cmath>
#include <functional>
#include <vector>

#include <glm/glm.hpp>

#include "xi/scene.h"

namespace xi::test {

// The camera ray through film point (fx, fy) in pixels (x right, y down from the top-left corner),
// as the scene defines the camera (forward = normalize(look_at − position), right =
// normalize(forward × up), up' = right × forward, vertical field of view) and compile_scene and
// generate.cl implement it; and the film point where world point p is seen. The film is the
// scene's, or w × h.
struct View {
  glm::dvec3 o, fwd, right, up;  // right and up scaled by the half-extents of the film at distance 1
  int w, h;
  explicit View(const Scene& s) : View(s, s.width, s.height) {}
  View(const Scene& s, int width, int height) : w(width), h(height) {
    const Camera& c = s.camera;
    o = glm::dvec3(c.position);
    fwd = glm::normalize(glm::dvec3(c.look_at) - o);
    const glm::dvec3 r = glm::normalize(glm::cross(fwd, glm::dvec3(c.up)));
    const double t = std::tan(glm::radians((double)c.vfov_degrees) / 2.0);
    right = r * t * ((double)w / h);
    up = glm::cross(r, fwd) * t;
  }
  glm::dvec3 ray(double fx, double fy) const {
    return glm::normalize(fwd + (2.0 * fx / w - 1.0) * right + (1.0 - 2.0 * fy / h) * up);
  }
  glm::dvec2 film(glm::dvec3 p) const {
    const glm::dvec3 d = p - o;
    const double z = glm::dot(d, fwd);
    const double sx = glm::dot(d, right) / glm::dot(right, right) / z, sy = glm::dot(d, up) / glm::dot(up, up) / z;
    return {(sx + 1.0) / 2.0 * w, (1.0 - sy) / 2.0 * h};
  }
  // The pixel that sees p.
  glm::ivec2 pixel(glm::dvec3 p) const {
    const glm::dvec2 f = film(p);
    return {(int)std::floor(f.x), (int)std::floor(f.y)};
  }
};

// The pixel's expected value (the box filter): f, the radiance along a camera ray direction (NaN
// where the case does not define it), averaged over the pixel's footprint by a k × k midpoint rule.
inline double footprint_mean(const View& v, int px, int py, const std::function<double(glm::dvec3)>& f, int k = 16) {
  double sum = 0.0;
  for (int i = 0; i < k; ++i)
    for (int j = 0; j < k; ++j) sum += f(v.ray(px + (i + 0.5) / k, py + (j + 0.5) / k));
  return sum / (k * k);
}

// The irradiance E at x (normal n) from a polygonal Lambertian emitter of radiance L, by Lambert's
// formula for a polygonal luminaire: E(x) = L/2 · |Σ_i Θ_i (n · u_i)| over the edges (v_i, v_i+1),
// Θ_i the angle the edge subtends at x, u_i the unit normal of the plane through x and the edge.
// In long double with Θ_i = atan2(|a × b|, a · b), which stays accurate for a polygon that subtends
// 1e-12 sr, where the terms (~1e-6) cancel to 1e-12.
inline double lambert_irradiance(const std::vector<glm::dvec3>& polygon, double radiance, glm::dvec3 x,
                                 glm::dvec3 n) {
  using LD = long double;
  LD sum = 0.0L;
  for (size_t i = 0; i < polygon.size(); ++i) {
    const glm::dvec3 pa = polygon[i], pb = polygon[(i + 1) % polygon.size()];
    const LD a[3] = {(LD)pa.x - x.x, (LD)pa.y - x.y, (LD)pa.z - x.z};
    const LD b[3] = {(LD)pb.x - x.x, (LD)pb.y - x.y, (LD)pb.z - x.z};
    const LD c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    const LD len = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    if (len == 0.0L) continue;
    const LD theta = std::atan2(len, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
    sum += theta * (n.x * c[0] + n.y * c[1] + n.z * c[2]) / len;
  }
  return (double)(0.5L * radiance * std::fabs(sum));
}

}  // namespace xi::test
