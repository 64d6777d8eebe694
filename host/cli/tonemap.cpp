// `xi tonemap`: an EXR as the PNG `xi render` writes beside it (a preview of a reference whose PNG
// was not kept, or of one layer), through the view --view names.
#include <algorithm>
#include <optional>

#include "cli.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/metrics.h"

namespace xi::cli {

PngView read_png_view(const Args& args, View fallback) {
  PngView v;
  v.exposure = (float)args.get_positive("--exposure", 1.0, "an exposure");
  v.view = fallback;
  if (args.has("--view")) {
    const std::string name = args.get("--view");
    const std::optional<View> view = view_from_name(name);
    if (!view) throw Error("unknown view '" + name + "': expected " + kViewNames, "--view " + name);
    v.view = *view;
  }
  return v;
}

const Command kTonemap = {
    .name = "tonemap",
    .operands = "IMAGE.exr OUT.png",
    .about = "the 8-bit sRGB PNG that `xi render` writes beside its EXR",
    .flags = {
        {"--view", "V",
         "standard (default), neutral or agx, as for render (whose\n"
         "default for an asset file is neutral)"},
        {"--exposure", "E", "scale the linear values by E > 0 first (default 1)"},
        {"--layer", "NAME",
         "an EXR layer (e.g. albedo) instead of RGB; spp: samples per\n"
         "pixel of an adaptive render, the most-sampled pixel white"},
    },
    .run = tonemap,
};

int tonemap(const std::vector<std::string>& argv) {
  Args args(argv, kTonemap);
  if (args.positional().size() != 2) throw Error("expected IMAGE.exr OUT.png", "xi tonemap");
  const std::filesystem::path out = args.positional()[1];
  if (out.extension() != ".png") throw Error("the output must be a .png file", out.string());
  const PngView png = read_png_view(args, View::Standard);
  const std::string in = args.positional()[0];
  Image image = read_exr(in, args.get("--layer"));
  check_finite(image, "image " + in);  // a PNG would show them as black, hiding them
  // Samples per pixel (adaptive sampling) are counts, not radiance: shown as grey, the most-sampled
  // pixel white.
  if (args.get("--layer") == "spp") {
    float most = 0.0f;
    for (const glm::vec3& n : image.pixels) most = std::max(most, n.x);
    if (most > 0.0f)
      for (glm::vec3& n : image.pixels) n /= most;
  }
  write_png(out, image, png.exposure, png.view);
  return 0;
}

}  // namespace xi::cli
