// Splitting a pass over many items between threads: the scene loaders, the BVH build and the
// compile share it.
#pragma once
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <thread>
#include <vector>

namespace xi {

// Runs work(begin, end, part) on `parts` contiguous stretches of [0, n), in order, each on a thread
// of its own but the last, which the calling thread takes.
template <class Work>
void parallel_chunks(size_t n, unsigned parts, const Work& work) {
  std::vector<std::thread> pool;
  for (unsigned p = 0; p + 1 < parts; ++p) pool.emplace_back(work, n * p / parts, n * (p + 1) / parts, p);
  work(n * (parts - 1) / parts, n, parts - 1);
  for (std::thread& t : pool) t.join();
}

// How many parts n items take on `threads` cores (0: all the machine has): a thread per 64K items
// at most, so that small passes stay on one.
inline unsigned parts_for(size_t n, unsigned threads = 0) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  return (unsigned)std::clamp<size_t>(n >> 16, 1, threads);
}

// The first i in [0, n) for which bad(i) holds, or SIZE_MAX: each part stops at its first.
template <class Bad>
size_t first_where(size_t n, const Bad& bad) {
  const unsigned parts = parts_for(n);
  std::vector<size_t> first(parts, SIZE_MAX);
  parallel_chunks(n, parts, [&](size_t begin, size_t end, unsigned part) {
    for (size_t i = begin; i < end; ++i)
      if (bad(i)) {
        first[part] = i;
        return;
      }
  });
  for (size_t i : first)
    if (i != SIZE_MAX) return i;
  return SIZE_MAX;
}

}  // namespace xi
