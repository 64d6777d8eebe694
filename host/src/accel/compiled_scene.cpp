#include "xi/compiled_scene.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstddef>
#include <future>
#include <thread>

#include "../parallel.h"
#include "xi/environment.h"
#include "xi/error.h"

// shade's xi_gather_material (bsdf.h) reads a material as three float4s with the type first in the third.
static_assert(sizeof(MaterialData) == 224 && offsetof(MaterialData, type) == 32 && offsetof(MaterialData, pbr) == 48 &&
                  offsetof(MaterialData, textures) == 64 && offsetof(MaterialData, specular) == 128 &&
                  offsetof(MaterialData, coat) == 144 && offsetof(MaterialData, sheen) == 160 &&
                  offsetof(MaterialData, anisotropy) == 176 && offsetof(MaterialData, iridescence) == 192 &&
                  offsetof(MaterialData, volume) == 208,
              "MaterialData layout");
static_assert(sizeof(TextureRef) == 48 && sizeof(EnvironmentData) == 80 && sizeof(PunctualLightData) == 64, "layout");

namespace xi {
namespace {

// In double: in float, |e1 × e2|² underflows for edges below about 1e-11 (a light dropped as
// having no area).
double triangle_area(const Mesh& mesh, const Triangle& t) {
  const glm::dvec3 v0(mesh.position(t, 0));
  return 0.5 * glm::length(glm::cross(glm::dvec3(mesh.position(t, 1)) - v0, glm::dvec3(mesh.position(t, 2)) - v0));
}

TextureRef texture_ref(const TextureSlot& slot) {
  TextureRef r{};
  // glm is column-major: row i of the transform is (m[0][i], m[1][i], m[2][i]).
  const glm::mat3& m = slot.transform;
  r.transform_u = glm::vec4(m[0][0], m[1][0], m[2][0], 0.0f);
  r.transform_v = glm::vec4(m[0][1], m[1][1], m[2][1], 0.0f);
  r.image = (uint32_t)slot.image;
  r.texcoord = (uint32_t)slot.texcoord;
  r.wrap_s = (uint32_t)slot.wrap_s;
  r.wrap_t = (uint32_t)slot.wrap_t;
  return r;
}

void upload_images(const Scene& scene, CompiledScene& cs) {
  for (const TextureImage& img : scene.images) {
    if (img.width < 1 || img.height < 1 || img.texels.size() != (size_t)img.width * img.height)
      throw Error("texture image '" + img.source + "' has no texels or the wrong number", scene.source);
    if (cs.texels.size() + img.texels.size() > UINT32_MAX)
      throw Error("the scene's textures hold over 2^32 texels", scene.source);
    cs.images.push_back(ImageHeader{(uint32_t)cs.texels.size(), (uint32_t)img.width, (uint32_t)img.height,
                                    img.srgb ? XI_IMAGE_SRGB8 : XI_IMAGE_LINEAR8});
    cs.texels.insert(cs.texels.end(), img.texels.begin(), img.texels.end());
  }
}

// The radius of the scene's bounding sphere: light arriving from infinity (the environment, a
// directional light) is picked by the power it brings onto a sphere that size.
double scene_radius(const Scene& scene) {
  const auto [lo, hi] = scene.bounds();
  return scene.triangles.empty() ? 1.0 : std::max(0.5 * glm::length(glm::dvec3(hi) - glm::dvec3(lo)), 1e-6);
}

double luminance(glm::vec3 c) { return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z; }

void add_punctual_lights(const Scene& scene, CompiledScene& cs, std::vector<double>& power) {
  if (scene.lights.empty()) return;  // (the radius is a pass over every triangle)
  const double r = scene_radius(scene);
  for (const Light& l : scene.lights) {
    PunctualLightData d{};
    d.position = glm::vec4(l.position, 0.0f);
    d.direction = glm::vec4(glm::normalize(l.direction), std::cos(l.angular_radius));
    d.intensity = glm::vec4(l.intensity, 0.0f);
    const bool sun = l.type == LightType::Directional;
    d.cone = glm::vec4(std::cos(l.inner_cone), std::cos(l.outer_cone), 0.0f,
                       (float)(sun ? XI_LIGHT_DIRECTIONAL : l.type == LightType::Spot ? XI_LIGHT_SPOT : XI_LIGHT_POINT));
    // Emitted power: 4π I (point), about 2π (1 - cos of the mean cone angle) I (spot); a directional
    // light's irradiance over the scene's cross-section.
    const double lum = luminance(l.intensity);
    const double p = sun ? lum * M_PI * r * r
                   : l.type == LightType::Spot ? lum * 2.0 * M_PI * (1.0 - 0.5 * (d.cone.x + d.cone.y))
                                               : lum * 4.0 * M_PI;
    if (!(p > 0.0) || !std::isfinite(p)) continue;
    cs.light_tri.push_back(XI_LIGHT_PUNCTUAL | (uint32_t)cs.punctual.size());
    cs.punctual.push_back(d);
    power.push_back(p);
  }
  cs.features.punctual = !cs.punctual.empty();
}

void add_environment(const Scene& scene, CompiledScene& cs, std::vector<double>& power) {
  if (!scene.environment) return;
  const Environment& e = *scene.environment;
  if (!(e.strength >= 0.0f) || !std::isfinite(e.strength))
    throw Error("the environment's strength must be finite and >= 0", e.file.string());
  if (!std::isfinite(e.rotation_degrees)) throw Error("the environment's rotation is not finite", e.file.string());
  EnvironmentMap map = load_environment(e.file);
  const bool samplable = map.has_distribution();
  cs.environment = make_environment_data(map, e.strength, e.rotation_degrees, 0.0f);
  cs.environment_texels = std::move(map.texels);
  cs.environment_cdf = std::move(map.cdf);
  cs.features.environment = true;
  // The power a uniform environment of the same mean radiance sends onto the scene's bounding
  // sphere: π L over its area 4π r².
  const double r = scene_radius(scene);
  const double p = samplable ? M_PI * map.mean_luminance * e.strength * 4.0 * M_PI * r * r : 0.0;
  if (p > 0.0 && std::isfinite(p)) {
    cs.light_tri.push_back(XI_LIGHT_ENVIRONMENT);
    power.push_back(p);
  }
}

}  // namespace

// Every kernel feature; multiple_scattering and albedo_scaling, choices of model rather than
// features, are left false here and taken from the scene (KernelConfig::make).
Features Features::everything() {
  Features f;
#define XI_ALL_FEATURES(name, bit, word, in_all) f.name = in_all;
  XI_FEATURES(XI_ALL_FEATURES)
#undef XI_ALL_FEATURES
  return f;
}

std::string Features::describe() const {
  std::string s = "diffuse";
#define XI_DESCRIBE_FEATURE(name, bit, word, in_all) \
  if (name) s += " " word;
  XI_FEATURES(XI_DESCRIBE_FEATURE)
#undef XI_DESCRIBE_FEATURE
  return s;
}

namespace {

// compile_scene; with `owner` (the scene itself), its triangles are freed once compiled.
CompiledScene compile(const Scene& scene, Scene* owner, int bvh_width, bool spatial_splits, unsigned build_threads) {
  check_scene_limits(scene);  // a scene built in code has not met the loaders' checks
  CompiledScene cs;
  cs.bvh = build_bvh(scene, bvh_width, spatial_splits, build_threads);
  const size_t n = scene.triangles.size();

  for (auto& m : scene.materials) {
    MaterialData md{};
    md.albedo = glm::vec4(m.albedo, m.ior);
    md.emission = glm::vec4(m.emission, m.two_sided ? 1.0f : 0.0f);
    md.type = (uint32_t)m.type;
    md.alpha_mode = (uint32_t)m.alpha_mode;
    md.alpha_cutoff = m.alpha_cutoff;
    md.alpha = m.alpha;
    md.pbr = glm::vec4(m.metallic, m.roughness, m.transmission, m.normal_scale);
    md.specular = glm::vec4(m.specular_color, m.specular);
    md.coat = glm::vec4(m.clearcoat, m.clearcoat_roughness, m.clearcoat_normal_scale, 0.0f);
    const bool has_volume = m.type == MaterialType::Pbr && m.volume_absorption() != glm::vec3(0.0f);
    md.volume = has_volume ? (uint32_t)cs.volumes.size() + 1u : 0u;
    if (has_volume) cs.volumes.push_back(glm::vec4(m.volume_absorption(), 0.0f));
    md.sheen = glm::vec4(m.sheen_color, m.sheen_roughness);
    const bool anisotropic = m.type == MaterialType::Pbr && m.anisotropy_strength > 0.0f;
    md.anisotropy = glm::vec4(anisotropic ? m.anisotropy_strength : 0.0f, std::cos(m.anisotropy_rotation),
                              std::sin(m.anisotropy_rotation), 0.0f);
    const bool iridescent = m.type == MaterialType::Pbr && m.iridescence > 0.0f;
    md.iridescence = glm::vec4(iridescent ? m.iridescence : 0.0f, m.iridescence_ior, m.iridescence_thickness_minimum,
                               m.iridescence_thickness_maximum);
    for (int k = 0; k < XI_TEXTURE_SLOTS; ++k) {
      const TextureSlot& slot = m.textures[k];
      md.textures[k] = XI_NO_TEXTURE;
      if (!slot.used()) continue;
      if (slot.image >= (int)scene.images.size())
        throw Error("material '" + m.name + "' names texture image " + std::to_string(slot.image) +
                        ", which does not exist", scene.source);
      md.textures[k] = (uint32_t)cs.texture_refs.size();
      cs.texture_refs.push_back(texture_ref(slot));
    }
    cs.materials.push_back(md);
    cs.features.mirror |= m.type == MaterialType::Mirror;
    cs.features.dielectric |= m.type == MaterialType::Dielectric;
    cs.features.pbr |= m.type == MaterialType::Pbr;
    cs.features.specular |= m.type == MaterialType::Pbr && (m.specular != 1.0f || m.specular_color != glm::vec3(1.0f));
    cs.features.clearcoat |= m.type == MaterialType::Pbr && m.clearcoat > 0.0f;
    cs.features.volume |= has_volume;
    cs.features.sheen |= m.type == MaterialType::Pbr && m.sheen_color != glm::vec3(0.0f);
    cs.features.anisotropy |= anisotropic;
    cs.features.iridescence |= iridescent;
    cs.features.alpha |= m.cuts_out();
  }
  // A path's volumes are volume indices + 1 in XI_VOLUME_BITS each of one 32-bit word (shade.cl).
  static_assert(XI_VOLUME_BITS * XI_VOLUME_LEVELS == 32 && XI_MAX_VOLUMES == (1u << XI_VOLUME_BITS) - 1u);
  if (cs.volumes.size() > XI_MAX_VOLUMES)
    throw Error("a scene holds at most " + std::to_string(XI_MAX_VOLUMES) + " materials with a volume, not " +
                    std::to_string(cs.volumes.size()),
                scene.source);
  cs.features.textures = !cs.texture_refs.empty();
  cs.features.multiple_scattering = cs.features.pbr && scene.render.multiple_scattering;
  cs.features.albedo_scaling = cs.features.pbr && scene.render.layering == Layering::AlbedoScaling;
  upload_images(scene, cs);

  // The lights in the scene's order, not the BVH's, so that a light sample does not depend on
  // how the BVH was built (spatial splits or not): only a tie between two hits can.
  std::vector<double> power;
  cs.tri_light_pdf.assign(n, 0.0f);
  for (size_t j = 0; j < n; ++j) {
    const Triangle& t = scene.triangles[j];
    const Material& m = scene.materials[t.material];
    if (!m.is_emitter()) continue;
    double area = triangle_area(scene, t);
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

  const size_t emissive_triangles = cs.light_tri.size();
  cs.features.emitters = emissive_triangles > 0;
  add_punctual_lights(scene, cs, power);
  add_environment(scene, cs, power);

  double total = 0.0;
  for (double p : power) total += p;
  cs.light_power = (float)total;
  double acc = 0.0;
  for (size_t k = 0; k < power.size(); ++k) {
    acc += power[k];
    cs.light_cdf.push_back(k + 1 == power.size() ? 1.0f : (float)(acc / total));
    const float pick = (float)(power[k] / total);
    if (k < emissive_triangles) {
      const Triangle& t = scene.triangles[cs.bvh.order[cs.light_tri[k]]];
      cs.tri_light_pdf[cs.light_tri[k]] = (float)(power[k] / total / triangle_area(scene, t));
    } else if (cs.light_tri[k] == XI_LIGHT_ENVIRONMENT) {
      cs.environment.scale.w = pick;
    } else {
      cs.punctual[cs.light_tri[k] & ~XI_LIGHT_PUNCTUAL].position.w = pick;
    }
  }
  // Texture coordinates where a texture or an anisotropy direction is read, tangents where a normal
  // map or an anisotropy direction is (both give the tangent frame).
  cs.features.normal_map = std::any_of(cs.materials.begin(), cs.materials.end(), [](const MaterialData& m) {
    return m.textures[XI_TEXTURE_NORMAL] != XI_NO_TEXTURE;
  });
  const bool uv = cs.features.textures || cs.features.anisotropy;
  const bool tangents = cs.features.normal_map || cs.features.anisotropy;
  cs.tri_vertices.resize(n);
  cs.tri_material.resize(n);
  if (uv) cs.tri_uv.resize(3 * n);
  if (tangents) cs.tri_tangents.resize(3 * n);
  // The triangles in BVH order, in one pass on every core: each read is a cache miss into the
  // scene's triangles (a 5M-triangle mesh: most of this function's time).
  const unsigned threads = std::max(1u, build_threads ? build_threads : std::thread::hardware_concurrency());
  std::vector<char> normals(threads, 0);
  parallel_chunks(n, parts_for(n, threads), [&](size_t begin, size_t end, unsigned part) {
    bool any_normals = false;
    for (size_t i = begin; i < end; ++i) {
      const Triangle& t = scene.triangles[cs.bvh.order[i]];
      cs.tri_vertices[i] = glm::uvec4(t.v[0], t.v[1], t.v[2], t.has_normals ? 1u : 0u);
      cs.tri_material[i] = t.material;
      any_normals |= t.has_normals;
      if (!uv && !tangents) continue;
      const TriangleTexcoords& c = texcoords_of(scene.texcoords, t);
      for (int k = 0; k < 3; ++k) {
        if (uv) cs.tri_uv[3 * i + k] = glm::vec4(c.uv[0][k], c.uv[1][k]);
        if (tangents) cs.tri_tangents[3 * i + k] = c.tangent[k];
      }
    }
    normals[part] = any_normals;
  });
  for (char has : normals) cs.features.normals |= has != 0;
  if (owner) {  // the scene's triangles are done with: freed before the vertices are laid out
    std::vector<Triangle>().swap(owner->triangles);
    std::vector<TriangleTexcoords>().swap(owner->texcoords);
  }
  // The vertices in the scene's order, each position beside its normal.
  const size_t nv = scene.vertices.size();
  cs.vertices.resize(XI_VERTEX_FLOAT4S * nv);
  parallel_chunks(nv, parts_for(nv, threads), [&](size_t begin, size_t end, unsigned) {
    for (size_t i = begin; i < end; ++i) {
      const Vertex& v = scene.vertices[i];
      cs.vertices[XI_VERTEX_FLOAT4S * i] = glm::vec4(v.position, 0.0f);
      cs.vertices[XI_VERTEX_FLOAT4S * i + 1] = glm::vec4(v.normal, 0.0f);
    }
  });
  if (owner) std::vector<Vertex>().swap(owner->vertices);

  if (cs.light_cdf.empty()) {  // OpenCL needs non-empty buffers
    cs.light_cdf.push_back(1.0f);
    cs.light_tri.push_back(0);
  }
  if (cs.punctual.empty()) cs.punctual.push_back(PunctualLightData{});
  if (cs.volumes.empty()) cs.volumes.push_back(glm::vec4(0.0f));
  if (cs.tri_uv.empty()) cs.tri_uv.push_back(glm::vec4(0.0f));
  if (cs.tri_tangents.empty()) cs.tri_tangents.push_back(glm::vec4(0.0f));
  if (cs.texture_refs.empty()) cs.texture_refs.push_back(TextureRef{});
  if (cs.images.empty()) cs.images.push_back(ImageHeader{});
  if (cs.texels.empty()) cs.texels.push_back(0u);
  if (cs.environment_texels.empty()) cs.environment_texels.push_back(glm::vec4(0.0f));
  if (cs.environment_cdf.empty()) cs.environment_cdf.push_back(1.0f);

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
  cs.background = glm::vec4(scene.background, 0.0f);  // (the environment replaces it where there is one)
  return cs;
}

}  // namespace

CompiledScene compile_scene(const Scene& scene, int bvh_width, bool spatial_splits, unsigned build_threads) {
  return compile(scene, nullptr, bvh_width, spatial_splits, build_threads);
}

CompiledScene compile_scene_freeing_triangles(Scene& scene, int bvh_width, bool spatial_splits, unsigned build_threads) {
  return compile(scene, &scene, bvh_width, spatial_splits, build_threads);
}

}  // namespace xi
