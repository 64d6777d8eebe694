// The ceiling: xi's extend kernel against Embree's rtcIntersect1 on the same rays, same scene,
// same run. Rays: camera rays and first-bounce rays recorded from a real render of the scene.
// Prints Mrays/s for both (medians of several timed runs) and the ratio xi / Embree; then Embree's
// rtcIntersect16 on packets of 16 rays in the recorded order, which is how Mitsuba 3's LLVM
// variant calls the same Embree (its wheel links Embree 3.13.4 and calls rtcIntersect4/8/16).
#include <embree3/rtcore.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <functional>
#include <numeric>
#include <string>
#include <thread>
#include <vector>

#include "xi/error.h"
#include "render/ray_probe.h"
#include "xi/renderer.h"

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Runs work(t, threads) on one thread per core, t = 0 .. threads - 1; returns the wall seconds.
template <class Work>
double on_all_cores(const Work& work) {
  const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  auto start = std::chrono::steady_clock::now();
  std::vector<std::thread> pool;
  for (unsigned t = 0; t < threads; ++t) pool.emplace_back([&, t] { work(t, threads); });
  for (auto& th : pool) th.join();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

struct Embree {
  RTCDevice device = rtcNewDevice(nullptr);
  RTCScene scene = rtcNewScene(device);

  Embree(const std::vector<glm::vec4>& tri_verts, RTCBuildQuality quality) {
    const size_t n = tri_verts.size() / 3;
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = (float*)rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                              3 * n);
    auto* idx = (unsigned*)rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                   3 * sizeof(unsigned), n);
    for (size_t i = 0; i < 3 * n; ++i) {
      v[3 * i] = tri_verts[i].x;
      v[3 * i + 1] = tri_verts[i].y;
      v[3 * i + 2] = tri_verts[i].z;
      idx[i] = (unsigned)i;
    }
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcSetSceneBuildQuality(scene, quality);
    rtcCommitScene(scene);
  }
  ~Embree() {
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
  }

  // Closest hits on all cores; returns seconds; prim[i] = triangle or -1.
  double trace(const xi::RayBatch& rays, std::vector<int>* prim) {
    const size_t n = rays.org.size();
    prim->assign(n, -1);
    return on_all_cores([&](unsigned t, unsigned threads) {
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      for (size_t i = t; i < n; i += threads) {
        RTCRayHit rh{};
        rh.ray.org_x = rays.org[i].x;
        rh.ray.org_y = rays.org[i].y;
        rh.ray.org_z = rays.org[i].z;
        rh.ray.dir_x = rays.dir[i].x;
        rh.ray.dir_y = rays.dir[i].y;
        rh.ray.dir_z = rays.dir[i].z;
        rh.ray.tnear = 0.0f;
        rh.ray.tfar = INFINITY;
        rh.ray.mask = ~0u;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &ctx, &rh);
        if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) (*prim)[i] = (int)rh.hit.primID;
      }
    });
  }

  // The same with rtcIntersect16 on packets of 16 consecutive rays (a thread takes every
  // `threads`-th packet); camera rays flagged coherent, as Mitsuba flags its primary rays.
  double trace16(const xi::RayBatch& rays, bool coherent, std::vector<int>* prim) {
    const size_t n = rays.org.size(), packets = (n + 15) / 16;
    prim->assign(n, -1);
    return on_all_cores([&](unsigned t, unsigned threads) {
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      ctx.flags = coherent ? RTC_INTERSECT_CONTEXT_FLAG_COHERENT : RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
      alignas(64) RTCRayHit16 rh;
      alignas(64) int valid[16];
      for (size_t p = t; p < packets; p += threads) {
        for (size_t k = 0; k < 16; ++k) {
          const size_t i = std::min(p * 16 + k, n - 1);
          valid[k] = p * 16 + k < n ? -1 : 0;
          rh.ray.org_x[k] = rays.org[i].x;
          rh.ray.org_y[k] = rays.org[i].y;
          rh.ray.org_z[k] = rays.org[i].z;
          rh.ray.dir_x[k] = rays.dir[i].x;
          rh.ray.dir_y[k] = rays.dir[i].y;
          rh.ray.dir_z[k] = rays.dir[i].z;
          rh.ray.tnear[k] = 0.0f;
          rh.ray.tfar[k] = INFINITY;
          rh.ray.mask[k] = ~0u;
          rh.ray.time[k] = 0.0f;
          rh.ray.flags[k] = 0;
          rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
        }
        rtcIntersect16(valid, scene, &ctx, &rh);
        for (size_t k = 0; k < 16 && p * 16 + k < n; ++k)
          if (rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID) (*prim)[p * 16 + k] = (int)rh.hit.primID[k];
      }
    });
  }
};

}  // namespace

// Embree's build quality: high (its default here) adds spatial splits to the binned SAH of medium.
RTCBuildQuality parse_quality(const std::string& s) {
  if (s == "high") return RTC_BUILD_QUALITY_HIGH;
  if (s == "medium") return RTC_BUILD_QUALITY_MEDIUM;
  if (s == "low") return RTC_BUILD_QUALITY_LOW;
  throw xi::Error("expected an Embree build quality: high, medium or low", s);
}

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: xi_ceiling SCENE.json [RUNS] [WIDTHxHEIGHT] [high|medium|low]\n");
    return 2;
  }
  try {
    int runs = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;
    xi::Scene scene = xi::load_scene(argv[1]);
    if (argc > 3 && std::sscanf(argv[3], "%dx%d", &scene.width, &scene.height) != 2)
      throw xi::Error("expected WIDTHxHEIGHT", argv[3]);
    const std::string quality = argc > 4 ? argv[4] : "high";
    const RTCBuildQuality embree_quality = parse_quality(quality);
    xi::Device device = xi::Device::open("");
    std::printf("scene %s: %zu triangles, %dx%d; device %s; %u host threads for Embree, build quality %s\n",
                argv[1], scene.triangles.size(), scene.width, scene.height, device.info().name.c_str(),
                std::thread::hardware_concurrency(), quality.c_str());
    for (int bounce : {0, 1}) {
      xi::RenderOptions opt;
      opt.spp = 1;
      opt.paths_in_flight = (size_t)scene.width * scene.height;  // one wave: trace_closest takes them all
      xi::Renderer recorder(device, scene, opt);
      xi::RayProbe probe(recorder);
      probe.record(bounce);
      recorder.run_pass();
      const xi::RayBatch& rays = probe.recorded();
      Embree embree(recorder.compiled().tri_verts, embree_quality);
      std::vector<double> xi_s, em_s, em16_s;
      std::vector<glm::vec4> hits;
      std::vector<int> prim, prim16;
      for (int r = 0; r < runs; ++r) {
        xi_s.push_back(probe.trace_closest(rays, &hits, bounce));
        em_s.push_back(embree.trace(rays, &prim));
        em16_s.push_back(embree.trace16(rays, bounce == 0, &prim16));
      }
      size_t agree = 0;
      for (size_t i = 0; i < rays.org.size(); ++i) {
        int ours = hits[i].x < 0.0f ? -1 : (int)as_uint(hits[i].w);
        agree += ours == prim[i];
      }
      double n = (double)rays.org.size();
      double xi_rate = n / median(xi_s) * 1e-6, em_rate = n / median(em_s) * 1e-6;
      std::printf("%-13s %9zu rays  xi extend %7.2f Mrays/s  embree %7.2f Mrays/s  ratio %.3f  same hit %.3f%%\n",
                  bounce == 0 ? "camera rays" : "bounce rays", rays.org.size(), xi_rate, em_rate, xi_rate / em_rate,
                  100.0 * agree / n);
      const double em16_rate = n / median(em16_s) * 1e-6;
      std::printf("%-13s embree rtcIntersect16 %7.2f Mrays/s (packets of 16 in the recorded order)  xi / packets "
                  "%.3f  packet / single hits the same %.3f%%\n",
                  "", em16_rate, xi_rate / em16_rate,
                  100.0 * (double)std::inner_product(prim.begin(), prim.end(), prim16.begin(), size_t{0}, std::plus<>(),
                                                     std::equal_to<>()) / n);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "xi_ceiling: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
