// Intel Open Image Denoise through dlopen: the search for the library, the choice of its device
// (the render's GPU if OIDN has it, else the CPU) and the RT filters of Cycles' "accurate" mode.
#include "xi/denoise.h"

#include <dlfcn.h>

#include <CL/cl_ext.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <optional>
#include <type_traits>
#include <utility>
#include <vector>

#include "oidn_api.h"
#include "xi/device.h"
#include "xi/error.h"
#include "xi/metrics.h"

namespace xi {
namespace {

namespace fs = std::filesystem;

constexpr const char* kLibrary = "libOpenImageDenoise.so.2";
constexpr const char* kInstallHint =
    "install it with `bash scripts/install-deps.sh --denoise`, or set XI_OIDN_PATH to the folder that holds "
    "libOpenImageDenoise.so.2";

// The entry points of the loaded library.
struct Api {
  oidn::GetNumPhysicalDevicesFn GetNumPhysicalDevices;
  oidn::GetPhysicalDeviceBoolFn GetPhysicalDeviceBool;
  oidn::GetPhysicalDeviceIntFn GetPhysicalDeviceInt;
  oidn::GetPhysicalDeviceStringFn GetPhysicalDeviceString;
  oidn::GetPhysicalDeviceDataFn GetPhysicalDeviceData;
  oidn::NewDeviceFn NewDevice;
  oidn::NewDeviceByIDFn NewDeviceByID;
  oidn::GetDeviceIntFn GetDeviceInt;
  oidn::CommitDeviceFn CommitDevice;
  oidn::GetDeviceErrorFn GetDeviceError;
  oidn::ReleaseDeviceFn ReleaseDevice;
  oidn::NewBufferFn NewBuffer;
  oidn::WriteBufferFn WriteBuffer;
  oidn::ReadBufferFn ReadBuffer;
  oidn::ReleaseBufferFn ReleaseBuffer;
  oidn::NewFilterFn NewFilter;
  oidn::SetFilterImageFn SetFilterImage;
  oidn::SetFilterBoolFn SetFilterBool;
  oidn::SetFilterIntFn SetFilterInt;
  oidn::CommitFilterFn CommitFilter;
  oidn::ExecuteFilterFn ExecuteFilter;
  oidn::ReleaseFilterFn ReleaseFilter;
};

// Looks up every entry point; false (naming the first missing one) for a library that is not OIDN 2.
bool bind(void* library, Api* api, std::string* missing) {
  bool ok = true;
  auto get = [&](auto* fn, const char* name) {
    *fn = ok ? reinterpret_cast<std::remove_pointer_t<decltype(fn)>>(dlsym(library, name)) : nullptr;
    if (ok && !*fn) {
      ok = false;
      *missing = name;
    }
  };
  get(&api->GetNumPhysicalDevices, "oidnGetNumPhysicalDevices");
  get(&api->GetPhysicalDeviceBool, "oidnGetPhysicalDeviceBool");
  get(&api->GetPhysicalDeviceInt, "oidnGetPhysicalDeviceInt");
  get(&api->GetPhysicalDeviceString, "oidnGetPhysicalDeviceString");
  get(&api->GetPhysicalDeviceData, "oidnGetPhysicalDeviceData");
  get(&api->NewDevice, "oidnNewDevice");
  get(&api->NewDeviceByID, "oidnNewDeviceByID");
  get(&api->GetDeviceInt, "oidnGetDeviceInt");
  get(&api->CommitDevice, "oidnCommitDevice");
  get(&api->GetDeviceError, "oidnGetDeviceError");
  get(&api->ReleaseDevice, "oidnReleaseDevice");
  get(&api->NewBuffer, "oidnNewBuffer");
  get(&api->WriteBuffer, "oidnWriteBuffer");
  get(&api->ReadBuffer, "oidnReadBuffer");
  get(&api->ReleaseBuffer, "oidnReleaseBuffer");
  get(&api->NewFilter, "oidnNewFilter");
  get(&api->SetFilterImage, "oidnSetFilterImage");
  get(&api->SetFilterBool, "oidnSetFilterBool");
  get(&api->SetFilterInt, "oidnSetFilterInt");
  get(&api->CommitFilter, "oidnCommitFilter");
  get(&api->ExecuteFilter, "oidnExecuteFilter");
  get(&api->ReleaseFilter, "oidnReleaseFilter");
  return ok;
}

// Where load_denoiser() looks (denoise.h): what dlopen is given, in order (a path, or a bare name
// for the system's search), and the same in words for the error.
struct Search {
  std::vector<std::string> tries;
  std::string described;
};

Search oidn_search() {
  if (const char* env = std::getenv("XI_OIDN_PATH"); env && *env) {
    std::error_code ec;
    const fs::path given(env);
    const fs::path file = fs::is_directory(given, ec) ? given / kLibrary : given;
    return {{file.string()}, "XI_OIDN_PATH=" + given.string() + " (while it is set, only there)"};
  }
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec).parent_path();
  std::vector<fs::path> folders = {(exe / "oidn/lib").lexically_normal()};
  const fs::path source_tree = fs::path(XI_SOURCE_OIDN_DIR).lexically_normal();
  if (source_tree != folders[0]) folders.push_back(source_tree);
  Search s;
  for (const fs::path& folder : folders) {
    s.tries.push_back((folder / kLibrary).string());
    s.described += folder.string() + ", ";
  }
  s.tries.insert(s.tries.end(), {kLibrary, "libOpenImageDenoise.so"});
  s.described += "or the system's library path";
  return s;
}

// dlerror()'s text for a library that is there but does not load (a missing dependency, a wrong
// architecture), or "" where `name` itself is simply absent.
std::string load_failure(const std::string& name, const char* error) {
  const std::string e = error ? error : "unknown error";
  const bool absent = e.rfind(name + ":", 0) == 0 && e.find("No such file") != std::string::npos;
  return absent ? "" : e;
}

// The loaded library: the first of the search that loads and is OIDN 2. Loaded once, never
// unloaded (OIDN and TBB keep threads); a failed search throws and is tried again next time.
const Api& api() {
  static std::mutex mutex;
  static std::optional<Api> loaded;
  std::lock_guard<std::mutex> lock(mutex);
  if (loaded) return *loaded;
  const Search search = oidn_search();
  std::string failures;  // libraries found that did not load
  for (const std::string& name : search.tries) {
    const bool path = name.find('/') != std::string::npos;
    std::error_code ec;
    if (path && !fs::exists(name, ec)) continue;
    dlerror();
    void* library = dlopen(name.c_str(), RTLD_NOW | RTLD_LOCAL);
    std::string failure = library ? "" : load_failure(name, dlerror());
    Api bound{};
    std::string missing;
    if (library && !bind(library, &bound, &missing)) failure = name + " is not OIDN 2: it has no " + missing;
    if (library && failure.empty()) return *(loaded = bound);
    if (!failure.empty()) failures += (failures.empty() ? "" : "; ") + failure;
  }
  if (!failures.empty()) throw Error("cannot load Intel Open Image Denoise (OIDN): " + failures, kInstallHint);
  throw Error("Intel Open Image Denoise 2 (OIDN) is not installed: no " + std::string(kLibrary) + " in " +
                  search.described,
              kInstallHint);
}

const char* error_name(oidn::ErrorCode code) {
  switch (code) {
    case oidn::OIDN_ERROR_NONE: return "no error";
    case oidn::OIDN_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case oidn::OIDN_ERROR_INVALID_OPERATION: return "invalid operation";
    case oidn::OIDN_ERROR_OUT_OF_MEMORY: return "out of memory";
    case oidn::OIDN_ERROR_UNSUPPORTED_HARDWARE: return "unsupported hardware";
    case oidn::OIDN_ERROR_CANCELLED: return "cancelled";
    default: return "unknown error";
  }
}

// OIDN's first error on `device` since the last call (null: a failed device creation), as one
// line; "" if there was none.
std::string take_error(const Api& a, oidn::Device device) {
  const char* message = nullptr;
  const oidn::ErrorCode code = a.GetDeviceError(device, &message);
  if (code == oidn::OIDN_ERROR_NONE) return "";
  std::string text = message && *message ? message : error_name(code);
  std::replace(text.begin(), text.end(), '\n', ' ');
  return text;
}

void check(const Api& a, oidn::Device device, const std::string& doing) {
  if (std::string e = take_error(a, device); !e.empty()) throw Error("OIDN failed " + doing + ": " + e);
}

const char* device_type_name(int type) {
  switch (type) {
    case oidn::OIDN_DEVICE_TYPE_CPU: return "CPU";
    case oidn::OIDN_DEVICE_TYPE_SYCL: return "SYCL";
    case oidn::OIDN_DEVICE_TYPE_CUDA: return "CUDA";
    case oidn::OIDN_DEVICE_TYPE_HIP: return "HIP";
    case oidn::OIDN_DEVICE_TYPE_METAL: return "Metal";
    default: return "GPU";
  }
}

// What identifies a GPU across APIs: its UUID and PCI address where the OpenCL driver tells them
// (OIDN advises trying more than one, as drivers do not all report them alike), and its name.
struct GpuIdentity {
  std::string name;
  std::optional<std::array<unsigned char, oidn::OIDN_UUID_SIZE>> uuid;
  std::optional<std::array<int, 4>> pci;  // domain (-1: not told), bus, device, function
};

// cl_nv_device_attribute_query's PCI queries (not in every cl_ext.h); the slot is device << 3 | function.
constexpr cl_device_info kPciBusIdNv = 0x4008, kPciSlotIdNv = 0x4009, kPciDomainIdNv = 0x400A;

std::optional<GpuIdentity> identify_gpu(Device& device) {
  const cl_device_id d = device.device()();
  cl_device_type type = 0;
  if (clGetDeviceInfo(d, CL_DEVICE_TYPE, sizeof type, &type, nullptr) != CL_SUCCESS || !(type & CL_DEVICE_TYPE_GPU))
    return std::nullopt;
  GpuIdentity id;
  id.name = device.info().name;
  const std::string extensions = " " + device.device().getInfo<CL_DEVICE_EXTENSIONS>() + " ";
  auto has = [&](const char* e) { return extensions.find(std::string(" ") + e + " ") != std::string::npos; };
  if (std::array<unsigned char, oidn::OIDN_UUID_SIZE> uuid;
      has("cl_khr_device_uuid") && clGetDeviceInfo(d, CL_DEVICE_UUID_KHR, uuid.size(), uuid.data(), nullptr) == CL_SUCCESS)
    id.uuid = uuid;
  if (cl_device_pci_bus_info_khr bus{};
      has("cl_khr_pci_bus_info") && clGetDeviceInfo(d, CL_DEVICE_PCI_BUS_INFO_KHR, sizeof bus, &bus, nullptr) == CL_SUCCESS) {
    id.pci = {{(int)bus.pci_domain, (int)bus.pci_bus, (int)bus.pci_device, (int)bus.pci_function}};
  } else if (cl_uint nv_bus = 0, slot = 0; has("cl_nv_device_attribute_query") &&
             clGetDeviceInfo(d, kPciBusIdNv, sizeof nv_bus, &nv_bus, nullptr) == CL_SUCCESS &&
             clGetDeviceInfo(d, kPciSlotIdNv, sizeof slot, &slot, nullptr) == CL_SUCCESS) {
    cl_uint domain = 0;
    const bool known = clGetDeviceInfo(d, kPciDomainIdNv, sizeof domain, &domain, nullptr) == CL_SUCCESS;
    id.pci = {{known ? (int)domain : -1, (int)nv_bus, (int)(slot >> 3), (int)(slot & 7)}};
  } else if (cl_device_topology_amd topology{}; has("cl_amd_device_attribute_query") &&
             clGetDeviceInfo(d, CL_DEVICE_TOPOLOGY_AMD, sizeof topology, &topology, nullptr) == CL_SUCCESS &&
             topology.raw.type == CL_DEVICE_TOPOLOGY_TYPE_PCIE_AMD) {
    id.pci = {{-1, (unsigned char)topology.pcie.bus, (unsigned char)topology.pcie.device,
               (unsigned char)topology.pcie.function}};
  }
  return id;
}

std::string lower_trimmed(const char* s) {
  std::string out = s ? s : "";
  while (!out.empty() && std::isspace((unsigned char)out.back())) out.pop_back();
  out.erase(0, std::min(out.size(), out.find_first_not_of(" \t")));
  std::transform(out.begin(), out.end(), out.begin(), [](unsigned char c) { return std::tolower(c); });
  return out;
}

// OIDN's GPU physical device that is `gpu`: the same UUID or the same PCI address; by name only
// where neither can be compared. -1 if none.
int matching_physical_device(const Api& a, const GpuIdentity& gpu) {
  const int count = a.GetNumPhysicalDevices();
  int found = -1;
  for (int i = 0; i < count && found < 0; ++i) {
    if (a.GetPhysicalDeviceInt(i, "type") == oidn::OIDN_DEVICE_TYPE_CPU) continue;
    bool compared = false;
    if (gpu.uuid && a.GetPhysicalDeviceBool(i, "uuidSupported")) {
      compared = true;
      size_t size = 0;
      const void* uuid = a.GetPhysicalDeviceData(i, "uuid", &size);
      if (uuid && size == gpu.uuid->size() && std::memcmp(uuid, gpu.uuid->data(), size) == 0) found = i;
    }
    if (found < 0 && gpu.pci && a.GetPhysicalDeviceBool(i, "pciAddressSupported")) {
      compared = true;
      const std::array<int, 4> pci = {a.GetPhysicalDeviceInt(i, "pciDomain"), a.GetPhysicalDeviceInt(i, "pciBus"),
                                      a.GetPhysicalDeviceInt(i, "pciDevice"), a.GetPhysicalDeviceInt(i, "pciFunction")};
      if (((*gpu.pci)[0] < 0 || (*gpu.pci)[0] == pci[0]) && std::equal(pci.begin() + 1, pci.end(), gpu.pci->begin() + 1))
        found = i;
    }
    if (found < 0 && !compared && lower_trimmed(a.GetPhysicalDeviceString(i, "name")) == lower_trimmed(gpu.name.c_str()))
      found = i;
  }
  take_error(a, nullptr);  // a query of a parameter a device lacks leaves an error behind
  return found;
}

}  // namespace

void load_denoiser() { api(); }

// OIDN's filter quality for ours.
int quality(DenoiseQuality q) {
  return q == DenoiseQuality::Fast       ? oidn::OIDN_QUALITY_FAST
         : q == DenoiseQuality::Balanced ? oidn::OIDN_QUALITY_BALANCED
                                         : oidn::OIDN_QUALITY_HIGH;
}

struct Denoiser::Impl {
  const Api& a;
  const DenoiseOptions options;
  oidn::Device device = nullptr;
  std::string description;
  double seconds = 0.0;

  // The buffers and filters of the last image, for the next one of the same size and guides.
  int width = 0, height = 0;
  bool with_albedo = false, with_normal = false;
  oidn::Buffer color = nullptr, albedo = nullptr, normal = nullptr, output = nullptr;
  oidn::Filter main = nullptr, albedo_filter = nullptr, normal_filter = nullptr;

  explicit Impl(const DenoiseOptions& opts) : a(api()), options(opts) {
    std::string kind, gpu_failure;
    if (options.render_device)
      if (const std::optional<GpuIdentity> gpu = identify_gpu(*options.render_device)) {
        if (const int id = matching_physical_device(a, *gpu); id >= 0) {
          const std::string type = device_type_name(a.GetPhysicalDeviceInt(id, "type"));
          device = a.NewDeviceByID(id);
          if (device) a.CommitDevice(device);
          gpu_failure = take_error(a, device);
          if (gpu_failure.empty()) {
            kind = type + " device " + gpu->name;
          } else {  // the CPU device still denoises; the summary says why the GPU did not
            if (device) a.ReleaseDevice(device);
            device = nullptr;
            gpu_failure = "; its " + type + " device for " + gpu->name + " failed: " + gpu_failure;
          }
        }
      }
    if (!device) {
      device = a.NewDevice(oidn::OIDN_DEVICE_TYPE_CPU);
      check(a, nullptr, "to create its CPU device");
      a.CommitDevice(device);
      if (std::string e = take_error(a, device); !e.empty()) {
        a.ReleaseDevice(device);
        throw Error("OIDN failed to start its CPU device: " + e);
      }
      kind = "CPU device";
    }
    const int version = a.GetDeviceInt(device, "version");  // major.minor.patch, two digits each
    description = "OIDN " + std::to_string(version / 10000) + "." + std::to_string(version / 100 % 100) + "." +
                  std::to_string(version % 100) + " (" + kind + gpu_failure + ")";
  }

  ~Impl() {
    release_filters();
    a.ReleaseDevice(device);
  }

  void release_filters() {
    for (oidn::Filter* f : {&main, &albedo_filter, &normal_filter})
      if (*f) a.ReleaseFilter(std::exchange(*f, nullptr));
    for (oidn::Buffer* b : {&color, &albedo, &normal, &output})
      if (*b) a.ReleaseBuffer(std::exchange(*b, nullptr));
  }

  // Buffers and filters for a w × h image with these guides, made anew when they change. Each
  // guide is first denoised alone, in place; the colour then is denoised with the clean guides.
  void prepare(int w, int h, bool use_albedo, bool use_normal) {
    if (main && w == width && h == height && use_albedo == with_albedo && use_normal == with_normal) return;
    release_filters();
    width = w, height = h, with_albedo = use_albedo, with_normal = use_normal;
    const size_t bytes = (size_t)w * h * sizeof(glm::vec3);
    color = a.NewBuffer(device, bytes);
    output = a.NewBuffer(device, bytes);
    if (use_albedo) albedo = a.NewBuffer(device, bytes);
    if (use_normal) normal = a.NewBuffer(device, bytes);
    check(a, device, "to allocate " + std::to_string(w) + "x" + std::to_string(h) + " images");
    auto image = [&](oidn::Filter f, const char* name, oidn::Buffer b) {
      a.SetFilterImage(f, name, b, oidn::OIDN_FORMAT_FLOAT3, (size_t)w, (size_t)h, 0, 0, 0);
    };
    auto prefilter = [&](const char* name, oidn::Buffer b) {
      oidn::Filter f = a.NewFilter(device, "RT");
      image(f, name, b);
      image(f, "output", b);
      a.SetFilterInt(f, "quality", options.prefilter == DenoisePrefilter::Fast ? oidn::OIDN_QUALITY_FAST
                                                                                : quality(options.quality));
      a.CommitFilter(f);
      return f;
    };
    const bool clean = options.prefilter != DenoisePrefilter::None;
    if (use_albedo && clean) albedo_filter = prefilter("albedo", albedo);
    if (use_normal && clean) normal_filter = prefilter("normal", normal);
    main = a.NewFilter(device, "RT");
    image(main, "color", color);
    if (use_albedo) image(main, "albedo", albedo);
    if (use_normal) image(main, "normal", normal);
    image(main, "output", output);
    a.SetFilterBool(main, "hdr", true);
    a.SetFilterInt(main, "quality", quality(options.quality));
    if (use_albedo && clean) a.SetFilterBool(main, "cleanAux", true);  // prefiltered above
    a.CommitFilter(main);
    check(a, device, "to set up its filters");
  }
};

Denoiser::Denoiser(const DenoiseOptions& options) : impl_(std::make_unique<Impl>(options)) {}
Denoiser::~Denoiser() = default;

const std::string& Denoiser::description() const { return impl_->description; }
double Denoiser::last_seconds() const { return impl_->seconds; }

Image Denoiser::run(const Image& color, const Image* albedo, const Image* normal) {
  if (color.width <= 0 || color.height <= 0 || color.pixels.size() != (size_t)color.width * color.height)
    throw Error("nothing to denoise: the image is empty");
  if (normal && !albedo) throw Error("a normal image to denoise with needs an albedo image too");
  for (auto [guide, name] : {std::pair{albedo, "albedo"}, std::pair{normal, "normal"}})
    if (guide && (guide->width != color.width || guide->height != color.height))
      throw Error(std::string("the ") + name + " is " + std::to_string(guide->width) + "x" +
                  std::to_string(guide->height) + " but the colour is " + std::to_string(color.width) + "x" +
                  std::to_string(color.height));
  check_finite(color, "colour");
  if (albedo) check_finite(*albedo, "albedo");
  if (normal) check_finite(*normal, "normal");

  const auto t0 = std::chrono::steady_clock::now();
  Impl& d = *impl_;
  const Api& a = d.a;
  d.prepare(color.width, color.height, albedo != nullptr, normal != nullptr);
  const size_t bytes = color.pixels.size() * sizeof(glm::vec3);
  a.WriteBuffer(d.color, 0, bytes, color.pixels.data());
  if (albedo) a.WriteBuffer(d.albedo, 0, bytes, albedo->pixels.data());
  if (normal) a.WriteBuffer(d.normal, 0, bytes, normal->pixels.data());
  if (d.albedo_filter) a.ExecuteFilter(d.albedo_filter);
  if (d.normal_filter) a.ExecuteFilter(d.normal_filter);
  a.ExecuteFilter(d.main);
  Image out(color.width, color.height);
  a.ReadBuffer(d.output, 0, bytes, out.pixels.data());
  check(a, d.device, "to denoise");
  d.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

DenoiseQuality parse_denoise_quality(const std::string& name) {
  if (name == "high") return DenoiseQuality::High;
  if (name == "balanced") return DenoiseQuality::Balanced;
  if (name == "fast") return DenoiseQuality::Fast;
  throw Error("expected high, balanced or fast", "--denoise-quality " + name);
}

DenoisePrefilter parse_denoise_prefilter(const std::string& name) {
  if (name == "accurate") return DenoisePrefilter::Accurate;
  if (name == "fast") return DenoisePrefilter::Fast;
  if (name == "none") return DenoisePrefilter::None;
  throw Error("expected accurate, fast or none", "--denoise-prefilter " + name);
}

Image denoise(const Image& color, const Image* albedo, const Image* normal, const DenoiseOptions& options) {
  return Denoiser(options).run(color, albedo, normal);
}

}  // namespace xi
