// Each wavefront stage kernel run alone on the OpenCL CPU device with fixed inputs, its outputs
// compared with the same quantities computed on the host (the shared headers compile as C++).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <numeric>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "layout.h"
#include "sampling.h"
#include "xi/compiled_scene.h"
#include "xi/device.h"
#include "xi/kernel_config.h"
#include "xi/scene.h"

#include "brute_force.h"

namespace {

using xi::test::BruteForce;
using xi::test::HostHit;

using glm::vec3;
using glm::vec4;

constexpr size_t kLocal = 64;  // the renderer's work-group size; global sizes are rounded up to it
constexpr uint32_t kGarbage = 0xdeadbeefu;  // fills buffers so that unwritten values show

size_t round_up(size_t n) { return (n + kLocal - 1) / kLocal * kLocal; }

template <class T>
std::vector<T> garbage(size_t n) {
  std::vector<T> v(n);
  std::vector<uint32_t> words(sizeof(T) * n / 4, kGarbage);
  std::memcpy(v.data(), words.data(), sizeof(T) * n);
  return v;
}

template <class T>
bool same_bits(const T& a, const T& b) { return std::memcmp(&a, &b, sizeof(T)) == 0; }

// One program with every stage, built once for the suite, extend and shadow again for 8-wide BVH
// nodes (the default one traverses 4-wide nodes), twice more with bounce and shadow rays in
// packets (XI_RAY_PACKETS) of 8 rays and of 16, and generate and shade again for 8 lanes (the
// default: 1). Features of the Cornell box (emitters, no lens), so generate is the pinhole camera.
class Kernel : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    device_.emplace(xi::Device::open(""));
    xi::KernelConfig c;
    c.features = xi::compile_scene(xi::load_scene(XI_SCENE_DIR "/cornell-box.json")).features;
    c.sampler = XI_SAMPLER_RANDOM;
    c.cpu_device = device_->info().type == "CPU";
    program_.emplace(xi::build_program(*device_, {"generate.cl", "extend.cl", "shade.cl", "shadow.cl", "accumulate.cl"},
                                       c.defines()));
    shading_word_ = c.shading_word();
    xi::KernelConfig lanes8 = c, width8 = c, packets8 = c;
    lanes8.lanes = 8;
    width8.bvh_width = packets8.bvh_width = 8;
    packets8.ray_packets = true;
    lanes8_.emplace(xi::build_program(*device_, {"generate.cl", "shade.cl"}, lanes8.defines()));
    program8_.emplace(xi::build_program(*device_, {"extend.cl", "shadow.cl"}, width8.defines()));
    ray_packets8_.emplace(xi::build_program(*device_, {"extend.cl", "shadow.cl"}, packets8.defines()));
    xi::KernelConfig packets16 = packets8;
    packets16.packet_width = 16;
    ray_packets16_.emplace(xi::build_program(*device_, {"extend.cl", "shadow.cl"}, packets16.defines()));
    xi::KernelConfig hybrid8 = width8, hybrid16 = width8;
    hybrid8.hybrid_packets = hybrid16.hybrid_packets = true;
    hybrid16.packet_width = 16;
    hybrid8_.emplace(xi::build_program(*device_, {"extend.cl", "shadow.cl"}, hybrid8.defines()));
    hybrid16_.emplace(xi::build_program(*device_, {"extend.cl", "shadow.cl"}, hybrid16.defines()));
    // 16 lanes and packets of 16, with the shuffles that move float4s between rows and lanes and with
    // their value-by-value form (compat.h's XI_HAS_SHUFFLE), which must give the same bits.
    xi::KernelConfig wide = packets16;
    wide.lanes = 16;
    std::vector<std::string> portable = wide.defines();
    portable.push_back("XI_PORTABLE_SHUFFLES");
    lanes16_.emplace(xi::build_program(*device_, {"generate.cl", "shade.cl"}, wide.defines()));
    portable16_.emplace(xi::build_program(*device_, {"generate.cl", "shade.cl", "extend.cl", "shadow.cl"}, portable));
  }
  static void TearDownTestSuite() {  // release OpenCL objects before the driver unloads
    program_.reset();
    program8_.reset();
    ray_packets8_.reset();
    ray_packets16_.reset();
    hybrid8_.reset();
    hybrid16_.reset();
    lanes8_.reset();
    lanes16_.reset();
    portable16_.reset();
    device_.reset();
  }

  // The programs holding generate and shade, by the paths each work item takes: 1, 8, 16, and 16
  // moving values one by one instead of by shuffles.
  struct ShadingProgram {
    int lanes;
    const xi::Program* program;
    const char* form;
  };
  static std::vector<ShadingProgram> shading_programs() {
    return {{1, &*program_, "1 lane"},
            {8, &*lanes8_, "8 lanes"},
            {16, &*lanes16_, "16 lanes"},
            {16, &*portable16_, "16 lanes, no shuffles"}};
  }

  cl::Context& ctx() { return device_->context(); }
  cl::CommandQueue& queue() { return device_->queue(); }
  cl::Kernel kernel(const char* name, int bvh_width = 4) {
    return cl::Kernel((bvh_width == 8 ? program8_ : program_)->program, name);
  }
  // A compiled scene's BVH nodes, of whichever width it was built with.
  cl::Buffer bvh_nodes(const xi::Bvh& bvh) { return bvh.width == 8 ? buffer(bvh.nodes8) : buffer(bvh.nodes); }

  template <class T, class A>
  cl::Buffer buffer(const std::vector<T, A>& data) {
    return cl::Buffer(ctx(), CL_MEM_READ_WRITE | CL_MEM_COPY_HOST_PTR, sizeof(T) * data.size(),
                      const_cast<T*>(data.data()));
  }
  template <class T>
  std::vector<T> read(const cl::Buffer& b, size_t n) {
    std::vector<T> v(n);
    queue().enqueueReadBuffer(b, CL_TRUE, 0, sizeof(T) * n, v.data());
    return v;
  }
  void launch(cl::Kernel& k, size_t items) {
    queue().enqueueNDRangeKernel(k, cl::NullRange, cl::NDRange(round_up(items)), cl::NDRange(kLocal));
    queue().finish();
  }

  // The path state, one buffer per XI_PATH_STATE field, of `slots` entries filled with garbage;
  // bind() sets them as a kernel's first arguments, in macro order, as the renderer does.
  struct PathState {
#define XI_FIELD(type, name) std::vector<type> name;
    XI_PATH_STATE(XI_FIELD)
#undef XI_FIELD
    explicit PathState(size_t slots) {
#define XI_FILL(type, name) name = garbage<type>(slots);
      XI_PATH_STATE(XI_FILL)
#undef XI_FILL
    }
  };
  // Every buffer of two path states holds the same bits.
  static void expect_same_bits(const PathState& a, const PathState& b) {
#define XI_COMPARE(type, name) \
  EXPECT_EQ(std::memcmp(a.name.data(), b.name.data(), a.name.size() * sizeof(type)), 0) << #name " differs";
    XI_PATH_STATE(XI_COMPARE)
#undef XI_COMPARE
  }

  struct PathBuffers {
#define XI_FIELD(type, name) cl::Buffer name;
    XI_PATH_STATE(XI_FIELD)
#undef XI_FIELD
  };
  PathBuffers upload(const PathState& s) {
    PathBuffers b;
#define XI_UPLOAD(type, name) b.name = buffer(s.name);
    XI_PATH_STATE(XI_UPLOAD)
#undef XI_UPLOAD
    return b;
  }
  // Sets a stage kernel's arguments: the path state first, then `rest` in the order the kernel
  // declares them.
  template <class... Rest>
  static void bind(cl::Kernel& k, const PathBuffers& b, const Rest&... rest) {
    int arg = 0;
#define XI_BIND(type, name) k.setArg(arg++, b.name);
    XI_PATH_STATE(XI_BIND)
#undef XI_BIND
    (k.setArg(arg++, rest), ...);
  }
  PathState download(const PathBuffers& b, size_t slots) {
    PathState s(slots);
#define XI_READ(type, name) s.name = read<type>(b.name, slots);
    XI_PATH_STATE(XI_READ)
#undef XI_READ
    return s;
  }

  static std::optional<xi::Device> device_;
  static std::optional<xi::Program> program_, program8_, ray_packets8_, ray_packets16_, hybrid8_, hybrid16_, lanes8_,
      lanes16_, portable16_;
  static uint32_t shading_word_;  // the programs' own (compiled in; the argument is read by generic programs)
};
std::optional<xi::Device> Kernel::device_;
std::optional<xi::Program> Kernel::program_, Kernel::program8_, Kernel::ray_packets8_, Kernel::ray_packets16_,
    Kernel::hybrid8_, Kernel::hybrid16_, Kernel::lanes8_, Kernel::lanes16_, Kernel::portable16_;
uint32_t Kernel::shading_word_ = 0;

vec3 random_direction(std::mt19937& rng) {
  std::normal_distribution<float> g;
  return glm::normalize(vec3(g(rng), g(rng), g(rng)));
}

// A box of 12 triangles, rotated about `axis`.
void add_box(xi::Mesh& out, vec3 center, vec3 half, vec3 axis, float radians) {
  vec3 a = glm::normalize(axis);
  auto rot = [&](vec3 p) {  // Rodrigues
    return p * std::cos(radians) + glm::cross(a, p) * std::sin(radians) + a * glm::dot(a, p) * (1 - std::cos(radians));
  };
  vec3 c[8];
  for (int i = 0; i < 8; ++i)
    c[i] = center + rot(half * vec3(i & 1 ? 1 : -1, i & 2 ? 1 : -1, i & 4 ? 1 : -1));
  const int faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (auto& f : faces)
    for (auto [i, j, k] : {std::array{f[0], f[1], f[2]}, std::array{f[0], f[2], f[3]}})
      out.add_triangle(c[i], c[j], c[k]);
}

// The extend tests' scene: an icosphere of radius 1 at the origin (its kSphereTriangles triangles
// first) and three boxes: one cutting into the sphere, one thin slab under it, one rotated.
constexpr size_t kSphereTriangles = 20480;
xi::Scene sphere_and_boxes() {
  xi::Scene scene = xi::parse_scene(R"({
    "camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [{"type": "sphere", "material": "white", "center": [0, 0, 0], "radius": 1, "subdivisions": 5}]})",
                                    "extend.json", ".");
  add_box(scene, vec3(0.9f, 0.6f, 0.2f), vec3(0.4f, 0.3f, 0.5f), vec3(0, 0, 1), 0.0f);
  add_box(scene, vec3(0.0f, -1.3f, 0.0f), vec3(2.0f, 0.05f, 2.0f), vec3(0, 1, 0), 0.0f);
  add_box(scene, vec3(-1.6f, 0.4f, 0.8f), vec3(0.3f, 0.7f, 0.2f), vec3(1, 2, 3), 0.7f);
  return scene;
}

// --- extend --------------------------------------------------------------------------------------

// 10^5 random rays against sphere_and_boxes(), in a shuffled queue; hits over 4- and 8-wide BVHs
// against brute force.
TEST_F(Kernel, ExtendMatchesBruteForce) {
  const xi::Scene scene = sphere_and_boxes();
  ASSERT_EQ(scene.triangles.size(), kSphereTriangles + 36u);

  const uint32_t n = 100000, extra = 64, slots = n + extra;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> box(-2.5f, 2.5f);
  PathState state(slots);
  for (uint32_t i = 0; i < slots; ++i) {
    state.ray_org[i] = vec4(box(rng), box(rng), box(rng), 0.0f);
    state.ray_dir[i] = vec4(random_direction(rng), 0.0f);
  }
  // Queue entries [0, n) are the rays in shuffled order; the entries past `count` point at the extra
  // slots, which the work items beyond `count` in the rounded-up launch must not touch.
  std::vector<uint32_t> q(slots);
  std::iota(q.begin(), q.end(), 0u);
  std::shuffle(q.begin(), q.begin() + n, rng);

  // The queue length comes from the counters of bounce 3; the launch covers every slot, as the
  // renderer launches over an upper bound.
  const uint32_t bounce = 3;
  std::vector<uint32_t> counters(XI_COUNTER_COUNT(8), 7u);
  counters[XI_COUNTER_RAYS(bounce)] = n;
  // The hits of the extend kernel over a BVH of either width. Both hold triangles in the same order
  // (the binary build's), so a hit's position means the same triangle in both.
  const xi::CompiledScene cs = xi::compile_scene(scene, 4), cs8 = xi::compile_scene(scene, 8);
  EXPECT_EQ(cs8.bvh.order, cs.bvh.order);
  auto trace = [&](const xi::CompiledScene& wide) {
    PathBuffers b = upload(state);
    cl::Buffer qb = buffer(q), cb = buffer(counters), nodes = bvh_nodes(wide.bvh), blocks = buffer(wide.bvh.blocks);
    cl::Kernel k = kernel("extend", wide.bvh.width);
    bind(k, b, qb, cb, bounce, nodes, blocks);
    launch(k, slots);
    return read<vec4>(b.hit, slots);
  };
  const std::vector<vec4> hit_by_width[2] = {trace(cs), trace(cs8)};

  BruteForce brute(scene);
  int hits[2] = {}, ties = 0, bad[2] = {};
  for (uint32_t i = 0; i < n && bad[0] + bad[1] < 10; ++i) {
    const vec3 o(state.ray_org[i]), d(state.ray_dir[i]);
    auto ref = brute.hits(o, d, INFINITY);
    if (i < 200) {  // the culled reference finds exactly what testing every triangle finds
      auto all = brute.hits(o, d, INFINITY, false);
      ASSERT_EQ(ref.size(), all.size());
      for (size_t j = 0; j < ref.size(); ++j) ASSERT_EQ(ref[j].tri, all[j].tri);
    }
    // A tie: the two nearest hits within 1e-5 relative t (a shared edge or vertex); the kernel may
    // report either, and its float contraction (-cl-mad-enable) may move the edge by an ulp.
    bool tie = ref.size() > 1 && ref[1].t <= ref[0].t * (1.0f + 1e-5f);
    ties += tie;
    for (int w = 0; w < 2; ++w) {
      const vec4 h = hit_by_width[w][i];
      SCOPED_TRACE(testing::Message() << (w ? 8 : 4) << "-wide BVH, slot " << i << ", hit (" << h.x << ", " << h.y
                                      << ", " << h.z << ", " << as_uint(h.w) << ")");
      if (ref.empty()) {
        bad[w] += !same_bits(h, vec4(-1.0f, 0.0f, 0.0f, 0.0f));
        EXPECT_TRUE(same_bits(h, vec4(-1.0f, 0.0f, 0.0f, 0.0f))) << "brute force misses";  // misses agree exactly
        continue;
      }
      hits[w]++;
      uint32_t pos = as_uint(h.w);
      if (!(h.x > 0.0f) || pos >= cs.bvh.order.size()) {
        bad[w]++;
        ADD_FAILURE() << "kernel missed triangle " << ref[0].tri << " at t = " << ref[0].t;
        continue;
      }
      uint32_t tri = cs.bvh.order[pos];
      auto same = std::find_if(ref.begin(), ref.end(), [&](const HostHit& r) { return r.tri == tri; });
      if (tie ? (same == ref.end() || same->t > ref[0].t * (1.0f + 1e-5f)) : tri != ref[0].tri) {
        bad[w]++;
        ADD_FAILURE() << "kernel hit triangle " << tri << ", nearest is " << ref[0].tri << " at t = " << ref[0].t;
        continue;
      }
      // Same triangle test, but the device fuses multiply-adds: t is a quotient of sums of products of
      // vertex coordinates relative to the origin, so its rounding error scales with the largest of
      // those distances, not with t (origins close to a face give t ≪ scale).
      float scale = same->t;
      for (auto& v : brute.tris[tri]) scale = std::max(scale, glm::length(v - o));
      bad[w] += std::abs(h.x - same->t) > 1e-5f * scale;
      EXPECT_NEAR(h.x, same->t, 1e-5f * scale);  // 1e-5 relative to the coordinates' scale: ~100 ulps
      // Barycentrics are edge functions (2×2 determinants of the vertices' offsets across the ray) over
      // their sum: a few-ulp error in each is relative to the offsets squared, and the division scales
      // it by their ratio to the determinant, large for grazing hits (NVIDIA's compiler contracts
      // differently from PoCL's and showed 1.06e-4 on one such hit).
      const auto& tv = brute.tris[tri];
      float offset2 = 0.0f;
      for (auto& v : tv) {
        const vec3 e = v - o;
        offset2 = std::max(offset2, glm::dot(e, e) - glm::dot(e, d) * glm::dot(e, d));
      }
      const float det = std::abs(glm::dot(glm::cross(tv[1] - tv[0], tv[2] - tv[0]), d));
      const float uv_tol = 1e-4f * std::max(1.0f, offset2 / det);
      EXPECT_NEAR(h.y, same->u, uv_tol);
      EXPECT_NEAR(h.z, same->v, uv_tol);
    }
  }
  for (int w = 0; w < 2; ++w) {
    SCOPED_TRACE(testing::Message() << (w ? 8 : 4) << "-wide BVH");
    EXPECT_EQ(bad[w], 0);
    EXPECT_GT(hits[w], (int)n / 5);  // both outcomes well represented
    EXPECT_LT(hits[w], (int)n * 9 / 10);
    for (uint32_t i = n; i < slots; ++i)
      EXPECT_EQ(as_uint(hit_by_width[w][i].x), kGarbage) << "slot " << i << " is not queued";
  }
  EXPECT_LT(ties, (int)n / 1000);  // edge ties are rare for random rays: < 0.1%
}

// Rays in packets (xi_trace_packet: extend at bounce 0 on an 8-wide tree, and at any bounce with
// XI_RAY_PACKETS, 8 or 16 queue entries per work item) find the hits that one ray per work item
// finds (extend at bounce 1 without it), bitwise but for ties: where two triangles are hit at the
// same t (a shared edge), the order of traversal may pick the other. The scene sphere_and_boxes();
// packets of 8 (and then of 16) rays of six kinds, cycled: camera fans (one origin outside,
// directions a pixel apart), thin-lens fans (origins on a lens, aimed at one focus), fans from
// inside the closed icosphere aimed exactly at the vertices and edges of one of its triangles
// (where a crack would let a ray escape: none may), fans leaving a point on the sphere (whose own
// triangle the error bound of t must refuse), all of which share one axis permutation and near
// planes (the packet's shared path), and two kinds that do not, as bounce rays do not (its per-ray
// path): random directions (different axis permutations) and fans across the plane x = 0 (different
// near planes). 4001 packets and a last one of five rays, traced one at a time, in a queue whose
// entries past the count point at slots that no work item may touch.
TEST_F(Kernel, PacketsFindTheHitsOfSingleRays) {
  for (const uint32_t w : {8u, 16u}) {
    SCOPED_TRACE(testing::Message() << "packets of " << w);
    const xi::Scene scene = sphere_and_boxes();
    const size_t sphere_tris = kSphereTriangles;
    ASSERT_EQ(scene.triangles.size(), kSphereTriangles + 36u);
    const xi::CompiledScene cs = xi::compile_scene(scene, 8);

    enum Kind { kCamera, kLens, kInside, kSurface, kRandom, kStraddle, kKinds };
    const uint32_t packets = 4001, n = w * packets + 5, extra = 64, slots = n + extra;
    std::mt19937 rng(29);
    std::uniform_real_distribution<float> u01(0.0f, 1.0f), jitter(-1e-3f, 1e-3f);
    std::uniform_real_distribution<float> box(-2.0f, 2.0f);
    PathState state(slots);
    std::vector<int> kind(slots, kRandom);
    for (uint32_t p = 0; p * w < n; ++p) {
      const Kind k = (Kind)(p % kKinds);
      const vec3 eye(0.0f, 0.0f, -5.0f), target(box(rng), box(rng), box(rng));
      const vec3 inside = 0.5f * vec3(u01(rng), u01(rng), u01(rng));
      const xi::Triangle& aim_tri = scene.triangles[(size_t)(u01(rng) * (float)sphere_tris) % sphere_tris];
      const vec3 aim[3] = {scene.position(aim_tri, 0), scene.position(aim_tri, 1), scene.position(aim_tri, 2)};
      const vec3 origin_random(box(rng), box(rng), box(rng));
      for (uint32_t lane = 0; lane < w && w * p + lane < n; ++lane) {
        const uint32_t i = w * p + lane;
        vec3 o = eye, d;
        if (k == kCamera) {
          d = glm::normalize(target - eye) + vec3(lane * 1e-3f, 0.0f, 0.0f);  // a row of pixels
        } else if (k == kLens) {
          o = eye + vec3(jitter(rng), jitter(rng), 0.0f) * 50.0f;
          d = target - o;
        } else if (k == kInside) {  // the triangle's vertices, its edges' midpoints, two points on an edge
          o = inside;
          const vec3 &a = aim[0], &b = aim[1], &c = aim[2];
          const vec3 points[8] = {a, b, c, 0.5f * (a + b), 0.5f * (b + c), 0.5f * (c + a), a + u01(rng) * (b - a),
                                  b + u01(rng) * (c - b)};
          d = points[lane % 8] - o;
        } else if (k == kSurface) {  // from a point of the triangle, outwards
          o = aim[0] + 0.3f * (aim[1] - aim[0]) + 0.3f * (aim[2] - aim[0]);
          d = glm::normalize(glm::cross(aim[1] - aim[0], aim[2] - aim[0])) + vec3(lane * 1e-3f, 0.0f, 0.0f);
          if (glm::dot(d, o) < 0.0f) d = -d;
        } else if (k == kRandom) {
          o = origin_random;
          d = random_direction(rng);
        } else {  // across x = 0
          d = vec3((float)lane - 3.5f, 0.0f, 0.0f) * 1e-3f + glm::normalize(vec3(0.0f, target.y, 5.0f));
        }
        state.ray_org[i] = vec4(o, 0.0f);
        state.ray_dir[i] = vec4(glm::normalize(d), 0.0f);
        kind[i] = k;
      }
    }
    std::vector<uint32_t> q(slots);
    std::iota(q.begin(), q.end(), 0u);

    // Which packets share one axis permutation and one sign per axis (as xi_packet decides):
    // the four kinds meant to, mostly, and never random or straddling rays, so both paths are taken.
    size_t together = 0;
    for (uint32_t p = 0; p + 1 < (n + w - 1) / w; ++p) {
      int kz0 = -1;
      bool same = true;
      glm::bvec3 back0{};
      for (uint32_t lane = 0; lane < w; ++lane) {
        const vec3 d(state.ray_dir[w * p + lane]), a = glm::abs(d);
        const int kz = a.x > a.y ? (a.x > a.z ? 0 : 2) : (a.y > a.z ? 1 : 2);
        const glm::bvec3 back = glm::lessThan(d, vec3(0.0f));
        if (lane == 0) kz0 = kz, back0 = back;
        same = same && kz == kz0 && back == back0;
      }
      const int k = kind[w * p];
      if (k == kRandom || k == kStraddle) EXPECT_FALSE(same) << "packet " << p << " should take the per-ray path";
      together += same;
    }
    EXPECT_GE(together, (size_t)packets / 2);  // most of the four kinds meant to share

    // w rays per work item at bounce 0, at bounce 3 with ray packets (and, 16 of them, without
    // shuffles: kPortable) and at bounce 1 with hybrid packets; one at bounce 1 without.
    enum Program { kPlain, kPackets, kHybrid, kPortable };
    auto trace = [&](uint32_t bounce, Program program) {
      PathBuffers b = upload(state);
      std::vector<uint32_t> counters(XI_COUNTER_COUNT(8), 7u);
      counters[XI_COUNTER_RAYS(bounce)] = n;
      cl::Buffer qb = buffer(q), cb = buffer(counters), nodes = bvh_nodes(cs.bvh), blocks = buffer(cs.bvh.blocks);
      // Packets of 16: bounce 0 from the program with ray packets too.
      const xi::Program& packets = w == 16 ? *ray_packets16_ : *ray_packets8_;
      const xi::Program& hybrid = w == 16 ? *hybrid16_ : *hybrid8_;
      cl::Kernel k = program == kHybrid                               ? cl::Kernel(hybrid.program, "extend")
                     : program == kPortable                            ? cl::Kernel(portable16_->program, "extend")
                     : program == kPackets || (w == 16 && bounce == 0) ? cl::Kernel(packets.program, "extend")
                                                                       : kernel("extend", 8);
      bind(k, b, qb, cb, bounce, nodes, blocks);
      const bool packets_always = program == kPackets || program == kPortable;
      const int rays = XI_EXTEND_RAYS(8, bounce, packets_always ? 1 : 0, program == kHybrid ? 1 : 0);
      EXPECT_EQ(rays, bounce == 0 || packets_always ? XI_RAYS_TOGETHER
                      : program == kHybrid               ? XI_RAYS_HYBRID
                                                         : XI_RAYS_ALONE);
      launch(k, slots / XI_RAYS_PER_ITEM(rays, w) + 1);
      return read<vec4>(b.hit, slots);
    };
    const std::vector<vec4> packet = trace(0, kPlain), single = trace(1, kPlain), bounce_packet = trace(3, kPackets),
                            hybrid = trace(1, kHybrid);
    for (uint32_t i = 0; i < slots; ++i)
      if (!same_bits(packet[i], bounce_packet[i]))
        ADD_FAILURE() << "slot " << i << ": a bounce packet's hit is not the camera packet's";
    if (w == 16) {
      const std::vector<vec4> portable = trace(3, kPortable);
      EXPECT_EQ(std::memcmp(portable.data(), bounce_packet.data(), slots * sizeof(vec4)), 0)
          << "packets without shuffles found other hits";
    }
    for (const bool is_hybrid : {false, true}) {
      SCOPED_TRACE(is_hybrid ? "hybrid packets" : "packets");
      const std::vector<vec4>& together = is_hybrid ? hybrid : packet;
      size_t aimed_ties = 0, other_ties = 0, differ = 0, hits = 0, inside = 0;
      for (uint32_t i = 0; i < n; ++i) {
        const vec4 a = together[i], b = single[i];
        hits += b.x > 0.0f;
        if (kind[i] == kInside) {
          inside++;
          EXPECT_GT(a.x, 0.0f) << "ray " << i << " from inside the sphere escaped its packet";
          EXPECT_GT(b.x, 0.0f) << "ray " << i << " from inside the sphere escaped";
        }
        if (same_bits(a, b)) continue;
        const bool tie = a.x > 0.0f && b.x > 0.0f && as_uint(a.w) != as_uint(b.w) &&
                         std::abs(a.x - b.x) <= 1e-5f * std::max(a.x, b.x);
        (kind[i] == kInside ? aimed_ties : other_ties) += tie;  // rays aimed at edges tie often
        differ += !tie;
        if (!tie && differ <= 10)
          ADD_FAILURE() << "ray " << i << " (kind " << kind[i] << "): packet hit (" << a.x << ", " << as_uint(a.w)
                        << "), alone (" << b.x << ", " << as_uint(b.w) << ")";
      }
      EXPECT_EQ(differ, 0u);
      EXPECT_LE(other_ties, (size_t)n / 1000) << "ties at shared edges are rare but where rays are aimed at them";
      EXPECT_LE(aimed_ties, inside / 4);
      EXPECT_GT(hits, (size_t)n / 2);  // so that agreeing says something
      EXPECT_GE(inside, (size_t)n / 7);
      for (uint32_t i = n; i < slots; ++i)
        EXPECT_EQ(as_uint(together[i].x), kGarbage) << "slot " << i << " past the count";
    }
  }
}

// The lane masks the traversal branches on (one movmskps on PoCL with AVX, a portable form on
// other devices, built here too) name exactly the true lanes of every 8-lane comparison, of its
// low four lanes, and of 16-lane comparisons.
TEST_F(Kernel, LaneBitsNameTheTrueLanes) {
  for (std::vector<std::string> defines : {std::vector<std::string>{}, {"XI_PORTABLE_LANE_BITS"}}) {
    SCOPED_TRACE(defines.empty() ? "the device's own form" : "the portable form");
    xi::Program tools = xi::build_program(*device_, {"tools.cl"}, defines);
    cl::Kernel k(tools.program, "lane_bits");
    cl::Buffer out = buffer(garbage<uint32_t>(768));
    k.setArg(0, out);
    launch(k, 256);
    std::vector<uint32_t> bits = read<uint32_t>(out, 768);
    for (uint32_t i = 0; i < 256; ++i) {
      EXPECT_EQ(bits[i], i) << "8 lanes";
      EXPECT_EQ(bits[256 + i], i & 15u) << "4 lanes, mask " << i;
      EXPECT_EQ(bits[512 + i], i | (i ^ 0xa5u) << 8) << "16 lanes, mask " << i;
    }
  }
}

// xi_div (lanes.h), the division generate uses for lanes, against the integer division it
// replaces: divisors of every form (1, powers of two, odd and even ones, those above 2^31, the
// largest) and random ones; numerators at both sides of quotient steps, the largest, and random.
TEST(LaneDivision, MatchesIntegerDivision) {
  std::mt19937 rng(46);
  std::vector<uint32_t> divisors = {1u,  2u,  3u,   4u,   5u,   6u,   7u,          8u,          11u,         37u,
                                    64u, 97u, 511u, 512u, 513u, 641u, 6700417u,    0x7fffffffu, 0x80000000u, 0x80000001u,
                                    0xfffffffeu, 0xffffffffu};
  for (int k = 0; k < 500; ++k) divisors.push_back(std::max(1u, (uint32_t)rng() >> (rng() % 32)));
  uint64_t checked = 0;
  for (uint32_t d : divisors) {
    const XiDivisor by = xi_divisor(d);
    std::vector<uint32_t> numerators = {0u, 1u, 0xfffffffeu, 0xffffffffu};
    for (uint64_t q : {1ull, 2ull, 3ull, 0xffffffffull / d, 0xffffffffull / d / 2 + 1}) {
      const uint64_t n = q * d;  // the first numerator of quotient q, and the last of q - 1
      if (n <= 0xffffffffull) numerators.insert(numerators.end(), {(uint32_t)n, (uint32_t)(n - 1)});
      if (n + 1 <= 0xffffffffull) numerators.push_back((uint32_t)(n + 1));
    }
    for (int k = 0; k < 200; ++k) numerators.push_back(rng());
    for (uint32_t n : numerators) {
      ASSERT_EQ(xi_div(n, by), n / d) << n << " / " << d;
      ++checked;
    }
  }
  EXPECT_GT(checked, 500u * 200u);
}

// --- generate ------------------------------------------------------------------------------------

TEST_F(Kernel, GenerateCameraRays) {
  const int W = 37, H = 23;  // odd and non-square: catches swapped axes and off-by-one centring
  const float vfov = 50.0f;
  xi::Scene scene = xi::parse_scene(R"({
    "camera": {"position": [1, 2, 3], "look_at": [0, 0.5, -1], "up": [0, 1, 0], "fov": 50},
    "film": {"width": 37, "height": 23},
    "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [{"type": "quad", "material": "white", "vertices": [[0,0,0], [1,0,0], [1,1,0], [0,1,0]]}]})",
                                    "generate.json", ".");
  xi::CompiledScene cs = xi::compile_scene(scene);
  ASSERT_FALSE(cs.features.lens);
  const CameraData cam = cs.camera;
  const SamplerParams sp = xi_make_sampler_params(7, 16);
  const uint32_t sample = 5, pixels = W * H, slots = 2048;

  std::vector<vec3> org(pixels), dir(pixels);
  // Two waves of one sample, the second starting mid-row, as the renderer splits large films; then
  // one wave of two samples of every pixel, as it fills a device with a small film; then a film of
  // every third row from row 2 (one process's share of a distributed render), two samples.
  // Last, a wave through a list of film pixels (adaptive sampling: the pixels still sampling), from
  // its entry 3 on.
  // Each with 1, 8 and 16 paths per work item (counts that are not multiples of 8 leave lanes off).
  const uint32_t share_pixels = W * 7;  // rows 2, 5, ..., 20 of 23
  std::vector<uint32_t> list(pixels);
  for (uint32_t i = 0; i < pixels; ++i) list[i] = (i * 7u) % pixels;  // every pixel once (7 and 851 are coprime)
  cl::Buffer list_b = buffer(list);
  for (WaveParams wave : {WaveParams{0, 500, sample, 1, W, 0, 1, 0}, WaveParams{500, pixels - 500, sample, 1, W, 0, 1, 0},
                          WaveParams{0, pixels, sample, 2, W, 0, 1, 0}, WaveParams{0, share_pixels, sample, 2, W, 2, 3, 0},
                          WaveParams{3, 301, sample, 3, W, 0, 1, 1}}) {
    std::optional<PathState> shuffled;  // 16 lanes' outputs, which the form without shuffles must repeat
    for (const ShadingProgram& shading : shading_programs()) {
      SCOPED_TRACE(shading.form);
      const uint32_t count = wave.pixels * wave.samples;
      PathState state(slots);
      PathBuffers b = upload(state);
      cl::Buffer qb = buffer(garbage<uint32_t>(slots));
      cl::Buffer cb = buffer(std::vector<uint32_t>(XI_COUNTER_COUNT(8), 7u));
      cl::Kernel k(shading.program->program, "generate");
      bind(k, b, qb, cb, list_b, cam, sp, shading_word_, wave);
      launch(k, (count + shading.lanes - 1) / shading.lanes);
      PathState out = download(b, slots);
      if (shading.program == &*portable16_) expect_same_bits(out, *shuffled);
      if (shading.program == &*lanes16_) shuffled = out;
      std::vector<uint32_t> q = read<uint32_t>(qb, slots);
      EXPECT_EQ(read<uint32_t>(cb, XI_COUNTER_COUNT(8))[XI_COUNTER_RAYS(0)], count);  // the first queue's length

      for (uint32_t slot = 0; slot < count; ++slot) {
        SCOPED_TRACE(testing::Message() << "slot " << slot << " of the wave at " << wave.first_pixel);
        const uint32_t at = XI_WAVE_PIXEL(wave, slot), s = XI_WAVE_SAMPLE(wave, slot);
        const uint32_t film_pixel = wave.pixel_list ? list[at] : at;
        const uint32_t pixel = (wave.first_row + film_pixel / W * wave.row_stride) * W + film_pixel % W;  // in the frame
        EXPECT_EQ(out.item_pixel[slot], pixel);  // what shade draws its samples for
        EXPECT_EQ(out.item_sample[slot], s);
        if (s != sample) {  // the second sample: a different jitter of the same pixel
          const uint32_t first = XI_WAVE_SLOT(wave, at - wave.first_pixel, 0u);
          EXPECT_GT(glm::length(vec3(out.ray_dir[slot]) - vec3(out.ray_dir[first])), 0.0f);
          continue;
        }
        // generate.cl's formula, evaluated on the host with the same sampler call.
        float2 u = xi_sample_2d(XI_SAMPLER_RANDOM, sp, pixel, s, XI_PAIR_PIXEL);
        float sx = 2.0f * ((float)(pixel % W) + u.x) / (float)W - 1.0f;
        float sy = 1.0f - 2.0f * ((float)(pixel / W) + u.y) / (float)H;
        vec3 want = glm::normalize(vec3(cam.forward) + sx * vec3(cam.right) + sy * vec3(cam.up));
        org[pixel] = vec3(out.ray_org[slot]);
        dir[pixel] = vec3(out.ray_dir[slot]);
        EXPECT_LE(glm::length(org[pixel] - vec3(cam.position)), 1e-5f);  // a pinhole: every ray starts at the eye
        EXPECT_LE(glm::length(dir[pixel] - want), 1e-5f);  // unit vectors; fused multiply-adds move a few ulps
        // Throughput and radiance are left alone: shade knows a camera ray's (1 and 0).
        EXPECT_EQ(as_uint(out.throughput[slot].x), kGarbage);
        EXPECT_EQ(as_uint(out.radiance[slot].x), kGarbage);
        EXPECT_TRUE(same_bits(out.aov_albedo[slot], vec4(0.0f)));
        EXPECT_TRUE(same_bits(out.aov_normal[slot], vec4(0.0f)));
        EXPECT_EQ(q[slot], slot);
      }
      for (uint32_t slot = count; slot < slots; ++slot) {  // beyond `count`, nothing is written
        EXPECT_EQ(as_uint(out.ray_dir[slot].x), kGarbage);
        EXPECT_EQ(q[slot], kGarbage);
      }
    }
  }

  // Geometry, independent of the formula: the camera frame from the scene's own vectors.
  const xi::Camera& c = scene.camera;
  const vec3 F = glm::normalize(c.look_at - c.position), R = glm::normalize(glm::cross(F, c.up)), U = glm::cross(R, F);
  const float tan_v = std::tan(glm::radians(vfov) / 2), tan_h = tan_v * W / H;  // square pixels
  auto tangents = [&](uint32_t pixel) {  // of the ray's horizontal and vertical angles to forward
    vec3 d = dir[pixel];
    return glm::vec2(glm::dot(d, R) / glm::dot(d, F), glm::dot(d, U) / glm::dot(d, F));
  };
  // The centre pixel (W, H odd) covers the film centre: its ray is within half a pixel of forward.
  glm::vec2 centre = tangents((H / 2) * W + W / 2);
  EXPECT_LE(std::abs(centre.x), tan_v / H + 1e-6f);  // half a pixel = tan(vfov/2) / H in tangent units
  EXPECT_LE(std::abs(centre.y), tan_v / H + 1e-6f);
  EXPECT_LE(std::acos(std::min(1.0f, glm::dot(dir[(H / 2) * W + W / 2], F))), std::atan(std::sqrt(2.0f) * tan_v / H) + 1e-5f);
  // Corner pixels: the ray lies in the outermost pixel, so its angles are vfov/2 (and the horizontal
  // counterpart) less at most one pixel; x grows to the right, y upwards, pixel 0 is top-left.
  struct Corner { uint32_t pixel; float sx, sy; };
  for (Corner k : {Corner{0, -1, 1}, Corner{W - 1, 1, 1}, Corner{(H - 1) * W, -1, -1}, Corner{H * W - 1, 1, -1}}) {
    glm::vec2 t = tangents(k.pixel);
    SCOPED_TRACE(testing::Message() << "corner pixel " << k.pixel << ", tangents " << t.x << ", " << t.y);
    EXPECT_GE(k.sx * t.x, tan_h * (1 - 2.0f / W) - 1e-5f);  // 1e-5: float rounding of the frame and dot products
    EXPECT_LE(k.sx * t.x, tan_h + 1e-5f);
    EXPECT_GE(k.sy * t.y, tan_v * (1 - 2.0f / H) - 1e-5f);
    EXPECT_LE(k.sy * t.y, tan_v + 1e-5f);
    float angle = std::atan(k.sy * t.y);  // vertical angle to forward, in radians
    EXPECT_LE(angle, glm::radians(vfov) / 2 + 1e-5f);
    EXPECT_GE(angle, glm::radians(vfov) / 2 - std::atan(2.0f * tan_v / H) - 1e-5f);  // one pixel below the edge
  }
}

// --- accumulate ----------------------------------------------------------------------------------

// Three waves over overlapping pixel ranges of a film with random starting sums, the last with two
// samples per pixel, then one through a list of film pixels. Every film sum is one float add per
// sample in sample order, so the host's sums in the same order must be bitwise equal; the albedo's
// w counts every sample, the dropped ones too.
TEST_F(Kernel, AccumulateSumsAndDropsNonFinite) {
  const uint32_t film = 1000, slots = 1024;
  std::mt19937 rng(21);
  std::uniform_real_distribution<float> value(0.0f, 10.0f);
  auto random_film = [&] {
    std::vector<vec4> f(film);
    for (auto& v : f) v = vec4(value(rng), value(rng), value(rng), (float)(rng() % 50));
    return f;
  };
  const std::vector<vec4> sum = random_film(), sum_sq = random_film(), albedo = random_film(), normal = random_film();
  cl::Buffer sum_b = buffer(sum), sum_sq_b = buffer(sum_sq), albedo_b = buffer(albedo), normal_b = buffer(normal);
  const int counter_count = XI_COUNTER_COUNT(8);
  std::vector<uint32_t> counters_before(counter_count);
  for (int c = 0; c < counter_count; ++c) counters_before[c] = 11u * (c + 1);
  cl::Buffer counters_b = buffer(counters_before);

  // The host reference. sum_sq has two, as the device may fuse `sum_sq += l * l` into an fma (OpenCL
  // C allows contraction by default): the whole film must match one of them exactly.
  std::vector<vec4> want_sum = sum, want_sq = sum_sq, want_sq_fma = sum_sq, want_albedo = albedo,
                    want_normal = normal;
  uint32_t nonfinite = 0;
  const float kNonFinite[] = {NAN, INFINITY, -INFINITY};
  // (accumulate adds to film pixels: the frame's width and rows do not enter)
  std::vector<uint32_t> list(film);
  for (uint32_t i = 0; i < film; ++i) list[i] = film - 1 - (i * 3u) % film;  // every pixel once
  cl::Buffer list_b = buffer(list);
  for (WaveParams wave : {WaveParams{100, 700, 0, 1, 40, 0, 1, 0}, WaveParams{450, 550, 1, 1, 40, 0, 1, 0},
                          WaveParams{300, 400, 2, 2, 40, 0, 1, 0}, WaveParams{10, 333, 4, 3, 40, 0, 1, 1}}) {
    const uint32_t count = wave.pixels * wave.samples;
    PathState state(slots);  // garbage in the fields accumulate does not read
    for (uint32_t i = 0; i < count; ++i) {
      vec4& r = state.radiance[i];
      r = vec4(value(rng), value(rng), value(rng), value(rng));
      if (rng() % 10 == 0) r.w = NAN;                             // w is not part of the sample
      if (rng() % 40 == 0) r[rng() % 3] = kNonFinite[rng() % 3];  // NaN, +inf or -inf in one channel
      state.aov_albedo[i] = vec4(value(rng), value(rng), value(rng), value(rng));
      state.aov_normal[i] = vec4(value(rng), value(rng), value(rng), value(rng)) - 5.0f;
    }
    PathBuffers b = upload(state);
    cl::Kernel k = kernel("accumulate");
    bind(k, b, sum_b, sum_sq_b, albedo_b, normal_b, counters_b, list_b, wave);
    launch(k, wave.pixels);

    for (uint32_t i = 0; i < count; ++i) {  // in slot order, so each pixel's samples in sample order
      const vec4 l(vec3(state.radiance[i]), 1.0f);
      const uint32_t at = XI_WAVE_PIXEL(wave, i), p = wave.pixel_list ? list[at] : at;
      want_albedo[p].w += 1.0f;
      if (!std::isfinite(l.x) || !std::isfinite(l.y) || !std::isfinite(l.z)) {
        nonfinite++;  // dropped whole: its AOVs too, so they stay averages over sum.w samples
        continue;
      }
      want_sum[p] += l;
      want_sq[p] += l * l;
      for (int c = 0; c < 4; ++c) want_sq_fma[p][c] = std::fma(l[c], l[c], want_sq_fma[p][c]);
      want_albedo[p] += state.aov_albedo[i];
      want_normal[p] += state.aov_normal[i];
    }
  }
  ASSERT_GT(nonfinite, 10u);
  const auto counters = read<uint32_t>(counters_b, counter_count);
  for (int c = 0; c < counter_count; ++c)  // one count per dropped sample; the other counters left alone
    EXPECT_EQ(counters[c], counters_before[c] + (c == XI_COUNTER_NONFINITE ? nonfinite : 0u)) << "counter " << c;
  auto mismatches = [&](const cl::Buffer& b, const std::vector<vec4>& want) {
    auto got = read<vec4>(b, film);
    int bad = 0;
    for (uint32_t p = 0; p < film; ++p) bad += !same_bits(got[p], want[p]);
    return bad;
  };
  // Bitwise: the same float adds in the same order (w of the sum counts the finite samples; pixels
  // 0..99 lie outside both passes and keep their starting values).
  EXPECT_EQ(mismatches(sum_b, want_sum), 0);
  EXPECT_EQ(mismatches(albedo_b, want_albedo), 0);
  EXPECT_EQ(mismatches(normal_b, want_normal), 0);
  int bad_sq = mismatches(sum_sq_b, want_sq), bad_sq_fma = mismatches(sum_sq_b, want_sq_fma);
  EXPECT_TRUE(bad_sq == 0 || bad_sq_fma == 0) << bad_sq << " pixels differ from mul+add, " << bad_sq_fma
                                              << " from fma";
}

// --- shade ---------------------------------------------------------------------------------------

// Camera-ray hits on every triangle of the Cornell box (and misses), shaded at bounce 0 from the
// state generate leaves (AOVs zero; garbage elsewhere, throughput and radiance too: a camera ray's
// are known): a miss gathers exactly the background (a black one too, where shade writes it), a hit
// exactly its emission (weight 1 after a camera ray), the AOVs are its albedo and normal (zero for a
// miss), and a continuing path carries exactly its albedo (f · cos / pdf of a cosine-weighted
// sample). 1 and 8 lanes.
TEST_F(Kernel, ShadeFirstHitsFromTheCamera) {
  xi::CompiledScene cs = xi::compile_scene(xi::load_scene(XI_SCENE_DIR "/cornell-box.json"));
  const uint32_t tris = (uint32_t)cs.tri_material.size(), count = 200, slots = 256;
  auto normal_of = [&](uint32_t tri) {
    vec3 p0 = cs.position(tri, 0), p1 = cs.position(tri, 1), p2 = cs.position(tri, 2);
    return glm::normalize(glm::cross(p1 - p0, p2 - p0));
  };
  PathState state(slots);
  for (uint32_t i = 0; i < count; ++i) {
    const uint32_t tri = i % tris;
    const bool miss = i % 5 == 4;
    state.hit[i] = miss ? vec4(-1.0f, 0.0f, 0.0f, 0.0f) : vec4(100.0f, 0.2f, 0.3f, as_float(tri));
    state.ray_dir[i] = vec4(-normal_of(tri), 0.0f);  // seen from the front
    state.throughput[i] = state.radiance[i] = vec4(as_float(kGarbage));
    state.aov_albedo[i] = state.aov_normal[i] = vec4(0.0f);
    state.item_pixel[i] = i;
    state.item_sample[i] = 0;
  }
  std::vector<uint32_t> identity(slots);
  std::iota(identity.begin(), identity.end(), 0u);
  for (const vec4 background : {vec4(0.25f, 0.5f, 0.75f, 0.0f), vec4(0.0f)}) {  // coloured and black
    struct Outputs {
      PathState paths;
      std::vector<vec4> shadows;
      std::vector<uint32_t> queue;
    };
    std::optional<Outputs> shuffled;  // as in GenerateCameraRays, with the shadow rays and the next queue
    for (const ShadingProgram& shading : shading_programs()) {
      SCOPED_TRACE(testing::Message() << shading.form << ", background " << background.x);
      PathBuffers b = upload(state);
      cl::Buffer queue_in = buffer(identity), queue_out = buffer(garbage<uint32_t>(slots));
      cl::Buffer shadow_org = buffer(garbage<vec4>(slots)), shadow_dir = buffer(garbage<vec4>(slots)),
                 shadow_contrib = buffer(garbage<vec4>(slots));
      std::vector<uint32_t> counters(XI_COUNTER_COUNT(8), 0u);
      counters[XI_COUNTER_RAYS(0)] = count;
      cl::Buffer cb = buffer(counters);
      // (Kernel arguments do not keep buffers alive: each is named until the launch.)
#define XI_UPLOAD_SCENE_BUFFER(type, name) cl::Buffer name = buffer(cs.name);
      XI_SCENE_BUFFERS(XI_UPLOAD_SCENE_BUFFER)
#undef XI_UPLOAD_SCENE_BUFFER
      cl::Kernel k(shading.program->program, "shade");
      const uint32_t light_count = (uint32_t)cs.light_tri.size();
      bind(k, b, queue_in, queue_out, shadow_org, shadow_dir, shadow_contrib, cb, 0u, XI_SCENE_BUFFERS(XI_ARG) light_count,
           cs.environment, xi_make_sampler_params(3, 16), shading_word_, 8u, background);
      launch(k, (count + shading.lanes - 1) / shading.lanes);
      PathState out = download(b, slots);
      const uint32_t next = read<uint32_t>(cb, XI_COUNTER_COUNT(8))[XI_COUNTER_RAYS(1)];
      std::vector<vec4> shadows = read<vec4>(shadow_org, slots), dirs = read<vec4>(shadow_dir, slots),
                        contribs = read<vec4>(shadow_contrib, slots);
      shadows.insert(shadows.end(), dirs.begin(), dirs.end());
      shadows.insert(shadows.end(), contribs.begin(), contribs.end());
      const std::vector<uint32_t> next_queue = read<uint32_t>(queue_out, slots);
      if (shading.program == &*portable16_) {
        expect_same_bits(out, shuffled->paths);
        EXPECT_EQ(std::memcmp(shadows.data(), shuffled->shadows.data(), shadows.size() * sizeof(vec4)), 0)
            << "shadow rays differ";
        EXPECT_EQ(next_queue, shuffled->queue);
      }
      if (shading.program == &*lanes16_) shuffled = Outputs{out, shadows, next_queue};
      std::vector<uint32_t> queued = next_queue;
      ASSERT_LE(next, count);
      queued.resize(next);
      int misses = 0, emitters = 0, continuing = 0;
      for (uint32_t i = 0; i < count; ++i) {
        SCOPED_TRACE(testing::Message() << "path " << i);
        const bool goes_on = std::find(queued.begin(), queued.end(), i) != queued.end();
        if (out.hit[i].x < 0.0f) {
          misses++;
          EXPECT_TRUE(same_bits(vec3(out.radiance[i]), vec3(background)));
          EXPECT_TRUE(same_bits(out.aov_albedo[i], vec4(0.0f)));
          EXPECT_TRUE(same_bits(out.aov_normal[i], vec4(0.0f)));
          EXPECT_FALSE(goes_on);
          continue;
        }
        const uint32_t tri = as_uint(out.hit[i].w);
        const MaterialData& m = cs.materials[cs.tri_material[tri]];
        emitters += glm::length(vec3(m.emission)) > 0.0f;
        EXPECT_TRUE(same_bits(vec3(out.radiance[i]), vec3(m.emission)));  // 0 + 1 · emission · weight 1
        EXPECT_TRUE(same_bits(vec3(out.aov_albedo[i]), vec3(m.albedo)));
        EXPECT_LE(glm::length(vec3(out.aov_normal[i]) - normal_of(tri)), 1e-6f);
        if (goes_on) {
          continuing++;
          EXPECT_TRUE(same_bits(vec3(out.throughput[i]), vec3(m.albedo)));  // 1 · f · cos / pdf = albedo
          EXPECT_GT(out.throughput[i].w, 0.0f);  // the pdf of its cosine-weighted direction
        }
      }
      EXPECT_EQ(misses, (int)count / 5);
      EXPECT_GT(emitters, 0);
      EXPECT_GT(continuing, (int)count / 2);
    }
  }
}

// --- shadow --------------------------------------------------------------------------------------

// Shadow rays between random points of the Cornell box's interior, occlusion known from brute
// force: only unoccluded rays add their contribution to their path's radiance (4- and 8-wide BVHs,
// and 8 wide with rays in packets of 8 and of 16, XI_RAY_PACKETS, and in hybrid packets of 8 and of
// 16 at bounce 0, XI_HYBRID_PACKETS). Every other packet's worth of
// rays is a fan between two small neighbourhoods, which share their axis permutation and signs, so
// packets take both the coherent and the per-ray traversal (packet.h); 500 rays leave a last packet
// of four, traced one by one.
TEST_F(Kernel, ShadowAddsOnlyUnoccluded) {
  xi::Scene scene = xi::load_scene(XI_SCENE_DIR "/cornell-box.json");
  for (int config : {4, 8, 80, 160, 81, 161}) {
    const int width = config == 4 ? 4 : 8;
    const bool packets = config == 80 || config == 160, hybrid = config == 81 || config == 161;
    const uint32_t packet = config >= 160 ? 16 : 8;  // rays per packet (and per fan)
    SCOPED_TRACE(testing::Message() << width << "-wide BVH" << (packets ? ", packets of " : "")
                                    << (hybrid ? ", hybrid packets of " : "")
                                    << (packets || hybrid ? std::to_string(packet) : ""));
    xi::CompiledScene cs = xi::compile_scene(scene, width);
    BruteForce brute(scene);
    const uint32_t n = 500, slots = 1024, extra = 64;
    std::mt19937 rng(31);
    std::uniform_real_distribution<float> x(1.0f, 555.0f), y(1.0f, 548.0f), z(1.0f, 558.0f), value(0.0f, 5.0f);
    std::uniform_real_distribution<float> near(-2.0f, 2.0f);

    PathState state(slots);
    for (auto& r : state.radiance) r = vec4(value(rng), value(rng), value(rng), value(rng));
    std::vector<uint32_t> slot_of(slots);
    std::iota(slot_of.begin(), slot_of.end(), 0u);
    std::shuffle(slot_of.begin(), slot_of.end(), rng);  // ray i feeds path slot_of[i], all distinct

    std::vector<vec4> org(n + extra), dir(n + extra), contrib(n + extra);
    std::vector<bool> occluded(n + extra);
    int blocked = 0;
    vec3 fan_from, fan_to;
    for (uint32_t i = 0; i < n + extra; ++i) {
      if (i % (2 * packet) == packet) fan_from = vec3(x(rng), y(rng), z(rng)), fan_to = vec3(x(rng), y(rng), z(rng));
      for (;;) {
        vec3 a(x(rng), y(rng), z(rng)), b(x(rng), y(rng), z(rng));
        if (i % (2 * packet) >= packet) {
          a = fan_from + vec3(near(rng), near(rng), near(rng));
          b = fan_to + vec3(near(rng), near(rng), near(rng));
        }
        float tmax = glm::length(b - a);
        vec3 d = glm::normalize(b - a);
        auto hits = brute.hits(a, d, INFINITY);
        // Skip the rare ray whose nearest hit is within 1e-4 of tmax: device rounding could flip it.
        if (!hits.empty() && std::abs(hits[0].t - tmax) < 1e-4f * tmax) continue;
        occluded[i] = !hits.empty() && hits[0].t < tmax;
        org[i] = vec4(a, tmax);
        dir[i] = vec4(d, 0.0f);
        break;
      }
      contrib[i] = vec4(value(rng), value(rng), value(rng), as_float(slot_of[i]));
      blocked += i < n && occluded[i];
    }
    // Both outcomes well represented.
    ASSERT_GT(blocked, (int)n / 5);
    ASSERT_LT(blocked, (int)n * 4 / 5);

    PathBuffers b = upload(state);
    cl::Buffer org_b = buffer(org), dir_b = buffer(dir), contrib_b = buffer(contrib);
    cl::Buffer nodes = bvh_nodes(cs.bvh), blocks = buffer(cs.bvh.blocks);
    const uint32_t bounce = hybrid ? 0 : 2;
    std::vector<uint32_t> counters(XI_COUNTER_COUNT(8), 3u);
    counters[XI_COUNTER_SHADOW(bounce)] = n;  // the entries past n must be ignored
    cl::Buffer cb = buffer(counters);
    cl::Kernel k = packets  ? cl::Kernel((packet == 16 ? ray_packets16_ : ray_packets8_)->program, "shadow")
                   : hybrid ? cl::Kernel((packet == 16 ? hybrid16_ : hybrid8_)->program, "shadow")
                            : kernel("shadow", width);
#define XI_UPLOAD_SURFACE_BUFFER(type, name) cl::Buffer name = buffer(cs.name);
    XI_SURFACE_BUFFERS(XI_UPLOAD_SURFACE_BUFFER)
#undef XI_UPLOAD_SURFACE_BUFFER
    bind(k, b, org_b, dir_b, contrib_b, cb, bounce, nodes, blocks, XI_SURFACE_BUFFERS(XI_ARG) 0u);
    // Over an upper bound, as the renderer launches.
    const int rays = XI_SHADOW_RAYS(width, bounce, packets ? 1 : 0, hybrid ? 1 : 0);
    EXPECT_EQ(rays, packets ? XI_RAYS_TOGETHER : hybrid ? XI_RAYS_HYBRID : XI_RAYS_ALONE);
    launch(k, (n + extra) / XI_RAYS_PER_ITEM(rays, packet));
    std::vector<vec4> got = read<vec4>(b.radiance, slots);

    std::vector<vec4> want = state.radiance;
    for (uint32_t i = 0; i < n; ++i)
      if (!occluded[i]) want[slot_of[i]] += vec4(vec3(contrib[i]), 0.0f);
    int bad = 0;
    for (uint32_t s = 0; s < slots; ++s) bad += !same_bits(got[s], want[s]);  // one float add per channel: exact
    EXPECT_EQ(bad, 0) << "of " << slots << " path slots, " << blocked << " rays occluded";
  }
}

}  // namespace
