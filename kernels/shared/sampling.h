// Sample sets: the canonical uniform ξ for (seed, pixel, sample index, dimension), drawn from one of
// four samplers. Dimensions come in pairs: pair 0 is the pixel position, pair 1 the lens, then a
// fixed block of pairs per bounce (see XI_PAIR_* below), so every sampler sees 2D points.
#ifndef XI_SAMPLING_H
#define XI_SAMPLING_H
#include "compat.h"
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
#define XI_BOUNCE_LIGHT_POINT 0u  // a point on the chosen light
#define XI_BOUNCE_BSDF_DIR 1u     // the BSDF direction
#define XI_BOUNCE_CHOICES 2u      // x: which light, y: which lobe (glass)
#define XI_BOUNCE_ROULETTE 3u     // x: Russian roulette

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
static inline uint xi_permute(uint i, uint n, uint p) {
  uint w = n - 1u;
  w |= w >> 1;
  w |= w >> 2;
  w |= w >> 4;
  w |= w >> 8;
  w |= w >> 16;
  do {
    i ^= p;
    i *= 0xe170893du;
    i ^= p >> 16;
    i ^= (i & w) >> 4;
    i ^= p >> 8;
    i *= 0x0929eb3fu;
    i ^= p >> 23;
    i ^= (i & w) >> 1;
    i *= 1u | p >> 27;
    i *= 0x6935fa69u;
    i ^= (i & w) >> 11;
    i *= 0x74dcb303u;
    i ^= (i & w) >> 2;
    i *= 0x9e501cc3u;
    i ^= (i & w) >> 2;
    i *= 0xc860a3dfu;
    i &= w;
    i ^= i >> 5;
  } while (i >= n);
  return (i + p) % n;
}

static inline uint xi_reverse_bits(uint v) {
  v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
  v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
  v = ((v >> 4) & 0x0f0f0f0fu) | ((v & 0x0f0f0f0fu) << 4);
  v = ((v >> 8) & 0x00ff00ffu) | ((v & 0x00ff00ffu) << 8);
  return (v >> 16) | (v << 16);
}

// The first two dimensions of the Sobol sequence, a (0,2)-sequence in base 2, as 32-bit fractions:
// dimension 0 is the van der Corput radical inverse, dimension 1 uses the Pascal generator matrix.
static inline uint xi_sobol_bits(uint index, uint dim) {
  if (dim == 0u) return xi_reverse_bits(index);
  uint x = 0u;
  for (uint v = 0x80000000u; index != 0u; index >>= 1, v ^= v >> 1)
    if (index & 1u) x ^= v;
  return x;
}

// A nested uniform (Owen) scramble in the Laine–Karras form: on bit-reversed input, each bit is
// changed only as a function of the bits below it, i.e. of the more significant bits of the
// fraction, so every elementary interval keeps exactly its share of points.
static inline uint xi_owen_scramble(uint v, uint seed) {
  v = xi_reverse_bits(v);
  v ^= v * 0x3d20adeau;
  v += seed;
  v *= (seed >> 16) | 1u;
  v ^= v * 0x05526c56u;
  v ^= v * 0x53a22864u;
  return xi_reverse_bits(v);
}

// Which sample of the set a pair of dimensions uses. Pair 0 uses the sample index itself; every
// other pair shuffles the set by its own permutation so dimensions do not correlate.
static inline uint xi_padded_index(SamplerParams p, uint pixel, uint index, uint pair) {
  if (pair == 0u) return index;
  return xi_permute(index, p.spp, xi_hash4(p.seed, pixel, pair, 0x5eed5u));
}

// (cell + j) / n for j in [0, 1), kept strictly inside the cell: rounding may carry a j close to 1
// onto the next cell's edge.
static inline float xi_in_cell(uint cell, float j, uint n) {
  float x = ((float)cell + j) / (float)n;
  float next = (float)(cell + 1u) / (float)n;
  return x < next ? x : nextafter(next, 0.0f);
}

static inline float2 xi_sample_2d(int sampler, SamplerParams p, uint pixel, uint index, uint pair) {
  if (sampler == XI_SAMPLER_RANDOM) {
    return make_float2(xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair)),
                       xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair + 1u)));
  }
  uint s = xi_padded_index(p, pixel, index % p.spp, pair);
  if (sampler == XI_SAMPLER_SOBOL) {
    uint h = xi_hash4(p.seed, pixel, pair, 0x50b01u);
    return make_float2(xi_unit_float(xi_owen_scramble(xi_sobol_bits(s, 0u), xi_mix32(h))),
                       xi_unit_float(xi_owen_scramble(xi_sobol_bits(s, 1u), xi_mix32(h ^ 0xa511e9b3u))));
  }
  // Grid: the centre of cell s; stratified: a uniform point inside it.
  float jx = 0.5f, jy = 0.5f;
  if (sampler == XI_SAMPLER_STRATIFIED) {
    jx = xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair));
    jy = xi_unit_float(xi_hash4(p.seed, pixel, index, 2u * pair + 1u));
  }
  return make_float2(xi_in_cell(s % p.nx, jx, p.nx), xi_in_cell(s / p.nx, jy, p.ny));
}

#endif
