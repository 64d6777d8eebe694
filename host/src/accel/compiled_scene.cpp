#include "xi/compiled_scene.h"

#include <cfloat>
#include <cmath>
#include <cstddef>

#include "xi/error.h"

// shade's xi_gather_material (bsdf.h) reads a material as three float4s with the type first in the third.
static_assert(sizeof(MaterialData) == 80 && offsetof(MaterialData, type) == 32 && offsetof(MaterialData, pbr) == 48 &&
                  offsetof(MaterialData, textures) == 64,
              "MaterialData layout");
static_assert(sizeof(TextureRef) == 48 && sizeof(EnvironmentData) == 80 && sizeof(PunctualLightData) == 64, "layout");

namespace xi {
namespace {

// In double: in float, |e1 × e2|² underflows for edges below about 1e-11 (a light dropped as
// having no area).
double triangle_area(const Triangle& t) {
  const glm::dvec3 v0(t.v[0]);
  return 0.5 * glm::length(glm::cross(glm::dvec3(t.v[1]) - v0, glm::dvec3(t.v[2]) - v0));
}

}  // namespace

Features Features::everything() { return Features{true, true, true, true, true}; }

std::string Features::describe() const {
  std::string s = "diffuse";
  if (mirror) s += " mirror";
  if (dielectric) s += " glass";
  if (normals) s += " normals";
  if (emitters) s += " emitters";
  if (lens) s += " lens";
  return s;
}

CompiledScene compile_scene(const Scene& scene, int bvh_width, bool spatial_splits, unsigned build_threads) {
  check_scene_limits(scene);  // a scene built in code has not met the loaders' checks
  CompiledScene cs;
  cs.bvh = build_bvh(scene.triangles, bvh_width, spatial_splits, build_threads);
  const size_t n = scene.triangles.size();

  for (auto& m : scene.materials) {
    MaterialData md{};
    md.albedo = glm::vec4(m.albedo, m.ior);
    md.emission = glm::vec4(m.emission, m.two_sided ? 1.0f : 0.0f);
    md.type = (uint32_t)m.type;
    cs.materials.push_back(md);
    cs.features.mirror |= m.type == MaterialType::Mirror;
    cs.features.dielectric |= m.type == MaterialType::Dielectric;
  }

  cs.tri_verts.resize(3 * n);
  cs.tri_material.resize(n);
  cs.tri_light_pdf.assign(n, 0.0f);
  for (auto& t : scene.triangles) cs.features.normals |= t.has_normals;
  // Always 3 per triangle: an --all-features build reads them even when no triangle has normals.
  cs.tri_normals.assign(3 * n, glm::vec4(0.0f));
  for (size_t i = 0; i < n; ++i) {
    const Triangle& t = scene.triangles[cs.bvh.order[i]];
    for (int k = 0; k < 3; ++k) {
      cs.tri_verts[3 * i + k] = glm::vec4(t.v[k], 0.0f);
      if (t.has_normals) cs.tri_normals[3 * i + k] = glm::vec4(t.n[k], 1.0f);
    }
    cs.tri_material[i] = t.material;
  }
  // The lights in the scene's order, not the BVH's, so that a light sample does not depend on
  // how the BVH was built (spatial splits or not): only a tie between two hits can.
  std::vector<double> power;
  for (size_t j = 0; j < n; ++j) {
    const Triangle& t = scene.triangles[j];
    const Material& m = scene.materials[t.material];
    if (!m.is_emitter()) continue;
    double area = triangle_area(t);
    double lum = 0.2126 * m.emission.x + 0.7152 * m.emission.y + 0.0722 * m.emission.z;
    double p = lum * area * M_PI * (m.two_sided ? 2.0 : 1.0);
    // Sampled only where its area density, at most 1 / area, is finite in single precision
    // (a triangle of side below about 1e-19; a light scaled by 1e-45 made it inf): such a light,
    // like one of no area, is reached by BSDF samples alone.
    if (p > 0.0 && area * FLT_MAX >= 1.0) {
      cs.light_tri.push_back(cs.bvh.position[j]);
      power.push_back(p);
    }
  }

  double total = 0.0;
  for (double p : power) total += p;
  cs.light_power = (float)total;
  double acc = 0.0;
  for (size_t k = 0; k < power.size(); ++k) {
    acc += power[k];
    cs.light_cdf.push_back(k + 1 == power.size() ? 1.0f : (float)(acc / total));
    const Triangle& t = scene.triangles[cs.bvh.order[cs.light_tri[k]]];
    double area = triangle_area(t);
    cs.tri_light_pdf[cs.light_tri[k]] = (float)(power[k] / total / area);
  }
  cs.features.emitters = !cs.light_tri.empty();
  if (cs.light_cdf.empty()) {  // OpenCL needs non-empty buffers
    cs.light_cdf.push_back(1.0f);
    cs.light_tri.push_back(0);
  }

  const Camera& c = scene.camera;
  glm::vec3 forward = glm::normalize(c.look_at - c.position);
  glm::vec3 right = glm::normalize(glm::cross(forward, c.up));
  glm::vec3 up = glm::cross(right, forward);
  float tan_half = std::tan(glm::radians(c.vfov_degrees) * 0.5f);
  float aspect = (float)scene.width / (float)scene.height;
  cs.camera.position = glm::vec4(c.position, 0.0f);
  cs.camera.forward = glm::vec4(forward, c.aperture_radius);
  cs.camera.right = glm::vec4(right * tan_half * aspect, c.focus_distance);
  cs.camera.up = glm::vec4(up * tan_half, 0.0f);
  cs.camera.width = (uint32_t)scene.width;
  cs.camera.height = (uint32_t)scene.height;
  cs.features.lens = c.aperture_radius > 0.0f;
  cs.background = glm::vec4(scene.background, 0.0f);
  return cs;
}

}  // namespace xi
