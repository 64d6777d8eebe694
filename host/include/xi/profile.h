// Reports built from the renderer's timed kernel launches: a per-stage and per-bounce table, and a
// Chrome trace event file (opened by Perfetto and chrome://tracing).
#pragma once
#include <cstdio>
#include <filesystem>
#include <vector>

#include "xi/renderer.h"

namespace xi {

// Per bounce: queue length entering extend, shade and shadow and each kernel's time (summed over
// passes); then totals per stage, rays per second for extend and shadow, and the time outside
// kernels (host work, transfers, synchronisation) out of `wall_seconds`.
void print_profile(std::FILE* out, const std::vector<Launch>& launches, double wall_seconds);

void write_chrome_trace(const std::filesystem::path& path, const std::vector<Launch>& launches);

}  // namespace xi
