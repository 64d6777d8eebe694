// A triangle of the scene's indexed mesh as the shading stages read it: its vertices' indices
// (tri_vertices, in BVH order), their positions and their normals (vertices, XI_VERTEX_FLOAT4S
// each: layout.h). Written on lane types (lanes.h).
#ifndef XI_MESH_H
#define XI_MESH_H
#include "lanes.h"

typedef struct {
  xuint v0, v1, v2;        // the corners' vertex indices
  xmask smooth;            // shaded with its vertex normals
  xfloat3 p0, p1, p2;      // the corners' positions
} TriangleCorners;

static inline XI_INLINE xfloat3 xi_vertex_position(__global const float4* vertices, xuint v) {
  return xi_gather_xyz(vertices, XI_VERTEX_FLOAT4S * v, 0);
}
static inline XI_INLINE xfloat3 xi_vertex_normal(__global const float4* vertices, xuint v) {
  return xi_gather_xyz(vertices, XI_VERTEX_FLOAT4S * v + 1u, 0);
}

static inline XI_INLINE TriangleCorners xi_triangle_corners(__global const uint4* tri_vertices,
                                                           __global const float4* vertices, xuint tri) {
  TriangleCorners c;
  xuint has_normals;
  xi_gather_uint4(tri_vertices, tri, &c.v0, &c.v1, &c.v2, &has_normals);
  c.smooth = has_normals != 0u;
  c.p0 = xi_vertex_position(vertices, c.v0);
  c.p1 = xi_vertex_position(vertices, c.v1);
  c.p2 = xi_vertex_position(vertices, c.v2);
  return c;
}

#endif
