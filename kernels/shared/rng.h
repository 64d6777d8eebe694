// Counter-based random numbers: a value is a pure function of (seed, pixel, sample, dimension),
// so an image never depends on which thread ran which path.
#ifndef XI_RNG_H
#define XI_RNG_H
#include "lanes.h"

// A 32-bit integer mixer with low bias (two multiply-xorshift rounds).
static inline xuint xi_mix32(xuint x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

// Every input goes through at least two rounds of xi_mix32: with one round after the last input
// (the dimension), dimensions a few low bits apart came out correlated (tail probabilities of
// u_d, u_d+2 off by 5%, u_d, u_d+16 by 1%), enough to bias Russian roulette, whose decisions at
// successive bounces take dimensions 8 apart: an albedo-1 furnace at depth 64 rendered 65.48 ± 0.07
// for the exact 65 (HardCases.AlbedoOneFurnaceAtDepth64SumsExactly65Terms).
// a and d are the same for every path (seed, dimension or tag), b and c the path's own.
static inline xuint xi_hash4(uint a, xuint b, xuint c, uint d) {
  xuint h = xi_mix32((xuint)(a ^ 0x9e3779b9u));
  h = xi_mix32(h ^ b);
  h = xi_mix32(h ^ c);
  return xi_mix32(xi_mix32(h ^ d));
}

// The top 24 bits as a float in [0, 1): the largest value is 1 - 2^-24, so ξ never reaches 1.
static inline xfloat xi_unit_float(xuint bits) { return xi_to_float(bits >> 8) * 0x1p-24f; }

#endif
