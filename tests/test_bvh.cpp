// BVH build and host-side traversal: the tree's invariants (4- and 8-wide) on three kinds of input,
// then closest- and any-hit queries of xi_trace (traverse.h, run on the host over the arrays
// compile_scene lays out for the kernels, 4 wide) against a brute-force loop over every triangle.
#include <gtest/gtest.h>

#include <algorithm>
#include <cfloat>
#include <cstdio>
#include <functional>
#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "traverse.h"
#include "xi/bvh.h"
#include "xi/compiled_scene.h"
#include "xi/scene.h"

#include "brute_force.h"

namespace {

using xi::test::BruteForce;
using xi::test::HostHit;

using glm::vec3;

xi::Scene cornell() { return xi::load_scene(XI_SCENE_DIR "/cornell-box.json"); }

xi::Scene icosphere() {  // subdivisions 5: 20 · 4^5 = 20480 triangles
  return xi::parse_scene(R"({
    "camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [{"type": "sphere", "material": "white", "center": [0.3, -0.2, 0.1], "radius": 1.5,
                "subdivisions": 5}]})",
                         "icosphere.json", ".");
}

xi::Scene with_triangles(xi::Mesh mesh) {
  xi::Scene s;
  s.materials.push_back(xi::Material{.name = "white", .albedo = vec3(0.5f)});
  static_cast<xi::Mesh&>(s) = std::move(mesh);
  return s;
}

// Triangles first to last of a mesh alone, over the vertices they use (shared as they were).
xi::Mesh sub_mesh(const xi::Mesh& mesh, size_t first, size_t last) {
  xi::Mesh out;
  std::vector<uint32_t> index(mesh.vertices.size(), UINT32_MAX);
  for (size_t i = first; i < last; ++i) {
    xi::Triangle t = mesh.triangles[i];
    for (uint32_t& v : t.v) {
      if (index[v] == UINT32_MAX) index[v] = (uint32_t)out.vertices.size(), out.vertices.push_back(mesh.vertices[v]);
      v = index[v];
    }
    t.texcoords = xi::kNoTexcoords;
    out.triangles.push_back(t);
  }
  return out;
}

// Triangles of mixed sizes (0.05 to 3 units) scattered through a 20-unit cube; they overlap freely.
xi::Scene soup(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> pos(-10.0f, 10.0f), unit(-1.0f, 1.0f), log_size(std::log(0.05f), std::log(3.0f));
  xi::Mesh tris;
  for (size_t i = 0; i < n; ++i) {
    vec3 c(pos(rng), pos(rng), pos(rng));
    float s = std::exp(log_size(rng));
    vec3 v[3];
    for (auto& p : v) p = c + s * vec3(unit(rng), unit(rng), unit(rng));
    tris.add_triangle(v[0], v[1], v[2]);
  }
  return with_triangles(std::move(tris));
}

struct Bounds {
  vec3 lo{INFINITY}, hi{-INFINITY};
  void grow(vec3 p) { lo = glm::min(lo, p), hi = glm::max(hi, p); }
  bool operator==(const Bounds&) const = default;
};
// A node's lanes, whichever its width: child k and its box.
struct NodeLanes {
  int width;
  const uint32_t* child;
  std::function<float(int plane, int k)> bound;  // plane: lo x, hi x, lo y, hi y, lo z, hi z
};
NodeLanes node_lanes(const xi::Bvh& bvh, size_t i) {
  if (bvh.width == 8) {
    const BvhNode8& n = bvh.nodes8[i];
    return {8, n.child, [&n](int plane, int k) { return n.bounds[plane].s[k]; }};
  }
  const BvhNode& n = bvh.nodes[i];
  return {4, n.child, [&n](int plane, int k) { return n.bounds[plane][k]; }};
}
size_t node_count(const xi::Bvh& bvh) { return bvh.width == 8 ? bvh.nodes8.size() : bvh.nodes.size(); }
Bounds lane_bounds(const NodeLanes& n, int k) {
  return {vec3(n.bound(0, k), n.bound(2, k), n.bound(4, k)), vec3(n.bound(1, k), n.bound(3, k), n.bound(5, k))};
}
Bounds root_bounds(const xi::Bvh& bvh) {
  Bounds b;
  NodeLanes root = node_lanes(bvh, 0);
  for (int k = 0; k < root.width; ++k)
    if (root.child[k] != XI_BVH_EMPTY) b.grow(lane_bounds(root, k).lo), b.grow(lane_bounds(root, k).hi);
  return b;
}
Bounds scene_bounds(const xi::Mesh& s) {
  Bounds b;
  for (auto& t : s.triangles)
    for (int k = 0; k < 3; ++k) b.grow(s.position(t, k));
  return b;
}

struct Walk {
  size_t nodes = 0, leaves = 0, max_leaf = 0, stack = 0, references = 0;
  int depth = 0;
  std::vector<std::vector<Bounds>> leaf_boxes;  // per position: the boxes of the leaf lanes holding it
};
bool contains(const Bounds& outer, const Bounds& inner) {
  return glm::all(glm::lessThanEqual(outer.lo, inner.lo)) && glm::all(glm::lessThanEqual(inner.hi, outer.hi));
}

// Walks the wide tree (4 or 8 lanes) from the root, checking the layout (children after their parent, empty
// lanes with empty boxes and only after used ones, leaves own disjoint ranges of triangle blocks
// whose lanes cover every position of `order`, every node reached once) and that every interior
// lane's box is exactly the bounds of what it holds. Without spatial splits (stats.references ==
// the triangles) every position is in exactly one leaf and a leaf's box is exactly its triangles'
// bounds; with them a position may be in several leaves (never twice in one) and a leaf's box may
// be within its triangles' bounds, the part it holds (check_coverage tests that the parts cover
// each triangle). Returns what the walk counted, including the traversal stack bound.
Walk check_tree(const xi::Bvh& bvh, const xi::Mesh& tris) {
  const size_t n = tris.triangles.size();
  EXPECT_EQ(bvh.order.size(), n);
  std::vector<int> seen_tri(n), seen_pos(n), seen_node(node_count(bvh)), seen_block(bvh.blocks.size());
  for (uint32_t t : bvh.order)
    if (t < n) seen_tri[t]++;
  EXPECT_EQ((size_t)std::count(seen_tri.begin(), seen_tri.end(), 1), n) << "order is not a permutation";
  EXPECT_EQ(bvh.position.size(), n);
  for (size_t p = 0; p < n && p < bvh.position.size(); ++p)
    if (bvh.order[p] < n) EXPECT_EQ(bvh.position[bvh.order[p]], p) << "position is not order's inverse";

  const bool split = bvh.stats.references != n;
  Walk w;
  w.leaf_boxes.resize(n);
  size_t loose_boxes = 0, bad = 0;
  // Returns the bounds of the node's content and the stack entries its traversal may need.
  std::function<std::pair<Bounds, size_t>(uint32_t, int)> walk = [&](uint32_t i, int depth) -> std::pair<Bounds, size_t> {
    Bounds all;
    if (i >= node_count(bvh) || seen_node[i]++) {
      ADD_FAILURE() << "node " << i << " is out of range or reached twice";
      bad++;
      return {all, 0};
    }
    const NodeLanes node = node_lanes(bvh, i);
    w.nodes++;
    size_t lanes = 0, below = 0;
    for (int k = 0; k < node.width; ++k) {
      uint32_t c = node.child[k];
      Bounds box = lane_bounds(node, k), content;
      if (c == XI_BVH_EMPTY) {
        EXPECT_TRUE(box.lo == vec3(INFINITY) && box.hi == vec3(-INFINITY)) << "empty lane " << k << " of node " << i;
        continue;
      }
      EXPECT_EQ(lanes, (size_t)k) << "used lane after an empty one in node " << i;
      lanes++;
      if (c & XI_BVH_LEAF) {
        uint32_t first = c & XI_BVH_FIRST_MASK, count = 1 + ((c >> 27) & 15u);
        w.leaves++;
        w.depth = std::max(w.depth, depth + 1);
        if (first >= bvh.blocks.size() || count > bvh.blocks.size() - first) {
          ADD_FAILURE() << "leaf in node " << i << " holds blocks [" << first << ", +" << count << ") beyond "
                        << bvh.blocks.size();
          bad++;
          continue;
        }
        // Blocks: used lanes first, each holding its triangle's vertices exactly; unused lanes NaN.
        size_t in_leaf = 0;
        std::vector<uint32_t> positions;
        for (uint32_t b = first; b < first + count; ++b) {
          const TriBlock& blk = bvh.blocks[b];
          seen_block[b]++;
          for (int l = 0; l < 4; ++l) {
            const uint32_t p = blk.tri[l];
            if (p == XI_BVH_EMPTY) {
              EXPECT_TRUE(std::isnan(blk.coord[0][0][l]) && std::isnan(blk.coord[1][1][l]) && std::isnan(blk.coord[2][2][l]));
              EXPECT_EQ(b + 1, first + count) << "a block with an unused lane before the leaf's last";
              continue;
            }
            if (p >= n) {
              ADD_FAILURE() << "block " << b << " holds triangle " << p << " of " << n;
              bad++;
              continue;
            }
            in_leaf++;
            seen_pos[p]++;
            positions.push_back(p);
            w.leaf_boxes[p].push_back(box);
            for (int j = 0; j < 3; ++j) {
              const vec3 v = tris.position(tris.triangles[bvh.order[p]], j);
              content.grow(v);
              EXPECT_TRUE(vec3(blk.coord[0][j][l], blk.coord[1][j][l], blk.coord[2][j][l]) == v) << "block " << b << " lane " << l;
            }
          }
        }
        EXPECT_EQ((in_leaf + 3) / 4, count) << "a leaf with a block it does not need";
        std::sort(positions.begin(), positions.end());
        EXPECT_TRUE(std::adjacent_find(positions.begin(), positions.end()) == positions.end())
            << "a triangle twice in one leaf of node " << i;
        w.max_leaf = std::max(w.max_leaf, in_leaf);
        w.references += in_leaf;
        // A leaf's box: the bounds of the parts of its triangles that it holds.
        if (split ? !contains(content, box) : !(box == content)) loose_boxes++;
        all.grow(box.lo), all.grow(box.hi);
        continue;
      } else {
        EXPECT_GT(c, i) << "child before its parent";
        auto [b, need] = walk(c, depth + 1);
        content = b;
        below = std::max(below, need);
      }
      // Box = exact min/max of its children's boxes (min/max do not round).
      if (!(box == content)) loose_boxes++;
      all.grow(content.lo), all.grow(content.hi);
    }
    EXPECT_GT(lanes, 0u) << "node " << i << " has no children";
    return {all, std::max(lanes, lanes - 1 + below)};
  };
  w.stack = walk(0, 0).second;
  EXPECT_EQ(bad, 0u);
  EXPECT_EQ(loose_boxes, 0u) << "boxes that are not exactly the bounds of their content";
  EXPECT_EQ(w.references, bvh.stats.references);
  if (split) EXPECT_EQ((size_t)std::count(seen_pos.begin(), seen_pos.end(), 0), 0u) << "positions in no leaf";
  else EXPECT_EQ((size_t)std::count(seen_pos.begin(), seen_pos.end(), 1), n) << "positions not in exactly one leaf";
  EXPECT_EQ((size_t)std::count(seen_node.begin(), seen_node.end(), 1), node_count(bvh)) << "unreachable nodes";
  EXPECT_EQ((size_t)std::count(seen_block.begin(), seen_block.end(), 1), bvh.blocks.size())
      << "blocks not in exactly one leaf";
  return w;
}

void check_stats(const xi::Bvh& bvh, const Walk& w, bool degenerate) {
  EXPECT_EQ(bvh.stats.nodes, w.nodes);
  EXPECT_EQ(bvh.stats.nodes, node_count(bvh));
  EXPECT_EQ(bvh.stats.leaves, w.leaves);
  EXPECT_EQ(bvh.stats.depth, w.depth);
  EXPECT_EQ(bvh.stats.max_leaf, w.max_leaf);
  EXPECT_EQ(bvh.stats.stack, w.stack);
  EXPECT_LE(w.stack, (size_t)XI_BVH_STACK);  // what the kernels' traversal stack holds
  // Every node has at least two lanes (but a root holding one leaf), so a 4-wide tree has fewer
  // nodes than leaves.
  EXPECT_LT(w.nodes, std::max<size_t>(w.leaves, 2));
  if (!degenerate) EXPECT_LE(w.max_leaf, 8u);
}

// Every point of every triangle lies in the box of a leaf lane that holds it (and so in every box
// above, interior boxes being exact unions): sampled at its vertices, edge midpoints and 16 random
// points, each allowed its own rounding. A spatial split that clipped a triangle's part wrongly
// would leave part of it where no ray finds it.
void check_coverage(const xi::Bvh& bvh, const xi::Mesh& tris, const Walk& w) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u01;
  size_t uncovered = 0;
  for (uint32_t p = 0; p < tris.triangles.size(); ++p) {
    const xi::Triangle& t = tris.triangles[bvh.order[p]];
    const vec3 tv[3] = {tris.position(t, 0), tris.position(t, 1), tris.position(t, 2)};
    std::vector<vec3> points(tv, tv + 3);
    for (int j = 0; j < 3; ++j) points.push_back(0.5f * (tv[j] + tv[(j + 1) % 3]));
    for (int k = 0; k < 16; ++k) {
      float a = u01(rng), b = u01(rng);
      if (a + b > 1.0f) a = 1.0f - a, b = 1.0f - b;
      points.push_back(tv[0] + a * (tv[1] - tv[0]) + b * (tv[2] - tv[0]));
    }
    for (const vec3& x : points) {
      const vec3 slack = 4.0f * FLT_EPSILON * glm::abs(x);
      uncovered += std::none_of(w.leaf_boxes[p].begin(), w.leaf_boxes[p].end(), [&](const Bounds& b) {
        return glm::all(glm::lessThanEqual(b.lo - slack, x)) && glm::all(glm::lessThanEqual(x, b.hi + slack));
      });
    }
  }
  EXPECT_EQ(uncovered, 0u) << "points of triangles outside every leaf box that holds them";
}

// The SAH cost of a wide tree as the build counts it: every lane's box area, times 1 for an
// interior child and its blocks for a leaf, over the root's area (the expected box and block
// tests of a ray through the scene's bounds).
double sah_cost(const xi::Bvh& bvh) {
  auto area = [](const Bounds& b) {
    vec3 d = b.hi - b.lo;
    return 2.0 * ((double)d.x * d.y + (double)d.y * d.z + (double)d.z * d.x);
  };
  double cost = 0.0;
  for (size_t i = 0; i < node_count(bvh); ++i) {
    NodeLanes node = node_lanes(bvh, i);
    for (int k = 0; k < node.width; ++k) {
      uint32_t c = node.child[k];
      if (c == XI_BVH_EMPTY) continue;
      cost += area(lane_bounds(node, k)) * ((c & XI_BVH_LEAF) ? 1.0 + ((c >> 27) & 15u) : 1.0);
    }
  }
  return cost / area(root_bounds(bvh));
}

// Directions uniform on the sphere, except that one ray in ten lies along an axis or in an axis
// plane (zero components exercise xi_safe_inverse).
vec3 random_direction(std::mt19937& rng) {
  std::normal_distribution<float> g;
  vec3 d(g(rng), g(rng), g(rng));
  uint32_t kind = rng() % 20;
  if (kind == 0) d = vec3(0.0f), d[rng() % 3] = (rng() & 1) ? 1.0f : -1.0f;
  if (kind == 1) d[rng() % 3] = 0.0f;
  return glm::normalize(d);
}

// 10^4 random rays from inside and around the scene: closest hit and any hit of xi_trace over the
// compiled (BVH-ordered) arrays against brute force over the scene's own triangles.
void check_queries(const xi::Scene& scene, const xi::CompiledScene& cs, uint32_t seed, int kRays = 10000) {
  const auto& tris = scene.triangles;
  BruteForce brute(scene);
  Bounds b = scene_bounds(scene);
  vec3 margin = 0.25f * (b.hi - b.lo);
  const float diag = glm::length(b.hi - b.lo);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);

  int hits = 0, ties = 0, any_hits = 0;
  for (int r = 0; r < kRays; ++r) {
    vec3 o = b.lo - margin + vec3(unit(rng), unit(rng), unit(rng)) * (b.hi - b.lo + 2.0f * margin);
    vec3 d = random_direction(rng);
    SCOPED_TRACE(testing::Message() << "ray " << r);
    auto ref = brute.hits(o, d, INFINITY);
    if (r < 100) {  // the culled reference finds exactly what testing every triangle finds
      auto all = brute.hits(o, d, INFINITY, false);
      ASSERT_EQ(ref.size(), all.size());
      for (size_t k = 0; k < ref.size(); ++k) ASSERT_EQ(ref[k].tri, all[k].tri);
    }

    float t = -1, u = 0, v = 0;
    uint32_t pos = xi_trace(cs.bvh.nodes.data(), cs.bvh.blocks.data(), o, d, INFINITY, false, &t, &u, &v);
    if (ref.empty()) {
      EXPECT_EQ(pos, XI_NO_HIT);  // misses agree exactly
    } else if (pos == XI_NO_HIT || pos >= tris.size()) {
      ADD_FAILURE() << "missed triangle " << ref[0].tri << " at t = " << ref[0].t;
    } else {
      hits++;
      uint32_t tri = cs.bvh.order[pos];
      // Ties: another triangle within 1e-5 relative t of the nearest (shared edges and vertices);
      // there the BVH may legitimately report either.
      auto same = std::find_if(ref.begin(), ref.end(), [&](const HostHit& h) { return h.tri == tri; });
      bool tie = ref.size() > 1 && ref[1].t <= ref[0].t * (1.0f + 1e-5f);
      ties += tie;
      if (!tie) EXPECT_EQ(tri, ref[0].tri) << "t = " << t << " vs " << ref[0].t;
      if (same == ref.end() || same->t > ref[0].t * (1.0f + 1e-5f)) {
        ADD_FAILURE() << "BVH hit triangle " << tri << " is not among the nearest hits";
      } else {
        EXPECT_NEAR(t, ref[0].t, 1e-5f * ref[0].t);  // same function on the same floats: only ties differ
        EXPECT_NEAR(u, same->u, 1e-6f);              // barycentrics of that very triangle: identical arithmetic
        EXPECT_NEAR(v, same->v, 1e-6f);
      }
    }

    // Any hit before a random tmax: hit/no-hit agrees with brute force, and the hit is genuine.
    float tmax = unit(rng) * diag;
    float ta = -1;
    uint32_t apos = xi_trace(cs.bvh.nodes.data(), cs.bvh.blocks.data(), o, d, tmax, true, &ta, &u, &v);
    bool occluded = !ref.empty() && ref[0].t < tmax;
    EXPECT_EQ(apos != XI_NO_HIT, occluded) << "tmax = " << tmax;  // same triangle test, same tmax: exact
    if (apos != XI_NO_HIT && apos < tris.size()) {
      any_hits++;
      uint32_t tri = cs.bvh.order[apos];
      auto same = std::find_if(ref.begin(), ref.end(), [&](const HostHit& h) { return h.tri == tri; });
      EXPECT_TRUE(same != ref.end() && same->t == ta && ta < tmax) << "any-hit reported a triangle the ray misses";
    }
  }
  // The ray sets must exercise both outcomes, or the comparisons above prove little.
  EXPECT_GT(hits, kRays / 10);
  EXPECT_LT(hits, kRays);
  EXPECT_GT(any_hits, kRays / 20);
  EXPECT_LT(ties, kRays / 1000 + 1);  // random rays hit an edge or a crossing within 1e-5 only rarely
}

void check_scene(const xi::Scene& scene, uint32_t seed) {
  xi::CompiledScene cs = xi::compile_scene(scene);
  ASSERT_EQ(cs.tri_vertices.size(), scene.triangles.size());
  // compile_scene stores triangle order[i] at position i.
  for (size_t i = 0; i < scene.triangles.size(); ++i)
    for (int k = 0; k < 3; ++k)
      ASSERT_EQ(cs.position(i, k), scene.position(scene.triangles[cs.bvh.order[i]], k)) << "position " << i;
  Walk w = check_tree(cs.bvh, scene);
  check_stats(cs.bvh, w, false);
  check_coverage(cs.bvh, scene, w);
  EXPECT_TRUE(root_bounds(cs.bvh) == scene_bounds(scene));  // the root box is the scene's bounds
  check_queries(scene, cs, seed);

  // The 8-wide tree of CPU devices (traversed by the kernels only: Kernel.ExtendMatchesBruteForce)
  // collapses the same binary tree: same triangle order, no deeper, fewer nodes. Its leaves may
  // differ: a leaf of up to eight triangles costs it one test, the 4-wide tree two.
  SCOPED_TRACE("8-wide");
  xi::CompiledScene cs8 = xi::compile_scene(scene, 8);
  EXPECT_EQ(cs8.bvh.order, cs.bvh.order);
  Walk w8 = check_tree(cs8.bvh, scene);
  check_stats(cs8.bvh, w8, false);
  check_coverage(cs8.bvh, scene, w8);
  EXPECT_TRUE(root_bounds(cs8.bvh) == scene_bounds(scene));
  EXPECT_LE(w8.depth, w.depth);
  if (w.nodes > 1) EXPECT_LT(w8.nodes, w.nodes);

  // Without spatial splits: every triangle in one leaf, every box exact, the same queries.
  SCOPED_TRACE("no spatial splits");
  xi::CompiledScene plain = xi::compile_scene(scene, 4, false);
  EXPECT_EQ(plain.bvh.stats.references, scene.triangles.size());
  Walk wp = check_tree(plain.bvh, scene);
  check_stats(plain.bvh, wp, false);
  EXPECT_TRUE(root_bounds(plain.bvh) == scene_bounds(scene));
  check_queries(scene, plain, seed + 1000);
}

TEST(BvhBuild, CornellBox) {
  xi::Scene s = cornell();
  ASSERT_EQ(s.triangles.size(), 32u);
  check_scene(s, 1);
}

// compile_scene_freeing_triangles empties the scene's triangles and texture coordinates and
// compiles what compile_scene does, array for array: a Cornell box whose white walls read a
// texture and a normal map (so texture coordinates and tangents are gathered too), with its light.
TEST(BvhBuild, FreeingTheTrianglesCompilesTheSame) {
  xi::Scene s = cornell();
  xi::TextureImage image;
  image.source = "test", image.width = image.height = 1, image.texels = {0xff8080ffu};
  s.images.push_back(image);
  size_t textured = 0;
  for (xi::Material& m : s.materials)
    if (!m.is_emitter()) {
      m.type = xi::MaterialType::Pbr;
      m.textures[XI_TEXTURE_BASE_COLOR].image = m.textures[XI_TEXTURE_NORMAL].image = 0;
      textured++;
    }
  ASSERT_GT(textured, 0u);
  ASSERT_FALSE(s.texcoords.empty());
  const xi::CompiledScene kept = xi::compile_scene(s, 8);
  ASSERT_EQ(s.triangles.size(), 32u);
  xi::CompiledScene freed = xi::compile_scene_freeing_triangles(s, 8);
  EXPECT_TRUE(s.triangles.empty() && s.triangles.capacity() == 0);
  EXPECT_TRUE(s.texcoords.empty() && s.texcoords.capacity() == 0);
  ASSERT_TRUE(kept.features.textures && kept.features.normal_map && kept.features.emitters);
  EXPECT_EQ(freed.features, kept.features);
  auto same_bytes = [](const auto& a, const auto& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof a[0]) == 0;
  };
  EXPECT_TRUE(same_bytes(freed.tri_vertices, kept.tri_vertices));
  EXPECT_TRUE(same_bytes(freed.vertices, kept.vertices));
  EXPECT_TRUE(same_bytes(freed.tri_material, kept.tri_material));
  EXPECT_TRUE(same_bytes(freed.tri_uv, kept.tri_uv));
  EXPECT_TRUE(same_bytes(freed.tri_tangents, kept.tri_tangents));
  EXPECT_TRUE(same_bytes(freed.tri_light_pdf, kept.tri_light_pdf));
  EXPECT_TRUE(same_bytes(freed.light_tri, kept.light_tri));
  EXPECT_TRUE(same_bytes(freed.light_cdf, kept.light_cdf));
  EXPECT_TRUE(same_bytes(freed.bvh.nodes8, kept.bvh.nodes8));
  EXPECT_TRUE(same_bytes(freed.bvh.blocks, kept.bvh.blocks));
  EXPECT_EQ(kept.tri_uv.size(), 3 * kept.tri_vertices.size());  // gathered, not the one unused entry
  EXPECT_EQ(kept.tri_tangents.size(), 3 * kept.tri_vertices.size());
}

TEST(BvhBuild, Icosphere) {
  xi::Scene s = icosphere();
  ASSERT_EQ(s.triangles.size(), 20480u);
  check_scene(s, 2);
}

TEST(BvhBuild, RandomSoup) {
  xi::Scene s = soup(20000, 3);
  check_scene(s, 4);
  EXPECT_GT(xi::build_bvh(s).stats.depth, 5);  // a real hierarchy (log4 of 20000 / 8 ≈ 5.6), not one flat leaf list
}

// Pipes: 120 cylinders 12 long and 1.2 thick, at random places and slants, each side one strip of
// 16 long thin triangles from end to end, as tessellated CAD parts are (the engine): the case
// spatial splits are for, where every triangle's box spans a slab of space it barely touches. They
// must split many (within the budget of 2 references per triangle), give a tree of much lower SAH
// cost than the build without them, and keep every query exact.
xi::Mesh pipes(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> pos(-10.0f, 10.0f);
  std::normal_distribution<float> g;
  xi::Mesh tris;
  for (int pipe = 0; pipe < count; ++pipe) {
    const vec3 a(pos(rng), pos(rng), pos(rng)), axis = glm::normalize(vec3(g(rng), g(rng), g(rng)));
    const vec3 u = glm::normalize(glm::cross(axis, vec3(g(rng), g(rng), g(rng)))), v = glm::cross(axis, u);
    auto rim = [&](int k) {
      float phi = 2.0f * 3.14159265f * (float)k / 16.0f;
      return 0.6f * (std::cos(phi) * u + std::sin(phi) * v);
    };
    for (int k = 0; k < 16; ++k) {
      const vec3 p0 = a + rim(k), p1 = a + rim(k + 1), q0 = p0 + 12.0f * axis, q1 = p1 + 12.0f * axis;
      tris.add_triangle(p0, p1, q1);
      tris.add_triangle(p0, q1, q0);
    }
  }
  return tris;
}

TEST(BvhBuild, SpatialSplitsTightenLongTriangles) {
  const xi::Mesh tris = pipes(120, 11);
  xi::Scene scene = with_triangles(tris);
  const xi::Bvh split = xi::build_bvh(tris, 4, true), plain = xi::build_bvh(tris, 4, false);
  const size_t n = tris.triangles.size();
  EXPECT_GT(split.stats.references, n + n / 10);
  EXPECT_LE(split.stats.references, 2 * n);
  const double split_cost = sah_cost(split), plain_cost = sah_cost(plain);
  std::printf("SAH cost: %.1f with spatial splits (%zu references), %.1f without\n", split_cost,
              split.stats.references, plain_cost);
  EXPECT_LT(split_cost, 0.8 * plain_cost);
  check_scene(scene, 12);
}

// The six walls of a closed room, two triangles each. Rays from outside enter a box around three
// walls as often as the three walls' own flat boxes, so the SAH alone cannot choose between them;
// rays from inside (every bounce) enter the big box always. The collapse's cost per triangle of a
// leaf must give each wall a leaf of its own, a flat box, at both widths (the greedy collapse of
// the binary build's leaves made two leaves of three walls each).
TEST(BvhBuild, RoomWallsGetLeavesOfTheirOwn) {
  xi::Mesh tris;
  for (int axis = 0; axis < 3; ++axis)
    for (float side : {0.0f, 1.0f}) {
      vec3 c[4];
      for (int k = 0; k < 4; ++k) {
        c[k][axis] = side;
        c[k][(axis + 1) % 3] = (float)(k & 1);
        c[k][(axis + 2) % 3] = (float)(k >> 1);
      }
      tris.add_triangle(c[0], c[1], c[3]);
      tris.add_triangle(c[0], c[3], c[2]);
    }
  for (int width : {4, 8}) {
    SCOPED_TRACE(width);
    const xi::Bvh bvh = xi::build_bvh(tris, width);
    const Walk w = check_tree(bvh, tris);
    EXPECT_EQ(w.leaves, 6u);
    for (const auto& boxes : w.leaf_boxes)
      for (const Bounds& b : boxes) {
        const vec3 extent = b.hi - b.lo;
        EXPECT_EQ(std::min({extent.x, extent.y, extent.z}), 0.0f) << "a leaf spans the room";
      }
  }
}

TEST(BvhBuild, IsDeterministic) {
  xi::Scene s = soup(5000, 5);
  xi::Bvh a = xi::build_bvh(s), b = xi::build_bvh(s);
  EXPECT_EQ(a.order, b.order);
  ASSERT_EQ(a.nodes.size(), b.nodes.size());
  EXPECT_EQ(std::memcmp(a.nodes.data(), b.nodes.data(), sizeof(BvhNode) * a.nodes.size()), 0);
  xi::Bvh a8 = xi::build_bvh(s, 8), b8 = xi::build_bvh(s, 8);
  ASSERT_EQ(a8.nodes8.size(), b8.nodes8.size());
  EXPECT_EQ(std::memcmp(a8.nodes8.data(), b8.nodes8.data(), sizeof(BvhNode8) * a8.nodes8.size()), 0);
  ASSERT_EQ(a.blocks.size(), b.blocks.size());
  EXPECT_EQ(std::memcmp(a.blocks.data(), b.blocks.data(), sizeof(TriBlock) * a.blocks.size()), 0);
}

// Subtrees of 4096 references or more are built on threads of their own and grafted back: the
// tree must be the one a single thread builds, byte for byte. The pipes (as above) make spatial
// splits (their budget shared across the forks) as well as object splits.
TEST(BvhBuild, ThreadsBuildTheSameTree) {
  xi::Mesh tris = soup(30000, 21);
  tris.append(pipes(200, 22));
  for (int width : {4, 8}) {
    for (bool splits : {true, false}) {
      SCOPED_TRACE(testing::Message() << "width " << width << (splits ? ", spatial splits" : ", no splits"));
      const xi::Bvh one = xi::build_bvh(tris, width, splits, 1), many = xi::build_bvh(tris, width, splits, 4);
      EXPECT_EQ(one.stats.threads, 1u);
      EXPECT_GE(many.stats.threads, 4u);  // 36400 triangles: forks at least two levels deep
      if (splits) EXPECT_GT(many.stats.references, tris.triangles.size());
      EXPECT_EQ(one.stats.references, many.stats.references);
      EXPECT_EQ(one.order, many.order);
      // (Byte for byte; the vector of the other width is empty, and memcmp may not see its null.)
      auto same_bytes = [](const auto& a, const auto& b) {
        return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), sizeof(a[0]) * a.size()) == 0);
      };
      EXPECT_TRUE(same_bytes(one.nodes, many.nodes));
      EXPECT_TRUE(same_bytes(one.nodes8, many.nodes8));
      EXPECT_TRUE(same_bytes(one.blocks, many.blocks));
      const Walk w = check_tree(many, tris);
      check_coverage(many, tris, w);
    }
  }
}

// A mesh of 327680 small triangles (an icosphere) in a room of 12 large ones, as scanned and
// generated meshes come: the top nodes share their passes over the references out to threads
// (over 2^17 references per thread), and spatial splits are not tried where every reference is
// smaller than a bin of the node. The tree must be the one a single thread builds, byte for byte,
// valid, and exact for queries.
TEST(BvhBuild, LargeMeshOfSmallTriangles) {
  xi::Scene s = xi::parse_scene(R"({
    "camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {"white": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [
      {"type": "quad", "material": "white", "vertices": [[-3, -3, -3], [3, -3, -3], [3, -3, 3], [-3, -3, 3]]},
      {"type": "quad", "material": "white", "vertices": [[-3, 3, -3], [-3, 3, 3], [3, 3, 3], [3, 3, -3]]},
      {"type": "quad", "material": "white", "vertices": [[-3, -3, 3], [3, -3, 3], [3, 3, 3], [-3, 3, 3]]},
      {"type": "quad", "material": "white", "vertices": [[-3, -3, -3], [-3, -3, 3], [-3, 3, 3], [-3, 3, -3]]},
      {"type": "quad", "material": "white", "vertices": [[3, -3, -3], [3, 3, -3], [3, 3, 3], [3, -3, 3]]},
      {"type": "sphere", "material": "white", "center": [0.3, -0.2, 0.1], "radius": 1.5, "subdivisions": 7},
      {"type": "quad", "material": "white", "vertices": [[-3, -3, -3], [-3, 3, -3], [3, 3, -3], [3, -3, -3]]}]})",
                                "room.json", ".");
  const size_t n = s.triangles.size();
  ASSERT_EQ(n, 12u + 327680u);
  auto same_bytes = [](const auto& a, const auto& b) {
    return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), sizeof(a[0]) * a.size()) == 0);
  };
  // The sphere alone too: its root's object split is partitioned on two threads (with the walls
  // the root splits them spatially).
  const xi::Mesh sphere = sub_mesh(s, 10, n - 2);
  for (const xi::Mesh* tris : {(const xi::Mesh*)&s, &sphere}) {
    SCOPED_TRACE(tris == &sphere ? "the sphere alone" : "the room");
    const xi::Bvh one = xi::build_bvh(*tris, 8, true, 1), many = xi::build_bvh(*tris, 8, true, 3);
    EXPECT_GE(many.stats.threads, 8u);
    EXPECT_EQ(one.order, many.order);
    EXPECT_TRUE(same_bytes(one.nodes8, many.nodes8));
    EXPECT_TRUE(same_bytes(one.blocks, many.blocks));
  }
  xi::CompiledScene cs = xi::compile_scene(s, 4, true, 3);
  const Walk w = check_tree(cs.bvh, s);
  EXPECT_GT(cs.bvh.stats.references, n);  // spatial splits still made where they pay
  check_stats(cs.bvh, w, false);
  check_coverage(cs.bvh, s, w);
  EXPECT_TRUE(root_bounds(cs.bvh) == scene_bounds(s));
  check_queries(s, cs, 31, 1000);
}

// 100 copies of one triangle: every centroid coincides, so no SAH split separates them.
TEST(BvhBuild, CoincidentCopies) {
  xi::Mesh copies;
  for (int i = 0; i < 100; ++i) copies.add_triangle(vec3(0, 0, 0), vec3(1, 0, 0), vec3(0, 1, 0));
  xi::Scene s = with_triangles(std::move(copies));
  xi::CompiledScene cs = xi::compile_scene(s);
  Walk w = check_tree(cs.bvh, s);
  check_stats(cs.bvh, w, true);

  const vec3 o(0.25f, 0.25f, -1.0f), d(0, 0, 1);
  float tt, u, v;
  uint32_t pos = xi_trace(cs.bvh.nodes.data(), cs.bvh.blocks.data(), o, d, INFINITY, false, &tt, &u, &v);
  ASSERT_LT(pos, 100u);
  EXPECT_FLOAT_EQ(tt, 1.0f);  // the plane z = 0 is one unit along the ray

  // Each copy is reachable by traversal: with every other copy collapsed to a point (which no ray
  // hits) but the same tree, the ray must still find it, in whichever leaf it was put.
  for (uint32_t keep = 0; keep < 100; ++keep) {
    auto blocks = cs.bvh.blocks;
    for (TriBlock& b : blocks)
      for (int l = 0; l < 4; ++l)
        if (b.tri[l] != keep && b.tri[l] != XI_NO_HIT)
          for (int j = 0; j < 3; ++j) b.coord[0][j][l] = 0.1f, b.coord[1][j][l] = 0.1f, b.coord[2][j][l] = 0.0f;
    EXPECT_EQ(xi_trace(cs.bvh.nodes.data(), blocks.data(), o, d, INFINITY, false, &tt, &u, &v), keep);
    EXPECT_EQ(xi_trace(cs.bvh.nodes.data(), blocks.data(), o, d, 2.0f, true, &tt, &u, &v), keep);
  }
}

// Triangles at x = 1.5^i (sizes from 0.1 to 10^16; beyond ~10^19 the edge functions' products
// overflow float): binned SAH peels a few off per level, giving a deep, lopsided tree.
TEST(BvhBuild, ExponentialSpacing) {
  xi::Mesh tris;
  for (int i = 0; i < 100; ++i) {
    float x = std::pow(1.5f, (float)i), s = 0.1f * x;
    tris.add_triangle(vec3(x, 0, 0), vec3(x + s, 0, 0), vec3(x, s, 0));
  }
  // Coordinates up to 1.5^99 = 2.7e17, beyond what a scene may have (compile_scene refuses it): the
  // builder alone.
  const xi::Bvh bvh = xi::build_bvh(tris);
  Walk w = check_tree(bvh, tris);
  check_stats(bvh, w, false);
  EXPECT_GT(w.depth, 6);  // lopsided: a balanced 4-wide tree over 100 triangles would be ~3 deep
  // Every triangle is still found, by a ray straight at it through the plane z = 0.
  for (uint32_t i = 0; i < tris.triangles.size(); ++i) {
    float x = tris.position(tris.triangles[i], 0).x, s = 0.1f * x, t, u, v;
    vec3 o(x + 0.25f * s, 0.25f * s, -1.0f);
    uint32_t pos = xi_trace(bvh.nodes.data(), bvh.blocks.data(), o, vec3(0, 0, 1), INFINITY, false, &t, &u, &v);
    ASSERT_LT(pos, tris.triangles.size()) << "triangle " << i;
    EXPECT_EQ(bvh.order[pos], i);
  }
}

}  // namespace
