// xi: a Monte Carlo path tracer on OpenCL. `xi help` lists the commands.
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <string>
#include <vector>

#include "cli.h"
#include "team.h"
#include "xi/device.h"
#include "xi/error.h"

namespace xi::cli {

Args::Args(std::vector<std::string> argv, std::vector<std::string> valued, std::vector<std::string> switches) {
  auto known = [](const std::vector<std::string>& list, const std::string& f) {
    for (auto& k : list)
      if (k == f) return true;
    return false;
  };
  for (size_t i = 0; i < argv.size(); ++i) {
    const std::string& a = argv[i];
    if (a.size() > 1 && a[0] == '-' && !(a.size() > 1 && (std::isdigit((unsigned char)a[1]) || a[1] == '.'))) {
      if (known(switches, a)) {
        values_.push_back({a, "1"});
      } else if (known(valued, a)) {
        if (i + 1 >= argv.size()) throw Error("missing value", a);
        values_.push_back({a, argv[++i]});
      } else {
        throw Error("unknown option '" + a + "'", "xi help lists the options");
      }
    } else {
      positional_.push_back(a);
    }
  }
}

bool Args::has(const std::string& flag) const {
  for (auto& [k, v] : values_)
    if (k == flag) return true;
  return false;
}

std::string Args::get(const std::string& flag, const std::string& fallback) const {
  std::string out = fallback;
  for (auto& [k, v] : values_)
    if (k == flag) out = v;  // the last one wins
  return out;
}

int Args::get_int(const std::string& flag, int fallback, int lo, int hi) const {
  if (!has(flag)) return fallback;
  std::string v = get(flag);
  size_t used = 0;
  long n = 0;
  try {
    n = std::stol(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v.size() || v.empty()) throw Error("expected a whole number, got '" + v + "'", flag);
  if (n < lo || n > hi)
    throw Error("value " + v + " out of range " + std::to_string(lo) + ".." + std::to_string(hi), flag);
  return (int)n;
}

double Args::get_seconds(const std::string& flag, double fallback) const {
  return get_positive(flag, fallback, "a number of seconds");
}

double Args::get_positive(const std::string& flag, double fallback, const std::string& what) const {
  if (!has(flag)) return fallback;
  const std::string v = get(flag);
  size_t used = 0;
  double x = 0.0;
  try {
    x = std::stod(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v.size() || v.empty() || !std::isfinite(x) || x <= 0.0 || x > 1e9)
    throw Error("expected " + what + " > 0, got '" + v + "'", flag);
  return x;
}

std::string describe_error(const std::exception& e) {
  if (auto* cl_error = dynamic_cast<const cl::Error*>(&e))
    return std::string("OpenCL call ") + cl_error->what() + " failed with code " + std::to_string(cl_error->err());
  return e.what();
}

}  // namespace xi::cli

static const char* kUsage =
    "usage: xi <command> [options]\n"
    "\n"
    "commands:\n"
    "  render [SCENE]        render a .json scene (default: the bundled Cornell box), or any other\n"
    "                        file through Assimp with its cameras and lights: every format Assimp\n"
    "                        reads (.gltf .glb .obj .ply .fbx .dae .3ds .blend ...; an unknown\n"
    "                        extension's error lists them all)\n"
    "      -o OUT.exr|OUT.png    output: the EXR (linear, float) and the 8-bit sRGB PNG beside it\n"
    "                            (through --view), whichever of the two is named\n"
    "      --view V              how the PNG shows the linear image: standard (clipped to [0, 1]),\n"
    "                            neutral (Khronos PBR Neutral, as glTF viewers show) or agx (AgX,\n"
    "                            Blender's default view, approximated); default: neutral for an\n"
    "                            asset file, standard for a JSON scene; the EXR stays linear\n"
    "      --exposure E          scale the linear values by E > 0 before the view (PNG only)\n"
    "      --camera NAME|INDEX   an asset file's camera (default: its first perspective camera;\n"
    "                            without one, its bounding sphere framed from --orbit)\n"
    "      --orbit YAW,PITCH     an asset file without a camera: the direction it is framed from,\n"
    "                            in degrees (default 0,15: the front, 15 above); yaw turns about +y\n"
    "                            toward +x, pitch is above the horizontal, -90 < PITCH < 90\n"
    "      --spp N               samples per pixel\n"
    "      --seed S              random seed\n"
    "      --max-depth K         maximum bounces (1 = direct light only)\n"
    "      --resolution WxH      override the scene's film size\n"
    "      --env FILE|none       an equirectangular environment map around the scene, replacing\n"
    "                            the scene's (none: no map, the scene's background)\n"
    "      --env-strength S      scale the environment's radiance by S >= 0 (default: the scene's, 1)\n"
    "      --env-rotate DEG      turn the environment about +y (default: the scene's, 0)\n"
    "      --background R,G,B|V  a constant background radiance, in place of any environment (an\n"
    "                            asset file without lights is otherwise lit by the bundled sky)\n"
    "      --sampler NAME        random | grid | stratified | sobol (default: the scene's, else\n"
    "                            sobol); random and sobol are progressive: any prefix of a\n"
    "                            render is a render; grid and stratified patterns need every spp,\n"
    "                            so --time and --snapshot-every refuse them\n"
    "      --strategy NAME       mis | nee | bsdf (light transport)\n"
    "      --noise-threshold T   adaptive sampling: a pixel stops once the relative standard error\n"
    "                            of its mean is below T (e.g. 0.02), --spp being the most it takes;\n"
    "                            random and sobol samplers only\n"
    "      --min-spp N           samples every pixel takes before it may stop (default 16)\n"
    "      --device D            OpenCL device: index or name substring (see `xi devices`); under\n"
    "                            mpirun a list D0,D1,... gives local rank i item i mod its length\n"
    "      --threads N           CPU threads PoCL renders on (default: one per core)\n"
    "      --local-size N        work-group size, at most 1024 (default 64; 0: the largest the kernel allows)\n"
    "      --lanes N             paths per generate and shade work item, 1, 8 or 16 (default: 16\n"
    "                            on a CPU with 512-bit vectors, 8 on another CPU, 1 on a GPU)\n"
    "      --bvh-width N         children per BVH node, 4 or 8 (default: 8 on a CPU, 4 on a\n"
    "                            GPU)\n"
    "      --kernels K           auto | scene | generic: which program shades; auto: the scene's\n"
    "                            own if built before, else the generic one (see `xi prebuild`) while\n"
    "                            the scene's own builds, taking over when ready; the image is the same\n"
    "      --ray-packets M       auto | on | hybrid | off: bounce and shadow rays through an 8-wide\n"
    "                            BVH in packets, as camera rays go (on), the first bounce's in\n"
    "                            hybrid packets (hybrid), or alone (off); default auto: on for\n"
    "                            trees of at most 8 nodes, else hybrid\n"
    "      --packet-width N      rays per packet, 8 or 16 (default: 16 on a CPU with 512-bit\n"
    "                            vectors, else 8)\n"
    "      --no-spatial-splits   a BVH whose triangles are never split between subtrees: a\n"
    "                            faster build, slower rays where long triangles overlap\n"
    "      --paths-in-flight N   most (pixel, sample) paths in one wave (default: sized for the\n"
    "                            device, 2^20 on a CPU, 2^25 on a GPU, within 1/4 of its memory)\n"
    "      --samples-per-pass N  most spp one pass adds (default: what the paths in flight hold;\n"
    "                            1 with --convergence)\n"
    "      --all-features        compile every kernel feature, not just what the scene uses\n"
    "      --profile             print per-bounce and per-stage timing tables\n"
    "      --trace OUT.json      write every kernel launch as a Chrome trace (Perfetto)\n"
    "      --reference REF.exr   measure the error against REF after the render\n"
    "      --convergence OUT.csv with --reference: the error after every pass\n"
    "      --quiet               no progress bar and no summary\n"
    "      --time SECONDS        stop after the pass that crosses this much render time\n"
    "      --snapshot-every N    write the image so far every N passes\n"
    "      --denoise             denoise the image (and snapshots) with Intel Open Image Denoise,\n"
    "                            as `xi denoise` does: R,G,B denoised, the raw mean in layer noisy\n"
    "      --denoise-quality Q   high (default), balanced or fast: OIDN's filter quality\n"
    "      --denoise-prefilter P accurate (default: albedo and normal denoised first), fast\n"
    "                            (denoised at fast quality) or none (used as rendered)\n"
    "      --checkpoint FILE     save the render's state to FILE every --checkpoint-every\n"
    "                            seconds (default 60) and when stopped early; removed once\n"
    "                            the render completes\n"
    "      --resume FILE         continue from a checkpoint (same scene, spp, seed, sampler,\n"
    "                            strategy, depth, kernels, device); keeps checkpointing to FILE\n"
    "      Ctrl-C or SIGTERM     finish the pass in flight, write the image with the spp done,\n"
    "                            exit 130 or 143; a second signal stops at once, writing nothing\n"
    "      mpirun -np N xi render ...  N processes, rank r rendering rows r, r+N, ...; rank 0 writes\n"
    "                            the image, bitwise the one-process image (built with MPI)\n"
    "  devices               list OpenCL platforms and devices\n"
    "  warp                  draw a sample set warped by a map (as PNG) or write it as CSV\n"
    "      --map NAME            square | sphere | hemisphere | cosine-hemisphere | disc |\n"
    "                            concentric-disc | triangle | disc-naive\n"
    "      --sampler NAME        random | grid | stratified | sobol (default stratified)\n"
    "      -n N                  number of points (default 1024)\n"
    "      --seed S              random seed\n"
    "      -o FILE.png|FILE.csv  output: a picture, or one x,y,z line per point\n"
    "  diff IMAGE.exr REFERENCE.exr   error of an image against a reference\n"
    "      --metric NAME         mse | rmse | relmse | mae | mrse (default: all)\n"
    "      --crop x0,y0,x1,y1    only pixels x0 <= x < x1, y0 <= y < y1\n"
    "      --heatmap OUT.png     write the per-pixel error in false colour\n"
    "      --layer NAME          compare an EXR layer (e.g. variance) instead of RGB\n"
    "  tonemap IMAGE.exr OUT.png   the 8-bit sRGB PNG that `xi render` writes beside its EXR\n"
    "      --view V              standard (default), neutral or agx, as for render (whose\n"
    "                            default for an asset file is neutral)\n"
    "      --exposure E          scale the linear values by E > 0 first (default 1)\n"
    "      --layer NAME          an EXR layer (e.g. albedo) instead of RGB; spp: samples per\n"
    "                            pixel of an adaptive render, the most-sampled pixel white\n"
    "  denoise IN.exr OUT.exr   denoise a render with Intel Open Image Denoise 2 (OIDN), guided\n"
    "                        by its albedo and normal layers (each denoised first); OUT keeps\n"
    "                        every layer and attribute, the colour read going to layer noisy.\n"
    "                        OIDN is loaded at run time: `bash scripts/install-deps.sh --denoise`\n"
    "                        installs it, or XI_OIDN_PATH names its folder\n"
    "      --device D            denoise on OIDN's GPU device that is this OpenCL device, if\n"
    "                            it has one (default: $XI_DEVICE; else OIDN's CPU device)\n"
    "      --denoise-quality Q, --denoise-prefilter P   as for render\n"
    "  prebuild              build the kernels any scene's first image can start with (the\n"
    "                        generic shading program), so that a new scene waits for no build\n"
    "      --device D            OpenCL device (as for render)\n"
    "      --lanes N, --bvh-width N   as for render (default: the device's)\n"
    "  export SCENE OUT_DIR  write the scene's triangles as xi renders them, in world space, for\n"
    "                        other renderers: one binary PLY per material (x y z nx ny nz; its\n"
    "                        flat triangles first, each with its face normal at its three\n"
    "                        vertices) and manifest.json naming each file's material and its\n"
    "                        count of flat triangles; OUT_DIR is made if its parent exists\n"
    "  help [COMMAND]        this text, or one command's part of it (also COMMAND --help)\n"
    "  version               xi's version (also --version)\n";

static bool is_help_flag(const std::string& a) { return a == "--help" || a == "-h"; }

// The usage text's lines for one command: its own line and its options, up to the next command's.
static std::string command_usage(const std::string& command) {
  const std::string text = kUsage;
  std::string out;
  bool inside = false;
  for (size_t at = 0; at < text.size();) {
    size_t end = text.find('\n', at);
    end = end == std::string::npos ? text.size() : end + 1;
    const std::string line = text.substr(at, end - at);
    at = end;
    const bool command_line = line.size() > 2 && line.compare(0, 2, "  ") == 0 && line[2] != ' ';
    if (command_line) inside = line.compare(2, command.size(), command) == 0 &&
                               (line.size() == 2 + command.size() || line[2 + command.size()] == ' ');
    if (inside) out += line;
  }
  return out;
}

// Prints one command's usage; false for a command the text does not know.
static bool print_command_usage(const std::string& command) {
  const std::string part = command_usage(command);
  if (part.empty()) return false;
  std::printf("usage: xi %s [options]\n\n%s", command.c_str(), part.c_str());
  return true;
}

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty() || args[0] == "help" || is_help_flag(args[0])) {
    if (args.size() > 1 && print_command_usage(args[1])) return 0;  // `xi help COMMAND`
    std::fputs(kUsage, args.empty() ? stderr : stdout);
    return args.empty() ? 2 : 0;
  }
  if (args[0] == "--version" || args[0] == "version") {
    std::printf("xi %s\n", XI_VERSION);
    return 0;
  }
  std::string command = args[0];
  args.erase(args.begin());
  for (const std::string& a : args)
    if (is_help_flag(a) && print_command_usage(command)) return 0;
  try {
    if (command == "render") return xi::cli::render(args);
    if (command == "devices") return xi::cli::devices(args);
    if (command == "warp") return xi::cli::warp(args);
    if (command == "diff") return xi::cli::diff(args);
    if (command == "tonemap") return xi::cli::tonemap(args);
    if (command == "prebuild") return xi::cli::prebuild(args);
    if (command == "export") return xi::cli::export_scene(args);
    if (command == "denoise") return xi::cli::denoise(args);
    throw xi::Error("unknown command '" + command + "'", "xi help lists the commands");
  } catch (const xi::cli::Team::QuietExit&) {
    // a rank of an MPI job whose setup error rank 0 reports
  } catch (const std::exception& e) {
    std::fprintf(stderr, "xi: error: %s\n", xi::cli::describe_error(e).c_str());
  }
  return 1;
}
