// The up-front memory check of a render: everything it will allocate, against what the device and
// the host have, before anything is allocated.
#pragma once
#include <cstddef>

#include "xi/device.h"

namespace xi {

struct MemoryNeeds {
  size_t pixels = 0;                // film pixels (four vec4 buffers on the device)
  size_t paths = 0;                 // paths in flight
  size_t path_bytes = 0;            // device bytes per path in flight
  size_t scene_bytes = 0;           // every scene buffer
  size_t largest_scene_buffer = 0;  // the largest of them (one allocation)
};

// Hands the whole pages within [begin, begin + bytes) of an array that will not be read again
// back to the system, so they take no memory until written again (their contents are lost): what
// a large array's copy or rewrite leaves behind goes as it goes, not when the array is freed.
void release_pages(const void* begin, size_t bytes);

// Throws one xi::Error naming what the render needs and what there is, so that a frame too large
// stops there rather than in the driver (PoCL aborts on a failed allocation).
void check_memory(Device& device, const MemoryNeeds& needs);

}  // namespace xi
