// The environment light: an equirectangular (latitude-longitude) image of radiance at infinity,
// looked up bilinearly and importance-sampled with a density proportional to the bilinear
// interpolation of its luminance × sin θ. Written on lane types (lanes.h): the same code runs on the host (its tests) and in
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
// Sampling density. The lookup is bilinear between texel centres, so the density follows it: in
// (u, v) it is the bilinear interpolation of the vertex weights Y·sin θ (Y the texel's luminance,
// Rec. 709: 0.2126, 0.7152, 0.0722; θ at the texel's centre) over the grid of texel centres, with a
// row of zero weights added at each pole (v = 0 and 1, where sin θ = 0). Its patches: W columns,
// patch x between the centres of texels x and x + 1 (wrapping in u), and H + 1 rows, row k between
// the centres of texel rows k − 1 and k (row 0 from the zenith to row 0's centres, row H from the last
// row's centres to the nadir: half as tall). Within a patch the lookup mixes exactly the texels of its
// corners (at the pole rows: of one row, constant in v), so the density is non-zero wherever the
// radiance is, and the estimator is unbiased; it follows the radiance as closely as a bilinear
// function of luminance can, where a piecewise-constant density over texel cells leaves the edges of
// a small bright source undersampled. (Mitsuba 3 warps such bilinear patches hierarchically; here a
// patch is chosen from a discrete distribution and the bilinear density inverted inside it.)
//
// The distribution's buffer `cdf` (host: build_environment_distribution in environment.cpp), with
// R = H + 1 patch rows:
//   cdf[k]                  for k < R: the marginal CDF over patch rows, P(row ≤ k);
//   cdf[R + k·W + x]        for x < W: patch row k's conditional CDF over columns, P(column ≤ x | k);
//   from G = XI_ENV_GUIDE_OFFSET(W, H) on, guide tables of float4 entries, one per CDF entry
//   in the same order (the CDF starting at cdf[b] has its guide table at float4 G/4 + b): for a
//   CDF of n entries, guide entry k = (cdf[i − 1], cdf[i], cdf[i + 1], i) for the first i whose
//   CDF value exceeds k / n (cdf[−1] read as 0, cdf[n] as cdf[n − 1]). A search for u reads entry
//   ⌊u n⌋ and is then done but where more than two CDF entries fall in one step of k / n: one
//   load where a binary search took log2 n dependent loads, and a plain guide table (the index
//   alone) three or more;
//   from XI_ENV_WEIGHT_OFFSET(W, H) on, the (H + 2) × W vertex weights, row r = 0 the zenith's zeros,
//   rows 1..H the texel rows, row H + 1 the nadir's zeros.
// Each CDF ends at exactly 1. A patch's probability is the product of the differences of
// consecutive entries (the entry before the first counts as 0), proportional to the integral of
// its bilinear weights; the host keeps every nonzero one at no less than 2^-20 of its CDF's total,
// so that no lit patch rounds to a zero probability in float. Within the patch the density is its
// bilinear weight over the mean of its four corners, and sampling and pdf read the very same numbers
// (xi_env_patch_density), so they agree whatever the rounding. In solid angle dω = 2π² sin θ du dv.
// A map that is black everywhere has no distribution (empty cdf) and the host gives it pick
// probability 0: then neither xi_env_sample nor xi_env_pdf may be called.
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

// The probability of patch (x, k) from the CDF differences.
static inline xfloat xi_env_patch_probability(__global const float* cdf, EnvironmentData env, xuint x, xuint k) {
  xuint row = env.height + 1u + k * env.width;
  xmask k0 = k == 0u, x0 = x == 0u;
  xfloat pk = xi_gather_float(cdf, k) - (k0 ? (xfloat)0.0f : xi_gather_float(cdf, k0 ? k : k - 1u));
  xfloat px = xi_gather_float(cdf, row + x) - (x0 ? (xfloat)0.0f : xi_gather_float(cdf, x0 ? row : row + x - 1u));
  return pk * px;
}

// The four corner weights of patch (x, k): *w00 and *w01 on its upper edge (columns x and x + 1),
// *w10 and *w11 on its lower one.
static inline void xi_env_patch_corners(__global const float* cdf, EnvironmentData env, xuint x, xuint k, xfloat* w00,
                                        xfloat* w01, xfloat* w10, xfloat* w11) {
  const uint weights = XI_ENV_WEIGHT_OFFSET(env.width, env.height);
  xuint x1 = x + 1u == env.width ? (xuint)0u : x + 1u;
  xuint upper = weights + k * env.width, lower = upper + env.width;
  *w00 = xi_gather_float(cdf, upper + x);
  *w01 = xi_gather_float(cdf, upper + x1);
  *w10 = xi_gather_float(cdf, lower + x);
  *w11 = xi_gather_float(cdf, lower + x1);
}

// Patch row k's extent in v: [*v0, *v0 + *dv] (the pole rows are half as tall).
static inline void xi_env_patch_rows(EnvironmentData env, xuint k, xfloat* v0, xfloat* dv) {
  float hf = (float)env.height;
  xfloat top = fmax((xi_to_float(k) - 0.5f) / hf, (xfloat)0.0f);
  xfloat bottom = fmin((xi_to_float(k) + 0.5f) / hf, (xfloat)1.0f);
  *v0 = top;
  *dv = bottom - top;
}

// x ∈ [0, 1) with density ∝ (1 − x)·a + x·b (a, b ≥ 0) from u ∈ [0, 1), the inverse of its CDF in
// the form that stays accurate when a and b are close; uniform where both are 0.
static inline xfloat xi_env_sample_linear(xfloat u, xfloat a, xfloat b) {
  xfloat root = a + sqrt((1.0f - u) * a * a + u * b * b);
  xfloat x = root > 0.0f ? u * (a + b) / root : u;
  return fmin(x, (xfloat)XI_ONE_MINUS_EPSILON);
}

// The solid-angle density at local coordinates (s, t) ∈ [0, 1)² of a patch of probability p, height
// dv and corner weights w.., whose direction has sin θ = sin_theta: p times the bilinear density,
// over the (u, v) area and the Jacobian 2π² sin θ. 0 at the poles (measure zero) and in unlit patches.
static inline xfloat xi_env_patch_density(EnvironmentData env, xfloat p, xfloat dv, xfloat w00, xfloat w01, xfloat w10,
                                          xfloat w11, xfloat s, xfloat t, xfloat sin_theta) {
  xfloat corners = w00 + w01 + w10 + w11;
  xfloat bilinear = (1.0f - t) * ((1.0f - s) * w00 + s * w01) + t * ((1.0f - s) * w10 + s * w11);
  xfloat area = dv / (float)env.width;
  xmask lit = corners > 0.0f && sin_theta > 0.0f;
  return lit ? p * (4.0f * bilinear / corners) / (area * (2.0f * XI_PI * XI_PI) * sin_theta) : (xfloat)0.0f;
}

// Samples a world direction from the map's distribution with u ∈ [0, 1)² (u.y picks the patch row,
// u.x the column, each then reused to invert the bilinear density within the patch: first in v, then
// in u given v). *pdf: its solid-angle density under this distribution alone, from the searches'
// interval lengths (the differences xi_env_patch_probability takes) and the corners read here; the
// caller multiplies by the pick probability env.scale.w. *radiance: xi_env_radiance of the direction
// (strength included).
static inline xfloat3 xi_env_sample(__global const float4* texels, __global const float* cdf, EnvironmentData env,
                                    xfloat2 u, xfloat* pdf, xfloat3* radiance) {
  xfloat uy = u.y, ux = u.x, pk, px;
  const uint rows = env.height + 1u;
  const uint guides = XI_ENV_GUIDE_OFFSET(env.width, env.height) / 4u;
  xuint k = xi_env_search(cdf, (xuint)0u, (xuint)guides, rows, &uy, &pk);
  xuint row = rows + k * env.width;
  xuint x = xi_env_search(cdf, row, guides + row, env.width, &ux, &px);
  xfloat w00, w01, w10, w11, v0, dv;
  xi_env_patch_corners(cdf, env, x, k, &w00, &w01, &w10, &w11);
  xi_env_patch_rows(env, k, &v0, &dv);
  xfloat t = xi_env_sample_linear(uy, w00 + w01, w10 + w11);
  xfloat s = xi_env_sample_linear(ux, (1.0f - t) * w00 + t * w10, (1.0f - t) * w01 + t * w11);
  float wf = (float)env.width;
  xfloat mu = (xi_to_float(x) + 0.5f + s) / wf;
  mu = mu >= 1.0f ? mu - 1.0f : mu;  // the last column's patch wraps around to u = 0
  mu = fmin(mu, (xfloat)XI_ONE_MINUS_EPSILON);
  xfloat mv = fmin(v0 + t * dv, (xfloat)XI_ONE_MINUS_EPSILON);
  xfloat sin_theta;
  xfloat3 dl = xi_env_uv_to_direction(make_xfloat2(mu, mv), &sin_theta);
  *pdf = xi_env_patch_density(env, pk * px, dv, w00, w01, w10, w11, s, t, sin_theta);
  *radiance = xi_env_lookup(texels, env, mu, mv);
  return xi_env_to_world(env, dl);
}

// The solid-angle density with which xi_env_sample returns the direction l of the map's frame
// (unit; uv = xi_env_direction_to_uv(l), which the caller may have for a lookup already).
static inline xfloat xi_env_pdf_local(__global const float* cdf, EnvironmentData env, xfloat3 l, xfloat2 uv) {
  float wf = (float)env.width, hf = (float)env.height;
  // The patch column: texel centres at s = 0, 1, ..., with u = 0 half a texel before the first.
  xfloat sx = uv.x * wf - 0.5f;
  sx = sx < 0.0f ? sx + wf : sx;
  xfloat fx = fmin(floor(sx), (xfloat)(wf - 1.0f));
  xuint x = xi_env_to_uint(fx);
  // The patch row: row k spans texel-row coordinates [k − ½, k + ½], clamped to the poles.
  xuint k = xi_env_to_uint(fmin(floor(uv.y * hf + 0.5f), (xfloat)hf));
  xfloat v0, dv;
  xi_env_patch_rows(env, k, &v0, &dv);
  xfloat s = clamp(sx - fx, 0.0f, 1.0f), t = clamp((uv.y - v0) / dv, 0.0f, 1.0f);
  xfloat w00, w01, w10, w11;
  xi_env_patch_corners(cdf, env, x, k, &w00, &w01, &w10, &w11);
  return xi_env_patch_density(env, xi_env_patch_probability(cdf, env, x, k), dv, w00, w01, w10, w11, s, t,
                              sqrt(l.x * l.x + l.z * l.z));
}

// The solid-angle density with which xi_env_sample returns the world direction d (unit).
static inline xfloat xi_env_pdf(__global const float* cdf, EnvironmentData env, xfloat3 d) {
  xfloat3 l = xi_env_to_local(env, d);
  return xi_env_pdf_local(cdf, env, l, xi_env_direction_to_uv(l));
}

#endif
