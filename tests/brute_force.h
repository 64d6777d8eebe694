// Brute-force ray/triangle queries over a triangle list, the reference for the BVH and extend tests.
#pragma once
#include <algorithm>
#include <cstdint>
#include <array>
#include <vector>

#include "triangle.h"
#include "xi/scene.h"

namespace xi::test {

using glm::vec3;

struct HostHit {
  uint32_t tri = XI_NO_HIT;  // scene order
  float t = INFINITY, u = 0.0f, v = 0.0f;
};

// The reference: xi_intersect_triangle on every triangle. A conservative bounding-sphere test
// (distance from the ray's line to the triangle's centroid, with slack far above float rounding)
// first skips triangles the line cannot touch; it only saves time (check_queries compares it with
// the unculled loop on a sample of rays).
struct BruteForce {
  std::vector<std::array<vec3, 3>> tris;  // each triangle's corners
  std::vector<float> cx, cy, cz, r2;
  explicit BruteForce(const xi::Mesh& mesh) {
    for (const xi::Triangle& t : mesh.triangles) {
      const std::array<vec3, 3> tri{mesh.position(t, 0), mesh.position(t, 1), mesh.position(t, 2)};
      tris.push_back(tri);
      vec3 c = (tri[0] + tri[1] + tri[2]) / 3.0f;
      float r = 0.0f;
      for (auto& v : tri) r = std::max(r, glm::length(v - c));
      cx.push_back(c.x), cy.push_back(c.y), cz.push_back(c.z), r2.push_back(1.01f * r * r);
    }
  }
  // Every hit of the ray (unit d) in (0, tmax), nearest first.
  std::vector<HostHit> hits(vec3 o, vec3 d, float tmax, bool cull = true) const {
    const size_t n = tris.size();
    std::vector<uint8_t> near(n);
    for (size_t i = 0; i < n; ++i) {  // vectorisable: no branches
      float px = cx[i] - o.x, py = cy[i] - o.y, pz = cz[i] - o.z;
      float qx = py * d.z - pz * d.y, qy = pz * d.x - px * d.z, qz = px * d.y - py * d.x;
      near[i] = !cull || qx * qx + qy * qy + qz * qz <= r2[i] + 1e-5f * (px * px + py * py + pz * pz);
    }
    RayShear s = xi_ray_shear(o, d);
    std::vector<HostHit> out;
    for (uint32_t i = 0; i < n; ++i) {
      HostHit h{i};
      if (near[i] && xi_intersect_triangle(s, tris[i][0], tris[i][1], tris[i][2], tmax, &h.t, &h.u, &h.v))
        out.push_back(h);
    }
    std::sort(out.begin(), out.end(), [](const HostHit& a, const HostHit& b) { return a.t < b.t; });
    return out;
  }
};

}  // namespace xi::test
