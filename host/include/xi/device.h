// OpenCL platforms and devices, and kernel programs built from kernels/ with an on-disk binary cache.
#pragma once
#include <filesystem>
#include <string>
#include <vector>

#include <CL/opencl.hpp>

namespace xi {

struct DeviceInfo {
  int index = 0;  // position in `xi devices`
  std::string platform;
  std::string name;
  std::string type;  // CPU, GPU, ACCELERATOR, ...
  std::string version;
  std::string opencl_c_version;
  std::string driver_version;
  int compute_units = 0;
};

// Every device of every platform, in a stable order.
std::vector<DeviceInfo> list_devices();

class Device {
 public:
  // selector: a number picks by index; other text picks the first device whose name or platform
  // contains it (case-insensitive); "" takes $XI_DEVICE as the selector if it is set, else the first
  // CPU device (else the first device).
  static Device open(const std::string& selector = "");

  const DeviceInfo& info() const { return info_; }
  cl::Context& context() { return context_; }
  cl::CommandQueue& queue() { return queue_; }  // in-order, with profiling enabled
  cl::Device& device() { return device_; }

 private:
  DeviceInfo info_;
  cl::Device device_;
  cl::Context context_;
  cl::CommandQueue queue_;
};

struct Program {
  cl::Program program;
  double build_seconds = 0.0;
  bool from_cache = false;
  std::string cache_file;
  std::string key;  // hash of every kernel source, the build options, the device and its driver
};

// The folder holding the .cl files, the first of: $XI_KERNEL_DIR; the folder given to
// set_kernel_dir(); kernels/ beside or above the running program, or its ../share/xi/kernels (an
// installed `xi`); the source tree's kernels/ (programs in the build tree); the install prefix
// chosen at configure time. A folder counts only if it holds shade.cl.
std::filesystem::path kernel_dir();
// Names the kernel folder for this process ("" forgets it); $XI_KERNEL_DIR still overrides it.
void set_kernel_dir(const std::filesystem::path& dir);

// A program built against an installed xi (CMake: find_package(xi), xi::xi) gets
// XI_PACKAGE_KERNEL_DIR, that install's share/xi/kernels wherever its prefix was put; naming it
// here, before main, means such a program finds the installed kernels rather than a source tree or
// the prefix libxi was configured with.
#ifdef XI_PACKAGE_KERNEL_DIR
namespace detail {
inline const bool package_kernel_dir_named = (set_kernel_dir(XI_PACKAGE_KERNEL_DIR), true);
}
#endif

// Where built binaries are cached: $XI_CACHE_DIR, else $XDG_CACHE_HOME/xi, else ~/.cache/xi.
std::filesystem::path cache_dir();

// Builds the given .cl files of kernel_dir() into one program with -D options. The binary is cached
// under a hash of every kernel source, the options, the device and driver; a cache entry that fails
// its checksum or does not load is rebuilt. A failing build throws xi::Error carrying the full log.
Program build_program(Device& device, const std::vector<std::string>& files,
                      const std::vector<std::string>& defines);
// Whether build_program would find that program in the cache, and the key it would give it; both
// without building. Thread-safe, as build_program is.
bool program_cached(Device& device, const std::vector<std::string>& files, const std::vector<std::string>& defines);
std::string program_key(Device& device, const std::vector<std::string>& files,
                        const std::vector<std::string>& defines);

}  // namespace xi
