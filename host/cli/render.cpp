// `xi render` and `xi devices`.
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <optional>
#include <thread>

#include "cli.h"
#include "xi/asset.h"
#include "xi/checkpoint.h"
#include "xi/denoise.h"
#include "xi/error.h"
#include "xi/image.h"
#include "xi/metrics.h"
#include "xi/profile.h"
#include "xi/renderer.h"
#include "team.h"

namespace xi::cli {

// `xi render`: its usage and its flags. The setup steps below give each flag its effect, reading it
// by name (Args refuses a name this table lacks); the effects are not in the table because many
// defaults come from the scene, and the order of the steps decides which error a user sees first.
const Command kRender = {
    .name = "render",
    .operands = "[SCENE]",
    .about = "render a .json scene (default: the bundled Cornell box), or any other\n"
             "file through Assimp with its cameras and lights: every format Assimp\n"
             "reads (.gltf .glb .obj .ply .fbx .dae .3ds .blend ...; an unknown\n"
             "extension's error lists them all)",
    .flags = {
        {"-o", "OUT.exr|OUT.png",
         "output: the EXR (linear, float) and the 8-bit sRGB PNG beside it\n"
         "(through --view), whichever of the two is named"},
        {"--view", "V",
         "how the PNG shows the linear image: standard (clipped to [0, 1]),\n"
         "neutral (Khronos PBR Neutral, as glTF viewers show) or agx (AgX,\n"
         "Blender's default view, approximated); default: neutral for an\n"
         "asset file, standard for a JSON scene; the EXR stays linear"},
        {"--exposure", "E", "scale the linear values by E > 0 before the view (PNG only)"},
        {"--camera", "NAME|INDEX",
         "an asset file's camera (default: its first perspective camera;\n"
         "without one, its bounding sphere framed from --orbit)"},
        {"--orbit", "YAW,PITCH",
         "an asset file without a camera: the direction it is framed from,\n"
         "in degrees (default 0,15: the front, 15 above); yaw turns about +y\n"
         "toward +x, pitch is above the horizontal, -90 < PITCH < 90"},
        {"--spp", "N", "samples per pixel"},
        {"--seed", "S", "random seed"},
        {"--max-depth", "K", "maximum bounces (1 = direct light only)"},
        {"--resolution", "WxH", "override the scene's film size"},
        {"--env", "FILE|none",
         "an equirectangular environment map around the scene, replacing\n"
         "the scene's (none: no map, the scene's background)"},
        {"--env-strength", "S", "scale the environment's radiance by S >= 0 (default: the scene's, 1)"},
        {"--env-rotate", "DEG", "turn the environment about +y (default: the scene's, 0)"},
        {"--background", "R,G,B|V",
         "a constant background radiance, in place of any environment (an\n"
         "asset file without lights is otherwise lit by the bundled sky)"},
        {"--sampler", "NAME",
         "random | grid | stratified | sobol (default: the scene's, else\n"
         "sobol); random and sobol are progressive: any prefix of a\n"
         "render is a render; grid and stratified patterns need every spp,\n"
         "so --time and --snapshot-every refuse them"},
        {"--strategy", "NAME", "mis | nee | bsdf (light transport)"},
        {"--layering", "NAME",
         "albedo-scaling | fresnel-mix: how a metallic-roughness material's\n"
         "specular layer dims its base (default: the scene's, else\n"
         "albedo-scaling, as Blender's Principled BSDF; fresnel-mix: by the\n"
         "Fresnel transmittance both ways, reciprocal but losing energy)"},
        {"--noise-threshold", "T",
         "adaptive sampling: a pixel stops once the relative standard error\n"
         "of its mean is below T (e.g. 0.02), --spp being the most it takes;\n"
         "random and sobol samplers only"},
        {"--min-spp", "N", "samples every pixel takes before it may stop (default 16)"},
        {"--device", "D",
         "OpenCL device: index or name substring (see `xi devices`); under\n"
         "mpirun a list D0,D1,... gives local rank i item i mod its length"},
        {"--threads", "N", "CPU threads PoCL renders on (default: one per core)"},
        {"--local-size", "N", "work-group size, at most 1024 (default 64; 0: the largest the kernel allows)"},
        {"--lanes", "N",
         "paths per generate and shade work item, 1, 8 or 16 (default: 16\n"
         "on a CPU with AVX2 or AVX-512, 8 on another CPU, 1 on a GPU)"},
        {"--bvh-width", "N",
         "children per BVH node, 4 or 8 (default: 8 on a CPU, 4 on a\n"
         "GPU)"},
        {"--kernels", "K",
         "auto | scene | generic: which program shades; auto: the scene's\n"
         "own if built before, else the generic one (see `xi prebuild`) while\n"
         "the scene's own builds, taking over when ready; the image is the same"},
        {"--ray-packets", "M",
         "auto | on | hybrid | off: bounce and shadow rays through an 8-wide\n"
         "BVH in packets, as camera rays go (on), the first bounce's in\n"
         "hybrid packets (hybrid), or alone (off); default auto: on for\n"
         "trees of at most 8 nodes, else hybrid"},
        {"--packet-width", "N",
         "rays per packet, 8 or 16 (default: 16 on a CPU with 512-bit\n"
         "vectors, else 8)"},
        {"--no-spatial-splits", nullptr,
         "a BVH whose triangles are never split between subtrees: a\n"
         "faster build, slower rays where long triangles overlap"},
        {"--paths-in-flight", "N",
         "most (pixel, sample) paths in one wave (default: sized for the\n"
         "device, 2^20 on a CPU, 2^25 on a GPU, within 1/4 of its memory)"},
        {"--samples-per-pass", "N",
         "most spp one pass adds (default: what the paths in flight hold;\n"
         "1 with --convergence)"},
        {"--all-features", nullptr, "compile every kernel feature, not just what the scene uses"},
        {"--profile", nullptr, "print per-bounce and per-stage timing tables"},
        {"--trace", "OUT.json", "write every kernel launch as a Chrome trace (Perfetto)"},
        {"--reference", "REF.exr", "measure the error against REF after the render"},
        {"--convergence", "OUT.csv", "with --reference: the error after every pass"},
        {"--quiet", nullptr, "no progress bar and no summary"},
        {"--time", "SECONDS", "stop after the pass that crosses this much render time"},
        {"--snapshot-every", "N", "write the image so far every N passes"},
        {"--denoise", nullptr,
         "denoise the image (and snapshots) with Intel Open Image Denoise,\n"
         "as `xi denoise` does: R,G,B denoised, the raw mean in layer noisy"},
        {"--denoise-quality", "Q", "high (default), balanced or fast: OIDN's filter quality"},
        {"--denoise-prefilter", "P",
         "accurate (default: albedo and normal denoised first), fast\n"
         "(denoised at fast quality) or none (used as rendered)"},
        {"--checkpoint", "FILE",
         "save the render's state to FILE every --checkpoint-every\n"
         "seconds (default 60) and when stopped early; removed once\n"
         "the render completes"},
        {"--checkpoint-every", "S", "seconds between the checkpoints --checkpoint saves (default 60)"},
        {"--resume", "FILE",
         "continue from a checkpoint (same scene, spp, seed, sampler,\n"
         "strategy, depth, kernels, device); keeps checkpointing to FILE"},
    },
    .notes = {
        {"Ctrl-C or SIGTERM",
         "finish the pass in flight, write the image with the spp done,\n"
         "exit 130 or 143; a second signal stops at once, writing nothing"},
        {"mpirun -np N xi render ...",
         "N processes, rank r rendering rows r, r+N, ...; rank 0 writes\n"
         "the image, bitwise the one-process image (built with MPI)"},
    },
    .run = render,
};

namespace {

std::filesystem::path default_scene() { return bundled_scene_file("cornell-box.json"); }

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

// A finite number in [lo, hi], the whole of `text`.
float parse_number(const std::string& text, double lo, double hi, const std::string& flag, const std::string& what) {
  size_t used = 0;
  double x = 0.0;
  try {
    x = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (text.empty() || used != text.size() || !std::isfinite(x) || x < lo || x > hi)
    throw Error("expected " + what + ", got '" + text + "'", flag + " " + text);
  return float(x);
}

// R,G,B or one value for all three, each a radiance >= 0.
glm::vec3 parse_background(const std::string& text) {
  std::vector<std::string> parts;
  for (size_t at = 0; at <= text.size();) {
    const size_t comma = std::min(text.find(',', at), text.size());
    parts.push_back(text.substr(at, comma - at));
    at = comma + 1;
  }
  if (parts.size() != 1 && parts.size() != 3)
    throw Error("expected R,G,B or one value, each >= 0, got '" + text + "'", "--background " + text);
  glm::vec3 c;
  for (int i = 0; i < 3; ++i)
    c[i] = parse_number(parts[parts.size() == 1 ? 0 : i], 0.0, 1e30, "--background",
                        "R,G,B or one value, each a number >= 0");
  return c;
}

// What lies around the scene, from --env FILE|none, --background, --env-strength and --env-rotate,
// read and checked before the scene is loaded.
struct EnvironmentFlags {
  std::optional<Environment> environment;  // --env FILE
  bool none = false;                       // --env none, or --background
  std::optional<glm::vec3> background;
  std::optional<float> strength, rotation;
};

EnvironmentFlags read_environment_flags(const Args& args) {
  EnvironmentFlags f;
  const std::string env = args.get("--env");
  if (args.has("--env") && env != "none") {
    if (args.has("--background"))
      throw Error("give either --env FILE or --background, not both", "--background " + args.get("--background"));
    std::error_code ec;
    if (!std::filesystem::is_regular_file(env, ec)) throw Error("environment map not found", "--env " + env);
    f.environment = Environment{env, 1.0f, 0.0f};
  }
  f.none = env == "none" || args.has("--background");
  if (args.has("--background")) f.background = parse_background(args.get("--background"));
  if (args.has("--env-strength"))
    f.strength = parse_number(args.get("--env-strength"), 0.0, 1e30, "--env-strength", "a number >= 0");
  if (args.has("--env-rotate"))
    f.rotation = parse_number(args.get("--env-rotate"), -1e6, 1e6, "--env-rotate", "an angle in degrees");
  return f;
}

void apply_environment_flags(Scene& scene, const EnvironmentFlags& f, const Args& args) {
  if (f.environment) scene.environment = f.environment;
  if (f.none) scene.environment.reset();
  if (f.background) scene.background = *f.background;
  for (const char* flag : {"--env-strength", "--env-rotate"})
    if (args.has(flag) && !scene.environment)
      throw Error(std::string(flag) + " needs an environment: the scene has none" +
                      (f.none ? " with --env none or --background" : "") + "; --env FILE gives one",
                  std::string(flag) + " " + args.get(flag));
  if (f.strength) scene.environment->strength = *f.strength;
  if (f.rotation) scene.environment->rotation_degrees = *f.rotation;
}

std::string format_seconds(double s) {
  char buf[32];
  if (s < 60) std::snprintf(buf, sizeof buf, "%.1fs", s);
  else std::snprintf(buf, sizeof buf, "%dm%02ds", (int)s / 60, (int)s % 60);
  return buf;
}

// One line, redrawn in place: [#####.....] 12/64 spp  1.23 Msamples/s  elapsed 3.0s  ETA 10.1s
// (with adaptive sampling, `sampling` is the share of pixels still sampling; else negative).
void draw_progress(int done, int total, double msps, double elapsed, double sampling) {
  const int width = 30;
  int filled = (int)std::lround(width * (double)done / total);
  std::string bar(filled, '#');
  bar += std::string(width - filled, '.');
  double eta = done > 0 ? elapsed * (total - done) / done : 0.0;
  char share[48] = "";
  if (sampling >= 0.0) std::snprintf(share, sizeof share, "  %.1f%% of pixels sampling", 100.0 * sampling);
  std::fprintf(stderr, "\r[%s] %d/%d spp%s  %.2f Msamples/s  elapsed %s  ETA %s   ", bar.c_str(), done, total,
               share, msps, format_seconds(elapsed).c_str(), format_seconds(eta).c_str());
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

// Everything `xi render` sets up before the first pass. Rank 0 of a team also holds what only it
// uses: the reference, the output paths it writes, the checkpoint it resumes from.
// When the process started (static initialisation, before main).
const std::chrono::steady_clock::time_point g_started = std::chrono::steady_clock::now();

struct Job {
  std::filesystem::path scene_path;
  bool asset = false;
  Scene scene;       // its triangles freed once compiled (open_renderer)
  size_t triangles = 0;
  RenderOptions opt;
  std::filesystem::path out, png, convergence, trace;
  PngView png_view;  // how the PNG shows the image (--view, --exposure)
  std::optional<Image> reference;
  bool measured = false;  // --reference given: every rank's share of the mean is gathered to measure it
  double time_budget = INFINITY;
  int snapshot_every = 0;
  std::filesystem::path resume, checkpoint;
  double checkpoint_every = 60.0;
  bool quiet = false, progress = false, profile = false, resolution_given = false;
  std::optional<Device> device;
  std::optional<Renderer> renderer;
  std::optional<Denoiser> denoiser;  // --denoise (rank 0, which writes the image)
  CheckpointKey key;
  RenderState resumed;  // rank 0: the whole frame's state read from --resume
  double first_pass_seconds = 0.0;  // since the process started: the wait for a first image
  int threads = 0;                   // --threads: PoCL's CPU threads (0: one per core)
};

// Each rank's device: --device (or $XI_DEVICE) as given; a comma-separated list gives local rank i
// its item i mod the list's length. Without either, ranks of a team spread over this host's GPUs,
// else share its CPU device.
std::string device_selector(const Args& args, const Team& team) {
  std::string selector = args.get("--device");
  // A single $XI_DEVICE is left to Device::open, whose errors then name it.
  const char* env = std::getenv("XI_DEVICE");
  const bool env_set = env && *env;
  if (selector.empty() && env_set && std::strchr(env, ',')) selector = env;
  if (selector.find(',') != std::string::npos) {
    std::vector<std::string> items;
    for (size_t at = 0; at <= selector.size();) {
      size_t comma = std::min(selector.find(',', at), selector.size());
      items.push_back(selector.substr(at, comma - at));
      at = comma + 1;
    }
    return items[team.local_rank() % items.size()];
  }
  if (selector.empty() && !env_set && team.size() > 1) {
    std::vector<DeviceInfo> gpus;
    for (const DeviceInfo& d : list_devices())
      if (d.type == "GPU") gpus.push_back(d);
    if (!gpus.empty()) return std::to_string(gpus[team.local_rank() % gpus.size()].index);
  }
  return selector;
}

// ---- Setup: each step checks what the user typed before the slow work starts. ----

// --orbit YAW,PITCH: two numbers, in degrees (load_asset checks the pitch's range).
Orbit parse_orbit(const std::string& text) {
  const size_t comma = text.find(',');
  try {
    if (comma != std::string::npos)
      return {parse_number(text.substr(0, comma), -1e6, 1e6, "--orbit", ""),
              parse_number(text.substr(comma + 1), -1e6, 1e6, "--orbit", "")};
  } catch (const Error&) {
  }
  throw Error("expected YAW,PITCH in degrees (-90 < PITCH < 90), got '" + text + "'", "--orbit " + text);
}

// The scene file, with --camera, --orbit and --resolution applied; every rank must get whole rows.
void load_job_scene(Job& job, const Args& args, const Team& team) {
  if (args.positional().size() > 1) throw Error("expected at most one scene file", args.positional()[1]);
  job.scene_path = args.positional().empty() ? default_scene() : std::filesystem::path(args.positional()[0]);
  // An asset file (.gltf, .glb, .obj, .ply...) is a whole scene: its cameras, lights and materials.
  job.asset = is_asset_file(job.scene_path);
  if (args.has("--camera") && !job.asset)
    throw Error("--camera chooses among an asset file's cameras (.gltf, .glb...); a JSON scene has one camera",
                "--camera " + args.get("--camera"));
  if (args.has("--orbit") && !job.asset)
    throw Error("--orbit turns the framing of an asset file without a camera (.gltf, .glb...); a JSON scene has "
                "its own camera",
                "--orbit " + args.get("--orbit"));
  const EnvironmentFlags environment = read_environment_flags(args);
  AssetOptions asset_options;
  asset_options.camera = args.get("--camera");
  if (args.has("--orbit")) asset_options.orbit = parse_orbit(args.get("--orbit"));
  asset_options.environment = environment.environment;
  asset_options.sky = !environment.none;
  Scene& scene = job.scene;
  scene = job.asset ? load_asset(job.scene_path, asset_options) : load_scene(job.scene_path);
  apply_environment_flags(scene, environment, args);
  job.resolution_given = args.has("--resolution");
  if (job.resolution_given) parse_resolution(args.get("--resolution"), &scene);
  if (team.size() > scene.height)
    throw Error(std::to_string(team.size()) + " processes but the frame has " + std::to_string(scene.height) +
                    " rows, and each process renders whole rows",
                "mpirun -np; use at most " + std::to_string(scene.height));
}

RenderOptions::RayPackets parse_ray_packets(const std::string& packets) {
  if (packets == "auto") return RenderOptions::RayPackets::Auto;
  if (packets == "on") return RenderOptions::RayPackets::On;
  if (packets == "hybrid") return RenderOptions::RayPackets::Hybrid;
  if (packets == "off") return RenderOptions::RayPackets::Off;
  throw Error("expected auto, on, hybrid or off", "--ray-packets " + packets);
}

RenderOptions::ShadingProgram parse_shading_program(const std::string& kernels) {
  if (kernels == "auto") return RenderOptions::ShadingProgram::Auto;
  if (kernels == "scene") return RenderOptions::ShadingProgram::Scene;
  if (kernels == "generic") return RenderOptions::ShadingProgram::Generic;
  throw Error("expected auto, scene or generic", "--kernels " + kernels);
}

// The sampling and kernel options; the scene's render settings are the defaults.
void read_render_options(Job& job, const Args& args, const Team& team) {
  if (args.has("--layering")) {
    try {
      job.scene.render.layering = parse_layering(args.get("--layering"));
    } catch (const Error& e) {
      throw Error(e.message(), "--layering");
    }
  }
  const Scene& scene = job.scene;
  RenderOptions& opt = job.opt;
  opt.spp = args.get_int("--spp", scene.render.spp, 1, 1 << 20);
  opt.max_depth = args.get_int("--max-depth", scene.render.max_depth, 1, 64);
  opt.seed = (uint32_t)args.get_int("--seed", (int)scene.render.seed, 0, INT32_MAX);
  opt.sampler = parse_sampler(args.get("--sampler", scene.render.sampler));
  opt.strategy = parse_strategy(args.get("--strategy", "mis"));
  opt.local_size = (size_t)args.get_int("--local-size", (int)opt.local_size, 0, (int)kMaxLocalSize);
  // 0 (the fallback, never a value a user may give): the device's default.
  opt.lanes = args.get_int("--lanes", 0, 1, 16);
  opt.bvh_width = args.get_int("--bvh-width", 0, 1, 8);
  opt.ray_packets = parse_ray_packets(args.get("--ray-packets", "auto"));
  opt.packet_width = args.get_int("--packet-width", 0, 8, 16);
  opt.shading_program = parse_shading_program(args.get("--kernels", "auto"));
  opt.all_features = args.has("--all-features");
  opt.spatial_splits = !args.has("--no-spatial-splits");
  opt.paths_in_flight = (size_t)args.get_int("--paths-in-flight", 0, 1, 1 << 30);
  // A convergence log has one row per pass: one spp per pass unless asked otherwise.
  opt.samples_per_pass = args.get_int("--samples-per-pass", args.has("--convergence") ? 1 : 0, 1, 1 << 20);
  opt.noise_threshold = (float)args.get_positive("--noise-threshold", 0.0, "a relative error > 0, such as 0.02");
  opt.min_spp = std::min(args.get_int("--min-spp", opt.min_spp, 1, 1 << 20), opt.spp);
  if (args.has("--min-spp") && !args.has("--noise-threshold"))
    throw Error("--min-spp is the least spp of adaptive sampling: it needs --noise-threshold", "--min-spp");
  job.profile = args.has("--profile");
  opt.profile = job.profile || args.has("--trace");
  opt.rows = team.rows();
}

// The files the render writes: the EXR and the PNG beside it (-o names either; the other takes
// its name with the other extension), the convergence log, the trace.
void read_output_names(Job& job, const Args& args) {
  job.out = args.get("-o", job.scene_path.stem().string() + ".exr");
  if (job.out.extension() != ".exr" && job.out.extension() != ".png")
    throw Error("the output must be an .exr or a .png file", "-o " + job.out.string());
  job.png = job.out;
  job.png.replace_extension(".png");
  job.out.replace_extension(".exr");
  job.convergence = args.get("--convergence");
  job.trace = args.get("--trace");
  // An asset file's PNG looks as glTF viewers show it; a JSON scene's is clipped, as it always was.
  job.png_view = read_png_view(args, job.asset ? View::Neutral : View::Standard);
  job.measured = args.has("--reference");
  if (args.has("--convergence") && !args.has("--reference")) throw Error("--convergence needs --reference", "--convergence");
}

// Long renders: a time budget, snapshots, checkpoints. Grid and stratified patterns are complete
// only at their spp, so a render cut short by --time or a snapshot would not be a valid image.
void read_long_render_options(Job& job, const Args& args) {
  job.time_budget = args.get_seconds("--time", INFINITY);
  job.snapshot_every = args.get_int("--snapshot-every", 0, 1, 1 << 20);
  for (const char* flag : {"--time", "--snapshot-every"})
    if (args.has(flag) && !sampler_is_progressive(job.opt.sampler))
      throw Error(std::string("the ") + sampler_name(job.opt.sampler) + " sampler's pattern is only complete at " +
                      std::to_string(job.opt.spp) + " spp, so it cannot stop early or show a partial image",
                  std::string(flag) + "; use --sampler sobol or random");
  job.resume = args.get("--resume");
  job.checkpoint = args.get("--checkpoint", job.resume.string());
  job.checkpoint_every = args.get_seconds("--checkpoint-every", 60.0);
  if (args.has("--checkpoint-every") && job.checkpoint.empty())
    throw Error("--checkpoint-every needs --checkpoint FILE", "--checkpoint-every");
}

// Rank 0 alone reads the reference and the checkpoint (and writes every file), so only its inputs
// are checked.
void read_leader_inputs(Job& job, const Args& args, const Team& team) {
  if (!team.leader()) return;
  for (const char* flag : {"--denoise-quality", "--denoise-prefilter"})
    if (args.has(flag) && !args.has("--denoise"))
      throw Error(std::string(flag) + " chooses how --denoise denoises: it needs --denoise", flag);
  read_denoise_options(args, nullptr);  // their values, checked now
  if (args.has("--denoise")) load_denoiser();  // a missing OIDN fails now, not after the slow setup
  if (args.has("--reference")) {
    job.reference = read_exr(args.get("--reference"));
    if (job.reference->width != job.scene.width || job.reference->height != job.scene.height)
      throw Error("reference is " + std::to_string(job.reference->width) + "x" +
                      std::to_string(job.reference->height) + " but the render is " + std::to_string(job.scene.width) +
                      "x" + std::to_string(job.scene.height),
                  "--reference " + args.get("--reference"));
  }
  if (!job.resume.empty() && !std::filesystem::is_regular_file(job.resume))
    throw Error("no such checkpoint", "--resume " + job.resume.string());
}

// Rank 0's output files, checked here, before the render, rather than found when writing after it
// (and after the files written before this one). Returns them (other ranks: none).
std::vector<std::filesystem::path> check_outputs(const Job& job, const Team& team) {
  std::vector<std::filesystem::path> outputs;
  if (!team.leader()) return outputs;
  const std::pair<const char*, std::filesystem::path> named[] = {
      {"-o", job.out}, {"-o", job.png}, {"--convergence", job.convergence}, {"--trace", job.trace},
      {"--checkpoint", job.checkpoint}};
  for (const auto& [flag, f] : named) {
    if (f.empty()) continue;
    const auto dir = f.has_parent_path() ? f.parent_path() : std::filesystem::path(".");
    if (!std::filesystem::is_directory(dir))
      throw Error("output folder does not exist", std::string(flag) + " " + f.string());
    if (std::filesystem::is_directory(f)) throw Error("output is a folder", std::string(flag) + " " + f.string());
    outputs.push_back(f);
  }
  return outputs;
}

// The slow part of setup: the device, the BVH and the kernels, and the checkpoint to resume from.
void open_renderer(Job& job, const Args& args, const Team& team) {
  job.device.emplace(Device::open(device_selector(args, team)));
  job.triangles = job.scene.triangles.size();
  // From here the compiled copy is the one rendered.
  CompiledScene compiled = Renderer::compile_freeing_triangles(*job.device, job.scene, job.opt);
  job.renderer.emplace(*job.device, std::move(compiled), job.opt);
  if (args.has("--denoise") && team.leader()) job.denoiser.emplace(read_denoise_options(args, &*job.device));
  if (!job.checkpoint.empty()) job.key = checkpoint_key(*job.renderer, job.scene_path, job.device->info().name);
  if (!job.resume.empty() && team.leader()) job.resumed = read_checkpoint(job.resume, job.key);
}

// --threads N caps the CPU threads PoCL runs work groups on, and the BVH build's. PoCL reads its
// environment when the OpenCL platform is first queried, so this comes before anything opens a
// device. (PoCL 3 reads POCL_MAX_PTHREAD_COUNT, PoCL 4 and later POCL_CPU_MAX_CU_COUNT; other
// drivers ignore both.)
void limit_cpu_threads(Job& job, const Args& args) {
  job.threads = args.get_int("--threads", 0, 1, 4096);
  if (job.threads == 0) return;
  job.opt.build_threads = (unsigned)job.threads;
  const std::string n = std::to_string(job.threads);
  setenv("POCL_MAX_PTHREAD_COUNT", n.c_str(), 1);
  setenv("POCL_CPU_MAX_CU_COUNT", n.c_str(), 1);
}

void prepare(Job& job, const std::vector<std::string>& argv, const Team& team) {
  const Args args(argv, kRender);
  limit_cpu_threads(job, args);
  load_job_scene(job, args, team);
  read_render_options(job, args, team);
  read_output_names(job, args);
  read_long_render_options(job, args);
  read_leader_inputs(job, args, team);
  job.quiet = args.has("--quiet") || !team.leader();
  job.progress = !job.quiet && isatty(STDERR_FILENO);
  install_stop_handlers(check_outputs(job, team));
  open_renderer(job, args, team);
}

// Says what was set up (rank 0; a team's ranks each name their device): the devices, the scene,
// then the BVH, the kernels and the passes.
void print_devices(const Job& job, const Team& team, const std::vector<std::string>& rank_devices) {
  const DeviceInfo& d = job.device->info();
  std::printf("device: %s (%s, %d compute units)\n", d.name.c_str(), d.platform.c_str(), d.compute_units);
  if (team.size() > 1) {
    std::printf("processes: %d, each rendering every %d%s row of the frame\n", team.size(), team.size(),
                team.size() == 2 ? "nd" : team.size() == 3 ? "rd" : "th");
    for (int r = 0; r < team.size(); ++r) std::printf("  rank %d: %s\n", r, rank_devices[r].c_str());
  }
}

void print_scene(const Job& job) {
  const Renderer& renderer = *job.renderer;
  std::printf("scene: %s, %zu triangles, %zu lights, features: %s\n", job.scene_path.string().c_str(),
              job.triangles, (size_t)renderer.light_count(),
              renderer.kernels().features.describe().c_str());
  for (const std::string& note : job.scene.notes) std::printf("%s\n", note.c_str());
  if (job.asset)
    std::printf("film: %dx%d (%s)\n", job.scene.width, job.scene.height,
                job.resolution_given ? "--resolution" : "height 512, width from the camera's aspect ratio");
}

void print_kernels(const Job& job, const Team& team) {
  const Renderer& renderer = *job.renderer;
  const CompiledScene& cs = renderer.compiled();
  std::printf(
      "bvh: %zu %d-wide nodes, %zu leaves, %zu triangle references, depth %d, stack %zu, built in %.2f ms "
      "on %zu thread%s%s%s%s\n",
      cs.bvh.stats.nodes, cs.bvh.width, cs.bvh.stats.leaves, cs.bvh.stats.references, cs.bvh.stats.depth,
      cs.bvh.stats.stack, cs.bvh.stats.build_seconds * 1e3, cs.bvh.stats.threads, cs.bvh.stats.threads == 1 ? "" : "s",
      renderer.kernels().ray_packets ? "; camera, bounce and shadow rays in packets of "
      : cs.bvh.width == 8            ? "; camera rays in packets of "
                                     : "",
      cs.bvh.width == 8 ? std::to_string(renderer.kernels().packet_width).c_str() : "",
      renderer.kernels().hybrid_packets ? ", the first bounce's in hybrid packets" : "");
  std::printf("kernels: %s in %.3f s%s\n", renderer.program().from_cache ? "loaded from cache" : "compiled",
              renderer.program().build_seconds,
              !renderer.generic_shading()        ? ""
              : renderer.scene_shading_pending() ? "; the generic ones shade while this scene's own build"
                                                 : "; the generic ones shade");
  if (job.opt.profile) {
    std::printf("kernel options: %s (key %s)\n", renderer.kernels().describe().c_str(), renderer.program().key.c_str());
    const Renderer::KernelTimes& t = renderer.kernel_times();
    std::printf("kernel time: tracing program %.3f s, shading program %.3f s, first launches %.3f s\n",
                t.trace_program, t.shading_program, t.first_launches);
  }
  std::printf("paths in flight: %zu, %d spp per pass%s\n", renderer.paths_in_flight(), renderer.samples_per_pass(),
              team.size() > 1 ? " (rank 0)" : "");
  if (!job.resume.empty())
    std::printf("resumed from %s at %d spp\n", job.resume.string().c_str(), renderer.spp_done());
}

void print_setup(const Job& job, const Team& team, const std::vector<std::string>& rank_devices) {
  print_devices(job, team, rank_devices);
  print_scene(job);
  print_kernels(job, team);
  std::fflush(stdout);
}

// ---- The render: passes until done, stopped or out of time, then the files and the summary. ----
// Every rank runs each step in the same order (the Team calls in them are collective); rank 0
// alone writes files and prints.
class RenderRun {
 public:
  RenderRun(Job& job, Team& team) : job_(job), team_(team), renderer_(*job.renderer) {}

  int run() {
    start();
    render_passes();
    if (job_.progress) std::fputs("\n", stderr);
    const bool stopped = team_.max({!renderer_.done()})[0] != 0;  // (ranks agree: what follows is collective)
    const int exit_code = stopped && stop_signal_ ? 128 + stop_signal_ : 0;
    if (stopped) report_stop();
    if (stopped && !image_is_valid()) return exit_code;
    // The image from every rank's rows and the counters summed (collective), then rank 0's files.
    const size_t overflowed = write_image(frame_spp());
    const uint64_t rays = team_.sum(renderer_.extend_rays() + renderer_.shadow_rays());
    const uint64_t samples = team_.sum(renderer_.samples_taken());
    const uint64_t nonfinite = team_.sum(renderer_.nonfinite_samples());
    if (!team_.leader()) return exit_code;
    write_logs(stopped);
    warn_about_samples(nonfinite, overflowed);
    if (!job_.quiet) print_summary(rays, samples);
    return exit_code;
  }

 private:
  // The ranks agree on the spp of a pass (shares of different sizes fit different numbers), so they
  // finish each pass together.
  void start() {
    renderer_.limit_samples_per_pass(team_.min(renderer_.samples_per_pass()));
    restore_resumed();
    announce();
    if (job_.reference) {
      csv_ = "pass,spp,seconds";
      for (Metric m : all_metrics()) csv_ += std::string(",") + metric_name(m);
      csv_ += "\n";
    }
  }

  // A resumed render continues from its checkpoint's state and clock.
  void restore_resumed() {
    if (!job_.resume.empty()) {
      RenderState share = team_.scatter(job_.resumed, scene().width, scene().height);
      renderer_.restore(share);
      seconds_ = share.seconds;
    }
    resumed_seconds_ = seconds_;
  }

  // The setup, and what the scene could not model (once per kind).
  void announce() {
    std::vector<std::string> rank_devices = team_.gather_strings(job_.device->info().name + " on " + team_.host());
    if (!job_.quiet) print_setup(job_, team_, rank_devices);
    if (!team_.leader()) return;
    for (const std::string& w : scene().warnings) std::fprintf(stderr, "xi: warning: %s\n", w.c_str());
    const DeviceInfo& device = job_.device->info();
    if (job_.threads > 0 && device.compute_units != job_.threads)
      std::fprintf(stderr, "xi: warning: --threads %d: %s runs %d compute units of its own (only PoCL's CPU device "
                           "takes a thread count)\n", job_.threads, device.name.c_str(), device.compute_units);
    // A point, spot or directional light is a delta: no BSDF sample ever reaches it.
    if (job_.opt.strategy == Strategy::Bsdf && renderer_.compiled().features.punctual)
      std::fprintf(stderr, "xi: warning: --strategy bsdf: punctual lights are reached by light sampling only, so "
                           "they light nothing here\n");
  }

  void render_passes() {
    last_checkpoint_ = std::chrono::steady_clock::now();
    for (;;) {
      const std::vector<int> agreed = agree_before_pass();
      stop_signal_ = agreed[0];
      if (!agreed[3] || agreed[0] || agreed[1]) return;
      if (agreed[2]) {
        save_checkpoint();
        last_checkpoint_ = std::chrono::steady_clock::now();
      }
      run_pass();
    }
  }

  // Before each pass the ranks agree: a signal to any of them, or rank 0's clock, stops them all;
  // rank 0's clock says when to checkpoint; the render goes on while any rank has pixels left (with
  // adaptive sampling one rank's pixels may all stop before another's; its passes then do nothing).
  // Returns {signal, time is up, checkpoint is due, some rank is not done}.
  std::vector<int> agree_before_pass() {
    const bool time_up = seconds_ - resumed_seconds_ >= job_.time_budget;
    const double since_checkpoint =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - last_checkpoint_).count();
    const bool checkpoint_due = !job_.checkpoint.empty() && since_checkpoint >= job_.checkpoint_every;
    return team_.max({(int)g_signal, team_.leader() && time_up, team_.leader() && checkpoint_due, !renderer_.done()});
  }

  // One pass, timed, then what follows it: the error, the progress bar, a snapshot.
  void run_pass() {
    auto t0 = std::chrono::steady_clock::now();
    renderer_.run_pass();
    const auto t1 = std::chrono::steady_clock::now();
    seconds_ += std::chrono::duration<double>(t1 - t0).count();
    if (job_.first_pass_seconds == 0.0) job_.first_pass_seconds = std::chrono::duration<double>(t1 - g_started).count();
    // What follows is collective, so the ranks agree on it first: with adaptive sampling one rank
    // may be done (its passes adding nothing) before another.
    const std::vector<int> agreed = team_.max({!renderer_.done(), renderer_.passes_done()});
    const bool done = !agreed[0];
    if (job_.measured && (!job_.convergence.empty() || done)) measure_error();
    if (job_.progress)
      draw_progress(renderer_.spp_done(), job_.opt.spp, (double)renderer_.samples_taken() / seconds_ * 1e-6, seconds_,
                    renderer_.adaptive() ? (double)renderer_.sampling_pixels() / renderer_.film_width() /
                                               renderer_.film_height()
                                         : -1.0);
    if (!done && job_.snapshot_every && agreed[1] % job_.snapshot_every == 0) write_image(frame_spp());
  }

  // The error against the reference after this pass: a row of the convergence log (the time spent
  // measuring is not counted). Collective: every rank has job.measured, only rank 0 the reference.
  void measure_error() {
    const Image now = team_.gather(renderer_.mean(), scene().height);
    if (!team_.leader()) return;
    char row[64];
    std::snprintf(row, sizeof row, "%d,%d,%.6f", renderer_.passes_done() - 1, renderer_.spp_done(), seconds_);
    csv_ += row;
    for (Metric m : all_metrics()) {
      double e = image_metric(now, *job_.reference, m);
      last_error_[metric_name(m)] = e;
      std::snprintf(row, sizeof row, ",%.9g", e);
      csv_ += row;
    }
    csv_ += "\n";
  }

  // A stopped render with no sample, or with an incomplete grid or stratified pattern, has no image.
  bool image_is_valid() const { return renderer_.spp_done() > 0 && sampler_is_progressive(job_.opt.sampler); }

  // Saves the state of a render stopped early and says why it stopped and what it wrote.
  void report_stop() {
    if (!job_.checkpoint.empty()) save_checkpoint();
    if (!team_.leader()) return;
    const RenderOptions& opt = job_.opt;
    const std::string why = stop_signal_ ? (stop_signal_ == SIGINT ? "SIGINT" : "SIGTERM") : "the time budget";
    const std::string at = std::to_string(renderer_.spp_done()) + " of " + std::to_string(opt.spp) + " spp";
    const std::string saved = job_.checkpoint.empty() ? "" : "; state saved to " + job_.checkpoint.string();
    if (!image_is_valid()) {
      const std::string reason = renderer_.spp_done() == 0 ? "no sample was done"
                                                           : std::string("the ") + sampler_name(opt.sampler) +
                                                                 " pattern is incomplete";
      std::fprintf(stderr, "xi: stopped by %s at %s: %s, no image written%s\n", why.c_str(), at.c_str(),
                   reason.c_str(), saved.c_str());
    } else {
      std::fprintf(stderr, "xi: stopped by %s after pass %d: %s%s\n", why.c_str(), renderer_.passes_done(), at.c_str(),
                   saved.c_str());
    }
  }

  // The most spp any rank's pixels have (collective): with adaptive sampling ranks may differ.
  int frame_spp() { return team_.max({renderer_.spp_done()})[0]; }

  // The whole frame's state, put together on rank 0 from every rank's rows (timed: the reduction).
  RenderState frame_state() {
    auto t0 = std::chrono::steady_clock::now();
    RenderState st = team_.gather(renderer_.state(), scene().width, scene().height);
    gather_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    st.seconds = seconds_;
    return st;
  }

  void save_checkpoint() {
    const RenderState st = frame_state();
    if (team_.leader()) write_checkpoint(job_.checkpoint, job_.key, st);
  }

  // --denoise: the mean denoised, for the image's R, G, B and its PNG; the time and the denoiser go
  // to `attrs`. A failure does not lose the render: one warning, and the image is not denoised.
  std::optional<Image> denoise(const Film& film, ExrAttributes& attrs) {
    if (!job_.denoiser) return std::nullopt;
    try {
      Image out = job_.denoiser->run(film.mean, &film.albedo, &film.normal);
      attrs["denoiseSeconds"] = job_.denoiser->last_seconds();
      attrs["denoiser"] = job_.denoiser->description();
      return out;
    } catch (const Error& e) {
      std::fprintf(stderr, "xi: warning: %s; the image is written without denoising\n", e.what());
      job_.denoiser.reset();
      return std::nullopt;
    }
  }

  // The image so far, written atomically: spp is what it holds (sppTarget: what was asked for).
  // Returns how many of its pixels' variances single precision cannot hold (rank 0).
  size_t write_image(int spp) {
    const RenderState st = frame_state();
    if (!team_.leader()) return 0;
    const RenderOptions& opt = job_.opt;
    const Film film = resolve_film(st, scene().width, scene().height);
    ExrAttributes attrs{{"spp", spp},
                        {"renderSeconds", seconds_},
                        {"seed", (int)opt.seed},
                        {"scene", std::filesystem::absolute(job_.scene_path).string()},
                        {"device", job_.device->info().name},
                        {"sampler", std::string(sampler_name(opt.sampler))},
                        {"strategy", std::string(strategy_name(opt.strategy))},
                        {"maxDepth", opt.max_depth}};
    if (team_.size() > 1) attrs["processes"] = team_.size();
    attrs["pngView"] = std::string(view_name(job_.png_view.view));  // the PNG's; these pixels are linear
    attrs["pngExposure"] = job_.png_view.exposure;
    if (spp < opt.spp) attrs["sppTarget"] = opt.spp;
    for (auto& [name, value] : last_error_) attrs["error." + name] = value;
    const std::optional<Image> denoised = denoise(film, attrs);
    const Image& color = denoised ? *denoised : film.mean;
    std::vector<ExrLayer> layers = {
        {"", &color}, {"variance", &film.variance}, {"albedo", &film.albedo}, {"normal", &film.normal}};
    if (denoised) layers.push_back({"noisy", &film.mean});
    if (opt.noise_threshold > 0.0f) {  // adaptive: how many samples each pixel took
      layers.push_back({"spp", &film.spp});
      double taken = 0.0;
      for (const glm::vec3& n : film.spp.pixels) taken += n.x;
      attrs["noiseThreshold"] = (double)opt.noise_threshold;
      attrs["minSpp"] = opt.min_spp;
      attrs["sppMean"] = taken / (double)film.spp.pixels.size();
    }
    write_exr(job_.out, layers, attrs);
    write_png(job_.png, color, job_.png_view.exposure, job_.png_view.view);
    return (size_t)std::count_if(film.variance.pixels.begin(), film.variance.pixels.end(),
                                 [](const glm::vec3& v) { return !std::isfinite(v.x + v.y + v.z); });
  }

  // After the image (rank 0): the checkpoint of a completed render goes, the log and trace are written.
  void write_logs(bool stopped) {
    if (!stopped && !job_.checkpoint.empty()) {  // the image holds the result now
      std::error_code ec;
      std::filesystem::remove(job_.checkpoint, ec);
    }
    if (!job_.convergence.empty()) {
      write_atomically(job_.convergence, [&](const std::filesystem::path& tmp) {
        std::FILE* f = std::fopen(tmp.c_str(), "w");
        if (!f || std::fputs(csv_.c_str(), f) < 0 || std::fclose(f) != 0) throw Error("cannot write file", tmp.string());
      });
    }
    if (!job_.trace.empty()) write_chrome_trace(job_.trace, renderer_.launches());
  }

  static void warn_about_samples(uint64_t nonfinite, size_t overflowed) {
    if (nonfinite)
      std::fprintf(stderr, "xi: warning: %llu non-finite samples were dropped\n", (unsigned long long)nonfinite);
    // Samples above about 1e19 (a radiance of 1e20 seen directly) square beyond the largest float.
    if (overflowed)
      std::fprintf(stderr,
                   "xi: warning: the variance of %zu pixel(s) overflows single precision (samples above about 1e19): "
                   "their variance layer holds infinity\n",
                   overflowed);
  }

  void print_summary(uint64_t rays, uint64_t samples) {
    const int spp = renderer_.spp_done();
    std::printf("%dx%d, %d spp, %.2f s, %.2f Msamples/s, %.2f Mrays/s%s\n", scene().width, scene().height, spp,
                seconds_, (double)samples / seconds_ * 1e-6, (double)rays / seconds_ * 1e-6,
                team_.size() > 1 ? (", " + std::to_string(team_.size()) + " processes").c_str() : "");
    if (renderer_.adaptive())
      std::printf("adaptive sampling to %g: %.2f spp on average (%llu samples), %d to %d per pixel\n",
                  (double)job_.opt.noise_threshold, (double)samples / pixels(), (unsigned long long)samples,
                  std::min(job_.opt.min_spp, spp), spp);
    if (team_.size() > 1)
      std::printf("film state gathered from %d processes: %.1f MB in %.3f s\n", team_.size(),
                  4.0 * sizeof(glm::vec4) * pixels() * 1e-6, gather_seconds_);
    if (job_.denoiser)
      std::printf("denoised with %s in %.2f s\n", job_.denoiser->description().c_str(), job_.denoiser->last_seconds());
    std::printf("wrote %s and %s\n", job_.out.string().c_str(), job_.png.string().c_str());
    if (job_.reference)
      std::printf("error vs reference: rmse %.6g, relmse %.6g\n", last_error_["rmse"], last_error_["relmse"]);
    if (job_.profile) {
      if (team_.size() > 1) std::printf("profile of rank 0:\n");
      print_profile(stdout, renderer_.launches(), seconds_);
    }
    std::printf("first pass done %.2f s after start%s\n", job_.first_pass_seconds,
                renderer_.shading_switch_pass() >= 0
                    ? ("; the scene's own kernels took over from the generic ones after pass " +
                       std::to_string(renderer_.shading_switch_pass()))
                          .c_str()
                : renderer_.generic_shading() ? "; shaded by the generic kernels throughout"
                                              : "");
    if (renderer_.scene_shading_pending())
      std::printf("kernels: finishing this scene's own build, so that its next render starts with them\n");
  }

  const Scene& scene() const { return job_.scene; }
  double pixels() const { return (double)scene().width * scene().height; }

  Job& job_;
  Team& team_;
  Renderer& renderer_;
  double seconds_ = 0.0;          // render time, this run's and any resumed run's (rank 0's clock)
  double resumed_seconds_ = 0.0;  // the part of it the checkpoint brought
  double gather_seconds_ = 0.0;   // the last gather of the frame's state
  std::string csv_;               // the convergence log (rank 0)
  std::map<std::string, double> last_error_;
  std::chrono::steady_clock::time_point last_checkpoint_;
  int stop_signal_ = 0;
};

// PoCL runs a CPU device on every core; ranks sharing a host split its cores instead (a variable
// the user set wins). Read when OpenCL starts, so set before anything touches it. Returns the
// cores this process may use, for the BVH build too: POCL_MAX_PTHREAD_COUNT, 0 (all) if unset.
unsigned share_cpu_cores(const Team& team) {
  if (team.local_size() >= 2 && !std::getenv("POCL_MAX_PTHREAD_COUNT")) {
    const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
    setenv("POCL_MAX_PTHREAD_COUNT", std::to_string(std::max(1u, cores / team.local_size())).c_str(), 0);
  }
  const char* cap = std::getenv("POCL_MAX_PTHREAD_COUNT");
  const long n = cap ? std::strtol(cap, nullptr, 10) : 0;
  return n > 0 ? (unsigned)n : 0u;  // (PoCL itself ignores a value that is not a positive number)
}

}  // namespace

int render(const std::vector<std::string>& argv) {
  Team team;
  const unsigned cores = share_cpu_cores(team);
  // Setup can fail on any rank (a file, a device): the ranks agree on it, then render together.
  auto job = std::make_unique<Job>();
  job->opt.build_threads = cores;
  std::string error;
  try {
    prepare(*job, argv, team);
  } catch (const std::exception& e) {
    error = describe_error(e);
  }
  team.agree_setup(error);
  try {
    const int code = RenderRun(*job, team).run();
    // Rank 0 has written every file: only now may the others end, since mpirun ends the whole job
    // when one rank exits with an error code. Rank 0's code is the job's.
    team.barrier();
    return team.leader() ? code : 0;
  } catch (const std::exception& e) {
    if (team.size() == 1) throw;
    // The other ranks wait in the next collective: end the job.
    std::fprintf(stderr, "xi: error: rank %d of %d (%s): %s\n", team.rank(), team.size(), team.host().c_str(),
                 describe_error(e).c_str());
    team.abort(1);
  }
}

int devices(const std::vector<std::string>& argv) {
  Args args(argv, kDevices);
  auto list = list_devices();
  if (list.empty()) throw Error("no OpenCL device found", "is an OpenCL driver installed? PoCL: apt-get install pocl-opencl-icd");
  std::printf("%-3s %-44s %-12s %-6s %5s  %s\n", "#", "device", "type", "units", "", "OpenCL C / platform");
  for (auto& d : list)
    std::printf("%-3d %-44s %-12s %-6d %5s  %s / %s\n", d.index, d.name.c_str(), d.type.c_str(), d.compute_units, "",
                d.opencl_c_version.c_str(), d.platform.c_str());
  return 0;
}

const Command kDevices = {.name = "devices", .about = "list OpenCL platforms and devices", .run = devices};

}  // namespace xi::cli
