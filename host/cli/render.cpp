// `xi render` and `xi devices`.
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <map>
#include <optional>

#include "cli.h"
#include "xi/asset.h"
#include "xi/checkpoint.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/metrics.h"
#include "xi/profile.h"
#include "xi/render.h"

namespace xi::cli {
namespace {

std::filesystem::path default_scene() {
  std::error_code ec;
  auto exe = std::filesystem::read_symlink("/proc/self/exe", ec).parent_path();
  for (auto dir : {exe.parent_path() / "scenes", exe.parent_path() / "share/xi/scenes",
                   std::filesystem::path(XI_SOURCE_SCENE_DIR)})
    if (std::filesystem::exists(dir / "cornell-box.json")) return dir / "cornell-box.json";
  throw Error("cannot find the bundled Cornell box", "pass a scene file");
}

void parse_resolution(const std::string& text, Scene* scene) {
  // Digits, 'x', digits: nothing else (no sign, spaces or overflow).
  const Error bad("expected WxH with 1 <= W, H <= 16384, got '" + text + "'", "--resolution");
  size_t x = text.find_first_of("xX");
  auto number = [&](const std::string& digits) {
    if (digits.empty() || digits.size() > 5 || digits.find_first_not_of("0123456789") != std::string::npos) throw bad;
    int v = std::stoi(digits);
    if (v < 1 || v > 16384) throw bad;
    return v;
  };
  if (x == std::string::npos) throw bad;
  scene->width = number(text.substr(0, x));
  scene->height = number(text.substr(x + 1));
}

std::string format_seconds(double s) {
  char buf[32];
  if (s < 60) std::snprintf(buf, sizeof buf, "%.1fs", s);
  else std::snprintf(buf, sizeof buf, "%dm%02ds", (int)s / 60, (int)s % 60);
  return buf;
}

// One line, redrawn in place: [#####.....] 12/64 spp  1.23 Msamples/s  elapsed 3.0s  ETA 10.1s
void draw_progress(int done, int total, double msps, double elapsed) {
  const int width = 30;
  int filled = (int)std::lround(width * (double)done / total);
  std::string bar(filled, '#');
  bar += std::string(width - filled, '.');
  double eta = done > 0 ? elapsed * (total - done) / done : 0.0;
  std::fprintf(stderr, "\r[%s] %d/%d spp  %.2f Msamples/s  elapsed %s  ETA %s   ", bar.c_str(), done, total,
               msps, format_seconds(elapsed).c_str(), format_seconds(eta).c_str());
  std::fflush(stderr);
}

// Stopping on a signal. The first SIGINT or SIGTERM asks the render loop to stop after the pass in
// flight; a second ends the process at once, removing the temporary files that a write in progress
// would leave (files appear only by renaming complete ones, so nothing half-written remains).
volatile std::sig_atomic_t g_signal = 0;
volatile std::sig_atomic_t g_signals = 0;
std::vector<std::string> g_temp_files;  // set before the handlers are installed, read-only after

void on_signal(int sig) {
  g_signal = sig;
  g_signals = g_signals + 1;
  if (g_signals < 2) return;
  for (const std::string& f : g_temp_files) unlink(f.c_str());  // async-signal-safe
  _exit(128 + sig);
}

void install_stop_handlers(const std::vector<std::filesystem::path>& outputs) {
  for (auto& out : outputs) g_temp_files.push_back(out.string() + ".tmp" + std::to_string(::getpid()));
  struct sigaction sa = {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;  // the first signal lets the pass in flight finish its calls
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

}  // namespace

int render(const std::vector<std::string>& argv) {
  Args args(argv,
            {"-o", "--spp", "--seed", "--device", "--max-depth", "--resolution", "--sampler", "--strategy",
             "--local-size", "--reference", "--convergence", "--trace", "--paths-in-flight", "--samples-per-pass",
             "--time", "--snapshot-every", "--checkpoint", "--checkpoint-every", "--resume", "--camera"},
            {"--profile", "--quiet", "--all-features"});
  if (args.positional().size() > 1) throw Error("expected at most one scene file", args.positional()[1]);
  std::filesystem::path scene_path = args.positional().empty() ? default_scene() : std::filesystem::path(args.positional()[0]);

  // Check everything the user typed before the slow work starts.
  // An asset file (.gltf, .glb, .obj, .ply...) is a whole scene: its cameras, lights and materials.
  const bool asset = is_asset_file(scene_path);
  if (args.has("--camera") && !asset)
    throw Error("--camera chooses among an asset file's cameras (.gltf, .glb...); a JSON scene has one camera",
                "--camera " + args.get("--camera"));
  AssetOptions asset_options;
  asset_options.camera = args.get("--camera");
  Scene scene = asset ? load_asset(scene_path, asset_options) : load_scene(scene_path);
  if (args.has("--resolution")) parse_resolution(args.get("--resolution"), &scene);
  RenderOptions opt;
  opt.spp = args.get_int("--spp", scene.render.spp, 1, 1 << 20);
  opt.max_depth = args.get_int("--max-depth", scene.render.max_depth, 1, 64);
  opt.seed = (uint32_t)args.get_int("--seed", (int)scene.render.seed, 0, INT32_MAX);
  opt.sampler = parse_sampler(args.get("--sampler", scene.render.sampler));
  opt.strategy = parse_strategy(args.get("--strategy", "mis"));
  opt.local_size = (size_t)args.get_int("--local-size", (int)opt.local_size, 0, 1024);
  opt.all_features = args.has("--all-features");
  opt.paths_in_flight = (size_t)args.get_int("--paths-in-flight", 0, 0, 1 << 30);
  // A convergence log has one row per pass: one spp per pass unless asked otherwise.
  opt.samples_per_pass = args.get_int("--samples-per-pass", args.has("--convergence") ? 1 : 0, 0, 1 << 20);
  opt.profile = args.has("--profile") || args.has("--trace");
  std::filesystem::path out = args.get("-o", scene_path.stem().string() + ".exr");
  if (out.extension() != ".exr") throw Error("the output must be an .exr file", "-o " + out.string());
  auto out_dir = out.has_parent_path() ? out.parent_path() : std::filesystem::path(".");
  if (!std::filesystem::is_directory(out_dir)) throw Error("output folder does not exist", out_dir.string());
  // Error tracking against a reference, after every pass.
  std::optional<Image> reference;
  if (args.has("--reference")) {
    reference = read_exr(args.get("--reference"));
    if (reference->width != scene.width || reference->height != scene.height)
      throw Error("reference is " + std::to_string(reference->width) + "x" + std::to_string(reference->height) +
                      " but the render is " + std::to_string(scene.width) + "x" + std::to_string(scene.height),
                  "--reference " + args.get("--reference"));
  }
  if (args.has("--convergence") && !reference) throw Error("--convergence needs --reference", "--convergence");
  // Long renders: a time budget, snapshots, checkpoints. Grid and stratified patterns are complete
  // only at their spp, so a render cut short by --time or a snapshot would not be a valid image.
  const double time_budget = args.get_seconds("--time", INFINITY);
  const int snapshot_every = args.get_int("--snapshot-every", 0, 1, 1 << 20);
  for (const char* flag : {"--time", "--snapshot-every"})
    if (args.has(flag) && !sampler_is_progressive(opt.sampler))
      throw Error(std::string("the ") + sampler_name(opt.sampler) + " sampler's pattern is only complete at " +
                      std::to_string(opt.spp) + " spp, so it cannot stop early or show a partial image",
                  std::string(flag) + "; use --sampler sobol or random");
  const std::filesystem::path resume = args.get("--resume");
  const std::filesystem::path checkpoint = args.get("--checkpoint", resume.string());
  const double checkpoint_every = args.get_seconds("--checkpoint-every", 60.0);
  if (args.has("--checkpoint-every") && checkpoint.empty())
    throw Error("--checkpoint-every needs --checkpoint FILE", "--checkpoint-every");
  if (!resume.empty() && !std::filesystem::is_regular_file(resume))
    throw Error("no such checkpoint", "--resume " + resume.string());
  if (!checkpoint.empty()) {
    auto dir = checkpoint.has_parent_path() ? checkpoint.parent_path() : std::filesystem::path(".");
    if (!std::filesystem::is_directory(dir))
      throw Error("checkpoint folder does not exist", "--checkpoint " + dir.string());
  }
  const bool quiet = args.has("--quiet");
  const bool progress = !quiet && isatty(STDERR_FILENO);

  auto png = out;
  png.replace_extension(".png");
  std::vector<std::filesystem::path> outputs = {out, png};
  for (const char* f : {"--convergence", "--trace"})
    if (args.has(f)) outputs.push_back(args.get(f));
  if (!checkpoint.empty()) outputs.push_back(checkpoint);
  install_stop_handlers(outputs);

  // What the scene could not model, once per kind, after every check that could still fail.
  for (const std::string& w : scene.warnings) std::fprintf(stderr, "xi: warning: %s\n", w.c_str());
  Device device = Device::open(args.get("--device"));
  Renderer renderer(device, scene, opt);
  const CompiledScene& cs = renderer.compiled();
  const CheckpointKey key =
      checkpoint.empty() ? CheckpointKey{} : checkpoint_key(renderer, scene_path, device.info().name);
  double seconds = 0.0;  // render time, this run's and any resumed run's
  if (!resume.empty()) {
    RenderState state = read_checkpoint(resume, key);
    renderer.restore(state);
    seconds = state.seconds;
  }
  const double resumed_seconds = seconds;
  if (!quiet) {
    std::printf("device: %s (%s, %d compute units)\n", device.info().name.c_str(), device.info().platform.c_str(),
                device.info().compute_units);
    std::printf("scene: %s, %zu triangles, %zu lights, features: %s\n", scene_path.string().c_str(),
                scene.triangles.size(), cs.features.emitters ? cs.light_tri.size() : 0,
                (opt.all_features ? Features::everything() : cs.features).describe().c_str());
    for (const std::string& note : scene.notes) std::printf("%s\n", note.c_str());
    if (asset)
      std::printf("film: %dx%d (%s)\n", scene.width, scene.height,
                  args.has("--resolution") ? "--resolution" : "height 512, width from the camera's aspect ratio");
    std::printf("bvh: %zu 4-wide nodes, %zu leaves, depth %d, stack %zu, built in %.2f ms\n", cs.bvh.stats.nodes,
                cs.bvh.stats.leaves, cs.bvh.stats.depth, cs.bvh.stats.stack, cs.bvh.stats.build_seconds * 1e3);
    std::printf("kernels: %s in %.3f s\n", renderer.program().from_cache ? "loaded from cache" : "compiled",
                renderer.program().build_seconds);
    std::printf("paths in flight: %zu, %d spp per pass\n", renderer.paths_in_flight(), renderer.samples_per_pass());
    if (!resume.empty())
      std::printf("resumed from %s at %d spp\n", resume.string().c_str(), renderer.spp_done());
    std::fflush(stdout);
  }

  // The convergence log: one row per pass; the time spent measuring the error is not counted.
  std::string csv;
  if (reference) {
    csv = "pass,spp,seconds";
    for (Metric m : all_metrics()) csv += std::string(",") + metric_name(m);
    csv += "\n";
  }
  std::map<std::string, double> last_error;

  const double pixels = (double)scene.width * scene.height;
  // The image so far, written atomically: spp is what it holds (sppTarget: what was asked for).
  auto write_image = [&](int spp) {
    Renderer::Film film = renderer.film();
    ExrAttributes attrs{{"spp", spp},
                        {"renderSeconds", seconds},
                        {"seed", (int)opt.seed},
                        {"scene", std::filesystem::absolute(scene_path).string()},
                        {"device", device.info().name},
                        {"sampler", std::string(sampler_name(opt.sampler))},
                        {"strategy", std::string(strategy_name(opt.strategy))},
                        {"maxDepth", opt.max_depth}};
    if (spp < opt.spp) attrs["sppTarget"] = opt.spp;
    for (auto& [name, value] : last_error) attrs["error." + name] = value;
    write_exr(out, {{"", &film.mean}, {"variance", &film.variance}, {"albedo", &film.albedo}, {"normal", &film.normal}},
              attrs);
    write_png(png, film.mean);
  };
  auto save_checkpoint = [&] {
    RenderState state = renderer.state();
    state.seconds = seconds;
    write_checkpoint(checkpoint, key, state);
  };
  auto last_checkpoint = std::chrono::steady_clock::now();
  while (!renderer.done() && !g_signal && seconds - resumed_seconds < time_budget) {
    auto t0 = std::chrono::steady_clock::now();
    renderer.run_pass();
    seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (reference && (args.has("--convergence") || renderer.done())) {
      Image now = renderer.mean();
      char row[64];
      std::snprintf(row, sizeof row, "%d,%d,%.6f", renderer.passes_done() - 1, renderer.spp_done(), seconds);
      csv += row;
      for (Metric m : all_metrics()) {
        double e = image_metric(now, *reference, m);
        last_error[metric_name(m)] = e;
        std::snprintf(row, sizeof row, ",%.9g", e);
        csv += row;
      }
      csv += "\n";
    }
    if (progress)
      draw_progress(renderer.spp_done(), opt.spp, pixels * renderer.spp_done() / seconds * 1e-6, seconds);
    if (renderer.done()) break;
    if (snapshot_every && renderer.passes_done() % snapshot_every == 0) write_image(renderer.spp_done());
    if (!checkpoint.empty() &&
        std::chrono::duration<double>(std::chrono::steady_clock::now() - last_checkpoint).count() >= checkpoint_every) {
      save_checkpoint();
      last_checkpoint = std::chrono::steady_clock::now();
    }
  }
  if (progress) std::fputs("\n", stderr);
  const bool stopped = !renderer.done();
  const int exit_code = stopped && g_signal ? 128 + g_signal : 0;
  if (stopped && !checkpoint.empty()) save_checkpoint();
  if (stopped) {
    const std::string why = g_signal ? (g_signal == SIGINT ? "SIGINT" : "SIGTERM") : "the time budget";
    const std::string at = std::to_string(renderer.spp_done()) + " of " + std::to_string(opt.spp) + " spp";
    const std::string saved = checkpoint.empty() ? "" : "; state saved to " + checkpoint.string();
    if (renderer.spp_done() == 0 || !sampler_is_progressive(opt.sampler)) {
      const std::string reason = renderer.spp_done() == 0 ? "no sample was done"
                                                          : std::string("the ") + sampler_name(opt.sampler) +
                                                                " pattern is incomplete";
      std::fprintf(stderr, "xi: stopped by %s at %s: %s, no image written%s\n", why.c_str(), at.c_str(),
                   reason.c_str(), saved.c_str());
      return exit_code;
    }
    std::fprintf(stderr, "xi: stopped by %s after pass %d: %s%s\n", why.c_str(), renderer.passes_done(), at.c_str(),
                 saved.c_str());
  }
  write_image(renderer.spp_done());
  if (!stopped && !checkpoint.empty()) {  // the image holds the result now
    std::error_code ec;
    std::filesystem::remove(checkpoint, ec);
  }
  if (args.has("--convergence")) {
    write_atomically(args.get("--convergence"), [&](const std::filesystem::path& tmp) {
      std::FILE* f = std::fopen(tmp.c_str(), "w");
      if (!f || std::fputs(csv.c_str(), f) < 0 || std::fclose(f) != 0) throw Error("cannot write file", tmp.string());
    });
  }
  if (args.has("--trace")) write_chrome_trace(args.get("--trace"), renderer.launches());

  if (uint32_t bad = renderer.nonfinite_samples())
    std::fprintf(stderr, "xi: warning: %u non-finite samples were dropped\n", bad);
  if (!quiet) {
    const double rays = (double)(renderer.extend_rays() + renderer.shadow_rays());
    const int spp = renderer.spp_done();
    std::printf("%dx%d, %d spp, %.2f s, %.2f Msamples/s, %.2f Mrays/s\n", scene.width, scene.height, spp, seconds,
                pixels * spp / seconds * 1e-6, rays / seconds * 1e-6);
    std::printf("wrote %s and %s\n", out.string().c_str(), png.string().c_str());
    if (reference) std::printf("error vs reference: rmse %.6g, relmse %.6g\n", last_error["rmse"], last_error["relmse"]);
    if (args.has("--profile")) print_profile(stdout, renderer.launches(), seconds);
  }
  return exit_code;
}

int devices(const std::vector<std::string>& argv) {
  Args args(argv, {}, {});
  auto list = list_devices();
  if (list.empty()) throw Error("no OpenCL device found", "is an OpenCL driver installed? PoCL: apt-get install pocl-opencl-icd");
  std::printf("%-3s %-44s %-12s %-6s %5s  %s\n", "#", "device", "type", "units", "", "OpenCL C / platform");
  for (auto& d : list)
    std::printf("%-3d %-44s %-12s %-6d %5s  %s / %s\n", d.index, d.name.c_str(), d.type.c_str(), d.compute_units, "",
                d.opencl_c_version.c_str(), d.platform.c_str());
  return 0;
}

}  // namespace xi::cli
