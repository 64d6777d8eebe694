#include "memory.h"

#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

#include <glm/glm.hpp>

#include "xi/error.h"

namespace xi {

void release_pages(const void* begin, size_t bytes) {
  static const uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE);
  const uintptr_t lo = ((uintptr_t)begin + page - 1) & ~(page - 1), hi = ((uintptr_t)begin + bytes) & ~(page - 1);
  if (hi > lo) madvise((void*)lo, hi - lo, MADV_DONTNEED);
}

namespace {

std::string gigabytes(double bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f GB", bytes * 1e-9);
  return buf;
}

// A "Key: value kB" line of a /proc file, in bytes; NaN if absent.
double proc_bytes(const char* file, const std::string& wanted) {
  std::ifstream in(file);
  for (std::string key; in >> key;) {
    double kb = 0;
    in >> kb;
    if (key == wanted) return kb * 1024.0;
    in.ignore(256, '\n');
  }
  return NAN;
}

// Host memory this process can still take: what the system has available, and what is left of
// an address-space limit (ulimit -v) after what is mapped already, whichever is less.
double host_bytes_available() {
  double available = proc_bytes("/proc/meminfo", "MemAvailable:");
  if (std::isnan(available)) available = INFINITY;
  rlimit limit{};
  if (getrlimit(RLIMIT_AS, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
    const double used = proc_bytes("/proc/self/status", "VmSize:");
    available = std::min(available, (double)limit.rlim_cur - (std::isnan(used) ? 0.0 : used));
  }
  return available;
}

}  // namespace

void check_memory(Device& device, const MemoryNeeds& n) {
  const double film = 4.0 * sizeof(glm::vec4) * n.pixels;  // sum, sum of squares, albedo, normal
  const double paths = (double)n.paths * n.path_bytes;
  const double needed = film + paths + (double)n.scene_bytes;
  const std::string what = " (film " + gigabytes(film) + " for " + std::to_string(n.pixels) + " pixels, " +
                           std::to_string(n.paths) + " paths in flight " + gigabytes(paths) + ", scene " +
                           gigabytes((double)n.scene_bytes) + ")";
  const std::string where = device.info().name + "; lower --resolution or --paths-in-flight";
  const double device_memory = (double)device.device().getInfo<CL_DEVICE_GLOBAL_MEM_SIZE>();
  if (needed > device_memory)
    throw Error("the render needs " + gigabytes(needed) + " of device memory" + what + ", the device has " +
                    gigabytes(device_memory), where);
  const double largest = std::max({sizeof(glm::vec4) * (double)n.pixels, sizeof(glm::vec4) * (double)n.paths,
                                   (double)n.largest_scene_buffer});
  const double max_alloc = (double)device.device().getInfo<CL_DEVICE_MAX_MEM_ALLOC_SIZE>();
  if (largest > max_alloc)
    throw Error("the render needs a buffer of " + gigabytes(largest) + what + ", the device allocates at most " +
                    gigabytes(max_alloc) + " at once", where);
  // The host reads the film back and resolves it (four vec4 and four vec3 images per pixel); a
  // device that shares host memory (a CPU) takes its buffers from there too.
  const bool shared = device.device().getInfo<CL_DEVICE_HOST_UNIFIED_MEMORY>();
  const double host = (4.0 * sizeof(glm::vec4) + 4.0 * sizeof(glm::vec3)) * n.pixels + (shared ? needed : 0.0);
  const double available = host_bytes_available();
  if (host > available)
    throw Error("the render needs " + gigabytes(host) + " of host memory" + what + ", " + gigabytes(available) +
                    " is available", where);
}

}  // namespace xi
