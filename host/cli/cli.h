// The `xi` program's commands, their flags, and the small argument reader they share.
#pragma once
#include <exception>
#include <string>
#include <vector>

#include "xi/denoise.h"
#include "xi/view.h"

namespace xi::cli {

// One flag of a command: what the parser accepts and what the usage text says about it.
struct Flag {
  const char* name;   // "--spp", "-o"
  const char* value;  // its value's placeholder ("N", "OUT.exr|OUT.png"); nullptr for a switch
  const char* help;   // the usage text's description, its lines split by '\n'
};

// A line of a command's usage after its flags, about something other than a flag.
struct Note {
  const char* label;
  const char* help;  // lines split by '\n'
};

// A command: its usage and its flags, declared once; Args accepts exactly these flags and the usage
// text lists them.
struct Command {
  const char* name;           // as typed after `xi`
  const char* operands = "";  // what follows the name in its usage line ("[SCENE]")
  const char* about;          // lines split by '\n'
  std::vector<Flag> flags = {};
  std::vector<Note> notes = {};
  int (*run)(const std::vector<std::string>& args) = nullptr;  // none for help and version (main's own)
};

// Every command, in the usage text's order.
const std::vector<const Command*>& commands();
std::string usage_text();                             // the whole usage, as `xi help` prints it
std::string command_usage(const std::string& name);   // one command's part of it; "" for no such command

// Reads a command's flags (`--flag value` pairs and switches) and positionals; a flag the command
// does not declare is an error.
class Args {
 public:
  Args(const std::vector<std::string>& argv, const Command& command);
  // Each flag asked about must be one of the command's (a logic error otherwise).
  bool has(const std::string& flag) const;
  std::string get(const std::string& flag, const std::string& fallback = "") const;
  int get_int(const std::string& flag, int fallback, int lo, int hi) const;
  double get_seconds(const std::string& flag, double fallback) const;  // a finite number > 0
  double get_positive(const std::string& flag, double fallback, const std::string& what) const;  // the same
  const std::vector<std::string>& positional() const { return positional_; }

 private:
  const Flag* find(const std::string& flag) const;
  void check_declared(const std::string& flag) const;

  const Command& command_;
  std::vector<std::pair<std::string, std::string>> values_;
  std::vector<std::string> positional_;
};

// One line for an error: xi::Error's what and where, an OpenCL call and its code, or what().
std::string describe_error(const std::exception& e);

// The commands, each declared in the file that runs it, and their run functions.
extern const Command kRender, kDevices, kWarp, kDiff, kTonemap, kDenoise, kPrebuild, kExport;
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
