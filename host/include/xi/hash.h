// FNV-1a, 64-bit: cache keys, checkpoint keys and checksums; not a defence against tampering.
#pragma once
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace xi {

struct Hasher {
  uint64_t h = 0xcbf29ce484222325ull;
  void add(const void* data, size_t n) {
    auto* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 0x100000001b3ull;
  }
  void add(const std::string& s) {
    add(s.data(), s.size());
    add("\0", 1);
  }
  template <typename T, typename A>
  void add(const std::vector<T, A>& v) {
    add(v.data(), sizeof(T) * v.size());
  }
};

inline std::string hex(uint64_t v) {
  char buf[17];
  std::snprintf(buf, sizeof buf, "%016llx", (unsigned long long)v);
  return buf;
}

}  // namespace xi
