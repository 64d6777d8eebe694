#include "ray_probe.h"

#include <chrono>
#include <cstring>
#include <string>

#include "xi/error.h"

namespace xi {

// Waits for this bounce's queue and keeps its rays.
void RayProbe::entering_extend(const cl::Buffer& queue, int bounce) {
  if (bounce != record_bounce_) return;
  Renderer& r = renderer_;
  cl::CommandQueue& q = r.device_.queue();
  uint32_t count = 0;
  q.enqueueReadBuffer(r.counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_RAYS(bounce), sizeof count, &count);
  std::vector<uint32_t> slots(count);
  std::vector<glm::vec4> org(r.paths_), dir(r.paths_);
  if (count > 0) q.enqueueReadBuffer(queue, CL_TRUE, 0, sizeof(uint32_t) * count, slots.data());
  q.enqueueReadBuffer(r.ray_org_, CL_TRUE, 0, sizeof(glm::vec4) * r.paths_, org.data());
  q.enqueueReadBuffer(r.ray_dir_, CL_TRUE, 0, sizeof(glm::vec4) * r.paths_, dir.data());
  for (uint32_t s : slots) {
    recorded_.org.push_back(org[s]);
    recorded_.dir.push_back(dir[s]);
  }
}

// Waits for this bounce's shadow queue and keeps its rays.
void RayProbe::leaving_shade(int bounce) {
  if (bounce != record_bounce_) return;
  Renderer& r = renderer_;
  cl::CommandQueue& q = r.device_.queue();
  uint32_t count = 0;
  q.enqueueReadBuffer(r.counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_SHADOW(bounce), sizeof count, &count);
  if (count == 0) return;
  const size_t first = recorded_shadow_.org.size();
  recorded_shadow_.org.resize(first + count);
  recorded_shadow_.dir.resize(first + count);
  q.enqueueReadBuffer(r.shadow_org_, CL_TRUE, 0, sizeof(glm::vec4) * count, recorded_shadow_.org.data() + first);
  q.enqueueReadBuffer(r.shadow_dir_, CL_TRUE, 0, sizeof(glm::vec4) * count, recorded_shadow_.dir.data() + first);
}

double RayProbe::trace_closest(const RayBatch& rays, std::vector<glm::vec4>* hits, int bounce) {
  Renderer& r = renderer_;
  const size_t n = rays.org.size();
  if (n > r.paths_ || rays.dir.size() != n) throw Error("ray batch larger than the paths in flight or malformed");
  if (bounce < 0 || bounce > r.options_.max_depth) throw Error("trace_closest: no bounce " + std::to_string(bounce));
  if (n == 0) {  // nothing to trace (OpenCL has no empty transfers)
    hits->clear();
    return 0.0;
  }
  cl::CommandQueue& q = r.device_.queue();
  std::vector<uint32_t> identity(n);
  for (size_t i = 0; i < n; ++i) identity[i] = (uint32_t)i;
  const uint32_t count = (uint32_t)n;
  q.enqueueWriteBuffer(r.ray_org_, CL_TRUE, 0, sizeof(glm::vec4) * n, rays.org.data());
  q.enqueueWriteBuffer(r.ray_dir_, CL_TRUE, 0, sizeof(glm::vec4) * n, rays.dir.data());
  q.enqueueWriteBuffer(r.queue_a_, CL_TRUE, 0, sizeof(uint32_t) * n, identity.data());
  q.enqueueWriteBuffer(r.counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_RAYS(bounce), sizeof count, &count);
  auto start = std::chrono::steady_clock::now();
  r.extend(r.queue_a_, bounce, n);
  q.finish();
  double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  hits->resize(n);
  q.enqueueReadBuffer(r.hit_, CL_TRUE, 0, sizeof(glm::vec4) * n, hits->data());
  r.launches_.clear();
  r.launch_events_.clear();
  return seconds;
}

double RayProbe::trace_shadow(const RayBatch& rays, std::vector<bool>* occluded, int bounce) {
  Renderer& r = renderer_;
  const size_t n = rays.org.size();
  if (n > r.paths_ || rays.dir.size() != n) throw Error("ray batch larger than the paths in flight or malformed");
  if (bounce < 0 || bounce > r.options_.max_depth) throw Error("trace_shadow: no bounce " + std::to_string(bounce));
  if (n == 0) {
    occluded->clear();
    return 0.0;
  }
  cl::CommandQueue& q = r.device_.queue();
  // Ray i adds 1 to path i's radiance if unoccluded.
  std::vector<glm::vec4> contrib(n);
  for (size_t i = 0; i < n; ++i) {
    const uint32_t slot = (uint32_t)i;
    float w;
    std::memcpy(&w, &slot, sizeof w);
    contrib[i] = glm::vec4(1.0f, 1.0f, 1.0f, w);
  }
  const uint32_t count = (uint32_t)n;
  q.enqueueWriteBuffer(r.shadow_org_, CL_TRUE, 0, sizeof(glm::vec4) * n, rays.org.data());
  q.enqueueWriteBuffer(r.shadow_dir_, CL_TRUE, 0, sizeof(glm::vec4) * n, rays.dir.data());
  q.enqueueWriteBuffer(r.shadow_contrib_, CL_TRUE, 0, sizeof(glm::vec4) * n, contrib.data());
  q.enqueueFillBuffer(r.radiance_, 0.0f, 0, sizeof(glm::vec4) * n);
  q.enqueueWriteBuffer(r.counters_, CL_TRUE, sizeof(uint32_t) * XI_COUNTER_SHADOW(bounce), sizeof count, &count);
  q.finish();
  auto start = std::chrono::steady_clock::now();
  r.shadow(bounce, n);
  q.finish();
  double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::vector<glm::vec4> radiance(n);
  q.enqueueReadBuffer(r.radiance_, CL_TRUE, 0, sizeof(glm::vec4) * n, radiance.data());
  occluded->resize(n);
  for (size_t i = 0; i < n; ++i) (*occluded)[i] = radiance[i].x == 0.0f;
  r.launches_.clear();
  r.launch_events_.clear();
  return seconds;
}

}  // namespace xi
