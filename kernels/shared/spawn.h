// Spawning rays robustly at any scale (after Pharr, Jakob and Humphreys, Physically Based Rendering
// 4th ed., "Managing Rounding Error"): a hit point with a bound on its rounding error, and the
// origin of a ray leaving it, moved just past that bound. Written on lane types (lanes.h).
#ifndef XI_SPAWN_H
#define XI_SPAWN_H
#include "lanes.h"

// Each product rounded on its own, as the bound below assumes (as in triangle.h).
#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT OFF
#endif

// p0 + b1 (p1 - p0) + b2 (p2 - p0) lies exactly in the triangle's plane for any b1, b2, so only the
// rounding of this sum moves the computed point off the plane: at most gamma(1) |p| + gamma(4)
// (|b1 (p1 - p0)| + |b2 (p2 - p0)|) per axis (the edges' own rounding included). That is an ulp or
// so of the coordinates, against the gamma(7) |p| that the barycentric form b0 p0 + b1 p1 + b2 p2
// allows, so offsets stay small far from the origin.
static inline xfloat3 xi_interpolate(xfloat3 p0, xfloat3 p1, xfloat3 p2, xfloat b1, xfloat b2, xfloat3* error) {
  xfloat3 d1 = xi_scale3(xi_sub3(p1, p0), b1), d2 = xi_scale3(xi_sub3(p2, p0), b2);
  xfloat3 p = xi_add3(xi_add3(p0, d1), d2);
  *error = xi_add3(xi_scale3(xi_abs3(p), XI_GAMMA(1)), xi_scale3(xi_add3(xi_abs3(d1), xi_abs3(d2)), XI_GAMMA(4)));
  return p;
}

// nextafter(x, ±inf) by the sign of offset, for finite x: one step of the bit pattern, up in
// magnitude when offset points away from zero. (PoCL's nextafter is far slower.)
static inline xfloat xi_round_away(xfloat x, xfloat offset) {
  // Zero takes from_zero below; stepping its bits is never used, and −0's (INT_MIN) would overflow.
  xfloat nonzero = x == 0.0f ? (xfloat)1.0f : x;
  xfloat stepped = xi_as_float(xi_as_int(nonzero) + ((x > 0.0f) == (offset > 0.0f) ? (xint)1 : (xint)-1));
  xfloat from_zero = offset > 0.0f ? (xfloat)0x1p-149f : (xfloat)-0x1p-149f;
  return offset == 0.0f ? x : (x == 0.0f ? from_zero : stepped);
}

// Moves p (per-axis error bound `error`) off its surface along the geometric normal n, to the side
// of the direction w, just past the box the exact point may lie in, so a ray leaving it cannot hit
// that surface again; then one more ulp away, for the rounding of the sum.
static inline xfloat3 xi_offset_ray_origin(xfloat3 p, xfloat3 error, xfloat3 n, xfloat3 w) {
  xfloat d = xi_dot3(xi_abs3(n), error);
  xfloat3 offset = xi_scale3(n, xi_dot3(w, n) < 0.0f ? -d : d);
  xfloat3 o = xi_add3(p, offset);
  return make_xfloat3(xi_round_away(o.x, offset.x), xi_round_away(o.y, offset.y), xi_round_away(o.z, offset.z));
}

#ifdef __OPENCL_VERSION__
#pragma OPENCL FP_CONTRACT DEFAULT
#endif

#endif
