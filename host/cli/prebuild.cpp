// `xi prebuild`: builds the kernels a new scene's first image needs, ahead of its first render.
#include <chrono>
#include <cstdio>

#include "cli.h"
#include "xi/device.h"
#include "xi/error.h"
#include "xi/renderer.h"

namespace xi::cli {

const Command kPrebuild = {
    .name = "prebuild",
    .about = "build the kernels any scene's first image can start with (the\n"
             "generic shading program), so that a new scene waits for no build",
    .flags = {
        {"--device", "D", "OpenCL device (as for render)"},
        {"--lanes", "N", "as for render (default: the device's)"},
        {"--bvh-width", "N", "as for render (default: the device's)"},
    },
    .run = prebuild,
};

int prebuild(const std::vector<std::string>& argv) {
  Args args(argv, kPrebuild);
  if (!args.positional().empty()) throw Error("expected no file", args.positional()[0]);
  RenderOptions options;
  options.lanes = args.get_int("--lanes", 0, 1, 16);  // 0: the device's default
  options.bvh_width = args.get_int("--bvh-width", 0, 1, 8);
  Device device = Device::open(args.get("--device"));
  const auto start = std::chrono::steady_clock::now();
  const std::vector<std::string> built = prebuild_kernels(device, options);
  std::printf("device: %s\n", device.info().name.c_str());
  for (const std::string& line : built) std::printf("built: %s\n", line.c_str());
  std::printf("kernels ready in %.2f s, cached in %s\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
              cache_dir().string().c_str());
  return 0;
}

}  // namespace xi::cli
