// `xi diff`: an error metric between an image and a reference, optionally as a false-colour map.
#include <cstdio>

#include "cli.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/metrics.h"

namespace xi::cli {

const Command kDiff = {
    .name = "diff",
    .operands = "IMAGE.exr REFERENCE.exr",
    .about = "error of an image against a reference",
    .flags = {
        {"--metric", "NAME", "mse | rmse | relmse | mae | mrse (default: all)"},
        {"--crop", "x0,y0,x1,y1", "only pixels x0 <= x < x1, y0 <= y < y1"},
        {"--heatmap", "OUT.png", "write the per-pixel error in false colour"},
        {"--layer", "NAME", "compare an EXR layer (e.g. variance) instead of RGB"},
    },
    .run = diff,
};

int diff(const std::vector<std::string>& argv) {
  Args args(argv, kDiff);
  if (args.positional().size() != 2) throw Error("expected IMAGE.exr REFERENCE.exr", "xi diff");
  Image image = read_exr(args.positional()[0], args.get("--layer"));
  Image reference = read_exr(args.positional()[1], args.get("--layer"));
  std::vector<Metric> metrics;
  if (args.has("--metric")) metrics.push_back(parse_metric(args.get("--metric")));
  else metrics = all_metrics();
  std::optional<Crop> crop;
  if (args.has("--crop")) crop = parse_crop(args.get("--crop"), image.width, image.height);
  for (Metric m : metrics) {
    double v = image_metric(image, reference, m, crop);
    if (metrics.size() == 1) std::printf("%.9g\n", v);
    else std::printf("%-7s %.9g\n", metric_name(m), v);
  }
  if (args.has("--heatmap"))
    write_png(args.get("--heatmap"), error_heatmap(image, reference, metrics.front()));
  return 0;
}

}  // namespace xi::cli
