// Fixtures shared by the test files: the device every library test renders on.
#pragma once
#include "xi/device.h"

namespace xi::test {

// The default OpenCL device ($XI_DEVICE, else the first CPU), opened once for the test binary.
inline Device& device() {
  static Device d = Device::open("");
  return d;
}

}  // namespace xi::test
