#include "xi/warp.h"

#include "sampling.h"
#include "warps.h"
#include "xi/error.h"

namespace xi {
namespace {
const char* kMapNames[] = {"square", "sphere", "hemisphere", "cosine-hemisphere",
                           "disc", "concentric-disc", "triangle", "disc-naive"};
}

int parse_warp_map(const std::string& name) {
  for (int m = 0; m <= XI_MAP_DISC_NAIVE; ++m)
    if (name == kMapNames[m]) return m;
  throw Error("unknown map '" + name + "'",
              "expected square, sphere, hemisphere, cosine-hemisphere, disc, concentric-disc, triangle or disc-naive");
}

const char* warp_map_name(int map) { return map >= 0 && map <= XI_MAP_DISC_NAIVE ? kMapNames[map] : "?"; }

bool warp_map_is_3d(int map) {
  return map == XI_MAP_SPHERE || map == XI_MAP_HEMISPHERE || map == XI_MAP_COSINE_HEMISPHERE;
}

WarpedSamples warp_samples(Device& device, int map, int sampler, uint32_t n, uint32_t seed, uint32_t pixel,
                           uint32_t pair) {
  if (n == 0) throw Error("the number of samples must be positive", "-n");
  Program program = build_program(device, {"tools.cl"}, {});
  cl::Kernel kernel(program.program, "warp_points");
  cl::Buffer points(device.context(), CL_MEM_WRITE_ONLY, sizeof(cl_float4) * n);
  cl::Buffer squares(device.context(), CL_MEM_WRITE_ONLY, sizeof(cl_float2) * n);
  SamplerParams params = xi_make_sampler_params(seed, n);
  int arg = 0;
  kernel.setArg(arg++, points);
  kernel.setArg(arg++, squares);
  kernel.setArg(arg++, map);
  kernel.setArg(arg++, sampler);
  kernel.setArg(arg++, params);
  kernel.setArg(arg++, pixel);
  kernel.setArg(arg++, pair);
  kernel.setArg(arg++, n);
  const size_t local = 64;
  device.queue().enqueueNDRangeKernel(kernel, cl::NullRange, cl::NDRange((n + local - 1) / local * local),
                                      cl::NDRange(local));
  std::vector<glm::vec4> p4(n);
  WarpedSamples out;
  out.squares.resize(n);
  device.queue().enqueueReadBuffer(points, CL_TRUE, 0, sizeof(glm::vec4) * n, p4.data());
  device.queue().enqueueReadBuffer(squares, CL_TRUE, 0, sizeof(glm::vec2) * n, out.squares.data());
  out.points.reserve(n);
  for (auto& p : p4) out.points.push_back(glm::vec3(p));
  return out;
}

}  // namespace xi
