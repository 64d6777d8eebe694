// What the shading stages (generate, shade) do beyond a diffuse surface lit by escaped rays: the
// scene's features and the light transport strategy as bits, with the sampler, in one word.
// A scene's own program is compiled with XI_SHADING set to its word, so code for what the scene
// does not use is not compiled at all. The generic program (XI_GENERIC) reads the word from its
// kernel argument instead: one build serves every scene, with the same arithmetic, and so renders
// a new scene's first passes, pixel for pixel as its own program would, while that one builds.
#ifndef XI_SHADING_H
#define XI_SHADING_H
#include "compat.h"

#define XI_USE_MIRROR 1u
#define XI_USE_DIELECTRIC 2u
#define XI_USE_NORMALS 4u    // interpolated vertex normals
#define XI_USE_EMITTERS 8u
#define XI_USE_LENS 16u      // a thin-lens camera
#define XI_USE_NEE 32u       // light sampling (next-event estimation), where there are emitters
#define XI_USE_MIS 64u       // light and BSDF sampling combined by the power heuristic, with NEE
#define XI_USE_PBR 128u      // the metallic-roughness material (microfacet.h)
#define XI_USE_TEXTURES 256u
#define XI_USE_ENVIRONMENT 512u  // an environment map (environment.h) instead of a constant background
#define XI_USE_PUNCTUAL 1024u    // point, spot and directional lights
#define XI_USE_ALPHA 2048u       // cut-out (alpha mask) and stochastically transparent surfaces
#define XI_USE_MULTIPLE_SCATTERING 4096u  // the metal's multiple-scattering lobe and the layer's scale (microfacet.h)
#define XI_USE_ALBEDO_SCALING 8192u       // the dielectric layer's albedo scaling of the base (microfacet.h)
#define XI_USE_SPECULAR 16384u            // KHR_materials_specular: a tinted or weakened dielectric layer
#define XI_USE_CLEARCOAT 32768u           // KHR_materials_clearcoat
#define XI_USE_VOLUME 65536u              // KHR_materials_volume: absorption inside transmissive meshes
#define XI_USE_SHEEN 131072u              // KHR_materials_sheen
#define XI_USE_ANISOTROPY 262144u         // KHR_materials_anisotropy
#define XI_USE_IRIDESCENCE 524288u        // KHR_materials_iridescence: a thin film over the base
#define XI_USE_NORMAL_MAP 1048576u        // a metallic-roughness base's normal map (with XI_USE_TEXTURES)
// (Feature bits stay below the sampler's: kernel_config.cpp checks that they do.)
#define XI_SAMPLER_SHIFT 24u     // the sampler (XI_SAMPLER_*) in the bits above

// The scene's features, each declared once as F(the host's Features field, its bit, its name in
// reports, 1 where --all-features compiles it in): the Features struct, the shading word and the
// reports all come from this list. (Multiple scattering and albedo scaling are choices of model,
// not features a scene may lack, so compiling every feature in leaves them as the scene has them.)
#define XI_FEATURES(F)                                          \
  F(mirror, XI_USE_MIRROR, "mirror", 1)                         \
  F(dielectric, XI_USE_DIELECTRIC, "glass", 1)                  \
  F(normals, XI_USE_NORMALS, "normals", 1)                      \
  F(emitters, XI_USE_EMITTERS, "emitters", 1)                   \
  F(lens, XI_USE_LENS, "lens", 1)                               \
  F(pbr, XI_USE_PBR, "pbr", 1)                                  \
  F(textures, XI_USE_TEXTURES, "textures", 1)                   \
  F(environment, XI_USE_ENVIRONMENT, "environment", 1)          \
  F(punctual, XI_USE_PUNCTUAL, "punctual", 1)                   \
  F(alpha, XI_USE_ALPHA, "alpha", 1)                            \
  F(specular, XI_USE_SPECULAR, "specular", 1)                   \
  F(clearcoat, XI_USE_CLEARCOAT, "clearcoat", 1)                \
  F(volume, XI_USE_VOLUME, "volume", 1)                         \
  F(sheen, XI_USE_SHEEN, "sheen", 1)                            \
  F(anisotropy, XI_USE_ANISOTROPY, "anisotropy", 1)             \
  F(iridescence, XI_USE_IRIDESCENCE, "iridescence", 1)          \
  F(normal_map, XI_USE_NORMAL_MAP, "normal-map", 1)             \
  F(multiple_scattering, XI_USE_MULTIPLE_SCATTERING, "multiple-scattering", 0) \
  F(albedo_scaling, XI_USE_ALBEDO_SCALING, "albedo-scaling", 0)

#if defined(XI_DEVICE) && (defined(XI_GENERIC) || defined(XI_SHADING))
// The shading word in force: the program's own, or in the generic program the argument's.
static inline uint xi_shading(uint argument) {
#ifdef XI_GENERIC
  return argument;
#else
  (void)argument;
  return XI_SHADING;
#endif
}
#endif

static inline bool xi_uses(uint shading, uint feature) { return (shading & feature) != 0u; }

// Whether a feature's code is compiled into this program, for code that does not see the shading
// word (the BSDFs): in a scene's own program its features only, a constant the compiler folds; in
// the generic program and on the host, every feature.
#if defined(XI_DEVICE) && defined(XI_SHADING) && !defined(XI_GENERIC)
#define XI_COMPILED(feature) ((XI_SHADING & (feature)) != 0u)
#else
#define XI_COMPILED(feature) 1
#endif

static inline int xi_sampler_of(uint shading) { return (int)(shading >> XI_SAMPLER_SHIFT); }

#endif
