// The part of Intel Open Image Denoise 2's C API (OpenImageDenoise/oidn.h) that xi calls, declared
// here from OIDN's documentation so that xi builds without OIDN's headers: the library is loaded at
// run time (denoise.cpp) and these are the types of the symbols looked up in it. The enum values
// and signatures are OIDN 2.x's ABI, which is stable across its minor versions.
#pragma once
#include <cstddef>

namespace xi::oidn {

// Opaque handles (reference counted by OIDN).
using Device = struct OIDNDeviceImpl*;
using Filter = struct OIDNFilterImpl*;
using Buffer = struct OIDNBufferImpl*;

enum DeviceType : int {
  OIDN_DEVICE_TYPE_DEFAULT = 0,
  OIDN_DEVICE_TYPE_CPU = 1,
  OIDN_DEVICE_TYPE_SYCL = 2,
  OIDN_DEVICE_TYPE_CUDA = 3,
  OIDN_DEVICE_TYPE_HIP = 4,
  OIDN_DEVICE_TYPE_METAL = 5,
};

enum ErrorCode : int {
  OIDN_ERROR_NONE = 0,
  OIDN_ERROR_UNKNOWN = 1,
  OIDN_ERROR_INVALID_ARGUMENT = 2,
  OIDN_ERROR_INVALID_OPERATION = 3,
  OIDN_ERROR_OUT_OF_MEMORY = 4,
  OIDN_ERROR_UNSUPPORTED_HARDWARE = 5,
  OIDN_ERROR_CANCELLED = 6,
};

enum Format : int {
  OIDN_FORMAT_UNDEFINED = 0,
  OIDN_FORMAT_FLOAT = 1,
  OIDN_FORMAT_FLOAT2 = 2,
  OIDN_FORMAT_FLOAT3 = 3,
  OIDN_FORMAT_FLOAT4 = 4,
};

constexpr size_t OIDN_UUID_SIZE = 16;

extern "C" {
// Physical devices: the CPU and the GPUs OIDN supports, by ID 0 .. count - 1.
using GetNumPhysicalDevicesFn = int (*)();
using GetPhysicalDeviceBoolFn = bool (*)(int physical_device_id, const char* name);
using GetPhysicalDeviceIntFn = int (*)(int physical_device_id, const char* name);
using GetPhysicalDeviceStringFn = const char* (*)(int physical_device_id, const char* name);
using GetPhysicalDeviceDataFn = const void* (*)(int physical_device_id, const char* name, size_t* byte_size);

// Logical devices.
using NewDeviceFn = Device (*)(DeviceType type);
using NewDeviceByIDFn = Device (*)(int physical_device_id);
using GetDeviceIntFn = int (*)(Device device, const char* name);
using CommitDeviceFn = void (*)(Device device);
// Returns the first error since the last call and clears it; `out_message` may be null. A null
// device asks for the error of a failed oidnNewDevice*.
using GetDeviceErrorFn = ErrorCode (*)(Device device, const char** out_message);
using ReleaseDeviceFn = void (*)(Device device);

// Buffers: device-accessible memory, copied to and from the host.
using NewBufferFn = Buffer (*)(Device device, size_t byte_size);
using WriteBufferFn = void (*)(Buffer buffer, size_t byte_offset, size_t byte_size, const void* src_host_ptr);
using ReadBufferFn = void (*)(Buffer buffer, size_t byte_offset, size_t byte_size, void* dst_host_ptr);
using ReleaseBufferFn = void (*)(Buffer buffer);

// Filters. Strides of 0 mean tightly packed; the output may be one of the inputs (in place).
using NewFilterFn = Filter (*)(Device device, const char* type);
using SetFilterImageFn = void (*)(Filter filter, const char* name, Buffer buffer, Format format, size_t width,
                                  size_t height, size_t byte_offset, size_t pixel_byte_stride, size_t row_byte_stride);
using SetFilterBoolFn = void (*)(Filter filter, const char* name, bool value);
using SetFilterIntFn = void (*)(Filter filter, const char* name, int value);
// The filters' "quality" parameter (OIDNQuality).
enum Quality : int { OIDN_QUALITY_FAST = 4, OIDN_QUALITY_BALANCED = 5, OIDN_QUALITY_HIGH = 6 };
using CommitFilterFn = void (*)(Filter filter);
using ExecuteFilterFn = void (*)(Filter filter);
using ReleaseFilterFn = void (*)(Filter filter);
}

}  // namespace xi::oidn
