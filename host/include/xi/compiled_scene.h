// A scene flattened for the kernels: triangles in BVH order, materials, the light distribution,
// the camera, and the set of features the kernels must be compiled with.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "layout.h"
#include "sampling.h"
#include "xi/bvh.h"
#include "xi/scene.h"

namespace xi {

// What a scene uses; each feature maps to one -D flag, so absent features compile no code.
struct Features {
  bool mirror = false;
  bool dielectric = false;
  bool normals = false;   // interpolated vertex normals
  bool emitters = false;
  bool lens = false;
  static Features everything();
  std::string describe() const;  // e.g. "diffuse mirror emitters"
  bool operator==(const Features&) const = default;
};

struct CompiledScene {
  Bvh bvh;
  std::vector<glm::vec4> tri_verts;    // 3 per triangle, BVH order
  std::vector<glm::vec4> tri_normals;  // 3 per triangle; w = 1 where the triangle has vertex normals
  std::vector<uint32_t> tri_material;
  std::vector<MaterialData> materials;
  std::vector<float> light_cdf;        // over emissive triangles, by power; last entry 1
  std::vector<uint32_t> light_tri;     // their positions in BVH order, listed in the scene's order
  std::vector<float> tri_light_pdf;    // per triangle: P(pick it) / its area, 0 if not emissive
  float light_power = 0.0f;            // total emitted power (luminance), for reports
  CameraData camera{};
  glm::vec4 background{0.0f};          // radiance of escaped rays
  Features features;
};

// bvh_width: the lanes of the BVH's nodes, 4 or 8 (the kernels' XI_BVH_WIDTH); spatial_splits and
// build_threads: build_bvh's spatial_splits and threads.
CompiledScene compile_scene(const Scene& scene, int bvh_width = 4, bool spatial_splits = true,
                            unsigned build_threads = 0);

}  // namespace xi
