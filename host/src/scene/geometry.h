// What the JSON scene reader (scene.cpp) and the asset reader (asset.cpp) share: affine transforms of
// triangles, the coordinate limit, the checks on loaded triangles, and Assimp mesh conversion.
#pragma once
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <utility>
#include <string>
#include <string_view>
#include <vector>

#include <glm/glm.hpp>

#include "../parallel.h"
#include "xi/scene.h"

struct aiMesh;

namespace xi::scene_detail {

// A file's extension in lower case (".gltf"), by which readers are chosen.
inline std::string lower_extension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  for (char& c : ext) c = char(std::tolower((unsigned char)c));
  return ext;
}

// The largest coordinate (and camera length) a scene may have, after its transforms. The renderer
// works in single precision, and a triangle's area and normal take the length of the cross product
// of two edges, whose square grows as the fourth power of the edge: edges up to 2e9 give at most
// 3 * (2 * (2e9)^2)^2 = 1.9e38 < FLT_MAX = 3.4e38. Beyond, light pdfs and normals overflow (and near
// 1e19 the BVH builder's box extents do). Float spacing at 1e9 is 64 units anyway.
constexpr float kMaxCoordinate = 1e9f;

// The smallest extent (the longest side of the bounding box) a scene's geometry may have. Single
// precision fails the other way there: |e1 x e2|^2 of edges shorter than about 1e-11 underflows
// (below the smallest float, 1.4e-45), so normals and light areas come out NaN or zero: the
// Cornell box scaled to an extent of 6e-12 rendered black but for its light, at 6e-11 it rendered
// right. 1e-6 leaves edges of a thousandth of the scene well clear of that.
constexpr double kMinExtent = 1e-6;

// Runs work(begin, end, part) over [0, n) in contiguous parts, on every core where n is large.
template <class Work>
void in_parts(size_t n, const Work& work) {
  parallel_chunks(n, parts_for(n), work);
}

// The longest side of the bounding box of the mesh's triangles (0 for none).
inline double extent(const Mesh& mesh) {
  const auto [lo, hi] = mesh.bounds();
  const glm::dvec3 size = glm::dvec3(hi) - glm::dvec3(lo);
  return mesh.triangles.empty() ? 0.0 : std::max({size.x, size.y, size.z});
}

// The error for geometry smaller than kMinExtent, else empty.
inline std::string too_small(const Mesh& mesh) {
  const double e = extent(mesh);
  if (mesh.triangles.empty() || e >= kMinExtent) return "";  // (no geometry: an error of its own)
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.3g", e);
  return std::string("the geometry spans only ") + buf +
         " units (the longest side of its bounding box; at least 1e-6): single precision cannot shade so small "
         "a scene; scale it up";
}

struct Transform {
  glm::dmat4 m{1.0};
  glm::dmat3 normal{1.0};  // inverse transpose of the linear part
  bool flips = false;      // negative determinant: mirrored, so triangle winding must be swapped
};

// The normal matrix and mirroring of an affine matrix (the caller checks it is not singular).
inline Transform make_transform(const glm::dmat4& m) {
  const glm::dmat3 linear(m);
  return {m, glm::transpose(glm::inverse(linear)), glm::determinant(linear) < 0.0};
}

// Moves the vertices of mesh from first_vertex on, and its triangles from first_triangle on (their
// texture coordinates' tangents, in entries of their own).
inline void transform_mesh(const Transform& xf, Mesh& mesh, size_t first_vertex, size_t first_triangle) {
  in_parts(mesh.vertices.size() - first_vertex, [&](size_t begin, size_t end, unsigned) {
    for (size_t i = first_vertex + begin; i < first_vertex + end; ++i) {
      Vertex& v = mesh.vertices[i];
      v.position = glm::vec3(xf.m * glm::dvec4(v.position, 1.0));
      const glm::dvec3 n = xf.normal * glm::dvec3(v.normal);
      v.normal = glm::dot(n, n) > 0.0 ? glm::vec3(glm::normalize(n)) : glm::vec3(0.0f);  // none, or NaN: zero
    }
  });
  in_parts(mesh.triangles.size() - first_triangle, [&](size_t begin, size_t end, unsigned) {
    for (size_t i = first_triangle + begin; i < first_triangle + end; ++i) {
      Triangle& tri = mesh.triangles[i];
      // Tangents lie in the surface: they move as its points do; a mirroring transform flips the
      // frame's handedness, so the bitangent's sign too.
      TriangleTexcoords* tc = tri.texcoords == kNoTexcoords ? nullptr : &mesh.texcoords[tri.texcoords];
      if (tc)
        for (auto& tg : tc->tangent)
          if (tg.w != 0.0f)
            tg = glm::vec4(glm::vec3(glm::normalize(glm::dmat3(xf.m) * glm::dvec3(tg))), xf.flips ? -tg.w : tg.w);
      if (xf.flips) {  // keep the front face (from the winding) on the same side as the normals
        std::swap(tri.v[1], tri.v[2]);
        if (tc) {
          std::swap(tc->tangent[1], tc->tangent[2]);
          for (auto& set : tc->uv) std::swap(set[1], set[2]);
        }
      }
    }
  });
}

// Every coordinate within +-kMaxCoordinate (false for NaN).
inline bool within_range(glm::vec3 v) {
  return std::abs(v.x) <= kMaxCoordinate && std::abs(v.y) <= kMaxCoordinate && std::abs(v.z) <= kMaxCoordinate;
}
inline bool within_range(const Mesh& mesh, const Triangle& t) {
  return within_range(mesh.position(t, 0)) && within_range(mesh.position(t, 1)) && within_range(mesh.position(t, 2));
}

// Zero area up to float noise: |e1 x e2| tiny next to the squared edge lengths (also catches NaN).
inline bool degenerate(const Mesh& mesh, const Triangle& t) {
  const glm::dvec3 v0(mesh.position(t, 0));
  const glm::dvec3 e1 = glm::dvec3(mesh.position(t, 1)) - v0, e2 = glm::dvec3(mesh.position(t, 2)) - v0;
  return !(glm::length(glm::cross(e1, e2)) > 1e-6 * std::max(glm::dot(e1, e1), glm::dot(e2, e2)));
}

// Room in `items` (triangles, vertices) for `more`: for a large mesh, at once (growing by doubling
// would copy it and hold it twice), with an eighth more for the shapes after it; for small ones,
// doubling as push_back does. Capacity never written takes no memory.
template <class T>
void make_room(std::vector<T>& items, size_t more) {
  const size_t need = items.size() + more;
  if (items.capacity() < need) items.reserve(std::max(need + need / 8, 2 * items.capacity()));
}

// Appends to `out` an Assimp mesh's vertices (with its vertex normals if it has them) and triangles,
// in the mesh's own coordinates, and their texture coordinates and tangents if it has either;
// points and lines (which survive triangulation) are skipped. Defined in asset.cpp.
// flip_v: v = 1 - v, undoing the flip Assimp applies to glTF files (glTF's v runs down the image).
void mesh_triangles(const aiMesh& mesh, uint32_t material, bool flip_v, Mesh& out);

// Transforms loaded geometry in place (transform_mesh), then checks its triangles as every mesh's
// are checked: a vertex beyond +-1e9 (or not finite) is an error (the index from first_triangle of
// the first such triangle is returned, else -1), degenerate triangles are dropped, and a triangle
// with a normal that is zero or not finite is shaded flat.
long long place_mesh(const Transform& xf, Mesh& mesh, size_t first_vertex = 0, size_t first_triangle = 0);

}  // namespace xi::scene_detail
