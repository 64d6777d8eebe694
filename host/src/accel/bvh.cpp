#include "xi/bvh.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <glm/gtc/type_ptr.hpp>
#include <string>

#include "intersect.h"
#include "xi/error.h"

namespace xi {
namespace {

constexpr int kBins = 16;
constexpr size_t kMaxLeaf = 8;      // triangles in a leaf, at most: two blocks of four
static_assert((kMaxLeaf + 3) / 4 <= XI_BVH_LEAF_MAX, "a leaf's block count must fit its child entry");
constexpr int kMaxSahDepth = 48;    // below it, ranges are halved by index: no deeper SAH recursion
// SAH costs, relative to testing one block of four triangles (a 4-wide node test costs about
// the same): triangles are tested four at a time, so a leaf costs its number of blocks.
constexpr float kTraversalCost = 1.0f;
float blocks_cost(size_t triangles) { return (float)((triangles + 3) / 4); }

struct Box {
  glm::vec3 lo{INFINITY}, hi{-INFINITY};
  void grow(const glm::vec3& p) { lo = glm::min(lo, p); hi = glm::max(hi, p); }
  void grow(const Box& b) { lo = glm::min(lo, b.lo); hi = glm::max(hi, b.hi); }
  float area() const {
    glm::vec3 d = hi - lo;
    return d.x < 0.0f ? 0.0f : 2.0f * (d.x * d.y + d.y * d.z + d.z * d.x);
  }
};

// The binary tree the SAH builds; collapsed into 4-wide nodes afterwards.
struct BinaryNode {
  Box box;
  uint32_t left = 0, right = 0;  // children, when count == 0
  uint32_t first = 0, count = 0; // a leaf's range of `order`
};

struct Builder {
  std::vector<Box> bounds;
  std::vector<glm::vec3> centroids;
  std::vector<uint32_t>& order;
  std::vector<BinaryNode> nodes;

  void leaf(size_t node, size_t first, size_t count) {
    nodes[node].first = (uint32_t)first;
    nodes[node].count = (uint32_t)count;
  }

  void build(size_t node, size_t first, size_t count, int depth) {
    Box box, cbox;
    for (size_t i = first; i < first + count; ++i) {
      box.grow(bounds[order[i]]);
      cbox.grow(centroids[order[i]]);
    }
    nodes[node].box = box;
    if (count == 1) return leaf(node, first, count);

    // Binned SAH over all three axes of the centroid bounds.
    float best_cost = INFINITY;
    int best_axis = -1, best_split = 0;
    for (int axis = 0; axis < 3 && depth < kMaxSahDepth; ++axis) {
      float lo = cbox.lo[axis], extent = cbox.hi[axis] - lo;
      if (!(extent > 0.0f)) continue;
      Box bin_box[kBins];
      size_t bin_count[kBins] = {};
      for (size_t i = first; i < first + count; ++i) {
        uint32_t t = order[i];
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
        right_cost[b] = acc.area() * blocks_cost(n);
      }
      acc = Box();
      n = 0;
      for (int b = 0; b < kBins - 1; ++b) {
        acc.grow(bin_box[b]);
        n += bin_count[b];
        float cost = acc.area() * blocks_cost(n) + right_cost[b + 1];
        if (n > 0 && n < count && cost < best_cost) {
          best_cost = cost;
          best_axis = axis;
          best_split = b + 1;
        }
      }
    }
    float leaf_cost = blocks_cost(count);
    float split_cost = kTraversalCost + best_cost / std::max(box.area(), 1e-30f);
    if (best_axis < 0) {  // every centroid in one point (or too deep): no split separates them
      if (count <= kMaxLeaf) return leaf(node, first, count);
    } else if (count <= kMaxLeaf && leaf_cost <= split_cost) {
      return leaf(node, first, count);
    }

    size_t mid;
    if (best_axis >= 0) {
      float lo = cbox.lo[best_axis], extent = cbox.hi[best_axis] - lo;
      auto* begin = order.data() + first;
      auto* m = std::partition(begin, begin + count, [&](uint32_t t) {
        int b = std::min(kBins - 1, (int)(kBins * (centroids[t][best_axis] - lo) / extent));
        return b < best_split;
      });
      mid = (size_t)(m - order.data());
    } else {
      mid = first + count / 2;  // coincident centroids: halve by index
    }
    uint32_t left = (uint32_t)nodes.size(), right = left + 1;
    nodes.resize(nodes.size() + 2);
    nodes[node].left = left;
    nodes[node].right = right;
    build(left, first, mid - first, depth + 1);
    build(right, mid, first + count - mid, depth + 1);
  }
};

static_assert(sizeof(BvhNode) == 128 && sizeof(BvhNode8) == 256, "node layouts as the kernels read them");

void set_lanes(glm::vec4& v, const float* lanes) { v = glm::make_vec4(lanes); }
void set_lanes(float8& v, const float* lanes) { std::copy(lanes, lanes + 8, v.s); }

// A node's lanes into the layout the kernels read (BvhNode or BvhNode8).
template <class Node, size_t Width>
void store_node(Node& n, const float (*lo)[8], const float (*hi)[8], const uint32_t* child) {
  for (int a = 0; a < 3; ++a) set_lanes(n.bounds[2 * a], lo[a]), set_lanes(n.bounds[2 * a + 1], hi[a]);
  std::copy(child, child + Width, n.child);
}

// Collapses the binary tree into wide nodes (4 or 8 lanes): each wide node starts from a binary
// node's two children and repeatedly opens the interior child of largest surface area (the one a
// ray is most likely to enter, by the SAH's own measure) until it has `width`.
struct Collapser {
  const std::vector<BinaryNode>& bin;
  const std::vector<Triangle>& tris;
  Bvh& bvh;

  uint32_t new_node() {
    if (bvh.width == 8) bvh.nodes8.push_back(BvhNode8{});
    else bvh.nodes.push_back(BvhNode{});
    return (uint32_t)(bvh.width == 8 ? bvh.nodes8.size() : bvh.nodes.size()) - 1;
  }

  // Appends the blocks of the leaf's triangles (positions first..first+count of bvh.order) and
  // returns its child entry.
  uint32_t leaf(uint32_t first, uint32_t count) {
    const uint32_t first_block = (uint32_t)bvh.blocks.size(), blocks = (count + 3) / 4;
    for (uint32_t b = 0; b < blocks; ++b) {
      TriBlock blk;
      for (auto& axis : blk.coord) std::fill(axis, axis + 3, glm::vec4(NAN));
      for (uint32_t k = 0; k < 4; ++k) {
        const uint32_t p = first + 4 * b + k;
        blk.tri[k] = 4 * b + k < count ? p : XI_NO_HIT;
        if (blk.tri[k] == XI_NO_HIT) continue;
        for (int j = 0; j < 3; ++j) {
          const glm::vec3& v = tris[bvh.order[p]].v[j];
          for (int a = 0; a < 3; ++a) blk.coord[a][j][k] = v[a];
        }
      }
      bvh.blocks.push_back(blk);
    }
    bvh.stats.leaves++;
    bvh.stats.max_leaf = std::max<size_t>(bvh.stats.max_leaf, count);
    return XI_BVH_LEAF | (blocks - 1) << 27 | first_block;
  }

  // Returns the stack entries a traversal of this subtree may hold beyond those below it.
  size_t collapse(uint32_t b, size_t wide, int depth) {
    std::vector<uint32_t> kids{bin[b].left, bin[b].right};
    if (bin[b].count > 0) kids = {b};  // a root that is a leaf: one leaf lane
    const size_t width = (size_t)bvh.width;
    while (kids.size() < width) {
      int open = -1;
      for (int k = 0; k < (int)kids.size(); ++k)
        if (bin[kids[k]].count == 0 && (open < 0 || bin[kids[k]].box.area() > bin[kids[open]].box.area())) open = k;
      if (open < 0) break;
      uint32_t c = kids[open];
      kids[open] = bin[c].left;
      kids.insert(kids.begin() + open + 1, bin[c].right);
    }
    bvh.stats.depth = std::max(bvh.stats.depth, depth + 1);
    const float inf = INFINITY;
    float lo[3][8], hi[3][8];
    uint32_t child[8];
    // A node's interior children are laid out side by side and its leaves' blocks likewise,
    // before any grandchild: a ray that enters one child is likely to enter its siblings.
    for (size_t k = 0; k < width; ++k) {
      for (int a = 0; a < 3; ++a) lo[a][k] = inf, hi[a][k] = -inf;
      child[k] = XI_BVH_EMPTY;
      if (k >= kids.size()) continue;
      const BinaryNode& c = bin[kids[k]];
      for (int a = 0; a < 3; ++a) lo[a][k] = c.box.lo[a], hi[a][k] = c.box.hi[a];
      if (c.count > 0) {
        child[k] = leaf(c.first, c.count);
      } else {
        child[k] = new_node();
      }
    }
    size_t below = 0;
    for (size_t k = 0; k < kids.size(); ++k)
      if (!(child[k] & XI_BVH_LEAF)) below = std::max(below, collapse(kids[k], child[k], depth + 1));
    if (width == 8) store_node<BvhNode8, 8>(bvh.nodes8[wide], lo, hi, child);
    else store_node<BvhNode, 4>(bvh.nodes[wide], lo, hi, child);
    // Traversal pushes up to one entry per lane and pops one to descend into an interior child.
    return std::max(kids.size(), kids.size() - 1 + below);
  }
};

}  // namespace

Bvh build_bvh(const std::vector<Triangle>& triangles, int width) {
  auto start = std::chrono::steady_clock::now();
  if (width != 4 && width != 8) throw Error("BVH width must be 4 or 8, not " + std::to_string(width), "--bvh-width");
  if (triangles.empty()) throw Error("cannot build a BVH over an empty scene");
  if (triangles.size() >= (1ull << 31)) throw Error("too many triangles for 32-bit indices");
  // Leaf entries address triangles with 27 bits (XI_BVH_FIRST_MASK).
  if (triangles.size() > XI_BVH_FIRST_MASK) throw Error("too many triangles for the BVH (at most 134217727)");
  Bvh bvh;
  bvh.width = width;
  Builder b{{}, {}, bvh.order, {}};
  b.bounds.resize(triangles.size());
  b.centroids.resize(triangles.size());
  for (size_t i = 0; i < triangles.size(); ++i) {
    for (auto& v : triangles[i].v) b.bounds[i].grow(v);
    b.centroids[i] = (triangles[i].v[0] + triangles[i].v[1] + triangles[i].v[2]) / 3.0f;
  }
  bvh.order.resize(triangles.size());
  for (size_t i = 0; i < triangles.size(); ++i) bvh.order[i] = (uint32_t)i;
  b.nodes.reserve(2 * triangles.size());
  b.nodes.push_back(BinaryNode{});
  b.build(0, 0, triangles.size(), 0);
  Collapser collapser{b.nodes, triangles, bvh};
  collapser.new_node();  // the root
  bvh.stats.stack = collapser.collapse(0, 0, 0);
  if (bvh.stats.stack > XI_BVH_STACK)
    throw Error("the scene's BVH is too deep for the kernels' traversal stack",
                "needs " + std::to_string(bvh.stats.stack) + " entries, XI_BVH_STACK is " + std::to_string(XI_BVH_STACK));
  bvh.stats.nodes = width == 8 ? bvh.nodes8.size() : bvh.nodes.size();
  bvh.stats.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return bvh;
}

}  // namespace xi
