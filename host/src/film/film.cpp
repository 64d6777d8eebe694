#include "xi/film.h"

#include <string>

#include "xi/error.h"

namespace xi {

void check_film_pixels(const RenderState& st, size_t pixels, const char* what) {
  for (auto buffer : kFilmBuffers)
    if ((st.*buffer).size() != pixels)
      throw Error(std::string(what) + " holds " + std::to_string((st.*buffer).size()) + " pixels, not " +
                  std::to_string(pixels));
}

Film resolve_film(const RenderState& st, int w, int h) {
  const size_t pixels = (size_t)w * h;
  check_film_pixels(st, pixels, "the render state");
  Film f{Image(w, h), Image(w, h), Image(w, h), Image(w, h), Image(w, h)};
  for (size_t i = 0; i < pixels; ++i) {
    f.spp.pixels[i] = glm::vec3(st.albedo[i].w);
    float n = st.sum[i].w;  // w: the finite samples
    if (n <= 0.0f) continue;
    glm::vec3 m = glm::vec3(st.sum[i]) / n;
    f.mean.pixels[i] = m;
    f.albedo.pixels[i] = glm::vec3(st.albedo[i]) / n;
    glm::vec3 nn = glm::vec3(st.normal[i]);
    f.normal.pixels[i] = glm::length(nn) > 0.0f ? glm::normalize(nn) : nn;
    if (n >= 2.0f)
      f.variance.pixels[i] = glm::max((glm::vec3(st.sum_sq[i]) - n * m * m) / (n - 1.0f), glm::vec3(0.0f)) / n;
  }
  return f;
}

RenderState select_rows(const RenderState& frame, FilmRows rows, int width, int height) {
  check_film_pixels(frame, (size_t)width * height, "the frame's render state");
  RenderState share;
  share.spp_done = frame.spp_done;
  share.passes = frame.passes;
  share.seconds = frame.seconds;
  share.extend_rays = frame.extend_rays;
  share.shadow_rays = frame.shadow_rays;
  share.nonfinite = frame.nonfinite;
  for (auto buffer : kFilmBuffers) share.*buffer = rows.select(frame.*buffer, width, height);
  return share;
}

void insert_rows(RenderState* frame, const RenderState& share, FilmRows rows, int width, int height) {
  check_film_pixels(*frame, (size_t)width * height, "the frame's render state");
  check_film_pixels(share, (size_t)width * rows.count(height), "the share's render state");
  for (auto buffer : kFilmBuffers) rows.insert(share.*buffer, &((*frame).*buffer), width, height);
}

}  // namespace xi
