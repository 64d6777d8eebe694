// A triangle of the scene's indexed mesh as the shading stages read it: its vertices' indices
// (tri_vertices, in BVH order) and their positions (vertices). Written on lane types (lanes.h).
#ifndef XI_MESH_H
#define XI_MESH_H
#include "lanes.h"

typedef struct {
  xuint v0, v1, v2;        // the corners' indices into vertices and vertex_normals
  xmask smooth;            // shaded with its vertex normals
  xfloat3 p0, p1, p2;      // the corners' positions
} TriangleCorners;

static inline XI_INLINE TriangleCorners xi_triangle_corners(__global const uint4* tri_vertices,
                                                           __global const float4* vertices, xuint tri) {
  TriangleCorners c;
  xuint has_normals;
  xi_gather_uint4(tri_vertices, tri, &c.v0, &c.v1, &c.v2, &has_normals);
  c.smooth = has_normals != 0u;
  c.p0 = xi_gather_xyz(vertices, c.v0, 0);
  c.p1 = xi_gather_xyz(vertices, c.v1, 0);
  c.p2 = xi_gather_xyz(vertices, c.v2, 0);
  return c;
}

#endif
