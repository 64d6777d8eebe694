// glTF 2.0 files built in memory by the tests: non-indexed triangles (positions, optionally normals,
// texture coordinate sets 0 and 1 and tangents) in one base64 buffer, written as a .gltf text.
#pragma once
#include <cmath>
#include <filesystem>
#include <string>
#include <type_traits>
#include <vector>

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include "cli_test.h"

namespace xi_test {

struct Gltf {
  nlohmann::json doc = {{"asset", {{"version", "2.0"}}}, {"scene", 0},
                        {"scenes", nlohmann::json::array({{{"nodes", nlohmann::json::array()}}})}};
  std::string bin;

  int add(const char* list, nlohmann::json item) {
    doc[list].push_back(std::move(item));
    return int(doc[list].size()) - 1;
  }
  // An accessor of float VEC2, VEC3 or VEC4 values (with the min and max glTF requires of positions).
  template <class V>
  int accessor(const std::vector<V>& values, const char* type) {
    while (bin.size() % 4) bin += '\0';
    const size_t offset = bin.size();
    bin.append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(V));
    const int view = add("bufferViews", {{"buffer", 0}, {"byteOffset", offset}, {"byteLength", bin.size() - offset}});
    nlohmann::json a = {{"bufferView", view}, {"componentType", 5126}, {"count", values.size()}, {"type", type}};
    if constexpr (std::is_same_v<V, glm::vec3>) {
      glm::vec3 lo(INFINITY), hi(-INFINITY);
      for (const auto& p : values) lo = glm::min(lo, p), hi = glm::max(hi, p);
      a["min"] = {lo.x, lo.y, lo.z};
      a["max"] = {hi.x, hi.y, hi.z};
    }
    return add("accessors", a);
  }
  // Triangles (3 positions each) drawn with `material` (< 0: none); normals, texture coordinates
  // and tangents (xyz, w the bitangent's sign) where given.
  int mesh(const std::vector<glm::vec3>& pos, const std::vector<glm::vec3>& normals, const std::vector<glm::vec2>& uv0,
           const std::vector<glm::vec2>& uv1, int material, const std::vector<glm::vec4>& tangents = {}) {
    nlohmann::json attributes = {{"POSITION", accessor(pos, "VEC3")}};
    if (!normals.empty()) attributes["NORMAL"] = accessor(normals, "VEC3");
    if (!uv0.empty()) attributes["TEXCOORD_0"] = accessor(uv0, "VEC2");
    if (!uv1.empty()) attributes["TEXCOORD_1"] = accessor(uv1, "VEC2");
    if (!tangents.empty()) attributes["TANGENT"] = accessor(tangents, "VEC4");
    nlohmann::json prim = {{"attributes", attributes}};
    if (material >= 0) prim["material"] = material;
    return add("meshes", {{"primitives", nlohmann::json::array({prim})}});
  }
  int mesh(const std::vector<glm::vec3>& positions, int material) { return mesh(positions, {}, {}, {}, material); }
  int node(nlohmann::json n, bool root = true) {
    const int i = add("nodes", std::move(n));
    if (root) doc["scenes"][0]["nodes"].push_back(i);
    return i;
  }
  std::string text() const {
    nlohmann::json d = doc;
    d["buffers"] = nlohmann::json::array(
        {{{"byteLength", bin.size()}, {"uri", "data:application/octet-stream;base64," + base64(bin)}}});
    return d.dump(1);
  }
  void write(const std::filesystem::path& p) const { write_text(p, text()); }
};

}  // namespace xi_test
