// Texture lookups: a material's TextureRef (layout.h) at a hit's texture coordinates, bilinear
// between texel centres, with the glTF sampler's wrap modes and KHR_texture_transform. Colour
// texels are decoded from sRGB before they are filtered. Written on lane types (lanes.h).
#ifndef XI_TEXTURES_H
#define XI_TEXTURES_H
#include "lanes.h"
#include "layout.h"

// The sRGB transfer function's inverse at the 256 values of an 8-bit channel: a table, since pow
// per channel of four texels per lookup dominated shading time.
XI_TABLE float xi_srgb_table[256] = {
    0.0f, 0.000303526984f, 0.000607053967f, 0.000910580951f, 0.00121410793f, 0.00151763492f, 0.0018211619f, 0.00212468888f,
    0.00242821587f, 0.00273174285f, 0.00303526984f, 0.00334653576f, 0.00367650732f, 0.00402471702f, 0.00439144204f, 0.00477695348f,
    0.0051815167f, 0.00560539162f, 0.00604883302f, 0.00651209079f, 0.00699541019f, 0.00749903204f, 0.00802319299f, 0.00856812562f,
    0.0091340587f, 0.00972121732f, 0.010329823f, 0.010960094f, 0.0116122452f, 0.0122864884f, 0.0129830323f, 0.013702083f,
    0.0144438436f, 0.0152085144f, 0.0159962934f, 0.0168073758f, 0.0176419545f, 0.0185002201f, 0.019382361f, 0.0202885631f,
    0.0212190104f, 0.0221738848f, 0.0231533662f, 0.0241576324f, 0.0251868596f, 0.0262412219f, 0.0273208916f, 0.0284260395f,
    0.0295568344f, 0.0307134437f, 0.0318960331f, 0.0331047666f, 0.0343398068f, 0.0356013149f, 0.0368894504f, 0.0382043716f,
    0.0395462353f, 0.0409151969f, 0.0423114106f, 0.0437350293f, 0.0451862044f, 0.0466650863f, 0.0481718242f, 0.049706566f,
    0.0512694584f, 0.052860647f, 0.0544802764f, 0.05612849f, 0.0578054302f, 0.0595112382f, 0.0612460542f, 0.0630100177f,
    0.0648032667f, 0.0666259386f, 0.0684781698f, 0.0703600957f, 0.0722718507f, 0.0742135684f, 0.0761853815f, 0.0781874218f,
    0.0802198203f, 0.0822827071f, 0.0843762115f, 0.086500462f, 0.0886555863f, 0.0908417112f, 0.0930589628f, 0.0953074666f,
    0.0975873471f, 0.0998987282f, 0.102241733f, 0.104616484f, 0.107023103f, 0.109461711f, 0.111932428f, 0.114435374f,
    0.116970668f, 0.119538428f, 0.122138772f, 0.124771818f, 0.12743768f, 0.130136477f, 0.132868322f, 0.13563333f,
    0.138431615f, 0.141263291f, 0.144128471f, 0.147027266f, 0.14995979f, 0.152926152f, 0.155926464f, 0.158960835f,
    0.162029376f, 0.165132195f, 0.1682694f, 0.171441101f, 0.174647404f, 0.177888416f, 0.181164244f, 0.184474995f,
    0.187820772f, 0.191201683f, 0.19461783f, 0.19806932f, 0.201556254f, 0.205078736f, 0.20863687f, 0.212230757f,
    0.2158605f, 0.2195262f, 0.223227957f, 0.226965874f, 0.230740049f, 0.234550582f, 0.238397574f, 0.242281122f,
    0.246201327f, 0.250158285f, 0.254152094f, 0.258182853f, 0.262250658f, 0.266355605f, 0.270497791f, 0.274677312f,
    0.278894263f, 0.28314874f, 0.287440838f, 0.29177065f, 0.296138271f, 0.300543794f, 0.304987314f, 0.309468923f,
    0.313988713f, 0.318546778f, 0.323143209f, 0.327778098f, 0.332451536f, 0.337163615f, 0.341914425f, 0.346704056f,
    0.3515326f, 0.356400144f, 0.36130678f, 0.366252596f, 0.37123768f, 0.376262123f, 0.381326011f, 0.386429434f,
    0.391572478f, 0.396755231f, 0.40197778f, 0.407240212f, 0.412542613f, 0.417885071f, 0.42326767f, 0.428690497f,
    0.434153636f, 0.439657174f, 0.445201195f, 0.450785783f, 0.456411023f, 0.462077f, 0.467783796f, 0.473531496f,
    0.479320183f, 0.48514994f, 0.49102085f, 0.496932995f, 0.502886458f, 0.508881321f, 0.514917665f, 0.520995573f,
    0.527115126f, 0.533276404f, 0.539479489f, 0.545724461f, 0.552011402f, 0.55834039f, 0.564711506f, 0.571124829f,
    0.57758044f, 0.584078418f, 0.590618841f, 0.597201788f, 0.603827339f, 0.610495571f, 0.617206562f, 0.623960392f,
    0.630757136f, 0.637596874f, 0.644479682f, 0.651405637f, 0.658374817f, 0.665387298f, 0.672443157f, 0.67954247f,
    0.686685312f, 0.693871761f, 0.701101892f, 0.70837578f, 0.715693501f, 0.723055129f, 0.73046074f, 0.737910409f,
    0.74540421f, 0.752942217f, 0.760524505f, 0.768151147f, 0.775822218f, 0.783537792f, 0.79129794f, 0.799102738f,
    0.806952258f, 0.814846572f, 0.822785754f, 0.830769877f, 0.838799012f, 0.846873232f, 0.854992608f, 0.863157213f,
    0.871367119f, 0.879622397f, 0.887923118f, 0.896269353f, 0.904661174f, 0.913098652f, 0.921581856f, 0.930110858f,
    0.938685728f, 0.947306537f, 0.955973353f, 0.964686248f, 0.97344529f, 0.98225055f, 0.991102097f, 1.0f,
};

// Channel bytes (0-255) decoded: from sRGB where srgb is true, else linearly.
static inline xfloat xi_decode_channel(xuint byte, xmask srgb) {
  xfloat linear = xi_to_float(byte) * (1.0f / 255.0f);
  if (!XI_ANY(srgb)) return linear;
  return srgb ? xi_gather_table(xi_srgb_table, byte) : linear;
}

// Texel index along an axis of n texels for the integer coordinate i (a float, |i| ≤ 1e6 + 1), by
// the wrap mode. In float arithmetic: the integer remainders it needs are no vector instruction, and
// eight lanes of them cost eight divisions each. floor(i / n) may round up by one near a multiple
// of n; one correction step makes the remainder exact.
static inline xuint xi_wrap_texel(xfloat i, xuint n, xuint mode) {
  xfloat nf = xi_to_float(n), period = 2.0f * nf;
  xfloat r = i - nf * floor(i / nf);
  r = r < 0.0f ? r + nf : r >= nf ? r - nf : r;
  xfloat m = i - period * floor(i / period);
  m = m < 0.0f ? m + period : m >= period ? m - period : m;
  xfloat mirror = m < nf ? m : period - 1.0f - m;
  xfloat clamped = clamp(i, (xfloat)0.0f, nf - 1.0f);
  return convert_xuint(mode == XI_WRAP_CLAMP ? clamped : mode == XI_WRAP_MIRROR ? mirror : r);
}

// One texel as RGBA in [0, 1], sRGB-decoded for colour images.
static inline xfloat3 xi_texel(__global const uint* texels, xuint at, xmask srgb, xfloat* alpha) {
  xuint t = xi_gather_uint(texels, at);
  *alpha = xi_to_float(t >> 24) * (1.0f / 255.0f);
  return make_xfloat3(xi_decode_channel(t & 255u, srgb), xi_decode_channel((t >> 8) & 255u, srgb),
                      xi_decode_channel((t >> 16) & 255u, srgb));
}

// The texture `ref` at texture coordinates uv0 (set 0) and uv1 (set 1), as the file gives them
// (v down the image). Lanes whose ref is XI_NO_TEXTURE get (1, 1, 1) and alpha 1, so a factor
// times the lookup is the factor alone.
static inline xfloat3 xi_texture(__global const TextureRef* refs, __global const ImageHeader* images,
                                 __global const uint* texels, xuint ref, xfloat2 uv0, xfloat2 uv1, xfloat* alpha) {
  xmask has = ref != XI_NO_TEXTURE;
  *alpha = 1.0f;
  if (!XI_ANY(has)) return xi_splat3(make_float3(1.0f, 1.0f, 1.0f));
  xuint r = has ? ref : (xuint)0u;
  xfloat ou, ov;
  xfloat3 tu = XI_GATHER_XYZ_FIELD(refs, r, transform_u, &ou), tv = XI_GATHER_XYZ_FIELD(refs, r, transform_v, &ov);
  xuint image = XI_GATHER_UINT_FIELD(refs, r, image), set = XI_GATHER_UINT_FIELD(refs, r, texcoord);
  xuint wrap_s = XI_GATHER_UINT_FIELD(refs, r, wrap_s), wrap_t = XI_GATHER_UINT_FIELD(refs, r, wrap_t);
  xfloat u0 = set == 1u ? uv1.x : uv0.x, v0 = set == 1u ? uv1.y : uv0.y;
  xfloat u = tu.x * u0 + tu.y * v0 + tu.z, v = tv.x * u0 + tv.y * v0 + tv.z;
  xuint offset = XI_GATHER_UINT_FIELD(images, image, offset), w = XI_GATHER_UINT_FIELD(images, image, width),
        h = XI_GATHER_UINT_FIELD(images, image, height);
  xmask srgb = XI_GATHER_UINT_FIELD(images, image, format) == XI_IMAGE_SRGB8;
  // Texel centres at half-integers: x in texel units, measured from the first centre.
  xfloat x = u * xi_to_float(w) - 0.5f, y = v * xi_to_float(h) - 0.5f;
  // Far outside [0, 1] a float has no fraction left and an int overflows: keep the coordinate
  // within a range where both hold (a wrap repeats every texel count anyway).
  x = clamp(x, (xfloat)-1e6f, (xfloat)1e6f);
  y = clamp(y, (xfloat)-1e6f, (xfloat)1e6f);
  xfloat fx0 = floor(x), fy0 = floor(y);
  xfloat fx = x - fx0, fy = y - fy0;
  xuint x0 = xi_wrap_texel(fx0, w, wrap_s), x1 = xi_wrap_texel(fx0 + 1.0f, w, wrap_s);
  xuint y0 = xi_wrap_texel(fy0, h, wrap_t), y1 = xi_wrap_texel(fy0 + 1.0f, h, wrap_t);
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

// Material mi's texture in slot k (XI_TEXTURE_*) at the hit's texture coordinates.
static inline xfloat3 xi_material_texture(__global const MaterialData* materials, __global const TextureRef* refs,
                                          __global const ImageHeader* images, __global const uint* texels, xuint mi, uint k,
                                          xfloat2 uv0, xfloat2 uv1, xfloat* alpha) {
  xuint ref = XI_GATHER_UINT_FIELD(materials, mi, textures[k]);
  return xi_texture(refs, images, texels, ref, uv0, uv1, alpha);
}

// Whether a ray passes through material mi at a hit (glTF's alphaMode), given the alpha of its
// base colour texture there: MASK cuts out where the alpha (factor times texture) is below the
// cutoff; BLEND lets the ray through with probability 1 - alpha (stochastic transparency:
// unbiased), deciding by the uniform u.
static inline xuint xi_alpha_mode(__global const MaterialData* materials, xuint mi) {
  return XI_GATHER_UINT_FIELD(materials, mi, alpha_mode);
}
static inline xmask xi_passes_through(__global const MaterialData* materials, xuint mi, xfloat texture_alpha, xfloat u) {
  xuint mode = xi_alpha_mode(materials, mi);
  xmask cut = mode != XI_ALPHA_OPAQUE;
  if (!XI_ANY(cut)) return XI_FALSE;
  xfloat cutoff = xi_as_float(XI_GATHER_UINT_FIELD(materials, mi, alpha_cutoff));
  xfloat alpha = xi_as_float(XI_GATHER_UINT_FIELD(materials, mi, alpha)) * texture_alpha;
  return cut && (mode == XI_ALPHA_MASK ? alpha < cutoff : u >= alpha);
}

#endif
