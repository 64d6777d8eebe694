// Measuring tools' access to the extend stage of a real renderer: the rays that enter it at one
// bounce of a render, and the stage run alone on given rays. For bench/ and the tests; not part of
// the installed API.
#pragma once
#include <vector>

#include "xi/renderer.h"

namespace xi {

struct RayBatch {
  std::vector<glm::vec4> org, dir;  // xyz used (org.w: a shadow ray's tmax)
};

class RayProbe {
 public:
  explicit RayProbe(Renderer& renderer) : renderer_(renderer) { renderer_.probe_ = this; }
  ~RayProbe() { renderer_.probe_ = nullptr; }
  RayProbe(const RayProbe&) = delete;
  RayProbe& operator=(const RayProbe&) = delete;

  // Keeps the rays that enter extend at `bounce`, and the shadow rays that shade queues there, in
  // every wave the renderer runs from now on.
  void record(int bounce) { record_bounce_ = bounce; }
  const RayBatch& recorded() const { return recorded_; }
  const RayBatch& recorded_shadow() const { return recorded_shadow_; }  // org.w: tmax

  // Runs the extend stage alone on the given rays (at most the paths in flight) as it runs at
  // `bounce`: in packets of consecutive rays where XI_EXTEND_RAYS says so, else one by one.
  // Returns the kernel's time in seconds and the hits (t or −1, u, v, triangle in BVH order as
  // float bits). An empty batch traces nothing: no hits, 0 s.
  double trace_closest(const RayBatch& rays, std::vector<glm::vec4>* hits, int bounce);
  // Runs the shadow stage alone on the given rays (org.w: tmax) as it runs at `bounce`. Returns the
  // kernel's time in seconds and, per ray, whether it is occluded (none for an empty batch).
  double trace_shadow(const RayBatch& rays, std::vector<bool>* occluded, int bounce);

 private:
  friend class Renderer;
  // Called by the renderer before extend at every bounce of a wave.
  void entering_extend(const cl::Buffer& queue, int bounce);
  // Called by the renderer after shade at every bounce of a wave.
  void leaving_shade(int bounce);

  Renderer& renderer_;
  int record_bounce_ = -1;
  RayBatch recorded_, recorded_shadow_;
};

}  // namespace xi
