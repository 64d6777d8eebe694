// Sample sets: the canonical uniform ξ for (seed, pixel, sample index, dimension), drawn from one of
// four samplers. Dimensions come in pairs: pair 0 is the pixel position, pair 1 the lens, then a
// fixed block of pairs per bounce (see XI_PAIR_* below), so every sampler sees 2D points.
#ifndef XI_SAMPLING_H
#define XI_SAMPLING_H
#include "lanes.h"
#include "rng.h"

#define XI_SAMPLER_RANDOM 0
#define XI_SAMPLER_GRID 1
#define XI_SAMPLER_STRATIFIED 2
#define XI_SAMPLER_SOBOL 3

// Pairs of dimensions used by the renderer.
#define XI_PAIR_PIXEL 0u
#define XI_PAIR_LENS 1u
#define XI_PAIRS_PER_BOUNCE 4u
#define XI_PAIR_BOUNCE(depth, k) (2u + (depth) * XI_PAIRS_PER_BOUNCE + (k))
#define XI_BOUNCE_LIGHT 0u     // x: which light, then (reused) with y the point on it
#define XI_BOUNCE_BSDF_DIR 1u  // the BSDF direction
#define XI_BOUNCE_LOBE 2u      // x: which lobe (glass)
#define XI_BOUNCE_ROULETTE 3u  // x: Russian roulette (drawn by the random sampler)

typedef struct {
  uint seed;
  uint spp;  // the number of samples per pixel of the whole render (grid and stratified need it)
  uint nx;   // grid and stratified: spp = nx * ny cells
  uint ny;
} SamplerParams;

// The most square nx × ny factorisation of n (nx ≤ ny); a prime n gives 1 × n strips.
static inline SamplerParams xi_make_sampler_params(uint seed, uint spp) {
  SamplerParams p;
  p.seed = seed;
  p.spp = spp;
  uint nx = (uint)sqrt((float)spp);
  while (nx > 1u && spp % nx != 0u) nx--;
  p.nx = nx < 1u ? 1u : nx;
  p.ny = spp / p.nx;
  return p;
}

// Kensler's hash-based permutation of [0, n) (Correlated Multi-Jittered Sampling, 2013):
// cycle-walks a bijection on the next power of two until the value falls inside [0, n).
static inline xuint xi_permute(xuint i, uint n, xuint p) {
  uint w = n - 1u;
  w |= w >> 1;
  w |= w >> 2;
  w |= w >> 4;
  w |= w >> 8;
  w |= w >> 16;
  // Each path walks until its value is inside; with lanes, a path that is done keeps its value.
  xmask walking = XI_TRUE;
  do {
    xuint j = i;
    j ^= p;
    j *= 0xe170893du;
    j ^= p >> 16;
    j ^= (j & w) >> 4;
    j ^= p >> 8;
    j *= 0x0929eb3fu;
    j ^= p >> 23;
    j ^= (j & w) >> 1;
    j *= 1u | p >> 27;
    j *= 0x6935fa69u;
    j ^= (j & w) >> 11;
    j *= 0x74dcb303u;
    j ^= (j & w) >> 2;
    j *= 0x9e501cc3u;
    j ^= (j & w) >> 2;
    j *= 0xc860a3dfu;
    j &= w;
    j ^= j >> 5;
    i = walking ? j : i;
    walking = walking && i >= n;
  } while (XI_ANY(walking));
  return (i + p) % n;
}

static inline xuint xi_reverse_bits(xuint v) {
  v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
  v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
  v = ((v >> 4) & 0x0f0f0f0fu) | ((v & 0x0f0f0f0fu) << 4);
  v = ((v >> 8) & 0x00ff00ffu) | ((v & 0x00ff00ffu) << 8);
  return (v >> 16) | (v << 16);
}

// The bits of index multiplied by the Pascal matrix mod 2 (entry (i, j) = C(j, i) mod 2), in five
// butterfly steps: the matrix of size 2^n is [[P, P], [0, P]] with P of size 2^(n−1).
static inline xuint xi_pascal_bits(xuint index) {
  index ^= (index >> 1) & 0x55555555u;
  index ^= (index >> 2) & 0x33333333u;
  index ^= (index >> 4) & 0x0f0f0f0fu;
  index ^= (index >> 8) & 0x00ff00ffu;
  index ^= (index >> 16) & 0x0000ffffu;
  return index;
}

// The first two dimensions of the Sobol sequence, a (0,2)-sequence in base 2, as 32-bit fractions:
// dimension 0 is the van der Corput radical inverse, dimension 1 uses the Pascal generator matrix
// (direction numbers v₀ = 1/2, v_{k+1} = v_k ⊕ v_k/2), both read with bit 0 as the half.
static inline xuint xi_sobol_bits(xuint index, uint dim) {
  return xi_reverse_bits(dim == 0u ? index : xi_pascal_bits(index));
}

// The Laine–Karras permutation: each bit of v is changed only as a function of the bits below it.
// On a bit-reversed fraction that is a nested uniform (Owen) scramble: each bit changes as a
// function of the more significant bits, so every elementary interval keeps its share of points.
static inline xuint xi_laine_karras(xuint v, xuint seed) {
  v ^= v * 0x3d20adeau;
  v += seed;
  v *= (seed >> 16) | 1u;
  v ^= v * 0x05526c56u;
  v ^= v * 0x53a22864u;
  return v;
}

static inline xuint xi_owen_scramble(xuint v, xuint seed) {
  return xi_reverse_bits(xi_laine_karras(xi_reverse_bits(v), seed));
}

// Which sample of the set a pair of dimensions uses, for grid and stratified. Pair 0 uses the
// sample index itself; every other pair shuffles the set by its own permutation so dimensions do
// not correlate.
static inline xuint xi_padded_index(SamplerParams p, xuint pixel, xuint index, uint pair) {
  if (pair == 0u) return index;
  return xi_permute(index, p.spp, xi_hash4(p.seed, pixel, (xuint)pair, 0x5eed5u));
}

// Sobol indices are taken modulo 2^20, the most samples per pixel a render has.
#define XI_SOBOL_INDEX_MASK 0xfffffu

// Sample `index` of a pixel's Owen-scrambled Sobol points for one pair of dimensions, progressive
// (Burley 2020, "Practical Hash-based Owen Scrambling"): pair 0 takes the points in order; every
// other pair shuffles the order by a nested uniform scramble of the index's bits. That maps each
// aligned block of 2^m indices onto another such block, so every 2^m-sample prefix is still a
// (0,m,2)-net in every pair, while the pairs decorrelate. Nothing depends on the final spp: a
// render's first N samples are what a render of N samples draws.
static inline XI_INLINE xfloat2 xi_sobol_2d(uint seed, xuint pixel, xuint index, uint pair) {
  xuint h = xi_hash4(seed, pixel, (xuint)pair, 0x50b01u);
  xuint i = index & XI_SOBOL_INDEX_MASK;
  if (pair != 0u) i = xi_owen_scramble(i, xi_mix32(h ^ 0x2f6b7a1du)) & XI_SOBOL_INDEX_MASK;
  // (The compiler cancels the bit reversal at the end of xi_sobol_bits against the one at the
  // start of xi_owen_scramble.)
  return make_xfloat2(xi_unit_float(xi_owen_scramble(xi_sobol_bits(i, 0u), xi_mix32(h))),
                     xi_unit_float(xi_owen_scramble(xi_sobol_bits(i, 1u), xi_mix32(h ^ 0xa511e9b3u))));
}

// (cell + j) / n for j in [0, 1), kept strictly inside the cell: rounding may carry a j close to 1
// onto the next cell's edge.
static inline xfloat xi_in_cell(xuint cell, xfloat j, uint n) {
  xfloat x = (xi_to_float(cell) + j) / (float)n;
  xfloat next = xi_to_float(cell + 1u) / (float)n;
  return x < next ? x : nextafter(next, (xfloat)0.0f);
}

static inline XI_INLINE xfloat2 xi_sample_2d(int sampler, SamplerParams p, xuint pixel, xuint index, uint pair) {
  if (sampler == XI_SAMPLER_RANDOM) {
    return make_xfloat2(xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair)),
                        xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair + 1u)));
  }
  if (sampler == XI_SAMPLER_SOBOL) return xi_sobol_2d(p.seed, pixel, index, pair);
  xuint s = xi_padded_index(p, pixel, index % p.spp, pair);
  // Grid: the centre of cell s; stratified: a uniform point inside it.
  xfloat jx = 0.5f, jy = 0.5f;
  if (sampler == XI_SAMPLER_STRATIFIED) {
    jx = xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair));
    jy = xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair + 1u));
  }
  return make_xfloat2(xi_in_cell(s % p.nx, jx, p.nx), xi_in_cell(s / p.nx, jy, p.ny));
}

#endif
