// The `xi` program's subcommands and the small argument reader they share.
#pragma once
#include <exception>
#include <string>
#include <vector>

#include "xi/denoise.h"
#include "xi/view.h"

namespace xi::cli {

// Reads `--flag value` pairs and positionals; every flag must be known to the command.
class Args {
 public:
  Args(std::vector<std::string> argv, std::vector<std::string> valued, std::vector<std::string> switches);
  bool has(const std::string& flag) const;
  std::string get(const std::string& flag, const std::string& fallback = "") const;
  int get_int(const std::string& flag, int fallback, int lo, int hi) const;
  double get_seconds(const std::string& flag, double fallback) const;  // a finite number > 0
  double get_positive(const std::string& flag, double fallback, const std::string& what) const;  // the same
  const std::vector<std::string>& positional() const { return positional_; }

 private:
  std::vector<std::pair<std::string, std::string>> values_;
  std::vector<std::string> positional_;
};

// One line for an error: xi::Error's what and where, an OpenCL call and its code, or what().
std::string describe_error(const std::exception& e);

int render(const std::vector<std::string>& args);
int devices(const std::vector<std::string>& args);
int warp(const std::vector<std::string>& args);
int diff(const std::vector<std::string>& args);
int tonemap(const std::vector<std::string>& args);
int prebuild(const std::vector<std::string>& args);
int export_scene(const std::vector<std::string>& args);  // `xi export`
int denoise(const std::vector<std::string>& args);       // `xi denoise`
// --view and --exposure (render and tonemap): how the PNG shows the linear image.
struct PngView {
  View view = View::Standard;
  float exposure = 1.0f;
};
PngView read_png_view(const Args& args, View fallback);
// --denoise-quality and --denoise-prefilter (render and denoise), for a render on `device`.
DenoiseOptions read_denoise_options(const Args& args, Device* device);

}  // namespace xi::cli
