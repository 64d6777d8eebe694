// Warps of the unit square [0,1)² to the domains the renderer samples, each with its pdf (with
// respect to area on the disc/triangle, solid angle on the sphere) and, where one exists, its
// inverse. Inputs at 0 and at the largest float below 1 give finite results. The maps that shade
// uses are written on lane types (lanes.h); the others, for the tools and tests, are compiled only
// where XI_LANES is 1.
#ifndef XI_WARPS_H
#define XI_WARPS_H
#include "lanes.h"

#if XI_LANES == 1
// The angle of (x, y) in [0, 1) turns.
static inline float xi_turns(float y, float x) {
  float t = atan2(y, x) * (0.5f * XI_INV_PI);
  // A tiny negative angle would round t + 1 up to exactly 1.
  return fmin(t < 0.0f ? t + 1.0f : t, XI_ONE_MINUS_EPSILON);
}

// --- Uniform sphere: z = 1 − 2ξ₁, φ = 2πξ₂.
static inline float3 xi_square_to_sphere(float2 u) {
  float z = 1.0f - 2.0f * u.x;
  float r = xi_safe_sqrt(1.0f - z * z);
  float phi = 2.0f * XI_PI * u.y;
  return make_float3(r * cos(phi), r * sin(phi), z);
}
static inline float xi_sphere_pdf(void) { return 0.25f * XI_INV_PI; }
static inline float2 xi_sphere_to_square(float3 d) {
  return make_float2(clamp(0.5f * (1.0f - d.z), 0.0f, XI_ONE_MINUS_EPSILON), xi_turns(d.y, d.x));
}

// --- Uniform hemisphere about +z: z = ξ₁, φ = 2πξ₂.
static inline float3 xi_square_to_hemisphere(float2 u) {
  float z = u.x;
  float r = xi_safe_sqrt(1.0f - z * z);
  float phi = 2.0f * XI_PI * u.y;
  return make_float3(r * cos(phi), r * sin(phi), z);
}
static inline float xi_hemisphere_pdf(float3 d) { return d.z >= 0.0f ? 0.5f * XI_INV_PI : 0.0f; }
static inline float2 xi_hemisphere_to_square(float3 d) {
  return make_float2(clamp(d.z, 0.0f, XI_ONE_MINUS_EPSILON), xi_turns(d.y, d.x));
}

// --- Uniform disc, polar: r = √ξ₁, θ = 2πξ₂ (the square root undoes the clustering at the centre).
static inline float2 xi_square_to_disc(float2 u) {
  float r = sqrt(u.x);
  float theta = 2.0f * XI_PI * u.y;
  return make_float2(r * cos(theta), r * sin(theta));
}
static inline float xi_disc_pdf(float2 p) { return p.x * p.x + p.y * p.y <= 1.0f ? XI_INV_PI : 0.0f; }
static inline float2 xi_disc_to_square(float2 p) {
  return make_float2(clamp(p.x * p.x + p.y * p.y, 0.0f, XI_ONE_MINUS_EPSILON), xi_turns(p.y, p.x));
}

// The lecture's "why not r = ξ₁": not uniform (density 1/(2πr)). Kept only so the χ² test can
// show that it catches a wrong warp against the uniform pdf.
static inline float2 xi_square_to_disc_naive(float2 u) {
  float theta = 2.0f * XI_PI * u.y;
  return make_float2(u.x * cos(theta), u.x * sin(theta));
}
#endif

// cos(πx) and sin(πx) for |x| ≤ 1/4, by their Taylor series: the first terms left out are below
// 2e-9 there. A few multiply-adds, where the library's cospi and sinpi reduce any argument, which
// costs far more.
static inline xfloat xi_cospi_quarter(xfloat x) {
  xfloat y = XI_PI * x, y2 = y * y;
  return 1.0f + y2 * (-1.0f / 2.0f + y2 * (1.0f / 24.0f + y2 * (-1.0f / 720.0f +
                y2 * (1.0f / 40320.0f + y2 * (-1.0f / 3628800.0f)))));
}
static inline xfloat xi_sinpi_quarter(xfloat x) {
  xfloat y = XI_PI * x, y2 = y * y;
  return y * (1.0f + y2 * (-1.0f / 6.0f + y2 * (1.0f / 120.0f + y2 * (-1.0f / 5040.0f + y2 * (1.0f / 362880.0f)))));
}

// --- Concentric disc (Shirley–Chiu): squares of the domain map to rings, keeping strata compact.
// The angle is π/4 · b/a in the right and left wedges (radius a) and π/2 − π/4 · a/b in the top
// and bottom ones (radius b), where cos and sin swap, so both need only |x| ≤ 1/4 half-turns.
static inline xfloat2 xi_square_to_concentric_disc(xfloat2 u) {
  xfloat a = 2.0f * u.x - 1.0f, b = 2.0f * u.y - 1.0f;
  xmask wide = fabs(a) > fabs(b);  // the right or left wedge
  xfloat r = wide ? a : b;
  xfloat x = 0.25f * (wide ? b / a : a / b);  // 0/0 only at the centre, which is set apart
  xfloat c = xi_cospi_quarter(x), s = xi_sinpi_quarter(x);
  xmask centre = a == 0.0f && b == 0.0f;
  return make_xfloat2(centre ? (xfloat)0.0f : r * (wide ? c : s), centre ? (xfloat)0.0f : r * (wide ? s : c));
}
#if XI_LANES == 1
static inline float2 xi_concentric_disc_to_square(float2 p) {
  float r = sqrt(p.x * p.x + p.y * p.y);
  float theta = atan2(p.y, p.x);  // (−π, π]
  if (theta < -0.25f * XI_PI) theta += 2.0f * XI_PI;  // now in [−π/4, 7π/4)
  float a, b;
  if (theta < 0.25f * XI_PI) {          // right wedge: r = a
    a = r;
    b = theta * 4.0f * XI_INV_PI * r;
  } else if (theta < 0.75f * XI_PI) {   // top wedge: r = b
    b = r;
    a = -(theta - 0.5f * XI_PI) * 4.0f * XI_INV_PI * r;
  } else if (theta < 1.25f * XI_PI) {   // left wedge: r = −a
    a = -r;
    b = (theta - XI_PI) * 4.0f * XI_INV_PI * a;
  } else {                              // bottom wedge: r = −b
    b = -r;
    a = -(theta - 1.5f * XI_PI) * 4.0f * XI_INV_PI * b;
  }
  return make_float2(clamp(0.5f * (a + 1.0f), 0.0f, XI_ONE_MINUS_EPSILON),
                     clamp(0.5f * (b + 1.0f), 0.0f, XI_ONE_MINUS_EPSILON));
}
#endif

// --- Cosine-weighted hemisphere by Malley's method: a uniform disc sample projected up to the
// hemisphere, z = √(1 − x² − y²). pdf = cos θ / π.
static inline xfloat3 xi_square_to_cosine_hemisphere(xfloat2 u) {
  xfloat2 d = xi_square_to_concentric_disc(u);
  return make_xfloat3(d.x, d.y, xi_safe_sqrt(1.0f - d.x * d.x - d.y * d.y));
}
static inline xfloat xi_cosine_hemisphere_pdf(xfloat3 d) { return fmax(d.z, (xfloat)0.0f) * XI_INV_PI; }
#if XI_LANES == 1
static inline float2 xi_cosine_hemisphere_to_square(float3 d) {
  return xi_concentric_disc_to_square(make_float2(d.x, d.y));
}
#endif

// --- Uniform triangle: barycentrics (b0, b1) with b0 = 1 − √ξ₁, b1 = ξ₂√ξ₁; pdf 1 / area.
static inline xfloat2 xi_square_to_triangle(xfloat2 u) {
  xfloat su = sqrt(u.x);
  return make_xfloat2(1.0f - su, u.y * su);
}
#if XI_LANES == 1
static inline float2 xi_triangle_to_square(float2 b) {
  float su = 1.0f - b.x;
  return make_float2(clamp(su * su, 0.0f, XI_ONE_MINUS_EPSILON),
                     su > 0.0f ? clamp(b.y / su, 0.0f, XI_ONE_MINUS_EPSILON) : 0.0f);
}

// Every warp by number, for tools and tests (`xi warp`, the χ² tests): 2D maps return z = 0.
#define XI_MAP_SQUARE 0
#define XI_MAP_SPHERE 1
#define XI_MAP_HEMISPHERE 2
#define XI_MAP_COSINE_HEMISPHERE 3
#define XI_MAP_DISC 4
#define XI_MAP_CONCENTRIC_DISC 5
#define XI_MAP_TRIANGLE 6
#define XI_MAP_DISC_NAIVE 7  // the lecture's wrong r = ξ₁, for the test that the χ² test can fail

static inline float3 xi_warp(int map, float2 u) {
  float2 d;
  switch (map) {
    case XI_MAP_SPHERE: return xi_square_to_sphere(u);
    case XI_MAP_HEMISPHERE: return xi_square_to_hemisphere(u);
    case XI_MAP_COSINE_HEMISPHERE: return xi_square_to_cosine_hemisphere(u);
    case XI_MAP_DISC: d = xi_square_to_disc(u); break;
    case XI_MAP_CONCENTRIC_DISC: d = xi_square_to_concentric_disc(u); break;
    case XI_MAP_TRIANGLE: d = xi_square_to_triangle(u); break;
    case XI_MAP_DISC_NAIVE: d = xi_square_to_disc_naive(u); break;
    default: d = u; break;
  }
  return make_float3(d.x, d.y, 0.0f);
}

// The density of xi_warp(map, ·) at p, with respect to area (2D maps; the triangle map returns
// barycentrics, a point of the half unit square) or solid angle (sphere and hemispheres). The naive
// disc deliberately claims the uniform disc's pdf.
static inline float xi_warp_pdf(int map, float3 p) {
  switch (map) {
    case XI_MAP_SPHERE: return xi_sphere_pdf();
    case XI_MAP_HEMISPHERE: return xi_hemisphere_pdf(p);
    case XI_MAP_COSINE_HEMISPHERE: return xi_cosine_hemisphere_pdf(p);
    case XI_MAP_DISC:
    case XI_MAP_CONCENTRIC_DISC:
    case XI_MAP_DISC_NAIVE: return xi_disc_pdf(make_float2(p.x, p.y));
    case XI_MAP_TRIANGLE: return p.x >= 0.0f && p.y >= 0.0f && p.x + p.y <= 1.0f ? 2.0f : 0.0f;
    default: return p.x >= 0.0f && p.x < 1.0f && p.y >= 0.0f && p.y < 1.0f ? 1.0f : 0.0f;
  }
}

#endif

// An orthonormal basis around a unit normal (Duff et al. 2017, branchless).
static inline void xi_basis(xfloat3 n, xfloat3* t, xfloat3* b) {
  xfloat s = n.z >= 0.0f ? (xfloat)1.0f : (xfloat)-1.0f;
  xfloat a = -1.0f / (s + n.z);
  xfloat c = n.x * n.y * a;
  *t = make_xfloat3(1.0f + s * n.x * n.x * a, s * c, -s * n.x);
  *b = make_xfloat3(c, s + n.y * n.y * a, -n.y);
}
static inline xfloat3 xi_to_world(xfloat3 v, xfloat3 n) {
  xfloat3 t, b;
  xi_basis(n, &t, &b);
  return xi_add3(xi_add3(xi_scale3(t, v.x), xi_scale3(b, v.y)), xi_scale3(n, v.z));
}

#endif
