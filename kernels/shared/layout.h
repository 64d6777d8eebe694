// Data shared between host and kernels: structs stored in device buffers and the path state.
// Buffers hold only float4/uint-sized members (never float3, whose size differs host vs device);
// every struct is a multiple of 16 bytes with its float4 members first, so C++ and OpenCL C agree.
#ifndef XI_LAYOUT_H
#define XI_LAYOUT_H
#include "compat.h"

#define XI_MATERIAL_DIFFUSE 0u
#define XI_MATERIAL_MIRROR 1u
#define XI_MATERIAL_DIELECTRIC 2u
#define XI_MATERIAL_PBR 3u  // glTF 2.0 metallic-roughness (microfacet.h)

#define XI_ALPHA_OPAQUE 0u
#define XI_ALPHA_MASK 1u   // cut out where alpha < alpha_cutoff
#define XI_ALPHA_BLEND 2u  // stochastic transparency: passed through with probability 1 - alpha

#define XI_NO_TEXTURE 0xffffffffu
// A material's texture slots (MaterialData::textures; xi::kTextureSlots names them on the host).
#define XI_TEXTURE_BASE_COLOR 0
#define XI_TEXTURE_METALLIC_ROUGHNESS 1
#define XI_TEXTURE_NORMAL 2
#define XI_TEXTURE_EMISSIVE 3
#define XI_TEXTURE_CLEARCOAT 4            // R: the coat's weight
#define XI_TEXTURE_CLEARCOAT_ROUGHNESS 5  // G: its roughness
#define XI_TEXTURE_SHEEN_COLOR 6
#define XI_TEXTURE_SHEEN_ROUGHNESS 7      // A
#define XI_TEXTURE_SPECULAR 8             // A: the specular layer's strength
#define XI_TEXTURE_SPECULAR_COLOR 9
#define XI_TEXTURE_CLEARCOAT_NORMAL 10    // tangent space: the coat's own normal
#define XI_TEXTURE_ANISOTROPY 11          // RG: the direction in tangent space, B: the strength
#define XI_TEXTURE_IRIDESCENCE 12         // R: the film's weight
#define XI_TEXTURE_IRIDESCENCE_THICKNESS 13  // G: the film's thickness from its minimum to its maximum
#define XI_TEXTURE_SLOTS 14
#define XI_TEXTURE_SLOTS_PADDED 16  // the array's length: the struct's float4s stay 16-byte aligned

// A path carries the volumes it is in (KHR_materials_volume), nested: each its index in the scene's
// volumes + 1 in XI_VOLUME_BITS bits of a 32-bit word, the innermost lowest, XI_VOLUME_LEVELS deep.
#define XI_VOLUME_BITS 8
#define XI_VOLUME_LEVELS 4
#define XI_MAX_VOLUMES 255  // volume materials a scene may hold: 2^XI_VOLUME_BITS − 1

typedef struct {
  float4 albedo;     // rgb: diffuse albedo, mirror or glass tint, base colour (pbr); w: index of refraction
  float4 emission;   // rgb radiance; w: 1 when both faces emit
  uint type;         // XI_MATERIAL_*
  uint alpha_mode;   // XI_ALPHA_*
  float alpha_cutoff;
  float alpha;       // the base colour's alpha factor
  float4 pbr;        // metallic, roughness (perceptual: GGX alpha = roughness²), transmission, normal map scale
  uint textures[XI_TEXTURE_SLOTS_PADDED];  // TextureRef index or XI_NO_TEXTURE, by XI_TEXTURE_*
  float4 specular;   // KHR_materials_specular (pbr): rgb the f0 tint, w the layer's strength (1, 1: none)
  float4 coat;       // KHR_materials_clearcoat (pbr): x weight (0: none), y roughness (perceptual), z the coat's normal map scale; w unused
  float4 sheen;      // KHR_materials_sheen (pbr): rgb colour (0: none), w roughness (perceptual)
  float4 anisotropy; // KHR_materials_anisotropy (pbr): x strength (0: none), y and z the cosine and sine of its rotation; w unused
  float4 iridescence;  // KHR_materials_iridescence (pbr): x weight (0: none), y the film's ior, z and w its thickness's minimum and maximum (nm)
  uint volume;       // KHR_materials_volume (pbr): the index of its σa in volumes + 1 (0: none)
  uint unused[3];
} MaterialData;

// Textures: every image's texels in one buffer of uints (RGBA, 8 bits each, red in the low byte),
// found through its header; a material refers to an image through a TextureRef, which adds the
// texture coordinate set, the wrap modes and KHR_texture_transform.
#define XI_IMAGE_SRGB8 0u    // colour: sRGB-encoded RGB, linear alpha
#define XI_IMAGE_LINEAR8 1u  // data: metallic-roughness, normals
typedef struct {
  uint offset;  // first texel in the texel buffer
  uint width;
  uint height;
  uint format;  // XI_IMAGE_*
} ImageHeader;
#define XI_WRAP_REPEAT 0u
#define XI_WRAP_CLAMP 1u
#define XI_WRAP_MIRROR 2u
typedef struct {
  float4 transform_u;  // u' = x u + y v + z (KHR_texture_transform, texture coordinates as the file has them)
  float4 transform_v;  // v' = x u + y v + z
  uint image;          // ImageHeader index
  uint texcoord;       // 0 or 1
  uint wrap_s;         // XI_WRAP_*
  uint wrap_t;
} TextureRef;

// The environment: an equirectangular image of radiance around the scene, at infinity, in
// Mitsuba 3's orientation (environment.h), rotated about the world's up axis.
typedef struct {
  float4 to_local[3];  // rows of the rotation from world directions to the map's frame
  float4 scale;        // rgb: strength (times the texels); w: probability of picking it among the lights
  uint width;
  uint height;
  uint pad0, pad1;
} EnvironmentData;
// Where the guide tables start in the sampling distribution's buffer (environment.h), in floats:
// after the CDFs' (H + 1)·(W + 1) entries (a marginal over H + 1 patch rows and a conditional of W
// per row), at a multiple of four, so that they read as float4; and where the vertex weights start,
// after the guide tables' four floats per CDF entry.
#define XI_ENV_CDF_ENTRIES(w, h) (((h) + 1u) * ((w) + 1u))
#define XI_ENV_GUIDE_OFFSET(w, h) ((XI_ENV_CDF_ENTRIES(w, h) + 3u) & ~3u)
#define XI_ENV_WEIGHT_OFFSET(w, h) (XI_ENV_GUIDE_OFFSET(w, h) + 4u * XI_ENV_CDF_ENTRIES(w, h))

// Punctual lights (KHR_lights_punctual and JSON): reached by light sampling only.
#define XI_LIGHT_POINT 0u
#define XI_LIGHT_SPOT 1u
#define XI_LIGHT_DIRECTIONAL 2u  // sun with angular radius 0
#define XI_LIGHT_PUNCTUAL 0x80000000u    // a light list entry: punctual light (index in the low bits)
#define XI_LIGHT_ENVIRONMENT 0xffffffffu  // a light list entry: the environment
typedef struct {
  float4 position;   // xyz (point, spot); w: probability of picking it among the lights
  float4 direction;  // xyz: unit direction the light shines in (spot, directional); w: cos of the sun's angular radius
  float4 intensity;  // rgb: radiant intensity (point, spot) or irradiance (directional)
  float4 cone;       // spot: cos of the inner and outer cone angles; w: type (XI_LIGHT_*) as a float
} PunctualLightData;

// A BVH node: the boxes of its children side by side, one lane each, so one vector operation
// tests a ray against all of them. 4 wide (float4) for GPUs; 8 wide (float8, one AVX register) on
// CPU devices, where a node of eight costs what one of four does and the tree is shallower. An
// unused lane has an inverted box (lo = +inf, hi = −inf, which no ray enters) and child
// XI_BVH_EMPTY.
#define XI_BVH_LEAF 0x80000000u   // child: leaf flag | (block count - 1) << 27 | first block
#define XI_BVH_LEAF_MAX 16u       // triangle blocks in one leaf, at most
#define XI_BVH_FIRST_MASK 0x07ffffffu
#define XI_BVH_EMPTY 0xffffffffu
// The width of the nodes the kernels traverse, set by the host (RenderOptions::bvh_width): 8 on CPU
// devices, 4 elsewhere and on the host (its tests' xi_trace).
#ifndef XI_BVH_WIDTH
#define XI_BVH_WIDTH 4
#endif
#if XI_BVH_WIDTH != 4 && XI_BVH_WIDTH != 8
#error "XI_BVH_WIDTH must be 4 or 8"
#endif
// How extend and shadow trace a bounce's rays; the host launches XI_RAYS_PER_ITEM of them per work
// item accordingly. Through an 8-wide tree, camera rays go in packets whose rays go through the tree
// together (packet.h); so do all rays of a small tree (XI_RAY_PACKETS: each ray visits most of it
// anyway). In a larger tree (XI_HYBRID_PACKETS) the rays that leave the surfaces camera rays hit
// (bounce 0's shadow rays, bounce 1's rays), which neighbouring pixels' paths send from nearby
// points, go in hybrid packets (together while many enter a box, alone below it). Every other ray
// goes alone (traverse.h). The host sets neither with cut-outs (shadow rays then go alone).
#ifndef XI_RAY_PACKETS
#define XI_RAY_PACKETS 0
#endif
#ifndef XI_HYBRID_PACKETS
#define XI_HYBRID_PACKETS 0
#endif
#define XI_RAYS_ALONE 0
#define XI_RAYS_TOGETHER 1
#define XI_RAYS_HYBRID 2
#define XI_EXTEND_RAYS(bvh_width, bounce, ray_packets, hybrid_packets)                \
  ((bvh_width) != 8                          ? XI_RAYS_ALONE                          \
   : (bounce) == 0 || (ray_packets)          ? XI_RAYS_TOGETHER                       \
   : (bounce) == 1 && (hybrid_packets)       ? XI_RAYS_HYBRID                         \
                                             : XI_RAYS_ALONE)
#define XI_SHADOW_RAYS(bvh_width, bounce, ray_packets, hybrid_packets)                \
  ((bvh_width) != 8                          ? XI_RAYS_ALONE                          \
   : (ray_packets)                           ? XI_RAYS_TOGETHER                       \
   : (bounce) == 0 && (hybrid_packets)       ? XI_RAYS_HYBRID                         \
                                             : XI_RAYS_ALONE)
#define XI_RAYS_PER_ITEM(rays, packet_width) ((rays) == XI_RAYS_ALONE ? 1 : (packet_width))
// Rays in a packet (packet.h), set by the host (KernelConfig::packet_width): 16 on CPUs with 512-bit
// vectors, else 8.
#ifndef XI_PACKET_WIDTH
#define XI_PACKET_WIDTH 8
#endif
#if XI_PACKET_WIDTH != 8 && XI_PACKET_WIDTH != 16
#error "XI_PACKET_WIDTH must be 8 or 16"
#endif
typedef struct {
  float4 bounds[6];  // child boxes, lane k = child k: lo x, hi x, lo y, hi y, lo z, hi z
  uint child[4];     // interior child: its node index; leaf: see above
  uint pad[4];       // 128 bytes: two whole cache lines
} BvhNode;
typedef struct {
  float8 bounds[6];  // as BvhNode's, eight lanes
  uint child[8];
  uint pad[8];       // 256 bytes: four whole cache lines
} BvhNode8;

#define XI_NO_HIT 0xffffffffu

// The triangles of a leaf in blocks of four, coordinates side by side, so one float4 operation
// works on four triangles (lane k = triangle tri[k]). An unused lane has NaN vertices, which no
// ray hits, and tri XI_NO_HIT.
typedef struct {
  float4 coord[3][3];  // [axis][j]: coordinate x, y or z of vertex j
  uint tri[4];         // the triangles' positions in BVH order (index of tri_vertices)
} TriBlock;

typedef struct {
  float4 position;
  float4 forward;  // unit view direction; w: lens radius (0 = pinhole)
  float4 right;    // unit, scaled by tan(vfov/2)·aspect; w: focus distance
  float4 up;       // unit, scaled by tan(vfov/2)
  uint width;
  uint height;
  uint pad0, pad1;
} CameraData;

// Per-path state, one device buffer per field, indexed by path slot. Each stage kernel takes all
// of them first (XI_PATH_PARAMS) in this order, and the host creates and binds them from this list.
#define XI_PATH_STATE(F)                                                    \
  F(float4, ray_org)    /* xyz: ray origin */                               \
  F(float4, ray_dir)    /* xyz: unit direction; w: as_float(the volumes it is in, XI_VOLUME_BITS each, the innermost low) */ \
  F(float4, hit)        /* t (< 0: miss), barycentric u, v, as_float(tri) */ \
  F(float4, throughput) /* rgb; w: solid-angle pdf of the last BSDF sample, 0 if specular */ \
  F(float4, radiance)   /* rgb gathered so far */                           \
  F(uint, item_pixel)   /* the wave item's frame pixel (set by generate) */ \
  F(uint, item_sample)  /* and its sample index */                          \
  F(float4, aov_albedo) /* rgb: reflectance at the first hit (for denoisers) */ \
  F(float4, aov_normal) /* xyz: shading normal at the first hit, facing the camera */

// Shadow rays queued by shade, traced by shadow. Compact: item i lives at index i.
#define XI_SHADOW_STATE(F)                                  \
  F(float4, shadow_org)     /* xyz: origin; w: tmax */      \
  F(float4, shadow_dir)     /* xyz: unit direction */       \
  F(float4, shadow_contrib) /* rgb; w: as_float(path slot) */

// A vertex in the vertices buffer: two float4s, its position (w = 0), then its normal (zero where
// it has none), so that shading finds both in one cache line.
#define XI_VERTEX_FLOAT4S 2u

// The scene's device buffers, each declared once as F(element type in the kernels, name): the
// host's buffers, the kernels' parameters and the host's bindings all expand these lists, and each
// buffer is uploaded from the CompiledScene field of its name. The tracing stages read the surface
// buffers too (shadow rays look up cut-out materials' alpha); shade reads them all.
#define XI_SURFACE_BUFFERS(F)                                                                           \
  F(MaterialData, materials) F(uint, tri_material) F(float4, tri_uv) F(TextureRef, texture_refs)         \
  F(ImageHeader, images) F(uint, texels)
#define XI_SCENE_BUFFERS(F)                                                                           \
  XI_SURFACE_BUFFERS(F)                                                                               \
  F(uint4, tri_vertices) F(float4, vertices) F(float4, tri_tangents)                                  \
  F(float, light_cdf) F(uint, light_tri)                                                              \
  F(float, tri_light_pdf) F(PunctualLightData, punctual) F(float4, environment_texels) F(float, environment_cdf) \
  F(float4, volumes)

// The film: one float4 per pixel in each of these buffers, which accumulate adds the finished
// paths to (its parameters film_sum, ...) and the host reads back into RenderState's fields of the
// same names (sum: radiance, w the sample count; sum_sq: squared radiance; albedo: first-hit
// reflectance, w the samples taken; normal: first-hit shading normal).
#define XI_FILM_BUFFERS(F) F(sum) F(sum_sq) F(albedo) F(normal)
#define XI_FILM_PARAM(name) __global float4* restrict film_##name,

#define XI_PARAM(type, name) __global type* restrict name,
#define XI_CONST_PARAM(type, name) __global const type* restrict name,
#define XI_PATH_PARAMS XI_PATH_STATE(XI_PARAM)
#define XI_ARG(type, name) name,
#define XI_PATH_ARGS XI_PATH_STATE(XI_ARG)
#define XI_SHADOW_PARAMS XI_SHADOW_STATE(XI_PARAM)

// Which (pixel, sample) items a wave holds: `pixels` consecutive pixels of the film from
// first_pixel, each with `samples` consecutive sample indices from first_sample (several where the
// film is small next to the paths in flight). With pixel_list (adaptive sampling) they are instead
// the entries from first_pixel on of the list of film pixels still sampling (XI_WAVE_FILM_PIXEL). Item (path slot) k is sample k % samples of the
// wave's pixel k / samples (XI_WAVE_*): a pixel's samples are neighbours, so the rays that one work
// item or one ray packet holds leave a few neighbouring pixels and stay close together.
// The film holds rows first_row, first_row + row_stride, ... of a frame `width` pixels wide (all
// rows: 0 and 1; one process of a distributed render: its share). Sample values depend on the frame
// pixel only, so films of different rows put together make the frame's image bitwise.
typedef struct {
  uint first_pixel;
  uint pixels;
  uint first_sample;
  uint samples;
  uint width;
  uint first_row;
  uint row_stride;
  uint pixel_list;  // 1: the wave's pixels are entries of the list of pixels still sampling
} WaveParams;

// The wave's pixel of a slot: a film pixel, or with pixel_list an index into the list.
#define XI_WAVE_PIXEL(wave, slot) ((wave).first_pixel + (slot) / (wave).samples)
#define XI_WAVE_SAMPLE(wave, slot) ((wave).first_sample + (slot) % (wave).samples)  // sample index
// The slot of the wave's pixel p (from first_pixel) and sample s (from first_sample).
#define XI_WAVE_SLOT(wave, p, s) ((p) * (wave).samples + (s))
// The film pixel of the wave's pixel `at` (XI_WAVE_PIXEL), read from `list` with pixel_list.
#define XI_WAVE_FILM_PIXEL(wave, list, at) ((wave).pixel_list ? (list)[at] : (at))

// The largest work group the host launches (shade keeps a group's queue entries in local memory).
#define XI_MAX_LOCAL_SIZE 1024

// Counters in one small device buffer, zeroed per wave but for the non-finite count. Kernels read
// their queue length from it, so the host launches over an upper bound without waiting for it.
#define XI_COUNTER_NONFINITE 0
#define XI_COUNTER_RAYS(bounce) (1 + 2 * (bounce))    // rays entering extend at this bounce
#define XI_COUNTER_SHADOW(bounce) (2 + 2 * (bounce))  // shadow rays shade queued at this bounce
#define XI_COUNTER_COUNT(max_depth) (XI_COUNTER_RAYS((max_depth) + 1) + 1)

#endif
