// The environment light: an equirectangular (latitude-longitude) image of radiance at infinity,
// looked up bilinearly and importance-sampled by a piecewise-constant 2D distribution over its
// texel cells. Written on lane types (lanes.h): the same code runs on the host (its tests) and in
// the kernels, 1 or 8 paths at a time.
//
// Orientation: Mitsuba 3's envmap emitter (src/emitters/envmap.cpp, uv_to_direction and
// direction_to_uv). In the map's own frame, with +y up,
//   u = atan2(d.x, −d.z) / 2π, wrapped to [0, 1),   v = acos(d.y) / π,
//   d(u, v) = (sin φ sin θ, cos θ, −cos φ sin θ),    φ = 2πu, θ = πv.
// u grows with the image column (column 0 at u = 0 looks along −z, u = 1/4 along +x, u = 1/2
// along +z, u = 3/4 along −x) and v with the row: row 0 is the top of the image, +y (the zenith),
// the last row the nadir. Texel (x, y) covers the cell [x/W, (x+1)/W) × [y/H, (y+1)/H) of (u, v)
// with its value at the cell's centre; the bilinear lookup wraps around in u and clamps in v. (In
// v Mitsuba puts rows 0 and H−1 on the poles themselves; here, as in u, at the cells' centres.)
//
// World ↔ map frame: EnvironmentData.to_local holds the rows of the rotation R⁻¹ taking world
// directions to the map's frame; the host builds R as a rotation about the world's +y by the
// user's angle, the same as Mitsuba's `to_world` rotate(y, angle): positive angles turn +z toward
// +x (the map's centre column, +z, is seen along +x after +90°).
//
// Sampling distribution (host: build_environment_distribution in environment.cpp), one float
// buffer `cdf`:
//   cdf[y]                  for y < H: the marginal CDF over rows, P(row ≤ y);
//   cdf[H + y·W + x]        for x < W: row y's conditional CDF over columns, P(column ≤ x | row y);
//   then, from G = XI_ENV_GUIDE_OFFSET(W, H) on, guide tables of float4 entries, one per CDF entry
//   in the same order (the CDF starting at cdf[b] has its guide table at float4 G/4 + b): for a
//   CDF of n entries, guide entry k = (cdf[i − 1], cdf[i], cdf[i + 1], i) for the first i whose
//   CDF value exceeds k / n (cdf[−1] read as 0, cdf[n] as cdf[n − 1]). A search for u reads entry
//   ⌊u n⌋ and is then done but where more than two CDF entries fall in one step of k / n: one
//   load where a binary search took log2 n dependent loads, and a plain guide table (the index
//   alone) three or more.
// Each CDF ends at exactly 1. A cell's probability is the product of the differences of
// consecutive entries (the entry before the first counts as 0), so sampling and pdf read the very
// same numbers and agree whatever the rounding. The density is constant in (u, v) over a cell:
// p_cell·W·H, and in solid angle (dω = 2π² sin θ du dv) p_cell·W·H / (2π² sin θ).
// A cell's weight is the luminance (Rec. 709: 0.2126, 0.7152, 0.0722) of the brightest of its
// texel and the texel's 8 neighbours, times sin θ at the cell's centre. The bilinear lookup
// anywhere in a cell mixes only texels of that 3×3 neighbourhood, so wherever the radiance is not
// zero the pdf is not zero either, and the estimator is unbiased. The host also keeps every
// nonzero weight at no less than 2^-20 of its CDF's total, so that no such cell rounds to a zero
// probability in float. A map that is black everywhere has no distribution (empty cdf) and the
// host gives it pick probability 0: then neither xi_env_sample nor xi_env_pdf may be called.
#ifndef XI_ENVIRONMENT_H
#define XI_ENVIRONMENT_H
#include "lanes.h"
#include "layout.h"

// float → uint of values already clamped to [0, 2^24) (rounds toward zero).
#if XI_LANES == 16
#define xi_env_to_uint(v) convert_uint16_sat_rtz(v)
#elif XI_LANES == 8
#define xi_env_to_uint(v) convert_uint8_sat_rtz(v)
#elif defined(XI_DEVICE)
#define xi_env_to_uint(v) convert_uint_sat_rtz(v)
#else
#define xi_env_to_uint(v) ((uint)(v))
#endif

#define XI_ENV_INV_2PI2 0.05066059182116888572f  // 1 / (2π²)

// World direction → the map's frame (rows of to_local), and back (its transpose).
static inline xfloat3 xi_env_to_local(EnvironmentData env, xfloat3 d) {
  return make_xfloat3(env.to_local[0].x * d.x + env.to_local[0].y * d.y + env.to_local[0].z * d.z,
                      env.to_local[1].x * d.x + env.to_local[1].y * d.y + env.to_local[1].z * d.z,
                      env.to_local[2].x * d.x + env.to_local[2].y * d.y + env.to_local[2].z * d.z);
}
static inline xfloat3 xi_env_to_world(EnvironmentData env, xfloat3 l) {
  return make_xfloat3(env.to_local[0].x * l.x + env.to_local[1].x * l.y + env.to_local[2].x * l.z,
                      env.to_local[0].y * l.x + env.to_local[1].y * l.y + env.to_local[2].y * l.z,
                      env.to_local[0].z * l.x + env.to_local[1].z * l.y + env.to_local[2].z * l.z);
}

// A unit direction in the map's frame → (u, v) in [0, 1)², Mitsuba's direction_to_uv.
static inline xfloat2 xi_env_direction_to_uv(xfloat3 d) {
  xfloat u = atan2(d.x, -d.z) * (0.5f * XI_INV_PI);
  u = u < 0.0f ? u + 1.0f : u;  // (−½, ½] turns → [0, 1)
  u = fmin(u, (xfloat)XI_ONE_MINUS_EPSILON);  // a tiny negative angle rounds up to 1
  xfloat v = acos(clamp(d.y, -1.0f, 1.0f)) * XI_INV_PI;
  return make_xfloat2(u, fmin(v, (xfloat)XI_ONE_MINUS_EPSILON));
}
// (u, v) → unit direction in the map's frame, Mitsuba's uv_to_direction; *sin_theta = sin(πv) ≥ 0.
static inline xfloat3 xi_env_uv_to_direction(xfloat2 uv, xfloat* sin_theta) {
  xfloat phi = (2.0f * XI_PI) * uv.x, theta = XI_PI * uv.y;
  xfloat st = sin(theta);
  *sin_theta = fmax(st, (xfloat)0.0f);
  return make_xfloat3(sin(phi) * st, cos(theta), -cos(phi) * st);
}

// Bilinear lookup of the texels (RGB of float4, row-major, top row first) at (u, v), times the
// strength. Wraps around in u, clamps in v; indices stay in the image whatever u and v (NaN too).
static inline xfloat3 xi_env_lookup(__global const float4* texels, EnvironmentData env, xfloat u, xfloat v) {
  float wf = (float)env.width, hf = (float)env.height;
  xfloat s = u * wf - 0.5f, t = v * hf - 0.5f;
  xfloat s0 = floor(s), t0 = floor(t);
  xfloat fx = s - s0, fy = t - t0;
  xfloat x0 = s0 < 0.0f ? s0 + wf : s0;
  x0 = fmin(fmax(x0, (xfloat)0.0f), (xfloat)(wf - 1.0f));  // fmax: NaN → 0
  xfloat x1 = x0 + 1.0f;
  x1 = x1 >= wf ? x1 - wf : x1;
  xfloat y0 = fmin(fmax(t0, (xfloat)0.0f), (xfloat)(hf - 1.0f));
  xfloat y1 = fmin(fmax(t0 + 1.0f, (xfloat)0.0f), (xfloat)(hf - 1.0f));
  xuint i0 = xi_env_to_uint(y0) * env.width, i1 = xi_env_to_uint(y1) * env.width;
  xuint c0 = xi_env_to_uint(x0), c1 = xi_env_to_uint(x1);
  xfloat3 a = xi_add3(xi_scale3(xi_gather_xyz(texels, i0 + c0, 0), 1.0f - fx), xi_scale3(xi_gather_xyz(texels, i0 + c1, 0), fx));
  xfloat3 b = xi_add3(xi_scale3(xi_gather_xyz(texels, i1 + c0, 0), 1.0f - fx), xi_scale3(xi_gather_xyz(texels, i1 + c1, 0), fx));
  xfloat3 c = xi_add3(xi_scale3(a, 1.0f - fy), xi_scale3(b, fy));
  return xi_mul3(c, xi_splat3(xyz(env.scale)));
}

// The radiance arriving from world direction d (unit): the environment seen along d.
static inline xfloat3 xi_env_radiance(__global const float4* texels, EnvironmentData env, xfloat3 d) {
  xfloat2 uv = xi_env_direction_to_uv(xi_env_to_local(env, d));
  return xi_env_lookup(texels, env, uv.x, uv.y);
}

// The first entry above *u of the n-entry CDF at cdf[base..], found from its guide table, whose
// entries are float4 number `guide` on; *u is then stretched back to [0, 1) within that entry's
// interval and *p = the interval's length (> 0: the entry found lies above *u, the one before it
// not).
static inline xuint xi_env_search(__global const float* cdf, xuint base, xuint guide, uint n, xfloat* u, xfloat* p) {
  xuint k = convert_xuint(*u * (float)n);
  k = k >= n ? (xuint)(n - 1u) : k;
  xfloat at_f;
  xfloat3 entry = xi_gather_xyz((__global const float4*)cdf, guide + k, &at_f);
  xfloat below = entry.x, above = entry.y;
  xuint at = convert_xuint(at_f);
  // The entry after, held in the guide entry too.
  xmask second = above <= *u && at < n - 1u;
  at = second ? at + 1u : at;
  below = second ? above : below;
  above = second ? entry.z : above;
  // ⌊u n⌋ in float may round up by one: then the answer may lie before the entry.
  xmask back = below > *u;
  while (XI_ANY(back)) {
    at = back ? at - 1u : at;
    above = back ? below : above;
    xmask first = at == 0u;
    xfloat before = first ? (xfloat)0.0f : xi_gather_float(cdf, base + (first ? at : at - 1u));
    below = back ? before : below;
    back = back && below > *u;
  }
  // Where more than two entries fall in one step of k / n.
  xmask forward = above <= *u && at < n - 1u;
  while (XI_ANY(forward)) {
    at = forward ? at + 1u : at;
    xfloat next = xi_gather_float(cdf, base + at);
    below = forward ? above : below;
    above = forward ? next : above;
    forward = forward && above <= *u && at < n - 1u;
  }
  *p = above - below;
  *u = clamp((*u - below) / *p, 0.0f, XI_ONE_MINUS_EPSILON);
  return at;
}

// The probability of cell (x, y) from the CDF differences.
static inline xfloat xi_env_cell_probability(__global const float* cdf, EnvironmentData env, xuint x, xuint y) {
  xuint row = env.height + y * env.width;
  xmask y0 = y == 0u, x0 = x == 0u;
  xfloat py = xi_gather_float(cdf, y) - (y0 ? (xfloat)0.0f : xi_gather_float(cdf, y0 ? y : y - 1u));
  xfloat px = xi_gather_float(cdf, row + x) - (x0 ? (xfloat)0.0f : xi_gather_float(cdf, x0 ? row : row + x - 1u));
  return py * px;
}

// Samples a world direction from the map's distribution with u ∈ [0, 1)² (u.y picks the row, u.x
// the column, each then placed uniformly in (u, v) within the cell). *pdf: its solid-angle density
// under this distribution alone (0 at the poles, which have measure zero); the caller multiplies
// by the pick probability env.scale.w. *radiance: xi_env_radiance of the direction (strength
// included).
static inline xfloat3 xi_env_sample(__global const float4* texels, __global const float* cdf, EnvironmentData env,
                                    xfloat2 u, xfloat* pdf, xfloat3* radiance) {
  xfloat uy = u.y, ux = u.x, py, px;
  const uint guides = XI_ENV_GUIDE_OFFSET(env.width, env.height) / 4u;
  xuint y = xi_env_search(cdf, (xuint)0u, (xuint)guides, env.height, &uy, &py);
  xuint row = env.height + y * env.width;
  xuint x = xi_env_search(cdf, row, guides + row, env.width, &ux, &px);
  float wf = (float)env.width, hf = (float)env.height;
  xfloat mu = (xi_to_float(x) + ux) / wf, mv = (xi_to_float(y) + uy) / hf;
  mu = fmin(mu, (xfloat)XI_ONE_MINUS_EPSILON);
  mv = fmin(mv, (xfloat)XI_ONE_MINUS_EPSILON);
  xfloat sin_theta;
  xfloat3 dl = xi_env_uv_to_direction(make_xfloat2(mu, mv), &sin_theta);
  *pdf = sin_theta > 0.0f ? py * px * (wf * hf * XI_ENV_INV_2PI2) / sin_theta : (xfloat)0.0f;
  *radiance = xi_env_lookup(texels, env, mu, mv);
  return xi_env_to_world(env, dl);
}

// The solid-angle density with which xi_env_sample returns the world direction d (unit).
static inline xfloat xi_env_pdf(__global const float* cdf, EnvironmentData env, xfloat3 d) {
  xfloat3 l = xi_env_to_local(env, d);
  xfloat2 uv = xi_env_direction_to_uv(l);
  float wf = (float)env.width, hf = (float)env.height;
  xuint x = xi_env_to_uint(fmin(floor(uv.x * wf), (xfloat)(wf - 1.0f)));
  xuint y = xi_env_to_uint(fmin(floor(uv.y * hf), (xfloat)(hf - 1.0f)));
  xfloat sin_theta = sqrt(l.x * l.x + l.z * l.z);
  xfloat p = xi_env_cell_probability(cdf, env, x, y);
  return sin_theta > 0.0f ? p * (wf * hf * XI_ENV_INV_2PI2) / sin_theta : (xfloat)0.0f;
}

#endif
