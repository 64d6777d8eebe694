#include <cmath>

#include "xi/view.h"

namespace xi {
namespace {

// Clips to [0, 1]; NaN becomes 0 (fmax returns the number of a NaN and a number).
float clip01(float v) { return std::fmin(std::fmax(v, 0.0f), 1.0f); }

float srgb_encode(float v) {
  v = clip01(v);
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

glm::vec3 non_negative(glm::vec3 c) {
  return {std::fmax(c.r, 0.0f), std::fmax(c.g, 0.0f), std::fmax(c.b, 0.0f)};
}

// Khronos PBR Neutral (the Khronos 3D Commerce "PBR Neutral" tone mapper, its reference GLSL): a
// base colour is shown unchanged up to 0.8 apart from a small offset that keeps blacks black, and
// brighter values are compressed toward 1, desaturating toward the peak as they near it.
glm::vec3 pbr_neutral(glm::vec3 c) {
  const float start_compression = 0.8f - 0.04f;
  const float desaturation = 0.15f;
  const float x = std::fmin(c.r, std::fmin(c.g, c.b));
  const float offset = x < 0.08f ? x - 6.25f * x * x : 0.04f;
  c -= offset;
  const float peak = std::fmax(c.r, std::fmax(c.g, c.b));
  if (peak < start_compression) return c;
  const float d = 1.0f - start_compression;
  const float new_peak = 1.0f - d * d / (peak + d - start_compression);
  c *= new_peak / peak;
  const float g = 1.0f - 1.0f / (desaturation * (peak - new_peak) + 1.0f);
  return glm::mix(c, glm::vec3(new_peak), g);
}

// AgX base (no look) for sRGB primaries: Troy Sobotka's AgX in the widely used "minimal AgX" form
// (Benjamin Wrensch's, as in three.js and Godot): the inset matrix, log2 encoding between -12.47393
// and +4.026069 EV around mid grey 0.18, the polynomial fit of AgX's default-contrast sigmoid, the
// inset's inverse (outset), then the 2.2 power back to display-linear. Blender's AgX applies its
// own LUT, which this reproduces to within a few code values, not exactly.
glm::vec3 agx(glm::vec3 c) {
  // Column-major, as GLSL's mat3 constructor lists them.
  const glm::mat3 inset(0.842479062253094f, 0.0423282422610123f, 0.0423756549057051f,
                        0.0784335999999992f, 0.878468636469772f, 0.0784336f,
                        0.0792237451477643f, 0.0791661274605434f, 0.879142973793104f);
  const glm::mat3 outset(1.19687900512017f, -0.0528968517574562f, -0.0529716355144438f,
                         -0.0980208811401368f, 1.15190312990417f, -0.0980434501171241f,
                         -0.0990297440797205f, -0.0989611768448433f, 1.15107367264116f);
  const float min_ev = -12.47393f, max_ev = 4.026069f;
  c = inset * c;
  for (int i = 0; i < 3; ++i) {
    const float ev = c[i] > 0.0f ? std::log2(c[i]) : min_ev;  // black: the bottom of the range
    c[i] = (std::fmin(std::fmax(ev, min_ev), max_ev) - min_ev) / (max_ev - min_ev);
  }
  const glm::vec3 x2 = c * c, x4 = x2 * x2;
  c = 15.5f * x4 * x2 - 40.14f * x4 * c + 31.96f * x4 - 6.868f * x2 * c + 0.4298f * x2 + 0.1191f * c - 0.00232f;
  c = outset * c;
  return glm::pow(non_negative(c), glm::vec3(2.2f));
}

}  // namespace

std::optional<View> view_from_name(const std::string& name) {
  for (View v : {View::Standard, View::Neutral, View::Agx})
    if (name == view_name(v)) return v;
  return std::nullopt;
}

const char* view_name(View view) {
  switch (view) {
    case View::Standard: return "standard";
    case View::Neutral: return "neutral";
    case View::Agx: return "agx";
  }
  return "?";
}

glm::vec3 apply_view(View view, glm::vec3 linear) {
  glm::vec3 shown = linear;  // View::Standard: clipped below
  if (view == View::Neutral) shown = pbr_neutral(non_negative(linear));
  if (view == View::Agx) shown = agx(non_negative(linear));
  return {clip01(shown.r), clip01(shown.g), clip01(shown.b)};
}

glm::u8vec3 display_pixel(View view, glm::vec3 linear, float exposure) {
  const glm::vec3 shown = apply_view(view, exposure * linear);
  glm::u8vec3 out;
  for (int c = 0; c < 3; ++c) out[c] = (unsigned char)std::lround(255.0f * srgb_encode(shown[c]));
  return out;
}

}  // namespace xi
