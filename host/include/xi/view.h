// View transforms: how linear radiance (scene-referred, linear sRGB/Rec.709 primaries) becomes an
// image for a display. Only 8-bit PNGs go through them; EXR files stay linear.
#pragma once
#include <optional>
#include <string>

#include <glm/glm.hpp>
#include <glm/ext/vector_uint3_sized.hpp>

namespace xi {

enum class View {
  Standard,  // clip to [0, 1]: values above 1 become white
  Neutral,   // Khronos PBR Neutral, what glTF viewers (model-viewer, the Khronos sample viewer) show
  Agx,       // AgX, the filmic view Blender 4 shows by default (approximated, see view.cpp)
};

// "standard", "neutral" or "agx"; nullopt for anything else.
std::optional<View> view_from_name(const std::string& name);
const char* view_name(View view);
inline constexpr const char* kViewNames = "standard, neutral or agx";

// Display-linear values in [0, 1] (sRGB primaries, before the sRGB encoding) of linear radiance.
// Negative and NaN channels count as 0.
glm::vec3 apply_view(View view, glm::vec3 linear);

// The 8-bit sRGB-encoded (IEC 61966-2-1) pixel of linear radiance scaled by `exposure`, then shown
// through `view`: what a PNG holds.
glm::u8vec3 display_pixel(View view, glm::vec3 linear, float exposure = 1.0f);

}  // namespace xi
