// Bounding volume hierarchy over triangles: a binary binned-SAH build with spatial splits on the
// host, collapsed into 4- or 8-wide nodes by their own SAH cost, siblings side by side, the array the
// kernels traverse (kernels/shared/traverse.h).
#pragma once
#include <cstdint>
#include <vector>

#include "layout.h"
#include "xi/default_init_allocator.h"
#include "xi/scene.h"

namespace xi {

struct BvhStats {
  double build_seconds = 0.0;
  size_t nodes = 0;       // wide nodes
  size_t leaves = 0;
  int depth = 0;          // longest root-to-leaf path, in edges of the wide tree
  size_t max_leaf = 0;    // most triangles in one leaf
  size_t references = 0;  // triangles in leaves: more than the scene's where spatial splits put one in several
  size_t stack = 0;       // most traversal stack entries any ray can need (≤ XI_BVH_STACK)
  size_t threads = 1;     // threads the build ran on: one, and one more per subtree it forked
};

struct Bvh {
  int width = 4;                 // lanes per node: 4 (nodes) or 8 (nodes8; the other vector is empty)
  std::vector<BvhNode> nodes;
  std::vector<BvhNode8> nodes8;
  std::vector<TriBlock, DefaultInitAllocator<TriBlock>> blocks;  // the leaves' triangles, in blocks of four
  std::vector<uint32_t> order;     // order[i]: the scene triangle at position i (blocks name triangles by position)
  std::vector<uint32_t> position;  // position[t]: where scene triangle t is in order (order's inverse)
  BvhStats stats;
};

// spatial_splits: let a triangle be split between subtrees where that tightens their boxes (the
// default; not tried where every triangle of a node is smaller than a sixteenth of it); without
// them every triangle is in exactly one leaf and every box is exactly the bounds of what it holds.
// threads: the cores to build on (0: all the machine has); subtrees are built, planned and laid
// out on threads of their own, the passes of the nodes above them shared out, and the tree is the
// same, byte for byte, for any number.
Bvh build_bvh(const Mesh& mesh, int width = 4, bool spatial_splits = true, unsigned threads = 0);

}  // namespace xi
