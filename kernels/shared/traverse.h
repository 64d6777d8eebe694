// One ray through the BVH (xi_trace): its closest hit, or for a shadow ray any hit before tmax.
// Used by the extend and shadow kernels and, compiled as C++, by the host's tests.
#ifndef XI_TRAVERSE_H
#define XI_TRAVERSE_H
#include "compat.h"
#include "layout.h"
#include "triangle.h"

// Every operation rounded as written, as in triangle.h, so the host's traversal and the packets'
// (packet.h) find what the kernels' does.
#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT OFF
#endif

#define XI_BVH_STACK 128  // entries; the BVH builder checks that its tree never needs more

// A little slack on box tests so rounding never rejects a box that a triangle in it would hit.
#define XI_BOX_SLACK 1.00000024f

// The nodes of XI_BVH_WIDTH lanes (layout.h), and their lanes as a vector.
#if XI_BVH_WIDTH == 8
typedef BvhNode8 TraceNode;
typedef float8 NodeFloat;
typedef int8 NodeMask;
static inline uint xi_node_lane_bits(NodeMask m) { return xi_lane_bits8(m); }
#else
typedef BvhNode TraceNode;
typedef float4 NodeFloat;
typedef int4 NodeMask;
static inline uint xi_node_lane_bits(NodeMask m) { return xi_lane_bits(m); }
#endif

// Lane k of a node's or a block's vector (the same type): k is a constant once the loop over the
// lanes is unrolled, so this is a register's lane, not a load.
static inline XI_INLINE float xi_lane(NodeFloat v, uint k) { return ((const float*)&v)[k]; }

// A leaf entry's blocks: first to end (exclusive).
static inline uint xi_leaf_first(uint entry) { return entry & XI_BVH_FIRST_MASK; }
static inline uint xi_leaf_end(uint entry) { return xi_leaf_first(entry) + 1u + ((entry >> 27) & 15u); }

static inline bool xi_one_bit(uint bits) { return bits != 0u && (bits & (bits - 1u)) == 0u; }

// The traversal stack holds node or leaf entries with the distance at which the ray (a packet: the
// nearest of its rays) enters them, so entries behind the best hit are skipped when popped; the
// host checks that no tree needs more than XI_BVH_STACK entries (xi::Bvh::stats.stack). One uint2
// per entry, (entry, distance as bits): one move each.
//
// Pushes the children of a node that the ray enters (bit k of `entered`: child k, entered at
// t_enter[k]). Every child is written and only the entered ones kept, with no branch on which ones
// those are (it differs from node to node, which a branch would mispredict). A closest-hit query
// then sorts them nearest on top, ties in the children's order, so the nearest is visited first; an
// any-hit query (shadow rays) stops at whichever hit it finds, so it skips the sort. (Branch-free
// placement, each lane's rank among the entered lanes by vector compares, was slower on PoCL.)
// The stack needs one entry more than a tree does: the last child is written, kept or not.
static inline XI_INLINE void xi_push_children(uint2* stack, uint* sp, __global const uint* children,
                                              const float* t_enter, uint entered, bool any_hit) {
  const uint base = *sp;
  XI_UNROLL for (uint k = 0u; k < XI_BVH_WIDTH; ++k) {
    stack[*sp] = make_uint2(children[k], as_uint(t_enter[k]));
    *sp += (entered >> k) & 1u;
  }
  if (any_hit) return;
  for (uint i = base + 1u; i < *sp; ++i) {
    const uint2 e = stack[i];
    uint j = i;
    for (; j > base && as_float(stack[j - 1u].y) < as_float(e.y); --j) stack[j] = stack[j - 1u];
    stack[j] = e;
  }
}

// Pops the next entry entered no farther than `limit` into *entry; false once the stack is empty.
static inline XI_INLINE bool xi_pop(const uint2* stack, uint* sp, float limit, uint* entry) {
  while (*sp != 0u) {
    --*sp;
    if (as_float(stack[*sp].y) <= limit) {
      *entry = stack[*sp].x;
      return true;
    }
  }
  return false;
}

// Requests the first three cache lines of a node or of a leaf's first block (most of what a ray
// reads there) ahead of the visit.
static inline XI_INLINE void xi_prefetch_entry(__global const TraceNode* nodes, __global const TriBlock* blocks,
                                               uint entry) {
  __global const char* at = (entry & XI_BVH_LEAF) ? (__global const char*)(blocks + xi_leaf_first(entry))
                                                  : (__global const char*)(nodes + entry);
  XI_PREFETCH(at, 0);
  XI_PREFETCH(at + 64, 0);
  XI_PREFETCH(at + 128, 0);
}

static inline float3 xi_safe_inverse(float3 d) {
  const float big = 1e30f;
  return make_float3(d.x != 0.0f ? 1.0f / d.x : big, d.y != 0.0f ? 1.0f / d.y : big,
                     d.z != 0.0f ? 1.0f / d.z : big);
}

// Closest hit (any_hit == false) or any hit before tmax (any_hit == true) in the subtree of `entry`
// (a node or a leaf entry; 0: the root). Returns the triangle index (its position in BVH order) or
// XI_NO_HIT; *t, *u, *v describe the hit.
static inline uint xi_trace_from(__global const TraceNode* nodes, __global const TriBlock* blocks, uint entry,
                                 float3 o, float3 d, float tmax, bool any_hit, float* t, float* u, float* v) {
  RayShear s = xi_ray_shear(o, d);
  float3 inv_d = xi_safe_inverse(d);
  // Which of a node's bounds (lo x, hi x, lo y, ...) is each axis's near plane: an index, so a
  // node's slab test loads its planes without a choice per plane.
  int near_x = inv_d.x < 0.0f ? 1 : 0, near_y = inv_d.y < 0.0f ? 3 : 2, near_z = inv_d.z < 0.0f ? 5 : 4;
  uint2 stack[XI_BVH_STACK + 1];
  uint sp = 0u;
  uint found = XI_NO_HIT;
  float best = tmax;
  for (;;) {
    if (entry & XI_BVH_LEAF) {
      const uint end = xi_leaf_end(entry);
      for (uint k = xi_leaf_first(entry); k < end; k += XI_BLOCK_LANES / 4) {
        // 8 lanes: a leaf's two blocks in one test; a lone block is tested twice over, the copy's
        // lanes off.
        const bool pair = XI_BLOCK_LANES == 8 && k + 1u < end;
        __global const TriBlock* b0 = blocks + k;
        __global const TriBlock* b1 = pair ? b0 + 1 : b0;
        BlockEdges e;
        const uint hits = xi_intersect_block(s, b0, b1, best, &e) & (pair ? 0xffu : 0x0fu);
        if (hits == 0u) continue;
        // The lanes in order, as xi_intersect_triangle would take the triangles one after the
        // other: a closer hit becomes the best.
        XI_UNROLL for (uint l = 0u; l < XI_BLOCK_LANES; ++l) {
          float tt, uu, vv;
          if ((hits & (1u << l)) && xi_edge_hit(xi_lane(e.e0, l), xi_lane(e.e1, l), xi_lane(e.e2, l),
                                                xi_lane(e.t_det, l), xi_lane(e.t_err_det, l), best, &tt, &uu, &vv)) {
            best = *t = tt;
            *u = uu;
            *v = vv;
            found = (l < 4u ? b0 : b1)->tri[l & 3u];
            if (any_hit) return found;
          }
        }
      }
    } else {
      // Slab test of all the child boxes at once, each axis's near plane chosen by the sign of the
      // direction (an unused lane's inverted box is then always missed). No NaN can arise (inv_d
      // is finite, a plane infinite only in an unused lane), so xi_min/xi_max will do.
      __global const TraceNode* n = nodes + entry;
      NodeFloat nx = n->bounds[near_x], fx = n->bounds[near_x ^ 1];
      NodeFloat ny = n->bounds[near_y], fy = n->bounds[near_y ^ 1];
      NodeFloat nz = n->bounds[near_z], fz = n->bounds[near_z ^ 1];
      NodeFloat tn = xi_max(xi_max((nx - o.x) * inv_d.x, (ny - o.y) * inv_d.y),
                            xi_max((nz - o.z) * inv_d.z, (NodeFloat)0.0f));
      NodeFloat tf = xi_min(xi_min((fx - o.x) * inv_d.x, (fy - o.y) * inv_d.y),
                            xi_min((fz - o.z) * inv_d.z, (NodeFloat)best));
      const uint hits = xi_node_lane_bits(xi_less_equal(tn, tf * XI_BOX_SLACK));
      if (xi_one_bit(hits)) {  // one child: go there, the stack untouched
        entry = n->child[31 - clz(hits)];
        continue;
      }
      // The entered children's lines requested together, so their misses overlap instead of each
      // waiting for its turn on the stack.
      for (uint left = hits; XI_HAS_PREFETCH && left != 0u; left &= left - 1u)
        xi_prefetch_entry(nodes, blocks, n->child[31 - clz(left & (0u - left))]);
      xi_push_children(stack, &sp, n->child, (const float*)&tn, hits, any_hit);
    }
    // The nearest entry the ray enters before its best hit so far.
    if (!xi_pop(stack, &sp, best * XI_BOX_SLACK, &entry)) return found;
  }
}

// The same through the whole tree.
static inline uint xi_trace(__global const TraceNode* nodes, __global const TriBlock* blocks, float3 o,
                            float3 d, float tmax, bool any_hit, float* t, float* u, float* v) {
  return xi_trace_from(nodes, blocks, 0u, o, d, tmax, any_hit, t, u, v);
}

#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT DEFAULT
#endif

#endif
