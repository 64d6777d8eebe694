// Rays in packets through an 8-wide tree: the extend kernel's camera rays, and in a small tree its
// bounce rays and the shadow kernel's rays too (layout.h's XI_EXTEND_PACKET and XI_SHADOW_PACKET).
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

// Whether any ray enters child k of node n before its best hit, each by xi_trace's slab test; if
// so, *t_enter is the nearest distance at which one does.
static inline XI_INLINE bool xi_packet_enters(const Packet* p, bool coherent, __global const BvhNode8* n, uint k,
                                              PacketFloat best, float* t_enter) {
  PacketFloat nx, fx, ny, fy, nz, fz;
  xi_packet_slab(n, k, 0, p->back_x, p->near_x, coherent, &nx, &fx);
  xi_packet_slab(n, k, 2, p->back_y, p->near_y, coherent, &ny, &fy);
  xi_packet_slab(n, k, 4, p->back_z, p->near_z, coherent, &nz, &fz);
  const PacketFloat tn = xi_max(xi_max((nx - p->ox) * p->inv_x, (ny - p->oy) * p->inv_y),
                                xi_max((nz - p->oz) * p->inv_z, (PacketFloat)0.0f));
  const PacketFloat tf =
      xi_min(xi_min((fx - p->ox) * p->inv_x, (fy - p->oy) * p->inv_y), xi_min((fz - p->oz) * p->inv_z, best));
  const PacketInt enter = xi_less_equal(tn, tf * XI_BOX_SLACK);
  if (xi_packet_bits(enter) == 0u) return false;
  *t_enter = xi_packet_min(select((PacketFloat)INFINITY, tn, enter));
  return true;
}

// The traversal of one packet, as xi_trace's of one ray: closest hits, or with any_hit, for each ray
// whether there is a hit before its tmax. Called with `coherent` and `any_hit` constants
// (xi_packet_query), so each of the four cases compiles to its own loop, neither tested inside it.
static inline XI_INLINE void xi_packet_traverse(__global const BvhNode8* nodes, __global const TriBlock* blocks,
                                                const Packet* p, bool coherent, bool any_hit, PacketFloat tmax,
                                                PacketFloat* t, PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  uint2 stack[XI_BVH_STACK];  // distances: the nearest at which one of the rays enters the entry
  uint sp = 0u, entry = 0u;
  PacketFloat best = tmax, best_u = 0.0f, best_v = 0.0f;
  PacketUint found = (PacketUint)XI_NO_HIT;
  for (;;) {
    if (entry & XI_BVH_LEAF) {
      const uint end = xi_leaf_end(entry);
      for (uint k = xi_leaf_first(entry); k < end; ++k) {
        for (uint j = 0u; j < 4u && blocks[k].tri[j] != XI_NO_HIT; ++j) {  // unused lanes come last
          PacketFloat tt, uu, vv;
          const PacketInt hit = xi_intersect_packet(&p->shear, coherent, blocks + k, j, best, &tt, &uu, &vv);
          if (xi_packet_bits(hit) == 0u) continue;
          found = select(found, (PacketUint)blocks[k].tri[j], hit);
          if (any_hit) {  // a ray that is done enters no box and hits no triangle again
            best = select(best, (PacketFloat)(-INFINITY), hit);
            if (xi_packet_bits(found != (PacketUint)XI_NO_HIT) == XI_PACKET_ALL) {
              *tri = found;
              return;
            }
          } else {
            best = select(best, tt, hit);
            best_u = select(best_u, uu, hit);
            best_v = select(best_v, vv, hit);
          }
        }
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
      const uint base = sp;
      for (uint k = 0u; k < 8u; ++k)
        if (hits & (1u << k)) xi_push(stack, &sp, base, n->child[k], t_enter[k], any_hit);
    }
    // The nearest entry that some ray enters before its best hit so far.
    if (!xi_pop(stack, &sp, xi_packet_max(best) * XI_BOX_SLACK, &entry)) {
      *t = best, *u = best_u, *v = best_v, *tri = found;
      return;
    }
  }
}

// A packet's rays (origins o, unit directions d, lane k = ray k) as xi_trace takes one: the coherent or
// the per-ray traversal, whichever the rays allow.
static inline XI_INLINE void xi_packet_query(__global const BvhNode8* nodes, __global const TriBlock* blocks,
                                             PacketFloat ox, PacketFloat oy, PacketFloat oz, PacketFloat dx,
                                             PacketFloat dy, PacketFloat dz, PacketFloat tmax, bool any_hit,
                                             PacketFloat* t, PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  const Packet p = xi_packet(ox, oy, oz, dx, dy, dz);
  if (p.coherent)
    xi_packet_traverse(nodes, blocks, &p, true, any_hit, tmax, t, u, v, tri);
  else
    xi_packet_traverse(nodes, blocks, &p, false, any_hit, tmax, t, u, v, tri);
}

// Closest hits of a packet's rays in (0, ∞): sets *t, *u, *v and *tri per lane as xi_trace would (tri
// XI_NO_HIT for a miss).
static inline void xi_trace_packet(__global const BvhNode8* nodes, __global const TriBlock* blocks, PacketFloat ox,
                                   PacketFloat oy, PacketFloat oz, PacketFloat dx, PacketFloat dy, PacketFloat dz,
                                   PacketFloat* t, PacketFloat* u, PacketFloat* v, PacketUint* tri) {
  xi_packet_query(nodes, blocks, ox, oy, oz, dx, dy, dz, (PacketFloat)INFINITY, false, t, u, v, tri);
}

// The rays of a packet (tmax per ray) that hit something before their tmax, as bits (lane k: bit k),
// each as xi_trace's any-hit query finds.
static inline uint xi_occluded_packet(__global const BvhNode8* nodes, __global const TriBlock* blocks, PacketFloat ox,
                                      PacketFloat oy, PacketFloat oz, PacketFloat dx, PacketFloat dy, PacketFloat dz,
                                      PacketFloat tmax) {
  PacketFloat t, u, v;
  PacketUint tri;
  xi_packet_query(nodes, blocks, ox, oy, oz, dx, dy, dz, tmax, true, &t, &u, &v, &tri);
  return xi_packet_bits(tri != (PacketUint)XI_NO_HIT);
}

#pragma OPENCL FP_CONTRACT DEFAULT

#endif

#endif
