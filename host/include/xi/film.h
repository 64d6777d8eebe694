// The film: per-pixel sums a render accumulates, the rows of a frame it holds, and the images it
// resolves to.
#pragma once
#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include <glm/glm.hpp>

#include "layout.h"
#include "xi/image.h"

namespace xi {

// A share of a frame's rows: first, first + stride, first + 2 stride, ... below its height. One
// process of a distributed render takes rows {rank, ranks}; every pixel's samples are the same
// whichever share holds it, so the shares' films put together equal the whole frame's bitwise.
struct FilmRows {
  int first = 0, stride = 1;
  int count(int height) const { return first < height ? (height - first + stride - 1) / stride : 0; }
  int frame_row(int k) const { return first + k * stride; }

  // A share's pixels (its row k is frame row frame_row(k)) taken out of a frame's, or put back:
  // the one place that knows how rows interleave, for render states and images alike.
  template <class T>
  std::vector<T> select(const std::vector<T>& frame, int width, int height) const {
    std::vector<T> share((size_t)width * count(height));
    for (int k = 0; k < count(height); ++k)
      std::copy_n(frame.begin() + (size_t)frame_row(k) * width, width, share.begin() + (size_t)k * width);
    return share;
  }
  template <class T>
  void insert(const std::vector<T>& share, std::vector<T>* frame, int width, int height) const {
    for (int k = 0; k < count(height); ++k)
      std::copy_n(share.begin() + (size_t)k * width, width, frame->begin() + (size_t)frame_row(k) * width);
  }
};

// Everything a render accumulates between passes: with the same scene and options, a renderer
// restored from it continues bitwise as if it had never stopped (film sums are added in sample order).
struct RenderState {
  int spp_done = 0;
  int passes = 0;
  double seconds = 0.0;  // render time so far: kept by the caller, carried through checkpoints
  uint64_t extend_rays = 0, shadow_rays = 0;
  uint32_t nonfinite = 0;
  // The film buffers (XI_FILM_BUFFERS), one vec4 per pixel each.
#define XI_FILM_FIELD(name) std::vector<glm::vec4> name;
  XI_FILM_BUFFERS(XI_FILM_FIELD)
#undef XI_FILM_FIELD
};

// The film buffers of a state, in XI_FILM_BUFFERS's order.
#define XI_FILM_MEMBER(name) &RenderState::name,
inline constexpr std::vector<glm::vec4> RenderState::*kFilmBuffers[] = {XI_FILM_BUFFERS(XI_FILM_MEMBER)};
#undef XI_FILM_MEMBER
// Pointers to a state's film buffers (const where the state is), in the same order.
template <class State>
auto film_buffers(State& st) {
  std::array<decltype(&st.sum), std::size(kFilmBuffers)> out;
  for (size_t i = 0; i < out.size(); ++i) out[i] = &(st.*kFilmBuffers[i]);
  return out;
}

// The rows `rows` of a whole frame's state (film buffers of width × height pixels), and back: the
// share's rows copied into their places. Counters and spp are the frame's; merging adds none.
RenderState select_rows(const RenderState& frame, FilmRows rows, int width, int height);
void insert_rows(RenderState* frame, const RenderState& share, FilmRows rows, int width, int height);

// Throws xi::Error unless every film buffer of the state holds `pixels` pixels; `what` names it.
void check_film_pixels(const RenderState& state, size_t pixels, const char* what);

// The film resolved to images: per pixel, the mean radiance, the variance of that mean (sample
// variance / sample count), the mean first-hit albedo and normal, and the samples taken (in all
// three channels; the albedo sum's w, which counts dropped non-finite samples too).
struct Film {
  Image mean, variance, albedo, normal, spp;
};
// The film buffers of a state (width × height pixels) resolved to images.
Film resolve_film(const RenderState& state, int width, int height);

}  // namespace xi
