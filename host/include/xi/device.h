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
};

// The folder holding the .cl files: $XI_KERNEL_DIR, else kernels/ beside or above the running
// binary (build tree, install prefix share/xi/kernels), else the source tree's.
std::filesystem::path kernel_dir();
// Where built binaries are cached: $XI_CACHE_DIR, else $XDG_CACHE_HOME/xi, else ~/.cache/xi.
std::filesystem::path cache_dir();

// Builds the given .cl files of kernel_dir() into one program with -D options. The binary is cached
// under a hash of every kernel source, the options, the device and driver; a cache entry that fails
// its checksum or does not load is rebuilt. A failing build throws xi::Error carrying the full log.
Program build_program(Device& device, const std::vector<std::string>& files,
                      const std::vector<std::string>& defines);

}  // namespace xi
