// Scenes built in C++ for the tests, so that each expectation can be derived from the very
// geometry: materials, triangles, quads and boxes added to a scene, the camera set, and meshes
// written to OBJ files in a temporary folder and loaded back through the scene parser (Assimp).
#pragma once
#include <unistd.h>

#include <array>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include <glm/glm.hpp>

#include "xi/scene.h"

namespace xi::test {

// The vector types the hard-case tests build their scenes and rays with.
using glm::dvec2;
using glm::dvec3;
using glm::vec3;

inline uint32_t add_material(Scene& s, const std::string& name, glm::vec3 albedo, glm::vec3 emission = glm::vec3(0.0f),
                             bool two_sided = false) {
  Material m;
  m.name = name;
  m.albedo = albedo;
  m.emission = emission;
  m.two_sided = two_sided;
  s.materials.push_back(m);
  return (uint32_t)s.materials.size() - 1;
}

inline void add_triangle(Scene& s, uint32_t material, glm::vec3 a, glm::vec3 b, glm::vec3 c) {
  s.add_triangle(a, b, c, material);
}

// As the scene parser splits a quad: (a, b, c) and (a, c, d); the front face is cross(b − a, c − a).
inline void add_quad(Scene& s, uint32_t material, glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d) {
  add_triangle(s, material, a, b, c);
  add_triangle(s, material, a, c, d);
}

// The axis-aligned box [lo, hi] as six quads; every box edge is an edge of both faces that meet
// there, with the same two vertices (a conforming, closed triangle mesh).
inline void add_box(Scene& s, uint32_t material, glm::vec3 lo, glm::vec3 hi, bool with_bottom = true) {
  auto p = [&](int x, int y, int z) { return glm::vec3(x ? hi.x : lo.x, y ? hi.y : lo.y, z ? hi.z : lo.z); };
  if (with_bottom) add_quad(s, material, p(0, 0, 0), p(1, 0, 0), p(1, 0, 1), p(0, 0, 1));
  add_quad(s, material, p(0, 1, 0), p(0, 1, 1), p(1, 1, 1), p(1, 1, 0));  // top
  add_quad(s, material, p(0, 0, 0), p(0, 1, 0), p(1, 1, 0), p(1, 0, 0));  // z = lo
  add_quad(s, material, p(0, 0, 1), p(1, 0, 1), p(1, 1, 1), p(0, 1, 1));  // z = hi
  add_quad(s, material, p(0, 0, 0), p(0, 0, 1), p(0, 1, 1), p(0, 1, 0));  // x = lo
  add_quad(s, material, p(1, 0, 0), p(1, 1, 0), p(1, 1, 1), p(1, 0, 1));  // x = hi
}

// The square y = const, x and z in [−half, half], facing up.
inline void add_floor(Scene& s, uint32_t m, float y, float half) {
  add_quad(s, m, glm::vec3(-half, y, -half), glm::vec3(-half, y, half), glm::vec3(half, y, half),
           glm::vec3(half, y, -half));
}

inline void set_camera(Scene& s, glm::vec3 position, glm::vec3 look_at, float vfov, glm::vec3 up = glm::vec3(0, 1, 0)) {
  s.camera.position = position;
  s.camera.look_at = look_at;
  s.camera.up = up;
  s.camera.vfov_degrees = vfov;
}

// A folder for the OBJ files the tests write, removed when the program ends.
inline std::string mesh_dir() {
  namespace fs = std::filesystem;
  struct Folder {
    fs::path path = fs::temp_directory_path() / ("xi_test_meshes_" + std::to_string(::getpid()));
    Folder() { fs::create_directories(path); }
    ~Folder() {
      std::error_code ec;
      fs::remove_all(path, ec);
    }
  };
  static const Folder folder;
  return folder.path.string();
}

// Writes triangles to an OBJ file in mesh_dir() (one v line per corner, so Assimp joins identical
// vertices back).
inline std::filesystem::path write_obj(const std::string& name, const std::vector<std::array<glm::dvec3, 3>>& tris) {
  const std::filesystem::path path = std::filesystem::path(mesh_dir()) / name;
  FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw std::runtime_error("cannot write " + path.string());
  for (const auto& t : tris)
    for (const glm::dvec3& p : t) std::fprintf(f, "v %.9g %.9g %.9g\n", (float)p.x, (float)p.y, (float)p.z);
  for (size_t i = 0; i < tris.size(); ++i) std::fprintf(f, "f %zu %zu %zu\n", 3 * i + 1, 3 * i + 2, 3 * i + 3);
  std::fclose(f);
  return path;
}

// Loads an OBJ through the scene parser (Assimp, degenerate-triangle filter) with one material.
inline Mesh load_obj(const std::filesystem::path& path) {
  const std::string json = R"({"camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {"m": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
    "shapes": [{"type": "mesh", "material": "m", "file": ")" + path.filename().string() + R"("}]})";
  return parse_scene(json, path.string(), path.parent_path());
}

// A closed, star-shaped and very uneven mesh: an icosphere (subdivided `levels` times) whose
// vertices are pushed to radii in [r_lo, r_hi] at random (a hash of the vertex, so shared vertices
// stay shared): deep narrow crevices, slivers, every dihedral angle. Centred on the origin.
inline std::vector<std::array<glm::dvec3, 3>> lumpy_mesh(int levels, double r_lo = 0.3, double r_hi = 1.5) {
  const std::string json = R"({"camera": {"position": [0, 0, -5], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
    "materials": {"m": {"type": "diffuse", "albedo": [1, 1, 1]}},
    "shapes": [{"type": "sphere", "material": "m", "center": [0, 0, 0], "radius": 1, "subdivisions": )" +
                           std::to_string(levels) + "}]}";
  const Scene sphere = parse_scene(json, "lumpy", ".");
  std::vector<std::array<glm::dvec3, 3>> out;
  for (const Triangle& t : sphere.triangles) {
    std::array<glm::dvec3, 3> tri;
    for (int k = 0; k < 3; ++k) {
      uint32_t h = 0x9e3779b9u;
      const glm::vec3 p = sphere.position(t, k);
      for (float c : {p.x, p.y, p.z}) {
        uint32_t bits;
        std::memcpy(&bits, &c, 4);
        h = (h ^ bits) * 0x85ebca6bu;
        h ^= h >> 13;
      }
      h *= 0xc2b2ae35u;
      h ^= h >> 16;
      tri[k] = glm::dvec3(p) * (r_lo + (r_hi - r_lo) * (h >> 8) * 0x1p-24);
    }
    out.push_back(tri);
  }
  return out;
}

}  // namespace xi::test
