// A scene flattened for the kernels: triangles in BVH order, materials, the light distribution,
// the camera, and the set of features the kernels must be compiled with.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "layout.h"
#include "sampling.h"
#include "shading.h"
#include "xi/bvh.h"
#include "xi/scene.h"

namespace xi {

// What a scene uses, one flag per XI_FEATURES entry (shading.h: their meaning and bits); each maps
// to one -D flag, so absent features compile no code.
struct Features {
#define XI_FEATURE_FIELD(name, bit, word, in_all) bool name = false;
  XI_FEATURES(XI_FEATURE_FIELD)
#undef XI_FEATURE_FIELD
  bool lights() const { return emitters || environment || punctual; }
  static Features everything();
  std::string describe() const;  // e.g. "diffuse mirror emitters"
  bool operator==(const Features&) const = default;
};

struct CompiledScene {
  // The arrays of one entry per triangle or vertex are filled on every core, not zeroed first.
  template <class T>
  using Array = std::vector<T, DefaultInitAllocator<T>>;
  Bvh bvh;
  // Per triangle, in BVH order: its corners (vertex indices) and w = 1 where it has vertex normals.
  Array<glm::uvec4> tri_vertices;
  // XI_VERTEX_FLOAT4S per vertex (layout.h: its position, then its normal), in the scene's order.
  Array<glm::vec4> vertices;
  Array<uint32_t> tri_material;
  std::vector<MaterialData> materials;
  // Textures (where the scene has some; else one unused entry each, as OpenCL needs buffers):
  std::vector<glm::vec4> tri_uv;       // 3 per triangle: texture coordinates u0, v0 (set 0), u1, v1 (set 1)
  // 3 per triangle where a material has a normal map: the file's tangents (Triangle::tangent).
  std::vector<glm::vec4> tri_tangents;
  std::vector<TextureRef> texture_refs;
  std::vector<ImageHeader> images;
  std::vector<uint32_t> texels;        // every image's RGBA8 texels
  std::vector<PunctualLightData> punctual;  // one unused entry when there are none
  // σa (rgb) of each material with a volume, in the order of their MaterialData's volume (index +
  // 1); one unused entry when there are none.
  std::vector<glm::vec4> volumes;
  // The environment (one unused texel and CDF entry when there is none):
  EnvironmentData environment{};
  std::vector<glm::vec4> environment_texels;
  std::vector<float> environment_cdf;
  // The lights, picked in proportion to their power: emissive triangles, then punctual lights,
  // then the environment.
  std::vector<float> light_cdf;        // over the lights; last entry 1
  std::vector<uint32_t> light_tri;     // a triangle's position in BVH order (listed in the scene's order), or
                                       // XI_LIGHT_PUNCTUAL | index, or XI_LIGHT_ENVIRONMENT
  std::vector<float> tri_light_pdf;    // per triangle: P(pick it) / its area, 0 if not emissive
  float light_power = 0.0f;            // total emitted power (luminance), for reports
  CameraData camera{};
  glm::vec4 background{0.0f};          // radiance of escaped rays
  Features features;

  // Corner k's position of the triangle at position i in BVH order.
  glm::vec3 position(size_t i, int k) const { return vertex_position(tri_vertices[i][k]); }
  glm::vec3 vertex_position(size_t v) const { return glm::vec3(vertices[XI_VERTEX_FLOAT4S * v]); }
  size_t vertex_count() const { return vertices.size() / XI_VERTEX_FLOAT4S; }
};

// bvh_width: the lanes of the BVH's nodes, 4 or 8 (the kernels' XI_BVH_WIDTH); spatial_splits and
// build_threads: build_bvh's spatial_splits and threads.
CompiledScene compile_scene(const Scene& scene, int bvh_width = 4, bool spatial_splits = true,
                            unsigned build_threads = 0);
// The same, emptying the scene's mesh (triangles, texture coordinates, then vertices) as each part
// is compiled: a large mesh is never held whole in both forms.
CompiledScene compile_scene_freeing_triangles(Scene& scene, int bvh_width = 4, bool spatial_splits = true,
                                              unsigned build_threads = 0);

}  // namespace xi
