#include "xi/device.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <thread>
#include <pthread.h>
#include <unistd.h>

#include "xi/error.h"
#include "xi/hash.h"

namespace xi {
namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

std::string trim(std::string s) {
  while (!s.empty() && (s.back() == '\0' || std::isspace((unsigned char)s.back()))) s.pop_back();
  return s;
}

std::string type_name(cl_device_type t) {
  if (t & CL_DEVICE_TYPE_CPU) return "CPU";
  if (t & CL_DEVICE_TYPE_GPU) return "GPU";
  if (t & CL_DEVICE_TYPE_ACCELERATOR) return "ACCELERATOR";
  return "OTHER";
}

struct Found {
  DeviceInfo info;
  cl::Device device;
};

// PoCL's CPU device runs a work group's items one after another on one of its threads and keeps
// each item's values that live across a barrier on that thread's stack, so shade at the largest
// work group (kMaxLocalSize, `--local-size 0`) needs more than glibc's default 8 MB. Threads
// created from here on, PoCL's pool among them, get this much (address space, touched only as
// used), unless their default is larger already.
constexpr size_t kThreadStackBytes = (size_t)32 << 20;

void widen_default_thread_stack() {
  pthread_attr_t attr;
  size_t size = 0;
  if (pthread_getattr_default_np(&attr) != 0) return;
  if (pthread_attr_getstacksize(&attr, &size) == 0 && size < kThreadStackBytes &&
      pthread_attr_setstacksize(&attr, kThreadStackBytes) == 0)
    pthread_setattr_default_np(&attr);
  pthread_attr_destroy(&attr);
}

std::vector<Found> enumerate() {
  widen_default_thread_stack();
  // PoCL compiles each kernel's work-group function once more for every launch configuration it
  // specialises on (the work-group size; grids of fewer than 65535 items or more), seconds per
  // new program at the first launches. xi's kernels run as fast from the one general function
  // built with the program, so PoCL builds only that. A value the user set is kept.
  setenv("POCL_WORK_GROUP_SPECIALIZATION", "0", 0);
  std::vector<cl::Platform> platforms;
  try {
    cl::Platform::get(&platforms);
  } catch (const cl::Error&) {
    platforms.clear();  // CL_PLATFORM_NOT_FOUND_KHR: no ICD installed
  }
  std::vector<Found> out;
  for (auto& platform : platforms) {
    std::vector<cl::Device> devices;
    try {
      platform.getDevices(CL_DEVICE_TYPE_ALL, &devices);
    } catch (const cl::Error&) {
      continue;  // a platform with no devices
    }
    for (auto& d : devices) {
      Found f;
      f.device = d;
      f.info.index = (int)out.size();
      f.info.platform = trim(platform.getInfo<CL_PLATFORM_NAME>());
      f.info.name = trim(d.getInfo<CL_DEVICE_NAME>());
      f.info.type = type_name(d.getInfo<CL_DEVICE_TYPE>());
      f.info.version = trim(d.getInfo<CL_DEVICE_VERSION>());
      f.info.opencl_c_version = trim(d.getInfo<CL_DEVICE_OPENCL_C_VERSION>());
      f.info.driver_version = trim(d.getInfo<CL_DRIVER_VERSION>());
      f.info.compute_units = (int)d.getInfo<CL_DEVICE_MAX_COMPUTE_UNITS>();
      out.push_back(f);
    }
  }
  return out;
}

std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw Error("cannot read kernel source", p.string());
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

constexpr char kMagic[8] = {'X', 'I', 'B', 'I', 'N', '0', '0', '1'};

// Cache file: magic, key, payload size, payload checksum, payload.
bool read_cache(const std::filesystem::path& file, uint64_t key, std::vector<unsigned char>* binary) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return false;
  char magic[8];
  uint64_t k = 0, size = 0, sum = 0;
  in.read(magic, 8);
  in.read(reinterpret_cast<char*>(&k), 8);
  in.read(reinterpret_cast<char*>(&size), 8);
  in.read(reinterpret_cast<char*>(&sum), 8);
  if (!in || std::memcmp(magic, kMagic, 8) != 0 || k != key || size == 0 || size > (1ull << 31)) return false;
  binary->resize(size);
  in.read(reinterpret_cast<char*>(binary->data()), (std::streamsize)size);
  if (!in) return false;
  Hasher h;
  h.add(binary->data(), binary->size());
  return h.h == sum;
}

void write_cache(const std::filesystem::path& file, uint64_t key, const std::vector<unsigned char>& binary) {
  std::error_code ec;
  std::filesystem::create_directories(file.parent_path(), ec);
  if (ec) return;  // the cache is an optimisation: no cache, no failure
  Hasher h;
  h.add(binary.data(), binary.size());
  uint64_t size = binary.size();
  auto tmp = file;
  // Unique per process and thread: a program may be built on a background thread (Renderer).
  const size_t thread = std::hash<std::thread::id>{}(std::this_thread::get_id());
  tmp += ".tmp" + std::to_string(::getpid()) + "." + std::to_string(thread);
  {
    std::ofstream out(tmp, std::ios::binary);
    out.write(kMagic, 8);
    out.write(reinterpret_cast<const char*>(&key), 8);
    out.write(reinterpret_cast<const char*>(&size), 8);
    out.write(reinterpret_cast<const char*>(&h.h), 8);
    out.write(reinterpret_cast<const char*>(binary.data()), (std::streamsize)size);
    if (!out) {
      std::filesystem::remove(tmp, ec);
      return;
    }
  }
  std::filesystem::rename(tmp, file, ec);
  if (ec) std::filesystem::remove(tmp, ec);
}

std::string build_log(const cl::Program& program, const cl::Device& device) {
  try {
    return program.getBuildInfo<CL_PROGRAM_BUILD_LOG>(device);
  } catch (const cl::Error&) {
    return "(no build log)";
  }
}

}  // namespace

std::vector<DeviceInfo> list_devices() {
  std::vector<DeviceInfo> out;
  for (auto& f : enumerate()) out.push_back(f.info);
  return out;
}

Device Device::open(const std::string& requested) {
  auto all = enumerate();
  if (all.empty())
    throw Error("no OpenCL device found", "is an OpenCL driver installed? PoCL: apt-get install pocl-opencl-icd");
  // XI_DEVICE picks the default, for the CLI and the test suite alike.
  std::string selector = requested;
  std::string where = "--device";
  if (const char* env = std::getenv("XI_DEVICE"); selector.empty() && env && *env) {
    selector = env;
    where = "XI_DEVICE";
  }
  const Found* pick = nullptr;
  if (selector.empty()) {
    for (auto& f : all)
      if (f.info.type == "CPU") { pick = &f; break; }
    if (!pick) pick = &all.front();
  } else if (std::all_of(selector.begin(), selector.end(), ::isdigit)) {
    size_t i = std::stoul(selector);
    if (i < all.size()) pick = &all[i];
  } else {
    for (auto& f : all)
      if (lower(f.info.name).find(lower(selector)) != std::string::npos ||
          lower(f.info.platform).find(lower(selector)) != std::string::npos) {
        pick = &f;
        break;
      }
  }
  if (!pick)
    throw Error("no OpenCL device matches '" + selector + "'",
                where + "; " + std::to_string(all.size()) + " device(s) found, `xi devices` lists them");
  Device d;
  d.info_ = pick->info;
  d.device_ = pick->device;
  try {
    d.context_ = cl::Context(d.device_);
    d.queue_ = cl::CommandQueue(d.context_, d.device_, CL_QUEUE_PROFILING_ENABLE);
  } catch (const cl::Error& e) {
    throw Error(std::string("cannot open the device: ") + e.what() + " (" + std::to_string(e.err()) + ")",
                d.info_.name);
  }
  return d;
}

// A function-local static: set_kernel_dir() runs during static initialisation (device.h).
static std::filesystem::path& named_kernel_dir() {
  static std::filesystem::path dir;
  return dir;
}

void set_kernel_dir(const std::filesystem::path& dir) { named_kernel_dir() = dir; }

std::filesystem::path kernel_dir() {
  if (const char* env = std::getenv("XI_KERNEL_DIR"); env && *env) {
    std::filesystem::path p(env);
    if (!std::filesystem::exists(p / "shade.cl"))
      throw Error("XI_KERNEL_DIR does not hold the kernels (no shade.cl)", p.string());
    return p;
  }
  // libxi is a static library, so it cannot know where it was installed: an installed program is
  // told by the CMake package (set_kernel_dir, device.h) or finds ../share/xi/kernels beside itself;
  // the source tree and the configure-time prefix come last, for programs in the build tree.
  std::error_code ec;
  auto exe = std::filesystem::read_symlink("/proc/self/exe", ec).parent_path();
  for (auto candidate : {named_kernel_dir(), exe / "kernels", exe.parent_path() / "kernels",
                         exe.parent_path() / "share/xi/kernels", std::filesystem::path(XI_SOURCE_KERNEL_DIR),
                         std::filesystem::path(XI_INSTALL_KERNEL_DIR)})
    if (!candidate.empty() && std::filesystem::exists(candidate / "shade.cl")) return candidate;
  throw Error("cannot find the kernel sources", "set XI_KERNEL_DIR to the kernels/ folder");
}

std::filesystem::path cache_dir() {
  if (const char* env = std::getenv("XI_CACHE_DIR"); env && *env) return env;
  if (const char* env = std::getenv("XDG_CACHE_HOME"); env && *env) return std::filesystem::path(env) / "xi";
  if (const char* env = std::getenv("HOME"); env && *env) return std::filesystem::path(env) / ".cache/xi";
  return std::filesystem::temp_directory_path() / "xi-cache";
}

namespace {

// What a build compiles: the build options, the stub that includes the files, and the key.
struct ProgramSource {
  std::string options, stub;
  Hasher key;
  std::string cache_file() const { return (cache_dir() / (hex(key.h) + ".bin")).string(); }
};

ProgramSource program_source(Device& device, const std::vector<std::string>& files,
                             const std::vector<std::string>& defines) {
  auto dir = kernel_dir();

  // The key covers every source the program can include, so editing a header invalidates it.
  Hasher key;
  std::vector<std::filesystem::path> sources;
  for (auto& e : std::filesystem::recursive_directory_iterator(dir))
    if (e.is_regular_file() && (e.path().extension() == ".cl" || e.path().extension() == ".h"))
      sources.push_back(e.path());
  std::sort(sources.begin(), sources.end());
  for (auto& s : sources) {
    key.add(std::filesystem::relative(s, dir).string());
    key.add(read_file(s));
  }
  // No -cl-fast-relaxed-math: it implies finite-math-only, and accumulate must see NaN and Inf.
  // -w: no warnings. A build that succeeds shows its log nowhere, but PoCL prints a count of them
  // on stderr, and 16-lane code built for a CPU without AVX-512 draws one per vector argument (the
  // ABI of passing 512-bit vectors, which the builtins, compiled for the same CPU, share). Errors
  // still fill the log shown when a build fails.
  // PoCL passes -I paths on unquoted, so a kernel folder with spaces in its path is refused.
  if (dir.string().find(' ') != std::string::npos)
    throw Error("the kernel folder's path contains a space, which OpenCL build options cannot carry", dir.string());
  std::string options =
      "-cl-std=CL1.2 -cl-mad-enable -w -I " + dir.string() + " -I " + (dir / "shared").string();
  for (auto& d : defines) options += " -D" + d;
  key.add(options);
  for (auto& f : files) key.add(f);
  key.add(device.info().platform);
  key.add(device.info().name);
  key.add(device.info().driver_version);
  key.add(device.info().version);

  // Including the files (rather than pasting them) makes compiler messages name the real file and
  // line. The hash line changes the source text whenever any source changes, so a driver's own
  // cache keyed on the text alone cannot serve a stale build.
  std::string stub = "// xi kernel sources " + hex(key.h) + "\n";
  for (auto& f : files) stub += "#include \"" + f + "\"\n";
  return ProgramSource{options, stub, key};
}

}  // namespace

bool program_cached(Device& device, const std::vector<std::string>& files, const std::vector<std::string>& defines) {
  return std::filesystem::exists(program_source(device, files, defines).cache_file());
}

std::string program_key(Device& device, const std::vector<std::string>& files,
                        const std::vector<std::string>& defines) {
  return hex(program_source(device, files, defines).key.h);
}

Program build_program(Device& device, const std::vector<std::string>& files,
                      const std::vector<std::string>& defines) {
  auto start = std::chrono::steady_clock::now();
  const ProgramSource source = program_source(device, files, defines);
  const std::string& options = source.options;
  const Hasher& key = source.key;
  Program result;
  result.key = hex(key.h);
  result.cache_file = source.cache_file();
  cl::Device dev = device.device();
  std::vector<unsigned char> binary;
  if (read_cache(result.cache_file, key.h, &binary)) {
    try {
      cl::Program::Binaries bins{binary};
      cl::Program p(device.context(), {dev}, bins);
      p.build({dev}, options.c_str());
      result.program = p;
      result.from_cache = true;
    } catch (const cl::Error&) {
      result.from_cache = false;  // a binary the driver no longer accepts: rebuild below
    }
  }
  if (!result.from_cache) {
    cl::Program p(device.context(), source.stub);
    try {
      p.build({dev}, options.c_str());
    } catch (const cl::Error&) {
      throw Error("kernel build failed:\n" + build_log(p, dev), device.info().name + ", options: " + options);
    }
    auto bins = p.getInfo<CL_PROGRAM_BINARIES>();
    if (!bins.empty() && !bins[0].empty()) write_cache(result.cache_file, key.h, bins[0]);
    result.program = p;
  }
  result.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace xi
