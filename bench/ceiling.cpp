// The ceiling: xi's extend and shadow kernels against Embree on the same rays, same scene, same
// run. Rays: camera rays, the rays of bounces 1 and 2 and the shadow rays of all three, recorded from a
// wave of a real render of the scene holding --spp samples of every pixel (4 by default, as a
// 512×512 render's waves do, each pixel's samples side by side), traced as the renderer traces them
// at that bounce (in packets, hybrid packets or alone: layout.h's XI_EXTEND_RAYS, XI_SHADOW_RAYS).
// Embree traces them one at a time (rtcIntersect1, rtcOccluded1) and in packets of 16 consecutive
// rays (rtcIntersect16, rtcOccluded16), which is how Mitsuba 3's LLVM variant calls the same Embree
// (its wheel links Embree 3.13.4). Prints Mrays/s (medians of several timed runs), how often the
// answers agree, and how many rays xi found a hit for.
// --rays-out DIR also writes the rays (float32 origin xyz, tmax, direction xyz, 0) for bench/peers.py
// to time Mitsuba's own ray queries on them.
// --build instead times the two builds alone on the scene's triangles, no device needed: xi's
// build_bvh (8 and 4 wide, with and without spatial splits, on every core) against Embree's
// rtcCommitScene at each build quality (on every core too, through TBB); medians of RUNS.
#include <embree3/rtcore.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numeric>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "xi/bvh.h"
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

// Ray i of the batch as Embree takes one ray, from 0 to tfar.
RTCRay embree_ray(const xi::RayBatch& rays, size_t i, float tfar) {
  RTCRay r{};
  r.org_x = rays.org[i].x;
  r.org_y = rays.org[i].y;
  r.org_z = rays.org[i].z;
  r.dir_x = rays.dir[i].x;
  r.dir_y = rays.dir[i].y;
  r.dir_z = rays.dir[i].z;
  r.tnear = 0.0f;
  r.tfar = tfar;
  r.mask = ~0u;
  return r;
}

// The same as lane k of a packet of 16.
void set_embree_lane(RTCRay16* r, size_t k, const xi::RayBatch& rays, size_t i, float tfar) {
  r->org_x[k] = rays.org[i].x;
  r->org_y[k] = rays.org[i].y;
  r->org_z[k] = rays.org[i].z;
  r->dir_x[k] = rays.dir[i].x;
  r->dir_y[k] = rays.dir[i].y;
  r->dir_z[k] = rays.dir[i].z;
  r->tnear[k] = 0.0f;
  r->tfar[k] = tfar;
  r->mask[k] = ~0u;
  r->time[k] = 0.0f;
  r->flags[k] = 0;
}

struct Embree {
  RTCDevice device = rtcNewDevice(nullptr);
  RTCScene scene = rtcNewScene(device);
  double build_seconds = 0.0;  // rtcCommitScene's, after the vertices are in Embree's buffer

  // vertices: positions (xyz); tris: each triangle's corners (xyz), indices into vertices.
  Embree(std::span<const glm::vec4> vertices, std::span<const glm::uvec4> tris, RTCBuildQuality quality) {
    const size_t n = tris.size();
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = (float*)rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                              vertices.size());
    auto* idx = (unsigned*)rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                   3 * sizeof(unsigned), n);
    for (size_t i = 0; i < vertices.size(); ++i) {
      v[3 * i] = vertices[i].x;
      v[3 * i + 1] = vertices[i].y;
      v[3 * i + 2] = vertices[i].z;
    }
    for (size_t i = 0; i < n; ++i)
      for (int k = 0; k < 3; ++k) idx[3 * i + k] = tris[i][k];
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcSetSceneBuildQuality(scene, quality);
    auto start = std::chrono::steady_clock::now();
    rtcCommitScene(scene);
    build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
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
        rh.ray = embree_ray(rays, i, INFINITY);
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &ctx, &rh);
        if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) (*prim)[i] = (int)rh.hit.primID;
      }
    });
  }

  // Any-hit queries (org.w: tmax) one ray at a time; *occluded gets 1 where a ray is blocked.
  double occluded(const xi::RayBatch& rays, std::vector<char>* occluded) {
    const size_t n = rays.org.size();
    occluded->assign(n, 0);
    return on_all_cores([&](unsigned t, unsigned threads) {
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      for (size_t i = t; i < n; i += threads) {
        RTCRay r = embree_ray(rays, i, rays.org[i].w);
        rtcOccluded1(scene, &ctx, &r);
        (*occluded)[i] = r.tfar < 0.0f;
      }
    });
  }

  // The same with rtcOccluded16 on packets of 16 consecutive rays.
  double occluded16(const xi::RayBatch& rays, std::vector<char>* occluded) {
    const size_t n = rays.org.size(), packets = (n + 15) / 16;
    occluded->assign(n, 0);
    return on_all_cores([&](unsigned t, unsigned threads) {
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
      alignas(64) RTCRay16 r;
      alignas(64) int valid[16];
      for (size_t p = t; p < packets; p += threads) {
        for (size_t k = 0; k < 16; ++k) {
          const size_t i = std::min(p * 16 + k, n - 1);
          valid[k] = p * 16 + k < n ? -1 : 0;
          set_embree_lane(&r, k, rays, i, rays.org[i].w);
        }
        rtcOccluded16(valid, scene, &ctx, &r);
        for (size_t k = 0; k < 16 && p * 16 + k < n; ++k) (*occluded)[p * 16 + k] = r.tfar[k] < 0.0f;
      }
    });
  }

  // Closest hits with rtcIntersect16 on packets of 16 consecutive rays (a thread takes every
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
          set_embree_lane(&rh.ray, k, rays, i, INFINITY);
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

const char* rays_kind(int rays) {
  return rays == XI_RAYS_TOGETHER ? "packets" : rays == XI_RAYS_HYBRID ? "hybrid packets" : "alone";
}

// Origins (w: tmax) and directions, one after the other per ray, as float32.
void write_rays(const std::filesystem::path& file, const xi::RayBatch& rays) {
  std::ofstream out(file, std::ios::binary);
  for (size_t i = 0; i < rays.org.size(); ++i) {
    out.write((const char*)&rays.org[i], sizeof(glm::vec4));
    out.write((const char*)&rays.dir[i], sizeof(glm::vec4));
  }
  if (!out) throw xi::Error("cannot write the rays", file.string());
}

// `hits`: the rays xi found a hit for (a shadow ray: occluded), which peers.py holds Mitsuba's count to.
void print_row(const char* what, size_t count, double xi_rate, int rays, double embree_rate, double embree16_rate,
               double same, size_t hits) {
  std::printf("%-13s %9zu rays  xi %7.2f Mrays/s (%s)  embree %7.2f Mrays/s  embree x16 %7.2f Mrays/s  same %.3f%%"
              "  hits %zu\n",
              what, count, xi_rate, rays_kind(rays), embree_rate, embree16_rate, same, hits);
}

// --build: both builders on the scene's triangles, RUNS times each, interleaved.
void time_builds(const xi::Scene& scene, int runs) {
  std::vector<glm::vec4> verts;
  std::vector<glm::uvec4> corners;
  verts.reserve(scene.vertices.size());
  corners.reserve(scene.triangles.size());
  for (const xi::Vertex& v : scene.vertices) verts.push_back(glm::vec4(v.position, 0.0f));
  for (const xi::Triangle& t : scene.triangles) corners.push_back(glm::uvec4(t.v[0], t.v[1], t.v[2], 0u));
  struct Row {
    std::string name;
    std::function<double()> build;
    std::vector<double> seconds;
  };
  std::vector<Row> rows;
  for (int width : {8, 4})
    for (bool splits : {true, false})
      rows.push_back({"xi " + std::to_string(width) + "-wide" + (splits ? ", spatial splits" : ""), [&, width, splits] {
                        return xi::build_bvh(scene, width, splits).stats.build_seconds;
                      }});
  for (const char* quality : {"high", "medium", "low"})
    rows.push_back({std::string("embree ") + quality, [&, quality] {
                      return Embree(verts, corners, parse_quality(quality)).build_seconds;
                    }});
  for (int r = 0; r < runs; ++r)
    for (Row& row : rows) row.seconds.push_back(row.build());
  for (const Row& row : rows)
    std::printf("%-28s %8.3f s (median of %d; fastest %.3f)\n", row.name.c_str(), median(row.seconds), runs,
                *std::min_element(row.seconds.begin(), row.seconds.end()));
}

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  bool build_only = false;
  if (auto at = std::find(args.begin(), args.end(), "--build"); at != args.end()) build_only = true, args.erase(at);
  std::filesystem::path rays_out;
  if (auto at = std::find(args.begin(), args.end(), "--rays-out"); at != args.end()) {
    if (at + 1 == args.end()) args.clear();
    else rays_out = *(at + 1), args.erase(at, at + 2);
  }
  int spp = 4;
  if (auto at = std::find(args.begin(), args.end(), "--spp"); at != args.end()) {
    if (at + 1 == args.end() || (spp = std::atoi((at + 1)->c_str())) < 1) args.clear();
    else args.erase(at, at + 2);
  }
  if (args.empty()) {
    std::fprintf(stderr,
                 "usage: xi_ceiling SCENE.json [RUNS] [WIDTHxHEIGHT] [high|medium|low] [--spp N] [--rays-out DIR]\n"
                 "       xi_ceiling SCENE.json [RUNS] --build\n");
    return 2;
  }
  try {
    int runs = args.size() > 1 ? std::max(1, std::atoi(args[1].c_str())) : 5;
    xi::Scene scene = xi::load_scene(args[0]);
    if (build_only) {
      std::printf("scene %s: %zu triangles; %u host threads\n", args[0].c_str(), scene.triangles.size(),
                  std::thread::hardware_concurrency());
      time_builds(scene, runs);
      return 0;
    }
    if (args.size() > 2 && std::sscanf(args[2].c_str(), "%dx%d", &scene.width, &scene.height) != 2)
      throw xi::Error("expected WIDTHxHEIGHT", args[2]);
    const std::string quality = args.size() > 3 ? args[3] : "high";
    const RTCBuildQuality embree_quality = parse_quality(quality);
    if (!rays_out.empty()) std::filesystem::create_directories(rays_out);
    xi::Device device = xi::Device::open("");
    std::printf("scene %s: %zu triangles, %dx%d, %d spp in one wave; device %s; %u host threads for Embree, build "
                "quality %s\n",
                args[0].c_str(), scene.triangles.size(), scene.width, scene.height, spp, device.info().name.c_str(),
                std::thread::hardware_concurrency(), quality.c_str());
    for (int bounce : {0, 1, 2}) {
      // Row names and --rays-out files: camera rays, bounce rays 1, shadow rays 0, ...; camera.f32, bounce1.f32, ...
      const std::string depth = std::to_string(bounce);
      const std::string closest = bounce == 0 ? "camera rays" : "bounce rays " + depth, shadow = "shadow rays " + depth;
      const std::string closest_file = bounce == 0 ? "camera.f32" : "bounce" + depth + ".f32";
      xi::RenderOptions opt;
      opt.spp = spp;
      opt.paths_in_flight = (size_t)scene.width * scene.height * spp;  // one wave: trace_closest takes them all
      xi::Renderer recorder(device, scene, opt);
      xi::RayProbe probe(recorder);
      probe.record(bounce);
      recorder.run_pass();
      const xi::KernelConfig& k = recorder.kernels();
      // Hits are compared by triangle index, so Embree gets the triangles in the renderer's BVH order
      // (the same build again: the renderer keeps no host copy).
      const xi::CompiledScene ordered =
          xi::compile_scene(scene, xi::KernelConfig::bvh_width_for(device.info(), opt), opt.spatial_splits);
      std::vector<glm::vec4> positions(ordered.vertex_count());
      for (size_t i = 0; i < positions.size(); ++i) positions[i] = glm::vec4(ordered.vertex_position(i), 0.0f);
      Embree embree(positions, ordered.tri_vertices, embree_quality);

      const xi::RayBatch& rays = probe.recorded();
      if (rays.org.empty()) {  // every path ended before this bounce (all escaped, say): so do later ones
        std::printf("%-13s: no rays, every path has ended\n", closest.c_str());
        break;
      }
      std::vector<double> xi_s, em_s, em16_s;
      std::vector<glm::vec4> hits;
      std::vector<int> prim, prim16;
      for (int r = 0; r < runs; ++r) {
        xi_s.push_back(probe.trace_closest(rays, &hits, bounce));
        em_s.push_back(embree.trace(rays, &prim));
        em16_s.push_back(embree.trace16(rays, bounce == 0, &prim16));
      }
      size_t agree = 0, hit_count = 0;
      for (size_t i = 0; i < rays.org.size(); ++i) {
        int ours = hits[i].x < 0.0f ? -1 : (int)as_uint(hits[i].w);
        agree += ours == prim[i] && prim[i] == prim16[i];
        hit_count += ours >= 0;
      }
      const double n = (double)rays.org.size();
      print_row(closest.c_str(), rays.org.size(), n / median(xi_s) * 1e-6,
                XI_EXTEND_RAYS(k.bvh_width, bounce, k.ray_packets, k.hybrid_packets), n / median(em_s) * 1e-6,
                n / median(em16_s) * 1e-6, 100.0 * agree / n, hit_count);

      const xi::RayBatch& shadow_rays = probe.recorded_shadow();
      if (!shadow_rays.org.empty()) {
        std::vector<double> xs, es, e16s;
        std::vector<bool> xi_occ;
        std::vector<char> em_occ, em16_occ;
        for (int r = 0; r < runs; ++r) {
          xs.push_back(probe.trace_shadow(shadow_rays, &xi_occ, bounce));
          es.push_back(embree.occluded(shadow_rays, &em_occ));
          e16s.push_back(embree.occluded16(shadow_rays, &em16_occ));
        }
        size_t same = 0, occluded = 0;
        for (size_t i = 0; i < shadow_rays.org.size(); ++i) {
          same += xi_occ[i] == (bool)em_occ[i] && em_occ[i] == em16_occ[i];
          occluded += xi_occ[i];
        }
        const double m = (double)shadow_rays.org.size();
        print_row(shadow.c_str(), shadow_rays.org.size(), m / median(xs) * 1e-6,
                  XI_SHADOW_RAYS(k.bvh_width, bounce, k.ray_packets, k.hybrid_packets), m / median(es) * 1e-6,
                  m / median(e16s) * 1e-6, 100.0 * same / m, occluded);
      }
      if (!rays_out.empty()) {
        write_rays(rays_out / closest_file, rays);
        write_rays(rays_out / ("shadow" + depth + ".f32"), shadow_rays);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "xi_ceiling: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
