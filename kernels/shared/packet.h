// Rays in packets through an 8-wide tree: the extend kernel's camera rays, and in a small tree its
// bounce rays and the shadow kernel's rays too; in a large tree, the rays that leave the surfaces
// camera rays hit, in hybrid packets (below; layout.h's XI_EXTEND_RAYS and XI_SHADOW_RAYS).
// A packet is XI_PACKET_WIDTH rays, one per vector lane: 8 (float8), or 16 (float16) where the CPU
// has 512-bit vectors, so that one instruction tests a box or a triangle against all of them.
//
// The packet's rays go through the tree together: a node's eight child boxes are each tested
// against all the rays, and a leaf's triangles each against all the rays at once, so a node's
// loads, its stack entries and its branches serve every ray, and a leaf of two triangles no longer
// costs each ray a whole eight-lane block test. A node is entered when any of the rays enters it,
// so the packet does the union of its rays' work: for neighbouring camera rays little more than
// each one's; for bounce rays, which part ways, little more only where each ray visits most of the
// tree anyway.
// Each ray's hit is the one xi_trace finds, bitwise (the same box and triangle arithmetic per lane;
// where two triangles are hit at exactly the same t, the order of traversal may pick the other).
#ifndef XI_PACKET_H
#define XI_PACKET_H
#include "traverse.h"

#if XI_BVH_WIDTH == 8

// Every operation rounded as written, as in xi_trace.
#pragma OPENCL FP_CONTRACT OFF

// The least and the greatest of a packet's lanes: 16 folded onto 8 first, then halved down to one.
#if XI_PACKET_WIDTH == 16
#define XI_PACKET_FOLD8(op, v) op((v).lo, (v).hi)
#else
#define XI_PACKET_FOLD8(op, v) (v)
#endif
static inline float xi_packet_min(PacketFloat v) {
  float8 w = XI_PACKET_FOLD8(xi_min, v);
  float4 a = xi_min(w.lo, w.hi);
  float2 b = xi_min(a.lo, a.hi);
  return b.x < b.y ? b.x : b.y;
}
static inline float xi_packet_max(PacketFloat v) {
  float8 w = XI_PACKET_FOLD8(xi_max, v);
  float4 a = xi_max(w.lo, w.hi);
  float2 b = xi_max(a.lo, a.hi);
  return b.x > b.y ? b.x : b.y;
}

// A packet's rays (lane k = ray k) as the traversal uses them. Each ray has its own axis permutation
// (the triangle test's) and near planes (the slab test's), chosen per lane by selects. Where all
// rays share both, as neighbouring camera rays do, the packet is `coherent`: it loads the one
// permutation's coordinates and the one set of near planes by index, as xi_trace does for one ray,
// which spares a select per plane and per coordinate on every node and triangle the packet visits.
typedef struct {
  RayShearPacket shear;
  PacketFloat ox, oy, oz;            // origins
  PacketFloat inv_x, inv_y, inv_z;   // 1 / direction, as xi_safe_inverse
  PacketInt back_x, back_y, back_z;  // direction negative on the axis: the box's hi plane is the near one
  bool coherent;                     // one permutation and one sign per axis for all the rays
  int near_x, near_y, near_z;        // lane 0's near planes as xi_trace's, all rays' where coherent
} Packet;

static inline XI_INLINE Packet xi_packet(PacketFloat ox, PacketFloat oy, PacketFloat oz, PacketFloat dx, PacketFloat dy,
                                         PacketFloat dz) {
  Packet p;
  p.shear = xi_ray_shear_packet(ox, oy, oz, dx, dy, dz);
  p.ox = ox, p.oy = oy, p.oz = oz;
  p.inv_x = select((PacketFloat)1e30f, 1.0f / dx, dx != 0.0f);
  p.inv_y = select((PacketFloat)1e30f, 1.0f / dy, dy != 0.0f);
  p.inv_z = select((PacketFloat)1e30f, 1.0f / dz, dz != 0.0f);
  p.back_x = p.inv_x < 0.0f, p.back_y = p.inv_y < 0.0f, p.back_z = p.inv_z < 0.0f;
  p.near_x = p.back_x.s0 ? 1 : 0, p.near_y = p.back_y.s0 ? 3 : 2, p.near_z = p.back_z.s0 ? 5 : 4;
  const uint back_x = xi_packet_bits(dx < 0.0f), back_y = xi_packet_bits(dy < 0.0f), back_z = xi_packet_bits(dz < 0.0f);
  p.coherent = p.shear.same_axes && (back_x == 0u || back_x == XI_PACKET_ALL) &&
               (back_y == 0u || back_y == XI_PACKET_ALL) && (back_z == 0u || back_z == XI_PACKET_ALL);
  return p;
}

// A packet's vector of member `c` of the rays' float4s a[0], a[1], ... (lane k: a[k].c).
#define XI_PACKET_OF8(a, c) a[0].c, a[1].c, a[2].c, a[3].c, a[4].c, a[5].c, a[6].c, a[7].c
#if XI_PACKET_WIDTH == 16
#define XI_PACKET_OF(a, c) \
  (PacketFloat)(XI_PACKET_OF8(a, c), a[8].c, a[9].c, a[10].c, a[11].c, a[12].c, a[13].c, a[14].c, a[15].c)
#else
#define XI_PACKET_OF(a, c) (PacketFloat)(XI_PACKET_OF8(a, c))
#endif
// Lane k of a packet's vector; k is a constant once a loop over the lanes is unrolled.
#define XI_PACKET_LANE(type, v, k) (((const type*)&(v))[k])

// The rays' float4s r[0], r[1], ... as a packet's x, y, z and w (XI_TRANSPOSE4).
static inline XI_INLINE void xi_packet_columns(const float4* r, PacketFloat* x, PacketFloat* y, PacketFloat* z,
                                               PacketFloat* w) {
#if XI_HAS_SHUFFLE
  XI_COLUMNS(XI_PACKET_WIDTH, r, *x, *y, *z, *w)
#else
  *x = XI_PACKET_OF(r, x), *y = XI_PACKET_OF(r, y), *z = XI_PACKET_OF(r, z), *w = XI_PACKET_OF(r, w);
#endif
}

// The packet of rays o[k], d[k] (lane k = ray k; origins and unit directions), with the origins' w
// (a shadow ray's tmax) in *w.
static inline XI_INLINE Packet xi_packet_of_rows(const float4* o, const float4* d, PacketFloat* w) {
  PacketFloat ox, oy, oz, dx, dy, dz, dw;
  xi_packet_columns(o, &ox, &oy, &oz, w);
  xi_packet_columns(d, &dx, &dy, &dz, &dw);
  return xi_packet(ox, oy, oz, dx, dy, dz);
}

// The inverse: rows x[k], y[k], z[k], w[k] of the packet's lanes stored to p[slot[k]].
static inline XI_INLINE void xi_packet_store_rows(__global float4* p, const uint* slot, PacketFloat x, PacketFloat y,
                                                  PacketFloat z, PacketFloat w) {
#if XI_HAS_SHUFFLE
  XI_TRANSPOSE4(XI_PACKET_WIDTH, x, y, z, w)
  XI_UNROLL for (uint k = 0u; k < XI_PACKET_WIDTH; ++k) p[slot[k]] = XI_ROW(XI_PACKET_WIDTH, x, y, z, w, k);
#else
  XI_UNROLL for (uint k = 0u; k < XI_PACKET_WIDTH; ++k)
    p[slot[k]] = (float4)(XI_PACKET_LANE(float, x, k), XI_PACKET_LANE(float, y, k), XI_PACKET_LANE(float, z, k),
                          XI_PACKET_LANE(float, w, k));
#endif
}

// Lane k of node n's bound `plane` (lo x, hi x, lo y, ...: 0 to 5), for all the packet's rays.
static inline XI_INLINE PacketFloat xi_node_plane(__global const BvhNode8* n, int plane, uint k) {
  __global const float* lanes = (__global const float*)&n->bounds[plane];
  return (PacketFloat)(lanes[k]);
}

// Child k's near and far planes on one axis (lo: that axis's lo plane, 0, 2 or 4) for each ray:
// the lo plane is the near one where the ray's direction is positive on the axis, the hi plane
// where it is negative (`back`). Coherent: the packet's near plane `near`, by index.
static inline XI_INLINE void xi_packet_slab(__global const BvhNode8* n, uint k, int lo, PacketInt back, int near,
                                            bool coherent, PacketFloat* near_plane, PacketFloat* far_plane) {
  if (coherent) {
    *near_plane = xi_node_plane(n, near, k);
    *far_plane = xi_node_plane(n, near ^ 1, k);
  } else {
    const PacketFloat lo_plane = xi_node_plane(n, lo, k), hi_plane = xi_node_plane(n, lo + 1, k);
    *near_plane = select(lo_plane, hi_plane, back);
    *far_plane = select(hi_plane, lo_plane, back);
  }
}

// The rays that enter child k of node n before their best hit, by xi_trace's slab test; *tn gets
// the distance at which each enters.
static inline XI_INLINE PacketInt xi_packet_entering(const Packet* p, bool coherent, __global const BvhNode8* n,
                                                     uint k, PacketFloat best, PacketFloat* tn) {
  PacketFloat nx, fx, ny, fy, nz, fz;
  xi_packet_slab(n, k, 0, p->back_x, p->near_x, coherent, &nx, &fx);
  xi_packet_slab(n, k, 2, p->back_y, p->near_y, coherent, &ny, &fy);
  xi_packet_slab(n, k, 4, p->back_z, p->near_z, coherent, &nz, &fz);
  const PacketFloat t_near = xi_max(xi_max((nx - p->ox) * p->inv_x, (ny - p->oy) * p->inv_y),
                                    xi_max((nz - p->oz) * p->inv_z, (PacketFloat)0.0f));
  const PacketFloat tf =
      xi_min(xi_min((fx - p->ox) * p->inv_x, (fy - p->oy) * p->inv_y), xi_min((fz - p->oz) * p->inv_z, best));
  *tn = t_near;
  return xi_less_equal(t_near, tf * XI_BOX_SLACK);
}

// Whether any ray enters child k of node n before its best hit, each by xi_trace's slab test; if
// so, *t_enter is the nearest distance at which one does (else ∞).
static inline XI_INLINE bool xi_packet_enters(const Packet* p, bool coherent, __global const BvhNode8* n, uint k,
                                              PacketFloat best, float* t_enter) {
  PacketFloat tn;
  const PacketInt enter = xi_packet_entering(p, coherent, n, k, best, &tn);
  *t_enter = INFINITY;
  if (xi_packet_bits(enter) == 0u) return false;
  *t_enter = xi_packet_min(select((PacketFloat)INFINITY, tn, enter));
  return true;
}

// The triangles of leaf `entry` against a packet's rays, each up to its `limit` (-∞: a ray that takes
// no part): a lane's hit puts its triangle into *found and its t, u, v into *best, *best_u, *best_v,
// or -∞ into *best for an any-hit query (the ray is answered: it enters no box, hits nothing again).
static inline XI_INLINE void xi_packet_leaf(__global const TriBlock* blocks, uint entry, const Packet* p,
                                            bool coherent, bool any_hit, PacketFloat limit, PacketFloat* best,
                                            PacketFloat* best_u, PacketFloat* best_v, PacketUint* found) {
  const uint end = xi_leaf_end(entry);
  for (uint k = xi_leaf_first(entry); k < end; ++k)
    for (uint j = 0u; j < 4u && blocks[k].tri[j] != XI_NO_HIT; ++j) {  // unused lanes come last
      PacketFloat tt, uu, vv;
      const PacketInt hit = xi_intersect_packet(&p->shear, coherent, blocks + k, j, limit, &tt, &uu, &vv);
      if (xi_packet_bits(hit) == 0u) continue;
      *found = select(*found, (PacketUint)blocks[k].tri[j], hit);
      if (any_hit) tt = -INFINITY;
      limit = select(limit, tt, hit);
      *best = select(*best, tt, hit);
      *best_u = select(*best_u, uu, hit);
      *best_v = select(*best_v, vv, hit);
    }
}

// The traversal of one packet, as xi_trace's of one ray: closest hits, or with any_hit, for each ray
// whether there is a hit before its tmax. Called with `coherent` and `any_hit` constants
// (xi_packet_query), so each of the four cases compiles to its own loop, neither tested inside it.
static inline XI_INLINE void xi_packet_traverse(__global const BvhNode8* nodes, __global const TriBlock* blocks,
                                                const Packet* p, bool coherent, bool any_hit, PacketFloat tmax,
                                                PacketFloat* t, PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  uint2 stack[XI_BVH_STACK + 1];  // distances: the nearest at which one of the rays enters the entry
  uint sp = 0u, entry = 0u;
  PacketFloat best = tmax, best_u = 0.0f, best_v = 0.0f;
  PacketUint found = (PacketUint)XI_NO_HIT;
  for (;;) {
    if (entry & XI_BVH_LEAF) {
      xi_packet_leaf(blocks, entry, p, coherent, any_hit, best, &best, &best_u, &best_v, &found);
      if (any_hit && xi_packet_bits(found != (PacketUint)XI_NO_HIT) == XI_PACKET_ALL) {  // all answered
        *tri = found;
        return;
      }
    } else {
      __global const BvhNode8* n = nodes + entry;
      uint hits = 0u;
      float t_enter[8];
      XI_UNROLL for (uint k = 0u; k < 8u; ++k)
        if (xi_packet_enters(p, coherent, n, k, best, &t_enter[k])) hits |= 1u << k;
      if (xi_one_bit(hits)) {  // one child: go there
        entry = n->child[31 - clz(hits)];
        continue;
      }
      xi_push_children(stack, &sp, n->child, t_enter, hits, any_hit);
    }
    // The nearest entry that some ray enters before its best hit so far.
    if (!xi_pop(stack, &sp, xi_packet_max(best) * XI_BOX_SLACK, &entry)) {
      *t = best, *u = best_u, *v = best_v, *tri = found;
      return;
    }
  }
}

// A packet's rays as xi_trace takes one: the coherent or the per-ray traversal, whichever the rays
// allow.
static inline XI_INLINE void xi_packet_query(__global const BvhNode8* nodes, __global const TriBlock* blocks,
                                             const Packet* p, PacketFloat tmax, bool any_hit, PacketFloat* t,
                                             PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  if (p->coherent)
    xi_packet_traverse(nodes, blocks, p, true, any_hit, tmax, t, u, v, tri);
  else
    xi_packet_traverse(nodes, blocks, p, false, any_hit, tmax, t, u, v, tri);
}

// Closest hits of the rays o[k], d[k] in (0, ∞): sets *t, *u, *v and *tri per lane as xi_trace would
// (tri XI_NO_HIT for a miss).
static inline void xi_trace_packet(__global const BvhNode8* nodes, __global const TriBlock* blocks, const float4* o,
                                   const float4* d, PacketFloat* t, PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  PacketFloat unused;
  const Packet p = xi_packet_of_rows(o, d, &unused);
  xi_packet_query(nodes, blocks, &p, (PacketFloat)INFINITY, false, t, u, v, tri);
}

// The rays o[k], d[k] (o[k].w: tmax) that hit something before their tmax, as bits (lane k: bit k),
// each as xi_trace's any-hit query finds.
static inline uint xi_occluded_packet(__global const BvhNode8* nodes, __global const TriBlock* blocks, const float4* o,
                                      const float4* d) {
  PacketFloat tmax, t, u, v;
  PacketUint tri;
  const Packet p = xi_packet_of_rows(o, d, &tmax);
  xi_packet_query(nodes, blocks, &p, tmax, true, &t, &u, &v, &tri);
  return xi_packet_bits(tri != (PacketUint)XI_NO_HIT);
}

// --- hybrid packets ----------------------------------------------------------------------------
// Rays that leave the surfaces neighbouring pixels' camera rays hit (bounce 0's shadow rays, bounce
// 1's rays) enter the same boxes near the top of a large tree, and part ways below it. A hybrid packet goes through
// the tree together while more than XI_HYBRID_ALONE of its rays enter a box, each stack entry
// carrying the rays that enter it, and below a box that few enter, each of them goes on alone
// from there (xi_trace_from), as Embree's hybrid traversal does. Each ray's hit is the one xi_trace
// finds (the same tests per ray; ties aside, as for packets).

// How few rays entering a box make them go on alone.
#define XI_HYBRID_ALONE 4

// Lane k holds bit k.
#if XI_PACKET_WIDTH == 16
#define XI_PACKET_LANE_BIT (PacketInt)(1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768)
#else
#define XI_PACKET_LANE_BIT (PacketInt)(1, 2, 4, 8, 16, 32, 64, 128)
#endif

// v where `rays` has a lane's bit, else `other`.
static inline XI_INLINE PacketFloat xi_packet_where(uint rays, PacketFloat v, float other) {
  return select((PacketFloat)other, v, (XI_PACKET_LANE_BIT & (PacketInt)(int)rays) != 0);
}

// The hybrid traversal of rays o[k], d[k] (lane k; the packet p made of them): closest hits before
// tmax, or with any_hit, for each ray whether there is a hit before its tmax. A ray whose any-hit
// query is answered leaves the packet (its best becomes -∞: it enters no box, hits nothing). Rays
// that leave a surface in all directions seldom share their signs, so the callers take the per-ray
// path (coherent false) alone, one copy of the code.
static inline XI_INLINE void xi_hybrid_traverse(__global const BvhNode8* nodes, __global const TriBlock* blocks,
                                                const Packet* p, bool coherent, bool any_hit, const float4* o,
                                                const float4* d, PacketFloat tmax, PacketFloat* t, PacketFloat* u,
                                                PacketFloat* v, PacketUint* tri) {
  uint4 stack[XI_BVH_STACK];  // (entry, the rays that enter it, as bits, the nearest distance one does)
  uint sp = 0u, entry = 0u, rays = XI_PACKET_ALL;
  PacketFloat best = tmax, best_u = 0.0f, best_v = 0.0f;
  PacketUint found = (PacketUint)XI_NO_HIT;
  for (;;) {
    if (any_hit) rays &= xi_packet_bits(best != (PacketFloat)(-INFINITY));  // those not answered yet
    const PacketFloat entering_best = xi_packet_where(rays, best, -INFINITY);  // the others' boxes are missed
    if (popcount(rays) <= XI_HYBRID_ALONE) {
      for (uint left = rays; left != 0u; left &= left - 1u) {
        const uint l = 31 - clz(left & (0u - left));
        const PacketInt lane = XI_PACKET_LANE_BIT == (PacketInt)(int)(1u << l);
        float lt, lu, lv;
        const uint hit = xi_trace_from(nodes, blocks, entry, o[l].xyz, d[l].xyz, XI_PACKET_LANE(float, best, l),
                                       any_hit, &lt, &lu, &lv);
        if (hit == XI_NO_HIT) continue;
        found = select(found, (PacketUint)hit, lane);
        best = select(best, (PacketFloat)(any_hit ? -INFINITY : lt), lane);
        best_u = select(best_u, (PacketFloat)lu, lane);
        best_v = select(best_v, (PacketFloat)lv, lane);
      }
    } else if (entry & XI_BVH_LEAF) {
      xi_packet_leaf(blocks, entry, p, coherent, any_hit, entering_best, &best, &best_u, &best_v, &found);
    } else {  // each child with the rays that enter it, the nearest on top
      __global const BvhNode8* n = nodes + entry;
      const uint base = sp;
      for (uint k = 0u; k < 8u; ++k) {
        PacketFloat tn;
        const PacketInt enter = xi_packet_entering(p, coherent, n, k, entering_best, &tn);
        const uint bits = xi_packet_bits(enter);
        if (bits == 0u) continue;
        const float t_enter = xi_packet_min(select((PacketFloat)INFINITY, tn, enter));
        uint j = sp++;
        for (; !any_hit && j > base && as_float(stack[j - 1u].z) < t_enter; --j) stack[j] = stack[j - 1u];
        stack[j] = (uint4)(n->child[k], bits, as_uint(t_enter), 0u);
      }
    }
    // The nearest entry that one of its rays enters before that ray's best hit so far.
    do {
      if (sp == 0u) {
        *t = best, *u = best_u, *v = best_v, *tri = found;
        return;
      }
      --sp;
    } while (!(as_float(stack[sp].z) <= xi_packet_max(xi_packet_where(stack[sp].y, best, -INFINITY)) * XI_BOX_SLACK));
    entry = stack[sp].x, rays = stack[sp].y;
  }
}

// Closest hits of the rays o[k], d[k] in (0, ∞), as xi_trace_packet's.
static inline void xi_trace_hybrid(__global const BvhNode8* nodes, __global const TriBlock* blocks, const float4* o,
                                   const float4* d, PacketFloat* t, PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  PacketFloat unused;
  const Packet p = xi_packet_of_rows(o, d, &unused);
  xi_hybrid_traverse(nodes, blocks, &p, false, false, o, d, (PacketFloat)INFINITY, t, u, v, tri);
}

// The rays o[k], d[k] (o[k].w: tmax) that hit something before their tmax, as bits, as
// xi_occluded_packet's.
static inline uint xi_occluded_hybrid(__global const BvhNode8* nodes, __global const TriBlock* blocks, const float4* o,
                                      const float4* d) {
  PacketFloat tmax, t, u, v;
  PacketUint tri;
  const Packet p = xi_packet_of_rows(o, d, &tmax);
  xi_hybrid_traverse(nodes, blocks, &p, false, true, o, d, tmax, &t, &u, &v, &tri);
  return xi_packet_bits(tri != (PacketUint)XI_NO_HIT);
}

#pragma OPENCL FP_CONTRACT DEFAULT

#endif

#endif
