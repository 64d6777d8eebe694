

#include "xi/bvh.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cfloat>
#include <cmath>
#include <chrono>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <future>
#include <memory>
#include <glm/gtc/type_ptr.hpp>
#include <span>
#include <string>
#include <thread>
#include <type_traits>

#include "../parallel.h"
#include "../render/memory.h"
#include "traverse.h"
#include "xi/error.h"

namespace xi {
namespace {

constexpr int kBins = 16;
constexpr size_t kTwoBinSets = 256;  // references in a pass, at least, to bin into two sets of bins
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
constexpr size_t kParallelMin = 1 << 17;  // references per thread, at least, where one node's passes share them out

struct Box {
  glm::vec3 lo{INFINITY}, hi{-INFINITY};
  void grow(const glm::vec3& p) { lo = glm::min(lo, p); hi = glm::max(hi, p); }
  void grow(const Box& b) { lo = glm::min(lo, b.lo); hi = glm::max(hi, b.hi); }
  bool empty() const { return !(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z); }
  Box intersect(const Box& b) const { return Box{glm::max(lo, b.lo), glm::min(hi, b.hi)}; }
  glm::vec3 centre() const { return 0.5f * (lo + hi); }
  float area() const;  // (Box4::area, below)
};

// A triangle, or the part of it on one side of the spatial splits above it: `box` bounds that part.
struct Ref {
  uint32_t tri;
  Box box;
};
static_assert(std::is_trivially_copyable_v<Ref> && std::is_trivially_destructible_v<Ref>, "kept in raw storage");

// A finished subtree's stretches of the reference arrays are handed back (release_pages) where
// they are at least this many bytes; smaller ones go with the subtree around them.
constexpr size_t kReleaseMin = 1 << 20;

// An array of n T's, uninitialised: malloc's pages are mapped only as they are written.
struct Free {
  void operator()(void* p) const { std::free(p); }
};
template <class T>
using RawArray = std::unique_ptr<T[], Free>;
template <class T>
RawArray<T> raw_array(size_t n) {
  T* p = static_cast<T*>(std::malloc(std::max<size_t>(n, 1) * sizeof(T)));
  if (!p) throw std::bad_alloc();
  return RawArray<T>(p);
}

// What each part of a pass over a node's references gathers, for `parts` parts: no allocation for
// one part (most nodes).
template <class T>
struct Parts {
  T first;
  std::vector<T> more;
  explicit Parts(unsigned parts) : more(parts - 1) {}
  T& operator[](unsigned part) { return part == 0 ? first : more[part - 1]; }
  unsigned size() const { return 1 + (unsigned)more.size(); }
};

// Runs work(i) for i in [0, n) on up to `threads` threads, each taking the next i as it is free
// (for tasks of uneven sizes; each writes only its own results).
template <class Work>
void on_threads(size_t n, unsigned threads, const Work& work) {
  std::atomic<size_t> next{0};
  auto run = [&] {
    for (size_t i; (i = next++) < n;) work(i);
  };
  std::vector<std::future<void>> pool;
  for (unsigned t = 1; t < std::min<size_t>(threads, n); ++t) pool.push_back(std::async(std::launch::async, run));
  run();
  for (auto& f : pool) f.get();
}

// The binning loops' boxes, as 4-lane vectors (GCC and Clang vector extensions; the fourth lane
// unused): a box grows by two vector min/max instead of six scalar ones, the build's commonest
// step. The same comparisons as Box::grow (glm::min, glm::max), so the same bits.
typedef float Vec4 __attribute__((vector_size(16)));
constexpr Vec4 kInf4 = {INFINITY, INFINITY, INFINITY, INFINITY};
struct Box4 {
  Vec4 lo = kInf4, hi = -kInf4;
  void grow(Vec4 l, Vec4 h) { lo = l < lo ? l : lo, hi = hi < h ? h : hi; }
  void grow(const Box4& b) { grow(b.lo, b.hi); }
  Box box() const { return Box{glm::vec3(lo[0], lo[1], lo[2]), glm::vec3(hi[0], hi[1], hi[2])}; }
  // Surface area, 0 for an empty box.
  float area() const {
    const Vec4 d = hi - lo, p = d * __builtin_shufflevector(d, d, 1, 2, 0, 3);  // dx dy, dy dz, dz dx
    return !(lo[0] <= hi[0] && lo[1] <= hi[1] && lo[2] <= hi[2]) ? 0.0f : 2.0f * (p[0] + p[1] + p[2]);
  }
};
Vec4 vec4_of(const glm::vec3& v) { return Vec4{v.x, v.y, v.z, 0.0f}; }
float Box::area() const { return Box4{vec4_of(lo), vec4_of(hi)}.area(); }
// A reference's box corners as vectors, read from within the reference (lanes 3 unused).
Vec4 lo_of(const Ref& r) {
  Vec4 v;
  std::memcpy(&v, reinterpret_cast<const char*>(&r) + offsetof(Ref, box), sizeof v);  // lo xyz, hi x
  return v;
}
Vec4 hi_of(const Ref& r) {
  Vec4 v;
  std::memcpy(&v, reinterpret_cast<const char*>(&r) + offsetof(Ref, box) + 2 * sizeof(float), sizeof v);  // lo z, hi xyz
  return __builtin_shufflevector(v, v, 1, 2, 3, 0);
}
static_assert(sizeof(Ref) == offsetof(Ref, box) + 6 * sizeof(float), "the vector loads stay within a reference");

// What a node needs to know of its references before it splits them: the bounds of their boxes and
// of their centroids, and the largest box's extent on each axis. Gathered while the parent shares
// them out (a pass over every node's references saved), in the order of one pass over them: min
// and max do not round, so the bounds are that pass's to the bit.
struct Bounds {
  Box box, centroids;
  glm::vec3 largest{0.0f};
  void grow(const Bounds& b) { box.grow(b.box), centroids.grow(b.centroids), largest = glm::max(largest, b.largest); }
};

// Bounds as they grow, reference by reference.
struct BoundsAcc {
  Box4 box, centroids;
  Vec4 largest = {0.0f, 0.0f, 0.0f, 0.0f};
  [[gnu::always_inline]] void grow(const Ref& r) {  // (the partitions' inner loops)
    const Vec4 lo = lo_of(r), hi = hi_of(r), c = 0.5f * (lo + hi), d = hi - lo;  // as Box::centre()
    box.grow(lo, hi), centroids.grow(c, c);
    largest = largest < d ? d : largest;
  }
  void grow(const BoundsAcc& b) {
    box.grow(b.box), centroids.grow(b.centroids);
    largest = largest < b.largest ? b.largest : largest;
  }
  Bounds bounds() const {
    return Bounds{box.box(), centroids.box(), glm::vec3(largest[0], largest[1], largest[2])};
  }
};

Bounds bounds_of(const Ref* refs, size_t count) {
  BoundsAcc b;
  for (size_t i = 0; i < count; ++i) b.grow(refs[i]);
  return b.bounds();
}

// Triangle t's three corners.
using Corners = std::array<glm::vec3, 3>;
Corners corners(const Mesh& mesh, uint32_t t) {
  const Triangle& tri = mesh.triangles[t];
  return {mesh.position(tri, 0), mesh.position(tri, 1), mesh.position(tri, 2)};
}

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
Box clip(const Corners& t, int axis, float lo, float hi, const Box& within) {
  Box part;
  for (int i = 0; i < 3; ++i) {
    const glm::vec3 &p = t[i], &q = t[(i + 1) % 3];
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
  const Mesh& mesh;
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
  // A subtree built on a thread of its own for node r here, when `nodes_at` nodes and
  // `leaves_at` leaf triangles had been built here: put in its place by flatten(), once, at the end
  // (taking each one in at its fork copied the deep ones once per level).
  struct Graft {
    uint32_t r;
    size_t nodes_at, leaves_at;
    std::unique_ptr<Builder> sub;
  };
  std::vector<Graft> grafts;
  enum class Side : uint8_t { Left, Right, Both };
  struct Straddler {
    Box left, right;  // the clipped parts on each side of the plane
    Side side;        // where the reference goes
    size_t at;        // its place among the node's references
  };
  std::vector<Straddler> straddlers;  // a spatial split's, in the order of its references
  std::vector<size_t> part_sides;     // per part of decide_spatial's pass: the references wholly left, wholly right

  const unsigned threads;             // the build's; a node at depth d bins on threads >> d of them

  Builder(const Mesh& m, bool splits, float area, Ref* all, Ref* spare, unsigned cores)
      : mesh(m), spatial_splits(splits), root_area(area), refs(all), scratch(spare), threads(cores) {}

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
  static void sweep(const Box4* bins, const size_t* left_counts, const size_t* right_counts, Take take) {
    Box4 right_box[kBins];
    size_t right_n[kBins];
    Box4 acc;
    size_t n = 0;
    for (int b = kBins - 1; b > 0; --b) {
      acc.grow(bins[b]);
      n += right_counts[b];
      right_box[b] = acc, right_n[b] = n;
    }
    acc = Box4();
    n = 0;
    for (int b = 1; b < kBins; ++b) {
      acc.grow(bins[b - 1]);
      n += left_counts[b - 1];
      if (n == 0 || right_n[b] == 0) continue;
      take(b, acc.area() * blocks_cost(n) + right_box[b].area() * blocks_cost(right_n[b]), acc, right_box[b], n,
           right_n[b]);
    }
  }

  // The bins of a pass over part of a node's references. Min and max do not round and counts add,
  // so the parts' bins merged, in any order, are those of one pass over them all.
  struct ObjectBins {
    Box4 box[3][kBins];
    size_t count[3][kBins] = {};
    void add(const ObjectBins& o) {
      for (int axis = 0; axis < 3; ++axis)
        for (int b = 0; b < kBins; ++b) box[axis][b].grow(o.box[axis][b]), count[axis][b] += o.count[axis][b];
    }
  };
  struct SpatialBins {
    Box4 box[3][kBins];
    size_t enters[3][kBins] = {}, exits[3][kBins] = {};
    void add(const SpatialBins& o) {
      for (int axis = 0; axis < 3; ++axis)
        for (int b = 0; b < kBins; ++b)
          box[axis][b].grow(o.box[axis][b]), enters[axis][b] += o.enters[axis][b], exits[axis][b] += o.exits[axis][b];
    }
  };

  // Binned SAH over the centroids of the references' boxes; *overlap gets the area where the
  // best split's two boxes overlap.
  Split object_split(std::span<const Ref> refs, const Box& cbox, float* overlap, unsigned parts) {
    Split best;
    // One pass over the references bins all three axes.
    const glm::vec3 scale = bin_scale(cbox);
    const Vec4 origin = vec4_of(cbox.lo), scale4 = vec4_of(scale);
    Parts<ObjectBins> part_bins(parts);
    auto bin = [&](ObjectBins& bins, const Ref& r) {
      const Vec4 lo = lo_of(r), hi = hi_of(r), at = (0.5f * (lo + hi) - origin) * scale4;  // centroid_bin's
      for (int axis = 0; axis < 3; ++axis) {
        const int b = std::min(kBins - 1, (int)at[axis]);
        bins.box[axis][b].grow(lo, hi);
        bins.count[axis][b]++;
      }
    };
    parallel_chunks(refs.size(), parts, [&](size_t begin, size_t end, unsigned part) {
      ObjectBins& bins = part_bins[part];
      size_t i = begin;
      // Neighbouring references mostly fall in the same bins: binned alternately into two sets,
      // one's box need not wait for the other's to be stored.
      if (end - begin >= kTwoBinSets) {
        ObjectBins odd;
        for (; i + 1 < end; i += 2) bin(bins, refs[i]), bin(odd, refs[i + 1]);
        bins.add(odd);
      }
      for (; i < end; ++i) bin(bins, refs[i]);
    });
    ObjectBins& bins = part_bins[0];  // the parts' bins, merged
    for (unsigned p = 1; p < part_bins.size(); ++p) bins.add(part_bins[p]);
    for (int axis = 0; axis < 3; ++axis) {
      if (scale[axis] == 0.0f) continue;
      sweep(bins.box[axis], bins.count[axis], bins.count[axis],
            [&](int bin, float cost, const Box4& left, const Box4& right, size_t, size_t) {
              if (cost >= best.cost) return;
              best = Split{cost, axis, bin, false};
              *overlap = left.box().intersect(right.box()).area();
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
    glm::vec3 centre[kMaxLeaf];  // each reference's centroid, once
    for (size_t i = 0; i < n; ++i) centre[i] = refs[i].box.centre();
    static_assert(kMaxLeaf <= 256);
    uint8_t order[kMaxLeaf], best_order[kMaxLeaf];  // the references' indices, not the references
    Box4 right[kMaxLeaf];
    for (int axis = 0; axis < 3; ++axis) {
      // Insertion sort by centroid: stable, and fast for a few.
      for (size_t i = 0; i < n; ++i) {
        size_t j = i;
        for (; j > 0 && centre[order[j - 1]][axis] > centre[i][axis]; --j) order[j] = order[j - 1];
        order[j] = (uint8_t)i;
      }
      auto grow = [&](Box4& b, size_t k) { b.grow(lo_of(refs[order[k]]), hi_of(refs[order[k]])); };
      right[n - 1] = Box4();
      grow(right[n - 1], n - 1);
      for (size_t i = n - 1; i-- > 1;) right[i] = right[i + 1], grow(right[i], i);
      Box4 left;
      for (size_t i = 1; i < n; ++i) {
        grow(left, i - 1);
        if (!(centre[order[i - 1]][axis] < centre[order[i]][axis])) continue;  // no plane between
        const float cost = left.area() * blocks_cost(i) + right[i].area() * blocks_cost(n - i);
        if (cost < best.cost) best = Split{cost, axis, (int)i, false}, std::copy(order, order + n, best_order);
      }
    }
    if (best.axis >= 0)
      for (size_t i = 0; i < n; ++i) sorted[i] = refs[best_order[i]];
    return best;
  }

  // Binned SAH over planes through the node's box, each reference clipped into the bins it spans.
  Split spatial_split(std::span<const Ref> refs, const Box& box, size_t budget, unsigned parts) const {
    // One pass over the references bins all three axes.
    const glm::vec3 scale = bin_scale(box);
    float planes[3][kBins + 1];  // computed once: recomputing them in bin_in took most of this pass
    for (int axis = 0; axis < 3; ++axis)
      for (int b = 0; b <= kBins; ++b) planes[axis][b] = plane(box, axis, b);
    Parts<SpatialBins> part_bins(parts);
    parallel_chunks(refs.size(), parts, [&](size_t begin, size_t end, unsigned part) {
      bin_spatial(refs.subspan(begin, end - begin), box, scale, planes, part_bins[part]);
    });
    SpatialBins& bins = part_bins[0];  // the parts' bins, merged
    for (unsigned p = 1; p < part_bins.size(); ++p) bins.add(part_bins[p]);
    Split best;
    for (int axis = 0; axis < 3; ++axis) {
      if (scale[axis] == 0.0f) continue;
      sweep(bins.box[axis], bins.enters[axis], bins.exits[axis],
            [&](int bin, float cost, const Box4&, const Box4&, size_t left, size_t right) {
              // (Both sides may hold every reference: each gets its clipped part of all of them.)
              if (left + right - refs.size() <= budget && cost < best.cost) best = Split{cost, axis, bin, true};
            });
    }
    return best;
  }

  // Bins references into spatial bins: each clipped into the bins it spans. A batch's references
  // within one bin on an axis are binned whole first; the few that span planes wait in a list
  // while their triangles are fetched ahead (read in the references' order, those loads miss the
  // cache). Min, max and counts do not depend on the order.
  void bin_spatial(std::span<const Ref> refs, const Box& box, const glm::vec3& scale, const float (*planes)[kBins + 1],
                   SpatialBins& out) const {
    Box4 (&bins4)[3][kBins] = out.box;
    size_t (&enters)[3][kBins] = out.enters;
    size_t (&exits)[3][kBins] = out.exits;
    struct Spanning {
      const Ref* ref;
      int8_t first[3], last[3];  // per axis; first == last: binned already
    };
    constexpr size_t kBatch = 256, kAhead = 8;
    Spanning spanning[kBatch];
    for (size_t begin = 0; begin < refs.size(); begin += kBatch) {
      const size_t end = std::min(refs.size(), begin + kBatch);
      size_t n = 0;
      for (size_t i = begin; i < end; ++i) {
        const Ref& r = refs[i];
        const Vec4 lo = lo_of(r), hi = hi_of(r);
        Spanning s{&r, {}, {}};
        bool spans = false;
        for (int axis = 0; axis < 3; ++axis) {
          if (scale[axis] == 0.0f) continue;
          const float* at = planes[axis];
          // Most references end in the bin they start in: one comparison tells, not a second search.
          const int first = bin_in(at, box.lo[axis], scale[axis], r.box.lo[axis]);
          const int last = first == kBins - 1 || r.box.hi[axis] < at[first + 1]
                               ? first
                               : bin_in(at, box.lo[axis], scale[axis], r.box.hi[axis]);
          enters[axis][first]++;
          exits[axis][last]++;
          s.first[axis] = (int8_t)first, s.last[axis] = (int8_t)last;
          if (first == last) bins4[axis][first].grow(lo, hi);
          else spans = true;
        }
        if (spans) {
          __builtin_prefetch(&mesh.triangles[r.tri]);
          spanning[n++] = s;
        }
      }
      for (size_t k = 0; k < n; ++k) {
        if (k + kAhead < n)
          for (uint32_t v : mesh.triangles[spanning[k + kAhead].ref->tri].v) __builtin_prefetch(&mesh.vertices[v]);
        const Spanning& s = spanning[k];
        const Ref& r = *s.ref;
        const Corners t = corners(mesh, r.tri);
        for (int axis = 0; axis < 3; ++axis) {
          const int first = s.first[axis], last = s.last[axis];
          if (first == last) continue;  // (so is an axis of no extent: both stay 0)
          // Only the costs need these boxes (partition_spatial clips the references it splits), so
          // each bin gets the vertices and edge crossings of its planes, clamped to the reference's
          // box and unwidened: each crossing computed once, for the two bins it bounds.
          Box4* bin_box = bins4[axis];
          const float* at = planes[axis];
          auto grow = [](Box4& bin, const glm::vec3& p) { bin.grow(vec4_of(p), vec4_of(p)); };
          for (const glm::vec3& p : t) {
            int b = bin_in(at, box.lo[axis], scale[axis], p[axis]);
            if (b >= first && b <= last) grow(bin_box[b], glm::clamp(p, r.box.lo, r.box.hi));
          }
          for (int b = first + 1; b <= last; ++b) {
            for (int i = 0; i < 3; ++i) {
              glm::vec3 x;
              if (!edge_crossing(t[i], t[(i + 1) % 3], axis, at[b], &x)) continue;
              x = glm::clamp(x, r.box.lo, r.box.hi);  // (x[axis] = at stays: the box spans the plane)
              grow(bin_box[b - 1], x), grow(bin_box[b], x);
            }
          }
        }
      }
    }
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
  // `straddlers` in order; *nl, *nr get the sides' reference counts. The pass that finds them is
  // shared out to `parts` threads.
  void decide_spatial(std::span<const Ref> refs, const Box& box, const Split& s, unsigned parts, size_t* nl, size_t* nr) {
    const float at = plane(box, s.axis, s.bin);
    struct Part {
      Box4 lbox, rbox;
      size_t left_only = 0, right_only = 0;
      std::vector<Straddler> straddlers;
    };
    Parts<Part> part(parts);
    // Both sides' clipped parts first, so that the unsplitting test sees the sides' full extent.
    parallel_chunks(refs.size(), parts, [&](size_t begin, size_t end, unsigned p) {
      Part& q = part[p];
      for (size_t i = begin; i < end; ++i) {
        const Ref& r = refs[i];
        switch (side_of(r, s.axis, at)) {
          case Side::Left: q.left_only++, q.lbox.grow(lo_of(r), hi_of(r)); break;
          case Side::Right: q.right_only++, q.rbox.grow(lo_of(r), hi_of(r)); break;
          case Side::Both: {
            const Corners t = corners(mesh, r.tri);
            const Straddler& st = q.straddlers.emplace_back(Straddler{clip(t, s.axis, -INFINITY, at, r.box),
                                                                      clip(t, s.axis, at, INFINITY, r.box), Side::Both, i});
            q.lbox.grow(vec4_of(st.left.lo), vec4_of(st.left.hi)), q.rbox.grow(vec4_of(st.right.lo), vec4_of(st.right.hi));
            break;
          }
        }
      }
    });
    Box lbox, rbox;
    size_t left_only = 0, right_only = 0;
    straddlers.clear(), part_sides.clear();
    for (unsigned p = 0; p < parts; ++p) {
      lbox.grow(part[p].lbox.box()), rbox.grow(part[p].rbox.box());
      left_only += part[p].left_only, right_only += part[p].right_only;
      part_sides.push_back(part[p].left_only), part_sides.push_back(part[p].right_only);
      straddlers.insert(straddlers.end(), part[p].straddlers.begin(), part[p].straddlers.end());
    }
    *nl = left_only + straddlers.size(), *nr = right_only + straddlers.size();
    for (Straddler& st : straddlers) {
      const Ref& r = refs[st.at];
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
  // straddlers, in the given order; *lb, *rb get their bounds. `spare`: room for a copy of `refs`.
  // The references wholly on one side are written on decide_spatial's `parts` threads.
  void partition_spatial(std::span<Ref> refs, Ref* spare, Ref* right, const Box& box, const Split& s, unsigned parts,
                         Bounds* lb, Bounds* rb) {
    const std::span<const Ref> given(spare, refs.size());
    const float at = plane(box, s.axis, s.bin);
    Parts<BoundsAcc> la(parts), ra(parts);
    parallel_chunks(refs.size(), parts, [&](size_t begin, size_t end, unsigned) {
      std::copy(refs.begin() + (ptrdiff_t)begin, refs.begin() + (ptrdiff_t)end, spare + begin);
    });
    parallel_chunks(refs.size(), parts, [&](size_t begin, size_t end, unsigned p) {
      size_t to_left = 0, to_right = 0;  // where part p's go: after the parts before it
      for (unsigned q = 0; q < p; ++q) to_left += part_sides[2 * q], to_right += part_sides[2 * q + 1];
      for (size_t i = begin; i < end; ++i) {
        const Ref& r = given[i];
        const Side side = side_of(r, s.axis, at);
        if (side == Side::Left) refs[to_left++] = r, la[p].grow(r);
        else if (side == Side::Right) right[to_right++] = r, ra[p].grow(r);
      }
    });
    BoundsAcc& l = la[0];
    BoundsAcc& rr = ra[0];
    for (unsigned p = 1; p < parts; ++p) l.grow(la[p]), rr.grow(ra[p]);
    size_t left = 0, right_n = 0;
    for (unsigned p = 0; p < parts; ++p) left += part_sides[2 * p], right_n += part_sides[2 * p + 1];
    for (const Straddler& st : straddlers) {
      const Ref& r = given[st.at];
      switch (st.side) {
        case Side::Left: refs[left++] = r, l.grow(r); break;
        case Side::Right: right[right_n++] = r, rr.grow(r); break;
        case Side::Both:
          refs[left++] = Ref{r.tri, st.left}, l.grow(refs[left - 1]);
          right[right_n++] = Ref{r.tri, st.right}, rr.grow(right[right_n - 1]);
          break;
      }
    }
    *lb = l.bounds(), *rb = rr.bounds();
  }

  // Whether every reference is smaller on every axis than a spatial bin along the node's longest
  // side. Then a plane cuts only references that small, and clipping them moves the children's
  // boxes by less than that, which an object split's boxes already come within: the spatial
  // split is not tried (a mesh of millions of small triangles spent most of its build there).
  static bool all_small(const glm::vec3& largest, const Box& box) {
    const glm::vec3 extent = box.hi - box.lo;
    const float bin = std::max({extent.x, extent.y, extent.z}) * (1.0f / kBins);
    return largest.x <= bin && largest.y <= bin && largest.z <= bin;
  }

  // An object split's partition on `parts` threads, stable as the one-thread loop in build(): each
  // part counts the references it sends left, then writes both sides at the offsets those counts
  // give, into scratch (the right ones first, as build() expects them; the left ones after them),
  // and the left ones are copied back in place.
  void partition_object(std::span<Ref> span, size_t first, const Split& best, const Box& cbox, unsigned parts, size_t* nl,
                        size_t* nr, Bounds* lb, Bounds* rb) {
    const glm::vec3 scale = bin_scale(cbox);
    auto left = [&](const Ref& r) { return centroid_bin(r, best.axis, cbox, scale) < best.bin; };
    std::vector<size_t> lefts(parts + 1, 0);  // lefts[p + 1]: part p's
    parallel_chunks(span.size(), parts, [&](size_t begin, size_t end, unsigned part) {
      for (size_t i = begin; i < end; ++i) lefts[part + 1] += left(span[i]);
    });
    for (unsigned p = 0; p < parts; ++p) lefts[p + 1] += lefts[p];
    *nl = lefts[parts], *nr = span.size() - *nl;
    std::vector<BoundsAcc> la(parts), ra(parts);
    parallel_chunks(span.size(), parts, [&](size_t begin, size_t end, unsigned part) {
      Ref* to_left = scratch + first + *nr + lefts[part];
      Ref* to_right = scratch + first + (begin - lefts[part]);
      for (size_t i = begin; i < end; ++i) {
        const Ref& r = span[i];
        if (left(r)) *to_left++ = r, la[part].grow(r);
        else *to_right++ = r, ra[part].grow(r);
      }
    });
    std::copy(scratch + first + *nr, scratch + first + span.size(), span.begin());
    *lb = Bounds(), *rb = Bounds();
    for (unsigned p = 0; p < parts; ++p) lb->grow(la[p].bounds()), rb->grow(ra[p].bounds());
  }

  // Builds the subtree of `node` over refs[first, first + count), whose bounds are `bounds`; its
  // spatial splits may add at most `budget` references. The budget is shared out between the
  // children by their sizes, not spent first come first served, so that the left subtree cannot
  // starve the right. Below `fork_levels` levels from here, the right child is built on a thread
  // of its own.
  void build(size_t node, size_t first, size_t count, int depth, size_t budget, int fork_levels, const Bounds& bounds) {
    const std::span<Ref> span(refs + first, count);
    const Box &box = bounds.box, &cbox = bounds.centroids;
    nodes[node].box = box;
    // Down to pairs: which subtrees become leaves is the collapse's choice, by the costs of the
    // wide tree.
    if (count <= kMinBinaryLeaf) return leaf(node, span);

    Split best;
    Ref sorted[kMaxLeaf];  // an exact split's order
    const bool exact = count <= kMaxLeaf;
    // The top of the tree, before the forks give every core a subtree: its passes over the
    // references on several threads, a part each (the results are those of one pass).
    const unsigned parts = (unsigned)std::clamp<size_t>(count / kParallelMin, 1, std::max(1u, threads >> std::min(depth, 31)));
    if (depth < kMaxSahDepth && exact) {
      best = exact_split(span, sorted);
    } else if (depth < kMaxSahDepth) {
      float overlap = 0.0f;
      best = object_split(span, cbox, &overlap, parts);
      // Not among a leaf's few references (above), which the collapse may well put in one leaf
      // (the engine's build 0.28 → 0.20 s).
      if (spatial_splits && budget > 0 && overlap > kSpatialOverlap * root_area && !all_small(bounds.largest, box)) {
        Split spatial = spatial_split(span, box, budget, parts);
        if (spatial.cost < best.cost) best = spatial;
      }
    }
    // Where no split separates the references (every centroid in one point, or too deep), a few
    // make one leaf; more are halved.
    if (best.axis < 0 && count <= kMaxLeaf) return leaf(node, span);

    // The children's references: left ones in order at `first`, right ones in order after the
    // left subtree's budget, each side's straddlers after the rest.
    size_t nl = 0, nr = 0;
    Bounds lb, rb;  // the children's
    if (best.spatial) {
      decide_spatial(span, box, best, parts, &nl, &nr);
    } else if (exact && best.axis >= 0) {  // the first best.bin in their sorted order go left
      nl = (size_t)best.bin, nr = count - nl;
      std::copy(sorted, sorted + nl, span.begin());
      std::copy(sorted + nl, sorted + count, scratch + first);
      lb = bounds_of(sorted, nl), rb = bounds_of(sorted + nl, nr);
    } else if (best.axis >= 0 && parts > 1) {
      partition_object(span, first, best, cbox, parts, &nl, &nr, &lb, &rb);
    } else if (best.axis >= 0) {  // left ones in place, right ones to scratch
      const glm::vec3 scale = bin_scale(cbox);
      BoundsAcc la, ra;
      for (const Ref& r : span) {
        if (centroid_bin(r, best.axis, cbox, scale) < best.bin) span[nl++] = r, la.grow(r);
        else scratch[first + nr++] = r, ra.grow(r);
      }
      lb = la.bounds(), rb = ra.bounds();
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
      lb = bounds_of(refs + first, nl), rb = bounds_of(refs + right_first, nr);
    } else if (!best.spatial) {
      std::copy(scratch + first, scratch + first + nr, refs + right_first);
    } else {
      partition_spatial(span, scratch + first, refs + right_first, box, best, parts, &lb, &rb);
    }
    uint32_t l = (uint32_t)nodes.size(), r = l + 1;
    nodes.resize(nodes.size() + 2);
    nodes[node].left = l;
    nodes[node].right = r;
    if (fork_levels > 0 && nr >= kForkMin) {
      auto right = std::make_unique<Builder>(mesh, spatial_splits, root_area, refs, scratch, threads);
      // As many as it can make, reserved (never-written capacity takes no memory): growing would
      // copy them into fresh pages each time.
      right->nodes.reserve(2 * (nr + right_budget)), right->leaf_tris.reserve(nr + right_budget);
      auto job = std::async(std::launch::async, [&] {
        right->build(0, right_first, nr, depth + 1, right_budget, fork_levels - 1, rb);
      });
      build(l, first, nl, depth + 1, left_budget, fork_levels - 1, lb);
      job.get();
      forks += 1 + right->forks;
      grafts.push_back(Graft{r, nodes.size(), leaf_tris.size(), std::move(right)});
    } else {
      build(l, first, nl, depth + 1, left_budget, fork_levels, lb);
      build(r, right_first, nr, depth + 1, right_budget, fork_levels, rb);
    }
    // The subtree is built: its stretches of both arrays are never read again. Handed back, so
    // that the pages its budget's gaps were spread over do not all stay held to the end.
    if ((nl + nr + budget) * sizeof(Ref) >= kReleaseMin) {
      release_pages(refs + first, (nl + nr + budget) * sizeof(Ref));
      release_pages(scratch + first, (nl + nr + budget) * sizeof(Ref));
    }
  }

  // The nodes and leaf triangles of this subtree, its grafts' included.
  size_t all_nodes() const {
    size_t n = nodes.size();
    for (const Graft& g : grafts) n += g.sub->all_nodes() - 1;  // (its root is node r here)
    return n;
  }
  size_t all_leaf_tris() const {
    size_t n = leaf_tris.size();
    for (const Graft& g : grafts) n += g.sub->all_leaf_tris();
    return n;
  }

  // Writes the subtree into one array of nodes and one of leaf triangles, each graft in its place:
  // its node 0 at out_nodes[root], its other nodes from out_nodes[first_node] on, its leaves'
  // triangles from out_leaves[first_leaf] on. A graft's nodes and triangles go after those built
  // here before it and before those built here after it, so that the whole tree is laid out as if
  // one thread had built it; the grafts are written on threads of their own.
  void flatten(BinaryNode* out_nodes, uint32_t* out_leaves, uint32_t root, size_t first_node, size_t first_leaf) const {
    std::vector<size_t> graft_nodes, graft_leaves;  // where each graft's go
    size_t node_shift = 0, leaf_shift = 0;
    for (const Graft& g : grafts) {
      graft_nodes.push_back(first_node + g.nodes_at - 1 + node_shift);
      graft_leaves.push_back(first_leaf + g.leaves_at + leaf_shift);
      node_shift += g.sub->all_nodes() - 1, leaf_shift += g.sub->all_leaf_tris();
    }
    auto place = [&](uint32_t i) -> uint32_t {  // where node i built here goes
      if (i == 0) return root;
      size_t shift = 0;
      for (const Graft& g : grafts)
        if (g.nodes_at <= i) shift += g.sub->all_nodes() - 1;
      return (uint32_t)(first_node + i - 1 + shift);
    };
    auto place_leaf = [&](uint32_t j) -> uint32_t {  // where triangle j of leaf_tris goes
      size_t shift = 0;
      for (const Graft& g : grafts)
        if (g.leaves_at <= j) shift += g.sub->all_leaf_tris();
      return (uint32_t)(first_leaf + j + shift);
    };
    std::vector<std::future<void>> jobs;
    for (size_t k = 0; k < grafts.size(); ++k)
      jobs.push_back(std::async(std::launch::async, [&, k] {
        grafts[k].sub->flatten(out_nodes, out_leaves, place(grafts[k].r), graft_nodes[k], graft_leaves[k]);
      }));
    std::vector<uint32_t> roots;  // the nodes here that grafts' roots fill
    for (const Graft& g : grafts) roots.push_back(g.r);
    for (uint32_t i = 0; i < nodes.size(); ++i) {
      if (std::find(roots.begin(), roots.end(), i) != roots.end()) continue;
      BinaryNode n = nodes[i];
      if (n.count > 0) n.first = place_leaf(n.first);
      else n.left = place(n.left), n.right = place(n.right);
      out_nodes[place(i)] = n;
    }
    for (size_t j = 0; j < leaf_tris.size(); ++j) out_leaves[place_leaf((uint32_t)j)] = leaf_tris[j];
    for (auto& job : jobs) job.get();
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
  std::span<const BinaryNode> bin;
  std::span<const uint32_t> leaf_tris;
  const Mesh& mesh;
  Bvh& bvh;

  struct Plan {
    uint8_t split[8];       // split[i − 1], i ≥ 2: the lanes of i its left subtree takes; 0: it takes i − 1 lanes' plan
    uint8_t node_split;     // as a wide node of its own: the lanes (of width) its left subtree takes
    bool leaf;              // given one lane: a leaf, else a wide node
    uint32_t first, count;  // its references, leaf_tris[first, first + count)
  };
  RawArray<Plan> plan;  // per binary node; uninitialised, each written by the thread that plans it
  // The least cost of a subtree given i lanes, cost[i − 1]: what its parent's plan is made from
  // (returned up the planning's recursion, not kept per node).
  struct Costs {
    float cost[8];
  };
  double root_area = 0.0, root_volume = 0.0;
  // The blocks' triangles (positions in bvh.order, XI_NO_HIT for an unused lane), laid out by the
  // collapse; the blocks themselves are made from them once the binary tree is freed (make_blocks).
  std::vector<std::array<uint32_t, 4>> block_tris;

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

  // Plans every node, bottom-up; the two subtrees of each node of the top `levels` levels on
  // threads of their own.
  void plan_tree(int levels) {
    plan = raw_array<Plan>(bin.size());
    const glm::dvec3 root = glm::dvec3(bin[0].box.hi) - glm::dvec3(bin[0].box.lo);
    root_area = bin[0].box.area(), root_volume = root.x * root.y * root.z;
    plan_subtree(0, levels);
  }

  // Plans binary node n and the nodes below it; returns n's costs.
  Costs plan_subtree(uint32_t n, int levels) {
    const BinaryNode& b = bin[n];
    if (b.count > 0) return plan_node(n, nullptr, nullptr);
    Costs l, r;
    if (levels > 0) {
      auto job = std::async(std::launch::async, [&] { return plan_subtree(b.right, levels - 1); });
      l = plan_subtree(b.left, levels - 1);
      r = job.get();
    } else {
      l = plan_subtree(b.left, 0), r = plan_subtree(b.right, 0);
    }
    return plan_node(n, &l, &r);
  }

  // Binary node n's plan, from its children's costs (none for a leaf); returns its costs.
  Costs plan_node(uint32_t n, const Costs* lc, const Costs* rc) {
    const int width = bvh.width;
    const BinaryNode& b = bin[n];
    Plan& p = plan[n];
    Costs out;
    const float w = weight(b.box);
    std::fill(p.split, p.split + 8, 0);
    p.node_split = 0;
    if (b.count > 0) {  // a binary leaf: the build made it no larger than a leaf may be
      p.first = b.first, p.count = b.count, p.leaf = true;
      std::fill(out.cost, out.cost + 8, leaf_cost(w, b.count));
      return out;
    }
    const Plan &l = plan[b.left], &r = plan[b.right];
    if (r.first != l.first + l.count) throw Error("internal: the BVH's leaves are out of order");
    p.first = l.first, p.count = l.count + r.count;
    float spread[9];  // spread[j]: the least cost of the two subtrees sharing j lanes
    uint8_t spread_split[9];
    for (int j = 2; j <= width; ++j) {
      spread[j] = INFINITY, spread_split[j] = 1;
      for (int k = 1; k < j; ++k) {
        float c = lc->cost[k - 1] + rc->cost[j - k - 1];
        if (c < spread[j]) spread[j] = c, spread_split[j] = (uint8_t)k;
      }
    }
    const float as_node = w * kNodeCost + spread[width];
    const float as_leaf = leaf_cost(w, p.count);
    p.leaf = as_leaf <= as_node;
    p.node_split = spread_split[width];
    out.cost[0] = std::min(as_leaf, as_node);
    for (int i = 2; i <= width; ++i) {
      out.cost[i - 1] = out.cost[i - 2];
      if (spread[i] < out.cost[i - 1]) out.cost[i - 1] = spread[i], p.split[i - 1] = spread_split[i];
    }
    return out;
  }

  // The binary nodes of a wide node's lanes (at most 8, no allocation).
  struct Lanes {
    uint32_t node[8];
    size_t size = 0;
    const uint32_t* begin() const { return node; }
    const uint32_t* end() const { return node + size; }
    uint32_t operator[](size_t k) const { return node[k]; }
  };

  // Appends to `lanes` the binary nodes that take the i lanes given to subtree n.
  void gather(uint32_t n, int i, Lanes& lanes) const {
    while (i > 1 && plan[n].split[i - 1] == 0) --i;
    if (i == 1) return void(lanes.node[lanes.size++] = n);
    gather(bin[n].left, plan[n].split[i - 1], lanes);
    gather(bin[n].right, i - plan[n].split[i - 1], lanes);
  }

  // The binary nodes that become the lanes of the wide node made from binary node n.
  Lanes lanes_of(uint32_t n) const {
    Lanes lanes;
    if (bin[n].count > 0) return lanes.node[lanes.size++] = n, lanes;  // a root that is a leaf: one leaf lane
    gather(bin[n].left, plan[n].node_split, lanes);
    gather(bin[n].right, bvh.width - plan[n].node_split, lanes);
    return lanes;
  }

  // The distinct triangles of leaf_tris[first, first + count) (spatial splits can put one there
  // twice), in order; returns their number.
  uint32_t unique_tris(uint32_t first, uint32_t count, uint32_t* out) const {
    uint32_t unique = 0;
    for (uint32_t i = first; i < first + count; ++i)
      if (std::find(out, out + unique, leaf_tris[i]) == out + unique) out[unique++] = leaf_tris[i];
    return unique;
  }

  // The wide nodes below the wide node made from binary node n, and the blocks it and they hold.
  struct Count {
    size_t nodes = 0, blocks = 0;
  };
  Count count(uint32_t n) const {
    Count c;
    for (uint32_t k : lanes_of(n)) {
      if (plan[k].leaf) {
        uint32_t tris[kMaxLeaf];
        c.blocks += (unique_tris(plan[k].first, plan[k].count, tris) + 3) / 4;
      } else {
        const Count below = count(k);
        c.nodes += 1 + below.nodes, c.blocks += below.blocks;
      }
    }
    return c;
  }

  // Where a subtree's collapse writes its wide nodes and blocks next, and what it counts on the way.
  struct Cursor {
    size_t node = 0, block = 0;
    size_t leaves = 0, references = 0, max_leaf = 0;
    int depth = 0;
  };

  // Writes the blocks of the triangles of leaf_tris[first, first + count) (scene indices; a
  // triangle spatial splits put there twice, once) and returns the leaf's child entry. Blocks name
  // a triangle by its position in bvh.order; their vertices are filled in afterwards, on every
  // core (fill_blocks: reading them from the scene's triangles was most of the collapse's time).
  uint32_t leaf(uint32_t first, uint32_t count, Cursor& at) {
    uint32_t tris[kMaxLeaf];
    const uint32_t unique = unique_tris(first, count, tris);
    const uint32_t first_block = (uint32_t)at.block, blocks = (unique + 3) / 4;
    for (uint32_t b = 0; b < blocks; ++b) {
      std::array<uint32_t, 4>& blk = block_tris[at.block++];
      for (uint32_t k = 0; k < 4; ++k) blk[k] = 4 * b + k < unique ? bvh.position[tris[4 * b + k]] : XI_NO_HIT;
    }
    at.leaves++;
    at.references += unique;
    at.max_leaf = std::max<size_t>(at.max_leaf, unique);
    return XI_BVH_LEAF | (blocks - 1) << 27 | first_block;
  }

  // Lays out the wide node `wide` made from binary node b and the nodes below it, from `at`'s
  // next node and block on. Returns the stack entries a traversal of this subtree may hold beyond
  // those below it. Given `counts` (count() of each of its lanes' binary nodes that is not a leaf),
  // the subtrees of its interior children are laid out on `threads` threads, each from where one
  // thread would have put it: the same tree for any number.
  size_t collapse(uint32_t b, size_t wide, int depth, Cursor& at, const Count* counts = nullptr, unsigned threads = 1) {
    const Lanes kids = lanes_of(b);
    const size_t width = (size_t)bvh.width;
    at.depth = std::max(at.depth, depth + 1);
    const float inf = INFINITY;
    float lo[3][8], hi[3][8];
    uint32_t child[8];
    // A node's interior children are laid out side by side and its leaves' blocks likewise,
    // before any grandchild: a ray that enters one child is likely to enter its siblings.
    for (size_t k = 0; k < width; ++k) {
      for (int a = 0; a < 3; ++a) lo[a][k] = inf, hi[a][k] = -inf;
      child[k] = XI_BVH_EMPTY;
      if (k >= kids.size) continue;
      const BinaryNode& c = bin[kids[k]];
      for (int a = 0; a < 3; ++a) lo[a][k] = c.box.lo[a], hi[a][k] = c.box.hi[a];
      child[k] = plan[kids[k]].leaf ? leaf(plan[kids[k]].first, plan[kids[k]].count, at) : (uint32_t)at.node++;
    }
    size_t below = 0;
    if (counts) {
      Cursor sub[8];
      size_t stack[8] = {};
      std::vector<size_t> interior;
      for (size_t k = 0; k < kids.size; ++k)
        if (!(child[k] & XI_BVH_LEAF)) interior.push_back(k);
      for (size_t k : interior) {
        sub[k].node = at.node, sub[k].block = at.block;
        at.node += counts[k].nodes, at.block += counts[k].blocks;
      }
      on_threads(interior.size(), threads, [&](size_t i) {
        const size_t k = interior[i];
        stack[k] = collapse(kids[k], child[k], depth + 1, sub[k]);
      });
      for (size_t k : interior) {
        below = std::max(below, stack[k]);
        at.leaves += sub[k].leaves, at.references += sub[k].references;
        at.max_leaf = std::max(at.max_leaf, sub[k].max_leaf), at.depth = std::max(at.depth, sub[k].depth);
      }
    } else {
      for (size_t k = 0; k < kids.size; ++k)
        if (!(child[k] & XI_BVH_LEAF)) below = std::max(below, collapse(kids[k], child[k], depth + 1, at));
    }
    if (width == 8) store_node<BvhNode8, 8>(bvh.nodes8[wide], lo, hi, child);
    else store_node<BvhNode, 4>(bvh.nodes[wide], lo, hi, child);
    // Traversal pushes up to one entry per lane and pops one to descend into an interior child.
    return std::max(kids.size, kids.size - 1 + below);
  }

  // The whole tree, its root's subtrees counted and laid out on `threads` threads.
  void collapse_tree(unsigned threads) {
    const Lanes kids = lanes_of(0);
    Count counts[8], total;
    on_threads(kids.size, threads, [&](size_t k) {
      if (!plan[kids[k]].leaf) counts[k] = count(kids[k]);
    });
    for (size_t k = 0; k < kids.size; ++k) {
      if (plan[kids[k]].leaf) {
        uint32_t tris[kMaxLeaf];
        total.blocks += (unique_tris(plan[kids[k]].first, plan[kids[k]].count, tris) + 3) / 4;
      } else {
        total.nodes += 1 + counts[k].nodes, total.blocks += counts[k].blocks;
      }
    }
    const size_t nodes = 1 + total.nodes;
    // Spatial splits can make up to twice as many blocks as the triangles' count checked up front.
    if (total.blocks > XI_BVH_FIRST_MASK)
      throw Error("too many triangle blocks for the BVH's 27-bit leaf entries", "try --no-spatial-splits");
    if (bvh.width == 8) bvh.nodes8.resize(nodes);
    else bvh.nodes.resize(nodes);
    block_tris.resize(total.blocks);
    Cursor at;
    at.node = 1;  // the root's is 0
    bvh.stats.stack = collapse(0, 0, 0, at, counts, threads);
    if (at.node != nodes || at.block != total.blocks) throw Error("internal: the BVH's collapse miscounted");
    bvh.stats.depth = at.depth, bvh.stats.leaves = at.leaves;
    bvh.stats.references = at.references, bvh.stats.max_leaf = at.max_leaf;
  }

  // The blocks, from block_tris and the vertices of the triangles they name (unused lanes NaN).
  void make_blocks(unsigned threads) {
    const size_t n = block_tris.size();
    bvh.blocks.resize(n);
    parallel_chunks(n, (unsigned)std::clamp<size_t>(n >> 14, 1, threads), [&](size_t begin, size_t end, unsigned) {
      for (size_t b = begin; b < end; ++b) {
        TriBlock& blk = bvh.blocks[b];
        for (auto& axis : blk.coord) std::fill(axis, axis + 3, glm::vec4(NAN));
        for (int k = 0; k < 4; ++k) {
          blk.tri[k] = block_tris[b][k];
          if (blk.tri[k] == XI_NO_HIT) continue;
          const Corners t = corners(mesh, bvh.order[blk.tri[k]]);
          for (int j = 0; j < 3; ++j)
            for (int a = 0; a < 3; ++a) blk.coord[a][j][k] = t[j][a];
        }
      }
    });
    std::vector<std::array<uint32_t, 4>>().swap(block_tris);
  }
};

}  // namespace

Bvh build_bvh(const Mesh& mesh, int width, bool spatial_splits, unsigned threads) {
  const std::vector<Triangle>& triangles = mesh.triangles;
  auto start = std::chrono::steady_clock::now();
  if (width != 4 && width != 8) throw Error("BVH width must be 4 or 8, not " + std::to_string(width), "--bvh-width");
  if (triangles.empty()) throw Error("cannot build a BVH over an empty scene");
  if (triangles.size() >= (1ull << 31)) throw Error("too many triangles for 32-bit indices");
  // Leaf entries address triangles with 27 bits (XI_BVH_FIRST_MASK).
  if (triangles.size() > XI_BVH_FIRST_MASK) throw Error("too many triangles for the BVH (at most 134217727)");
  Bvh bvh;
  bvh.width = width;
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  const size_t n = triangles.size();
  const size_t budget = spatial_splits ? (size_t)((kMaxReferences - 1.0) * (double)n) : 0;
  // Uninitialised: pages are written only as references land there (the budget's part only if
  // spatial splits use it), not all zeroed up front.
  RawArray<Ref> refs = raw_array<Ref>(n + budget), scratch = raw_array<Ref>(n + budget);
  const unsigned init_parts = parts_for(n, threads);
  std::vector<BoundsAcc> parts(init_parts);
  parallel_chunks(n, init_parts, [&](size_t begin, size_t end, unsigned part) {
    for (size_t i = begin; i < end; ++i) {
      Ref& r = refs[i];
      r.tri = (uint32_t)i, r.box = Box();
      for (const glm::vec3& v : corners(mesh, (uint32_t)i)) r.box.grow(v);
      parts[part].grow(r);
    }
  });
  Bounds root;
  for (const BoundsAcc& b : parts) root.grow(b.bounds());
  Builder b(mesh, spatial_splits, root.box.area(), refs.get(), scratch.get(), threads);
  b.nodes.reserve(2 * n);
  b.leaf_tris.reserve(n + budget);
  // Forks down to about four subtrees per core, so that uneven halves still keep every core busy.
  int fork_levels = 0;
  for (unsigned k = 1; threads > 1 && k < 4 * threads && fork_levels < 8; k *= 2) ++fork_levels;
  b.build(0, 0, n, 0, budget, fork_levels, root);
  refs.reset(), scratch.reset();  // done with: the collapse needs room
  bvh.stats.threads = 1 + b.forks;
  // The subtrees built on threads of their own, in their places in one tree (uninitialised arrays:
  // their pages are first written by the threads that fill them).
  const size_t node_count = b.all_nodes(), leaf_count = b.all_leaf_tris();
  RawArray<BinaryNode> all_nodes;
  RawArray<uint32_t> all_leaves;
  std::span<const BinaryNode> bin(b.nodes);
  std::span<const uint32_t> leaf_tris(b.leaf_tris);
  if (!b.grafts.empty()) {
    all_nodes = raw_array<BinaryNode>(node_count), all_leaves = raw_array<uint32_t>(leaf_count);
    b.flatten(all_nodes.get(), all_leaves.get(), 0, 1, 0);
    bin = std::span<const BinaryNode>(all_nodes.get(), node_count);
    leaf_tris = std::span<const uint32_t>(all_leaves.get(), leaf_count);
    b.grafts.clear(), std::vector<BinaryNode>().swap(b.nodes), std::vector<uint32_t>().swap(b.leaf_tris);
  }
  // BVH order: the triangles by their first place in a leaf, leaves left to right, so that the
  // arrays in this order (CompiledScene) follow the tree.
  constexpr uint32_t kUnplaced = ~0u;
  std::vector<uint32_t>& position = bvh.position;
  position.assign(triangles.size(), kUnplaced);
  bvh.order.reserve(triangles.size());
  for (uint32_t t : leaf_tris)
    if (position[t] == kUnplaced) position[t] = (uint32_t)bvh.order.size(), bvh.order.push_back(t);
  if (bvh.order.size() != triangles.size()) throw Error("internal: the BVH lost a triangle");
  Collapser collapser{bin, leaf_tris, mesh, bvh, nullptr, 0.0, 0.0, {}};
  collapser.plan_tree(fork_levels);
  collapser.collapse_tree(threads);
  // The binary tree and its plan are done with: freed before the blocks, the largest array, are made.
  collapser.plan.reset(), collapser.bin = {}, collapser.leaf_tris = {};
  all_nodes.reset(), all_leaves.reset();
  std::vector<BinaryNode>().swap(b.nodes), std::vector<uint32_t>().swap(b.leaf_tris), b.grafts.clear();
  collapser.make_blocks(threads);
  if (bvh.stats.stack > XI_BVH_STACK)
    throw Error("the scene's BVH is too deep for the kernels' traversal stack",
                "needs " + std::to_string(bvh.stats.stack) + " entries, XI_BVH_STACK is " + std::to_string(XI_BVH_STACK));
  bvh.stats.nodes = width == 8 ? bvh.nodes8.size() : bvh.nodes.size();
  bvh.stats.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return bvh;
}

}  // namespace xi
