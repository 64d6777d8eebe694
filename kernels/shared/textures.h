// Texture lookups: a material's TextureRef (layout.h) at a hit's texture coordinates, bilinear
// between texel centres, with the glTF sampler's wrap modes and KHR_texture_transform. Colour
// texels are decoded from sRGB before they are filtered. Written on lane types (lanes.h).
#ifndef XI_TEXTURES_H
#define XI_TEXTURES_H
#include "lanes.h"
#include "layout.h"

static inline xfloat xi_srgb_to_linear(xfloat c) {
  return c <= 0.04045f ? c * (1.0f / 12.92f) : pow((c + 0.055f) * (1.0f / 1.055f), (xfloat)2.4f);
}

// Texel index along an axis of n texels for integer coordinate i, by the wrap mode.
static inline xuint xi_wrap_texel(xint i, xuint n, xuint mode) {
  xint ni = convert_xint(n);
  xint repeat = ((i % ni) + ni) % ni;
  xint period = 2 * ni;
  xint m = ((i % period) + period) % period;
  xint mirror = m < ni ? m : period - 1 - m;
  xint clamped = clamp(i, (xint)0, ni - 1);
  return convert_xuint(mode == XI_WRAP_CLAMP ? clamped : mode == XI_WRAP_MIRROR ? mirror : repeat);
}

// One texel as RGBA in [0, 1], sRGB-decoded for colour images.
static inline xfloat3 xi_texel(__global const uint* texels, xuint at, xmask srgb, xfloat* alpha) {
  xuint t = xi_gather_uint(texels, at);
  const float scale = 1.0f / 255.0f;
  xfloat3 c = make_xfloat3(xi_to_float(t & 255u) * scale, xi_to_float((t >> 8) & 255u) * scale,
                           xi_to_float((t >> 16) & 255u) * scale);
  *alpha = xi_to_float(t >> 24) * scale;
  return make_xfloat3(srgb ? xi_srgb_to_linear(c.x) : c.x, srgb ? xi_srgb_to_linear(c.y) : c.y,
                      srgb ? xi_srgb_to_linear(c.z) : c.z);
}

// The texture `ref` at texture coordinates uv0 (set 0) and uv1 (set 1), as the file gives them
// (v down the image). Lanes whose ref is XI_NO_TEXTURE get (1, 1, 1) and alpha 1, so a factor
// times the lookup is the factor alone.
static inline xfloat3 xi_texture(__global const TextureRef* refs, __global const uint* headers,
                                 __global const uint* texels, xuint ref, xfloat2 uv0, xfloat2 uv1, xfloat* alpha) {
  xmask has = ref != XI_NO_TEXTURE;
  *alpha = 1.0f;
  if (!XI_ANY(has)) return xi_splat3(make_float3(1.0f, 1.0f, 1.0f));
  xuint r = has ? ref : (xuint)0u;
  __global const float4* rf = (__global const float4*)refs;
  __global const uint* ru = (__global const uint*)refs;
  xfloat ou, ov;
  xfloat3 tu = xi_gather_xyz(rf, 3u * r, &ou), tv = xi_gather_xyz(rf, 3u * r + 1u, &ov);
  xuint image = xi_gather_uint(ru, 12u * r + 8u), set = xi_gather_uint(ru, 12u * r + 9u);
  xuint wrap_s = xi_gather_uint(ru, 12u * r + 10u), wrap_t = xi_gather_uint(ru, 12u * r + 11u);
  xfloat u0 = set == 1u ? uv1.x : uv0.x, v0 = set == 1u ? uv1.y : uv0.y;
  xfloat u = tu.x * u0 + tu.y * v0 + tu.z, v = tv.x * u0 + tv.y * v0 + tv.z;
  xuint offset = xi_gather_uint(headers, 4u * image), w = xi_gather_uint(headers, 4u * image + 1u),
        h = xi_gather_uint(headers, 4u * image + 2u);
  xmask srgb = xi_gather_uint(headers, 4u * image + 3u) == XI_IMAGE_SRGB8;
  // Texel centres at half-integers: x in texel units, measured from the first centre.
  xfloat x = u * xi_to_float(w) - 0.5f, y = v * xi_to_float(h) - 0.5f;
  // Far outside [0, 1] a float has no fraction left and an int overflows: keep the coordinate
  // within a range where both hold (a wrap repeats every texel count anyway).
  x = clamp(x, (xfloat)-1e6f, (xfloat)1e6f);
  y = clamp(y, (xfloat)-1e6f, (xfloat)1e6f);
  xfloat fx0 = floor(x), fy0 = floor(y);
  xfloat fx = x - fx0, fy = y - fy0;
  xint ix = convert_xint(fx0), iy = convert_xint(fy0);
  xuint x0 = xi_wrap_texel(ix, w, wrap_s), x1 = xi_wrap_texel(ix + 1, w, wrap_s);
  xuint y0 = xi_wrap_texel(iy, h, wrap_t), y1 = xi_wrap_texel(iy + 1, h, wrap_t);
  xfloat a00, a10, a01, a11;
  xfloat3 c00 = xi_texel(texels, offset + y0 * w + x0, srgb, &a00), c10 = xi_texel(texels, offset + y0 * w + x1, srgb, &a10),
          c01 = xi_texel(texels, offset + y1 * w + x0, srgb, &a01), c11 = xi_texel(texels, offset + y1 * w + x1, srgb, &a11);
  xfloat w00 = (1.0f - fx) * (1.0f - fy), w10 = fx * (1.0f - fy), w01 = (1.0f - fx) * fy, w11 = fx * fy;
  xfloat3 c = xi_add3(xi_add3(xi_scale3(c00, w00), xi_scale3(c10, w10)), xi_add3(xi_scale3(c01, w01), xi_scale3(c11, w11)));
  xfloat a = a00 * w00 + a10 * w10 + a01 * w01 + a11 * w11;
  *alpha = has ? a : (xfloat)1.0f;
  return xi_select3(has, c, xi_splat3(make_float3(1.0f, 1.0f, 1.0f)));
}

// Texture coordinates at barycentrics (b1, b2) of triangle tri: sets 0 and 1, interpolated as the
// hit point is (tri_uv holds u0, v0, u1, v1 per vertex).
static inline void xi_hit_uv(__global const float4* tri_uv, xuint tri, xfloat b1, xfloat b2, xfloat2* uv0, xfloat2* uv1) {
  xfloat w0, w1, w2;
  xfloat3 ta = xi_gather_xyz(tri_uv, 3u * tri, &w0), tb = xi_gather_xyz(tri_uv, 3u * tri + 1u, &w1),
          tc = xi_gather_xyz(tri_uv, 3u * tri + 2u, &w2);
  xfloat b0 = 1.0f - b1 - b2;
  *uv0 = make_xfloat2(ta.x * b0 + tb.x * b1 + tc.x * b2, ta.y * b0 + tb.y * b1 + tc.y * b2);
  *uv1 = make_xfloat2(ta.z * b0 + tb.z * b1 + tc.z * b2, w0 * b0 + w1 * b1 + w2 * b2);
}

// Whether a ray passes through material mi at a hit (glTF's alphaMode): MASK cuts out where the
// alpha (factor times base colour texture) is below the cutoff; BLEND lets the ray through with
// probability 1 - alpha (stochastic transparency: unbiased), deciding by the uniform u.
static inline xmask xi_passes_through(__global const MaterialData* materials, __global const TextureRef* refs,
                                      __global const uint* headers, __global const uint* texels, xuint mi,
                                      xfloat2 uv0, xfloat2 uv1, xfloat u) {
  __global const uint* words = (__global const uint*)materials;
  xuint mode = xi_gather_uint(words, 20u * mi + 9u);
  xmask cut = mode != XI_ALPHA_OPAQUE;
  if (!XI_ANY(cut)) return XI_FALSE;
  xfloat cutoff = xi_as_float(xi_gather_uint(words, 20u * mi + 10u));
  xfloat alpha = xi_as_float(xi_gather_uint(words, 20u * mi + 11u));
  xfloat texture_alpha;
  xi_texture(refs, headers, texels, xi_gather_uint(words, 20u * mi + 16u + XI_TEXTURE_BASE_COLOR), uv0, uv1,
             &texture_alpha);
  alpha = alpha * texture_alpha;
  return cut && (mode == XI_ALPHA_MASK ? alpha < cutoff : u >= alpha);
}

#endif
