

#include "xi/bvh.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <chrono>
#include <cstring>
#include <future>
#include <glm/gtc/type_ptr.hpp>
#include <span>
#include <string>
#include <thread>

#include "traverse.h"
#include "xi/error.h"

namespace xi {
namespace {

constexpr int kBins = 16;
constexpr size_t kMaxLeaf = 8;      // triangles in a leaf, at most: two blocks of four
static_assert((kMaxLeaf + 3) / 4 <= XI_BVH_LEAF_MAX, "a leaf's block count must fit its child entry");
constexpr int kMaxSahDepth = 48;    // below it, ranges are halved by index: no deeper SAH recursion
// The binary build's SAH weighs a side by its blocks of four triangles (they are tested four at a
// time); the collapse into wide nodes (Collapser) decides which subtrees become leaves.
float blocks_cost(size_t triangles) { return (float)((triangles + 3) / 4); }
// The collapse's costs, tuned on PoCL: a wide node's
// (its slab test of all lanes at once, then its pushes and pops) and a leaf's triangle test's (a
// block of four; on 8 lanes, a leaf's two blocks at once), each weighted by how likely a ray is to
// enter the box (Collapser::weight).
constexpr float kNodeCost = 1.0f;
constexpr float kLeafTestCost = 2.0f;
// The binary build stops at this many references: the collapse then chooses the leaves among
// subtrees of pairs (a mesh's quads). Going down to single triangles makes the build slower and
// the rays no faster.
constexpr size_t kMinBinaryLeaf = 2;
// Spatial splits (Stich, Friedrich and Dietrich 2009, "Spatial Splits in Bounding Volume
// Hierarchies") are tried only where the best object split's two boxes overlap by more than this
// fraction of the root's area, and only while the references stay within kMaxReferences per
// triangle: long thin triangles stop stretching boxes over empty space, at a bounded memory cost.
constexpr float kSpatialOverlap = 1e-5f;
constexpr double kMaxReferences = 2.0;
constexpr size_t kForkMin = 4096;  // references below which a subtree is not worth a thread

struct Box {
  glm::vec3 lo{INFINITY}, hi{-INFINITY};
  void grow(const glm::vec3& p) { lo = glm::min(lo, p); hi = glm::max(hi, p); }
  void grow(const Box& b) { lo = glm::min(lo, b.lo); hi = glm::max(hi, b.hi); }
  bool empty() const { return !(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z); }
  Box intersect(const Box& b) const { return Box{glm::max(lo, b.lo), glm::min(hi, b.hi)}; }
  glm::vec3 centre() const { return 0.5f * (lo + hi); }
  float area() const {
    glm::vec3 d = hi - lo;
    return empty() ? 0.0f : 2.0f * (d.x * d.y + d.y * d.z + d.z * d.x);
  }
};

// A triangle, or the part of it on one side of the spatial splits above it: `box` bounds that part.
struct Ref {
  uint32_t tri;
  Box box;
};

// Where edge p–q crosses the plane p[axis] = at, if it does (an endpoint on the plane is no
// crossing); the point's coordinate on `axis` is exactly `at`, the others rounded.
bool edge_crossing(const glm::vec3& p, const glm::vec3& q, int axis, float at, glm::vec3* x) {
  if (!((p[axis] < at && q[axis] > at) || (p[axis] > at && q[axis] < at))) return false;
  *x = p + (at - p[axis]) / (q[axis] - p[axis]) * (q - p);
  (*x)[axis] = at;
  return true;
}

// The bounds of the part of triangle `t` with `lo` ≤ p[axis] ≤ `hi`, within `within` (the part a
// reference already stands for). An edge's crossing of a plane is rounded; the box is widened by
// a bound on that rounding so that it never cuts off a sliver of the triangle (the intersection
// with `within` keeps it tight). Empty when the triangle does not reach the slab.
Box clip(const Triangle& t, int axis, float lo, float hi, const Box& within) {
  Box part;
  for (int i = 0; i < 3; ++i) {
    const glm::vec3 &p = t.v[i], &q = t.v[(i + 1) % 3];
    if (p[axis] >= lo && p[axis] <= hi) part.grow(p);
    for (float plane : {lo, hi}) {
      glm::vec3 x;
      if (!edge_crossing(p, q, axis, plane, &x)) continue;
      // s = (plane − p)/(q − p) and s·(q − p) round a few times over magnitudes up to |p| + |q|:
      // 16 ε of the larger endpoint bounds the error with room to spare.
      glm::vec3 err = 16.0f * FLT_EPSILON * glm::max(glm::abs(p), glm::abs(q));
      err[axis] = 0.0f;
      part.grow(x - err);
      part.grow(x + err);
    }
  }
  return part.intersect(within);
}

// The binary tree the SAH builds; collapsed into 4- or 8-wide nodes afterwards.
struct BinaryNode {
  Box box;
  uint32_t left = 0, right = 0;  // children, when count == 0
  uint32_t first = 0, count = 0; // a leaf's range of `leaf_tris`
};

// Builds a subtree: the top of the tree on one thread, subtrees below it on threads of their own,
// each with its own Builder, grafted into their parent's when done.
struct Builder {
  const std::vector<Triangle>& tris;
  const bool spatial_splits;
  const float root_area;
  // Every node's references, in place: a subtree over `count` references at `first` owns
  // refs[first, first + count + budget), room for those its spatial splits may add, and the same
  // stretch of scratch, where a node's references wait while they are shared out to its children
  // (two arrays for the whole build, no allocation per node; threads work on disjoint stretches).
  Ref* const refs;
  Ref* const scratch;
  std::vector<BinaryNode> nodes{1};  // the root first
  std::vector<uint32_t> leaf_tris;   // the leaves' triangles (scene indices), leaf after leaf
  size_t forks = 0;                  // subtrees built on threads of their own, below this one
  enum class Side : uint8_t { Left, Right, Both };
  struct Straddler {
    Box left, right;  // the clipped parts on each side of the plane
    Side side;        // where the reference goes
  };
  std::vector<Straddler> straddlers;  // a spatial split's, in the order of its references

  Builder(const std::vector<Triangle>& triangles, bool splits, float area, Ref* all, Ref* spare)
      : tris(triangles), spatial_splits(splits), root_area(area), refs(all), scratch(spare) {}

  struct Split {
    float cost = INFINITY;  // SAH area × blocks of the two sides
    int axis = -1;
    int bin = 0;            // the first bin of the right side
    bool spatial = false;
  };

  void leaf(size_t node, std::span<const Ref> refs) {
    nodes[node].first = (uint32_t)leaf_tris.size();
    nodes[node].count = (uint32_t)refs.size();
    for (const Ref& r : refs) leaf_tris.push_back(r.tri);
  }

  // The centroid bin of reference r on `axis` of centroid bounds `cbox`, given scale = kBins /
  // the bounds' extent (0 on an axis of no extent, or one too thin for kBins / extent to be
  // finite: bin 0, and no split on that axis).
  static int centroid_bin(const Ref& r, int axis, const Box& cbox, const glm::vec3& scale) {
    return std::min(kBins - 1, (int)((r.box.centre()[axis] - cbox.lo[axis]) * scale[axis]));
  }
  static glm::vec3 bin_scale(const Box& cbox) {
    glm::vec3 extent = cbox.hi - cbox.lo, scale;
    for (int a = 0; a < 3; ++a) {
      scale[a] = extent[a] > 0.0f ? (float)kBins / extent[a] : 0.0f;
      if (!std::isfinite(scale[a])) scale[a] = 0.0f;
    }
    return scale;
  }
  // The plane between spatial bins b − 1 and b of the node's box.
  static float plane(const Box& box, int axis, int b) {
    return box.lo[axis] + (box.hi[axis] - box.lo[axis]) * (float)b / kBins;
  }

  // One axis's SAH sweep: the plane before bin b (1 ≤ b < kBins) has bins < b on its left, with
  // left_counts[< b] references, and the rest on its right, with right_counts[≥ b]. Calls
  // take(b, cost, left box, right box, left count, right count) for each plane with references on
  // both sides.
  template <class Take>
  static void sweep(const Box* bins, const size_t* left_counts, const size_t* right_counts, Take take) {
    Box right_box[kBins];
    size_t right_n[kBins];
    Box acc;
    size_t n = 0;
    for (int b = kBins - 1; b > 0; --b) {
      acc.grow(bins[b]);
      n += right_counts[b];
      right_box[b] = acc, right_n[b] = n;
    }
    acc = Box();
    n = 0;
    for (int b = 1; b < kBins; ++b) {
      acc.grow(bins[b - 1]);
      n += left_counts[b - 1];
      if (n == 0 || right_n[b] == 0) continue;
      take(b, acc.area() * blocks_cost(n) + right_box[b].area() * blocks_cost(right_n[b]), acc, right_box[b], n,
           right_n[b]);
    }
  }

  // Binned SAH over the centroids of the references' boxes; *overlap gets the area where the
  // best split's two boxes overlap.
  Split object_split(std::span<const Ref> refs, const Box& cbox, float* overlap) {
    Split best;
    // One pass over the references bins all three axes.
    const glm::vec3 scale = bin_scale(cbox);
    Box bins[3][kBins];
    size_t counts[3][kBins] = {};
    for (const Ref& r : refs) {
      for (int axis = 0; axis < 3; ++axis) {
        int b = centroid_bin(r, axis, cbox, scale);
        bins[axis][b].grow(r.box);
        counts[axis][b]++;
      }
    }
    for (int axis = 0; axis < 3; ++axis) {
      if (scale[axis] == 0.0f) continue;
      sweep(bins[axis], counts[axis], counts[axis],
            [&](int bin, float cost, const Box& left, const Box& right, size_t, size_t) {
              if (cost >= best.cost) return;
              best = Split{cost, axis, bin, false};
              *overlap = left.intersect(right).area();
            });
    }
    return best;
  }

  // Exact SAH among a leaf's few references (most nodes, as the build goes down to pairs): every
  // split between two distinct centroids on each axis, cheaper than filling and sweeping 16 bins
  // per axis (million.json's build 1.27–1.55 → 1.13–1.22 s, its rays as fast). `sorted` gets the
  // references in the best split's order; its `bin` is the left side's count.
  Split exact_split(std::span<const Ref> refs, Ref* sorted) const {
    Split best;
    const size_t n = refs.size();
    Ref order[kMaxLeaf];
    Box right[kMaxLeaf];
    for (int axis = 0; axis < 3; ++axis) {
      // Insertion sort by centroid: stable, and fast for a few.
      for (size_t i = 0; i < n; ++i) {
        size_t j = i;
        for (; j > 0 && order[j - 1].box.centre()[axis] > refs[i].box.centre()[axis]; --j) order[j] = order[j - 1];
        order[j] = refs[i];
      }
      right[n - 1] = order[n - 1].box;
      for (size_t i = n - 1; i-- > 1;) right[i] = right[i + 1], right[i].grow(order[i].box);
      Box left;
      bool improved = false;
      for (size_t i = 1; i < n; ++i) {
        left.grow(order[i - 1].box);
        if (!(order[i - 1].box.centre()[axis] < order[i].box.centre()[axis])) continue;  // no plane between
        const float cost = left.area() * blocks_cost(i) + right[i].area() * blocks_cost(n - i);
        if (cost < best.cost) best = Split{cost, axis, (int)i, false}, improved = true;
      }
      if (improved) std::copy(order, order + n, sorted);
    }
    return best;
  }

  // Binned SAH over planes through the node's box, each reference clipped into the bins it spans.
  Split spatial_split(std::span<const Ref> refs, const Box& box, size_t budget) {
    // One pass over the references bins all three axes.
    const glm::vec3 scale = bin_scale(box);
    float planes[3][kBins + 1];  // computed once: recomputing them in bin_in took most of this pass
    for (int axis = 0; axis < 3; ++axis)
      for (int b = 0; b <= kBins; ++b) planes[axis][b] = plane(box, axis, b);
    Box bins[3][kBins];
    size_t enters[3][kBins] = {}, exits[3][kBins] = {};
    for (const Ref& r : refs) {
      for (int axis = 0; axis < 3; ++axis) {
        if (scale[axis] == 0.0f) continue;
        Box* bin_box = bins[axis];
        const float* at = planes[axis];
        auto bin_of = [&](float x) { return bin_in(at, box.lo[axis], scale[axis], x); };
        int first = bin_of(r.box.lo[axis]), last = bin_of(r.box.hi[axis]);
        enters[axis][first]++;
        exits[axis][last]++;
        if (first == last) {
          bin_box[first].grow(r.box);
          continue;
        }
        // Only the costs need these boxes (partition_spatial clips the references it splits), so
        // each bin gets the vertices and edge crossings of its planes, clamped to the reference's
        // box and unwidened: each crossing computed once, for the two bins it bounds.
        const Triangle& t = tris[r.tri];
        for (const glm::vec3& p : t.v) {
          int b = bin_of(p[axis]);
          if (b >= first && b <= last) bin_box[b].grow(glm::clamp(p, r.box.lo, r.box.hi));
        }
        for (int b = first + 1; b <= last; ++b) {
          for (int i = 0; i < 3; ++i) {
            glm::vec3 x;
            if (!edge_crossing(t.v[i], t.v[(i + 1) % 3], axis, at[b], &x)) continue;
            x = glm::clamp(x, r.box.lo, r.box.hi);  // (x[axis] = at stays: the box spans the plane)
            bin_box[b - 1].grow(x), bin_box[b].grow(x);
          }
        }
      }
    }
    Split best;
    for (int axis = 0; axis < 3; ++axis) {
      if (scale[axis] == 0.0f) continue;
      sweep(bins[axis], enters[axis], exits[axis],
            [&](int bin, float cost, const Box&, const Box&, size_t left, size_t right) {
              // (Both sides may hold every reference: each gets its clipped part of all of them.)
              if (left + right - refs.size() <= budget && cost < best.cost) best = Split{cost, axis, bin, true};
            });
    }
    return best;
  }

  // The spatial bin of coordinate x: the b with planes[b] ≤ x < planes[b + 1], by the same planes
  // the references are clipped to (scale = kBins / the extent from lo only guesses it).
  static int bin_in(const float* planes, float lo, float scale, float x) {
    int b = std::clamp((int)((x - lo) * scale), 0, kBins - 1);
    while (b > 0 && x < planes[b]) --b;
    while (b < kBins - 1 && x >= planes[b + 1]) ++b;
    return b;
  }

  // Which side of the plane p[axis] = at a reference lies on; Both where it straddles the plane.
  static Side side_of(const Ref& r, int axis, float at) {
    if (r.box.hi[axis] <= at) return Side::Left;
    if (r.box.lo[axis] >= at) return Side::Right;
    return Side::Both;
  }

  // Where a spatial split sends each reference that straddles its plane: to both sides, clipped,
  // unless putting it whole into one side costs less (Stich et al.'s unsplitting). Fills
  // `straddlers` in order; *nl, *nr get the sides' reference counts.
  void decide_spatial(std::span<const Ref> refs, const Box& box, const Split& s, size_t* nl, size_t* nr) {
    const float at = plane(box, s.axis, s.bin);
    Box lbox, rbox;
    size_t left_only = 0, right_only = 0;
    straddlers.clear();
    // Both sides' clipped parts first, so that the unsplitting test sees the sides' full extent.
    for (const Ref& r : refs) {
      switch (side_of(r, s.axis, at)) {
        case Side::Left: left_only++, lbox.grow(r.box); break;
        case Side::Right: right_only++, rbox.grow(r.box); break;
        case Side::Both:
          straddlers.push_back(Straddler{clip(tris[r.tri], s.axis, -INFINITY, at, r.box),
                                         clip(tris[r.tri], s.axis, at, INFINITY, r.box), Side::Both});
          lbox.grow(straddlers.back().left), rbox.grow(straddlers.back().right);
          break;
      }
    }
    *nl = left_only + straddlers.size(), *nr = right_only + straddlers.size();
    size_t k = 0;
    for (const Ref& r : refs) {
      if (side_of(r, s.axis, at) != Side::Both) continue;
      Straddler& st = straddlers[k++];
      Box lwhole = lbox, rwhole = rbox;
      lwhole.grow(r.box), rwhole.grow(r.box);
      float both = lbox.area() * *nl + rbox.area() * *nr;
      float only_left = lwhole.area() * *nl + rbox.area() * (*nr - 1);
      float only_right = lbox.area() * (*nl - 1) + rwhole.area() * *nr;
      if (st.right.empty() || (!st.left.empty() && only_left <= std::min(both, only_right))) {
        st.side = Side::Left, lbox = lwhole, --*nr;
      } else if (st.left.empty() || only_right <= both) {
        st.side = Side::Right, rbox = rwhole, --*nl;
      }
    }
  }

  // Writes a spatial split's left references from the start of `refs` and its right ones from
  // `right`, as decide_spatial decided: on each side, those wholly on it first, then the
  // straddlers, in the given order. `spare`: room for a copy of `refs`.
  void partition_spatial(std::span<Ref> refs, Ref* spare, Ref* right, const Box& box, const Split& s) {
    const std::span<const Ref> given(spare, refs.size());
    std::copy(refs.begin(), refs.end(), spare);
    const float at = plane(box, s.axis, s.bin);
    Ref* left = refs.data();
    for (const Ref& r : given) {
      const Side side = side_of(r, s.axis, at);
      if (side == Side::Left) *left++ = r;
      else if (side == Side::Right) *right++ = r;
    }
    size_t k = 0;
    for (const Ref& r : given) {
      if (side_of(r, s.axis, at) != Side::Both) continue;
      const Straddler& st = straddlers[k++];
      switch (st.side) {
        case Side::Left: *left++ = r; break;
        case Side::Right: *right++ = r; break;
        case Side::Both: *left++ = Ref{r.tri, st.left}, *right++ = Ref{r.tri, st.right}; break;
      }
    }
  }

  // Builds the subtree of `node` over refs[first, first + count); its spatial splits may add at
  // most `budget` references. The budget is shared out between the children by their sizes, not
  // spent first come first served, so that the left subtree cannot starve the right.
  // Below `fork_levels` levels from here, the right child is built on a thread of its own.
  void build(size_t node, size_t first, size_t count, int depth, size_t budget, int fork_levels) {
    const std::span<Ref> span(refs + first, count);
    Box box, cbox;
    for (const Ref& r : span) box.grow(r.box), cbox.grow(r.box.centre());
    nodes[node].box = box;
    // Down to pairs: which subtrees become leaves is the collapse's choice, by the costs of the
    // wide tree.
    if (count <= kMinBinaryLeaf) return leaf(node, span);

    Split best;
    Ref sorted[kMaxLeaf];  // an exact split's order
    const bool exact = count <= kMaxLeaf;
    if (depth < kMaxSahDepth && exact) {
      best = exact_split(span, sorted);
    } else if (depth < kMaxSahDepth) {
      float overlap = 0.0f;
      best = object_split(span, cbox, &overlap);
      // Not among a leaf's few references (above), which the collapse may well put in one leaf
      // (the engine's build 0.28 → 0.20 s).
      if (spatial_splits && budget > 0 && overlap > kSpatialOverlap * root_area) {
        Split spatial = spatial_split(span, box, budget);
        if (spatial.cost < best.cost) best = spatial;
      }
    }
    // Where no split separates the references (every centroid in one point, or too deep), a few
    // make one leaf; more are halved.
    if (best.axis < 0 && count <= kMaxLeaf) return leaf(node, span);

    // The children's references: left ones in order at `first`, right ones in order after the
    // left subtree's budget, each side's straddlers after the rest.
    size_t nl = 0, nr = 0;
    if (best.spatial) {
      decide_spatial(span, box, best, &nl, &nr);
    } else if (exact && best.axis >= 0) {  // the first best.bin in their sorted order go left
      nl = (size_t)best.bin, nr = count - nl;
      std::copy(sorted, sorted + nl, span.begin());
      std::copy(sorted + nl, sorted + count, scratch + first);
    } else if (best.axis >= 0) {  // left ones in place, right ones to scratch
      const glm::vec3 scale = bin_scale(cbox);
      for (const Ref& r : span) {
        if (centroid_bin(r, best.axis, cbox, scale) < best.bin) span[nl++] = r;
        else scratch[first + nr++] = r;
      }
    }
    // No split (coincident centroids, or a split unsplit to one side): halve, in the given order
    // (untouched: an object split that sends all to one side moves none).
    const bool halve = nl == 0 || nr == 0;
    if (halve) nl = count / 2, nr = count - nl;
    budget -= nl + nr - count;
    const size_t left_budget = (size_t)((double)budget * (double)nl / (double)(nl + nr));
    const size_t right_budget = budget - left_budget;
    const size_t right_first = first + nl + left_budget;
    if (halve) {
      std::copy_backward(span.begin() + (ptrdiff_t)nl, span.end(), refs + right_first + nr);
    } else if (!best.spatial) {
      std::copy(scratch + first, scratch + first + nr, refs + right_first);
    } else {
      partition_spatial(span, scratch + first, refs + right_first, box, best);
    }
    uint32_t l = (uint32_t)nodes.size(), r = l + 1;
    nodes.resize(nodes.size() + 2);
    nodes[node].left = l;
    nodes[node].right = r;
    if (fork_levels > 0 && nr >= kForkMin) {
      Builder right(tris, spatial_splits, root_area, refs, scratch);
      auto job = std::async(std::launch::async, [&] {
        right.build(0, right_first, nr, depth + 1, right_budget, fork_levels - 1);
      });
      build(l, first, nl, depth + 1, left_budget, fork_levels - 1);
      job.get();
      graft(r, right);
    } else {
      build(l, first, nl, depth + 1, left_budget, fork_levels);
      build(r, right_first, nr, depth + 1, right_budget, fork_levels);
    }
  }

  // Takes in the subtree `sub` built for node r, after everything built here so far: its nodes
  // renumbered, its leaves' triangles after those already here (leaves stay left to right).
  void graft(uint32_t r, const Builder& sub) {
    const uint32_t base = (uint32_t)nodes.size() - 1, leaf_base = (uint32_t)leaf_tris.size();
    auto renumber = [&](uint32_t i) { return i == 0 ? r : base + i; };
    for (size_t i = 0; i < sub.nodes.size(); ++i) {
      BinaryNode n = sub.nodes[i];
      if (n.count > 0) n.first += leaf_base;
      else n.left = renumber(n.left), n.right = renumber(n.right);
      if (i == 0) nodes[r] = n;
      else nodes.push_back(n);
    }
    leaf_tris.insert(leaf_tris.end(), sub.leaf_tris.begin(), sub.leaf_tris.end());
    forks += 1 + sub.forks;
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

// Collapses the binary tree into wide nodes (4 or 8 lanes) of least SAH cost (Ylitie, Karras and
// Laine 2017, "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", 3.1): for
// each binary node, bottom-up, the cost of its subtree given i lanes of a wide parent, i ≤ width, as
// one leaf, one wide node, or its two subtrees sharing the i lanes; then the least-cost choices are
// laid out top-down. (A greedy collapse kept the binary build's leaves: in the Cornell box one leaf
// held three walls, so every ray inside the room tested it.)
struct Collapser {
  const std::vector<BinaryNode>& bin;
  const std::vector<uint32_t>& leaf_tris;
  const std::vector<Triangle>& tris;
  Bvh& bvh;

  struct Plan {
    float cost[8];          // cost[i − 1]: the least cost of the subtree given i lanes
    uint8_t split[8];       // split[i − 1], i ≥ 2: the lanes of i its left subtree takes; 0: it takes i − 1 lanes' plan
    uint8_t node_split;     // as a wide node of its own: the lanes (of width) its left subtree takes
    bool leaf;              // given one lane: a leaf, else a wide node
    uint32_t first, count;  // its references, leaf_tris[first, first + count)
  };
  std::vector<Plan> plan;
  double root_area = 0.0, root_volume = 0.0;

  // How likely a ray is to enter box b, up to a factor the same for every box: the SAH's surface
  // area (rays from outside the scene), plus the box's volume times the root's area over its
  // volume. For a ray from a uniform point inside the root, the chance it starts in b is
  // V_b / V_root, and that it reaches b from outside about A_b / A_root (a random line meets a
  // convex box in proportion to its area). Bounce rays start inside the scene; without this term
  // the SAH sees no difference between a leaf of three walls of a room and three leaves of one
  // wall each (rays from outside enter them as often), while every ray from inside the room enters
  // the big leaf. The term matters only for boxes the size of the scene: deeper, volumes vanish
  // against areas.
  float weight(const Box& b) const {
    const double area = b.area();
    if (b.empty() || root_volume <= 0.0) return (float)area;  // a flat scene: areas alone
    const glm::dvec3 d = glm::dvec3(b.hi) - glm::dvec3(b.lo);
    return (float)(area + d.x * d.y * d.z * root_area / root_volume);
  }

  // The cost of a leaf of `count` references in a box of weight `w`; infinite for more than a
  // leaf may hold. 8 lanes test a leaf's two blocks at once.
  float leaf_cost(float w, uint32_t count) const {
    if (count > kMaxLeaf) return INFINITY;
    return w * kLeafTestCost * std::ceil((float)count / (bvh.width == 8 ? 8.0f : 4.0f));
  }

  // Children come after their parents in `bin`, so one backward pass is bottom-up.
  void plan_tree() {
    const int width = bvh.width;
    plan.resize(bin.size());
    const glm::dvec3 root = glm::dvec3(bin[0].box.hi) - glm::dvec3(bin[0].box.lo);
    root_area = bin[0].box.area(), root_volume = root.x * root.y * root.z;
    for (size_t n = bin.size(); n-- > 0;) {
      const BinaryNode& b = bin[n];
      Plan& p = plan[n];
      const float w = weight(b.box);
      std::fill(p.split, p.split + 8, 0);
      p.node_split = 0;
      if (b.count > 0) {  // a binary leaf: the build made it no larger than a leaf may be
        p.first = b.first, p.count = b.count, p.leaf = true;
        std::fill(p.cost, p.cost + 8, leaf_cost(w, b.count));
        continue;
      }
      const Plan &l = plan[b.left], &r = plan[b.right];
      if (r.first != l.first + l.count) throw Error("internal: the BVH's leaves are out of order");
      p.first = l.first, p.count = l.count + r.count;
      float spread[9];  // spread[j]: the least cost of the two subtrees sharing j lanes
      uint8_t spread_split[9];
      for (int j = 2; j <= width; ++j) {
        spread[j] = INFINITY, spread_split[j] = 1;
        for (int k = 1; k < j; ++k) {
          float c = l.cost[k - 1] + r.cost[j - k - 1];
          if (c < spread[j]) spread[j] = c, spread_split[j] = (uint8_t)k;
        }
      }
      const float as_node = w * kNodeCost + spread[width];
      const float as_leaf = leaf_cost(w, p.count);
      p.leaf = as_leaf <= as_node;
      p.node_split = spread_split[width];
      p.cost[0] = std::min(as_leaf, as_node);
      for (int i = 2; i <= width; ++i) {
        p.cost[i - 1] = p.cost[i - 2];
        if (spread[i] < p.cost[i - 1]) p.cost[i - 1] = spread[i], p.split[i - 1] = spread_split[i];
      }
    }
  }

  // Appends to `lanes` the binary nodes that take the i lanes given to subtree n.
  void gather(uint32_t n, int i, std::vector<uint32_t>& lanes) const {
    while (i > 1 && plan[n].split[i - 1] == 0) --i;
    if (i == 1) return lanes.push_back(n);
    gather(bin[n].left, plan[n].split[i - 1], lanes);
    gather(bin[n].right, i - plan[n].split[i - 1], lanes);
  }

  // The binary nodes that become the lanes of the wide node made from binary node n.
  std::vector<uint32_t> lanes_of(uint32_t n) const {
    std::vector<uint32_t> lanes;
    if (bin[n].count > 0) return {n};  // a root that is a leaf: one leaf lane
    gather(bin[n].left, plan[n].node_split, lanes);
    gather(bin[n].right, bvh.width - plan[n].node_split, lanes);
    return lanes;
  }

  // The triangle blocks the wide node made from n and the nodes below it hold, at most (reserved
  // up front: growing a vector of this size would copy it into fresh pages).
  size_t blocks_below(uint32_t n) const {
    size_t blocks = 0;
    for (uint32_t k : lanes_of(n)) blocks += plan[k].leaf ? (plan[k].count + 3) / 4 : blocks_below(k);
    return blocks;
  }

  uint32_t new_node() {
    if (bvh.width == 8) bvh.nodes8.push_back(BvhNode8{});
    else bvh.nodes.push_back(BvhNode{});
    return (uint32_t)(bvh.width == 8 ? bvh.nodes8.size() : bvh.nodes.size()) - 1;
  }

  // Appends the blocks of the triangles of leaf_tris[first, first + count) (scene indices; a
  // triangle spatial splits put there twice, once) and returns the leaf's child entry. Blocks name
  // a triangle by its position in bvh.order.
  uint32_t leaf(uint32_t first, uint32_t count) {
    uint32_t unique_tris[kMaxLeaf];
    uint32_t unique = 0;
    for (uint32_t i = first; i < first + count; ++i)
      if (std::find(unique_tris, unique_tris + unique, leaf_tris[i]) == unique_tris + unique)
        unique_tris[unique++] = leaf_tris[i];
    const uint32_t first_block = (uint32_t)bvh.blocks.size(), blocks = (unique + 3) / 4;
    // Spatial splits can make up to twice as many blocks as the triangles' count checked up front.
    if (first_block + blocks > XI_BVH_FIRST_MASK)
      throw Error("too many triangle blocks for the BVH's 27-bit leaf entries", "try --no-spatial-splits");
    for (uint32_t b = 0; b < blocks; ++b) {
      TriBlock blk;
      for (auto& axis : blk.coord) std::fill(axis, axis + 3, glm::vec4(NAN));
      for (uint32_t k = 0; k < 4; ++k) {
        blk.tri[k] = XI_NO_HIT;
        if (4 * b + k >= unique) continue;
        const uint32_t tri = unique_tris[4 * b + k];
        blk.tri[k] = bvh.position[tri];
        for (int j = 0; j < 3; ++j)
          for (int a = 0; a < 3; ++a) blk.coord[a][j][k] = tris[tri].v[j][a];
      }
      bvh.blocks.push_back(blk);
    }
    bvh.stats.leaves++;
    bvh.stats.references += unique;
    bvh.stats.max_leaf = std::max<size_t>(bvh.stats.max_leaf, unique);
    return XI_BVH_LEAF | (blocks - 1) << 27 | first_block;
  }

  // Lays out the wide node `wide` made from binary node b and the nodes below it. Returns the
  // stack entries a traversal of this subtree may hold beyond those below it.
  size_t collapse(uint32_t b, size_t wide, int depth) {
    const std::vector<uint32_t> kids = lanes_of(b);
    const size_t width = (size_t)bvh.width;
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
      child[k] = plan[kids[k]].leaf ? leaf(plan[kids[k]].first, plan[kids[k]].count) : new_node();
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

Bvh build_bvh(const std::vector<Triangle>& triangles, int width, bool spatial_splits, unsigned threads) {
  auto start = std::chrono::steady_clock::now();
  if (width != 4 && width != 8) throw Error("BVH width must be 4 or 8, not " + std::to_string(width), "--bvh-width");
  if (triangles.empty()) throw Error("cannot build a BVH over an empty scene");
  if (triangles.size() >= (1ull << 31)) throw Error("too many triangles for 32-bit indices");
  // Leaf entries address triangles with 27 bits (XI_BVH_FIRST_MASK).
  if (triangles.size() > XI_BVH_FIRST_MASK) throw Error("too many triangles for the BVH (at most 134217727)");
  Bvh bvh;
  bvh.width = width;
  const size_t budget = spatial_splits ? (size_t)((kMaxReferences - 1.0) * (double)triangles.size()) : 0;
  std::vector<Ref> refs(triangles.size() + budget), scratch(refs.size());
  Box root;
  for (size_t i = 0; i < triangles.size(); ++i) {
    refs[i].tri = (uint32_t)i;
    for (auto& v : triangles[i].v) refs[i].box.grow(v);
    root.grow(refs[i].box);
  }
  Builder b(triangles, spatial_splits, root.area(), refs.data(), scratch.data());
  b.nodes.reserve(2 * triangles.size());
  b.leaf_tris.reserve(refs.size());
  // Forks down to about four subtrees per core, so that uneven halves still keep every core busy.
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  int fork_levels = 0;
  for (unsigned n = 1; threads > 1 && n < 4 * threads && fork_levels < 8; n *= 2) ++fork_levels;
  b.build(0, 0, triangles.size(), 0, budget, fork_levels);
  std::vector<Ref>().swap(refs), std::vector<Ref>().swap(scratch);  // done with: the collapse needs room
  bvh.stats.threads = 1 + b.forks;
  // BVH order: the triangles by their first place in a leaf, leaves left to right, so that the
  // arrays in this order (CompiledScene) follow the tree.
  constexpr uint32_t kUnplaced = ~0u;
  std::vector<uint32_t>& position = bvh.position;
  position.assign(triangles.size(), kUnplaced);
  for (uint32_t t : b.leaf_tris)
    if (position[t] == kUnplaced) position[t] = (uint32_t)bvh.order.size(), bvh.order.push_back(t);
  if (bvh.order.size() != triangles.size()) throw Error("internal: the BVH lost a triangle");
  Collapser collapser{b.nodes, b.leaf_tris, triangles, bvh, {}, 0.0, 0.0};
  collapser.plan_tree();
  bvh.blocks.reserve(collapser.blocks_below(0));
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
