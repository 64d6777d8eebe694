// Spawned ray origins (spawn.h), on the host: the one-float step they take past their error bound.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "spawn.h"

namespace {

// Spawned origins step one float past their error box with xi_round_away, an integer step of the
// bit pattern: it must be exactly nextafter toward ±∞ as offset's sign says (x unchanged for 0),
// across zero, denormals, the smallest and largest normals and 10^5 random finite floats.
TEST(Spawn, RoundAwayIsNextafter) {
  std::vector<float> xs = {0.0f, -0.0f, 0x1p-149f, -0x1p-149f, 0x1p-126f, -0x1p-126f, 1.0f, -1.0f,
                           0x1.fffffep+127f, -0x1.fffffep+127f, 3.0e-39f, -3.0e-39f};
  std::mt19937 rng(0x5a17u);
  while (xs.size() < 100000) {
    const float x = as_float(rng());
    if (std::isfinite(x)) xs.push_back(x);
  }
  for (float x : xs)
    for (float offset : {1e-3f, -1e-3f, 0.0f}) {
      const float want = offset > 0.0f ? std::nextafter(x, INFINITY) : offset < 0.0f ? std::nextafter(x, -INFINITY) : x;
      ASSERT_EQ(as_uint(xi_round_away(x, offset)), as_uint(want)) << "x " << x << " offset " << offset;
    }
}

}  // namespace
