#include "xi/bvh.h"

#include <algorithm>
#include <chrono>
#include <cstring>

#include "xi/error.h"

namespace xi {
namespace {

constexpr int kBins = 16;
constexpr size_t kMaxLeaf = 8;      // a leaf never holds more, unless the centroids coincide
constexpr int kMaxDepth = 56;       // below the kernels' traversal stack (XI_BVH_STACK)
constexpr float kTraversalCost = 1.0f;  // relative to one triangle test

struct Box {
  glm::vec3 lo{INFINITY}, hi{-INFINITY};
  void grow(const glm::vec3& p) { lo = glm::min(lo, p); hi = glm::max(hi, p); }
  void grow(const Box& b) { lo = glm::min(lo, b.lo); hi = glm::max(hi, b.hi); }
  float area() const {
    glm::vec3 d = hi - lo;
    return d.x < 0.0f ? 0.0f : 2.0f * (d.x * d.y + d.y * d.z + d.z * d.x);
  }
};

struct Builder {
  const std::vector<Triangle>& tris;
  std::vector<Box> bounds;
  std::vector<glm::vec3> centroids;
  Bvh& bvh;

  void leaf(size_t node, size_t first, size_t count) {
    bvh.nodes[node].bmin.w = as_float((uint32_t)first);
    bvh.nodes[node].bmax.w = as_float((uint32_t)count);
    bvh.stats.leaves++;
    bvh.stats.max_leaf = std::max(bvh.stats.max_leaf, count);
  }

  void build(size_t node, size_t first, size_t count, int depth) {
    bvh.stats.depth = std::max(bvh.stats.depth, depth);
    Box box, cbox;
    for (size_t i = first; i < first + count; ++i) {
      box.grow(bounds[bvh.order[i]]);
      cbox.grow(centroids[bvh.order[i]]);
    }
    bvh.nodes[node].bmin = glm::vec4(box.lo, 0.0f);
    bvh.nodes[node].bmax = glm::vec4(box.hi, 0.0f);
    if (count == 1 || depth >= kMaxDepth) return leaf(node, first, count);

    // Binned SAH over all three axes of the centroid bounds.
    float best_cost = INFINITY;
    int best_axis = -1, best_split = 0;
    for (int axis = 0; axis < 3; ++axis) {
      float lo = cbox.lo[axis], extent = cbox.hi[axis] - lo;
      if (!(extent > 0.0f)) continue;
      Box bin_box[kBins];
      size_t bin_count[kBins] = {};
      for (size_t i = first; i < first + count; ++i) {
        uint32_t t = bvh.order[i];
        int b = std::min(kBins - 1, (int)(kBins * (centroids[t][axis] - lo) / extent));
        bin_box[b].grow(bounds[t]);
        bin_count[b]++;
      }
      // Sweep from the right to get the area × count of every right part, then from the left.
      float right_cost[kBins];
      Box acc;
      size_t n = 0;
      for (int b = kBins - 1; b > 0; --b) {
        acc.grow(bin_box[b]);
        n += bin_count[b];
        right_cost[b] = acc.area() * (float)n;
      }
      acc = Box();
      n = 0;
      for (int b = 0; b < kBins - 1; ++b) {
        acc.grow(bin_box[b]);
        n += bin_count[b];
        float cost = acc.area() * (float)n + right_cost[b + 1];
        if (n > 0 && n < count && cost < best_cost) {
          best_cost = cost;
          best_axis = axis;
          best_split = b + 1;
        }
      }
    }
    float leaf_cost = (float)count;
    float split_cost = kTraversalCost + best_cost / std::max(box.area(), 1e-30f);
    if (best_axis < 0) {  // every centroid in one point: no split separates them
      if (count <= kMaxLeaf) return leaf(node, first, count);
    } else if (count <= kMaxLeaf && leaf_cost <= split_cost) {
      return leaf(node, first, count);
    }

    size_t mid;
    if (best_axis >= 0) {
      float lo = cbox.lo[best_axis], extent = cbox.hi[best_axis] - lo;
      auto* begin = bvh.order.data() + first;
      auto* m = std::partition(begin, begin + count, [&](uint32_t t) {
        int b = std::min(kBins - 1, (int)(kBins * (centroids[t][best_axis] - lo) / extent));
        return b < best_split;
      });
      mid = (size_t)(m - bvh.order.data());
    } else {
      mid = first + count / 2;  // coincident centroids: halve by index
    }
    size_t left = bvh.nodes.size();
    bvh.nodes.push_back(BvhNode{});
    build(left, first, mid - first, depth + 1);
    size_t right = bvh.nodes.size();
    bvh.nodes.push_back(BvhNode{});
    build(right, mid, first + count - mid, depth + 1);
    bvh.nodes[node].bmin.w = as_float((uint32_t)right);
    bvh.nodes[node].bmax.w = as_float(0u);
  }
};

}  // namespace

Bvh build_bvh(const std::vector<Triangle>& triangles) {
  auto start = std::chrono::steady_clock::now();
  if (triangles.empty()) throw Error("cannot build a BVH over an empty scene");
  if (triangles.size() >= (1ull << 31)) throw Error("too many triangles for 32-bit indices");
  Bvh bvh;
  Builder b{triangles, {}, {}, bvh};
  b.bounds.resize(triangles.size());
  b.centroids.resize(triangles.size());
  for (size_t i = 0; i < triangles.size(); ++i) {
    for (auto& v : triangles[i].v) b.bounds[i].grow(v);
    b.centroids[i] = (triangles[i].v[0] + triangles[i].v[1] + triangles[i].v[2]) / 3.0f;
  }
  bvh.order.resize(triangles.size());
  for (size_t i = 0; i < triangles.size(); ++i) bvh.order[i] = (uint32_t)i;
  bvh.nodes.reserve(2 * triangles.size());
  bvh.nodes.push_back(BvhNode{});
  b.build(0, 0, triangles.size(), 0);
  bvh.stats.nodes = bvh.nodes.size();
  bvh.stats.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return bvh;
}

}  // namespace xi
