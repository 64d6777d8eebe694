// Splitting a pass over many items between threads: the scene loaders, the BVH build and the
// compile share it.
#pragma once
#include <algorithm>
#include <cstddef>
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

}  // namespace xi
