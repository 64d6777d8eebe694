// What the commands share: the argument reader, the usage text made from their flag tables, and
// the one-line description of an error.
#include "cli.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <stdexcept>

#include "xi/device.h"
#include "xi/error.h"

namespace xi::cli {

const std::vector<const Command*>& commands() {
  // help and version are main's own: a usage line each, no flags and no run function.
  static const Command help = {.name = "help",
                               .operands = "[COMMAND]",
                               .about = "this text, or one command's part of it (also COMMAND --help)"};
  static const Command version = {.name = "version", .about = "xi's version (also --version)"};
  static const std::vector<const Command*> all = {&kRender,  &kDevices,  &kWarp,   &kDiff, &kTonemap,
                                                  &kDenoise, &kPrebuild, &kExport, &help,  &version};
  return all;
}

namespace {

// The column a command's description starts at, and that of a flag's or note's.
constexpr size_t kCommandColumn = 24, kFlagColumn = 28;

// `label` indented, then `text` from `column` on, each of its lines under the first; a label that
// reaches the column is followed by three spaces instead.
void append_entry(std::string& out, size_t indent, const std::string& label, const std::string& text, size_t column) {
  std::string line = std::string(indent, ' ') + label;
  line += line.size() < column ? std::string(column - line.size(), ' ') : std::string(3, ' ');
  for (size_t at = 0; at <= text.size();) {
    const size_t end = std::min(text.find('\n', at), text.size());
    out += line + text.substr(at, end - at) + "\n";
    line = std::string(column, ' ');
    at = end + 1;
  }
}

std::string command_block(const Command& c) {
  std::string out;
  append_entry(out, 2, std::string(c.name) + (*c.operands ? " " : "") + c.operands, c.about, kCommandColumn);
  for (const Flag& f : c.flags)
    append_entry(out, 6, std::string(f.name) + (f.value ? std::string(" ") + f.value : ""), f.help, kFlagColumn);
  for (const Note& n : c.notes) append_entry(out, 6, n.label, n.help, kFlagColumn);
  return out;
}

}  // namespace

std::string usage_text() {
  std::string out = "usage: xi <command> [options]\n\ncommands:\n";
  for (const Command* c : commands()) out += command_block(*c);
  return out;
}

std::string command_usage(const std::string& name) {
  for (const Command* c : commands())
    if (c->name == name) return command_block(*c);
  return "";
}

Args::Args(const std::vector<std::string>& argv, const Command& command) : command_(command) {
  for (size_t i = 0; i < argv.size(); ++i) {
    const std::string& a = argv[i];
    // "-1" and "-.5" are numbers, not flags
    if (a.size() > 1 && a[0] == '-' && !(std::isdigit((unsigned char)a[1]) || a[1] == '.')) {
      const Flag* flag = find(a);
      if (!flag) throw Error("unknown option '" + a + "'", "xi help lists the options");
      if (!flag->value) {
        values_.push_back({a, "1"});
      } else {
        if (i + 1 >= argv.size()) throw Error("missing value", a);
        values_.push_back({a, argv[++i]});
      }
    } else {
      positional_.push_back(a);
    }
  }
}

const Flag* Args::find(const std::string& flag) const {
  for (const Flag& f : command_.flags)
    if (f.name == flag) return &f;
  return nullptr;
}

// A command may only ask about the flags its table declares, so that the table is the whole of it.
void Args::check_declared(const std::string& flag) const {
  if (!find(flag)) throw std::logic_error("'" + flag + "' is not a flag of xi " + command_.name);
}

bool Args::has(const std::string& flag) const {
  check_declared(flag);
  for (auto& [k, v] : values_)
    if (k == flag) return true;
  return false;
}

std::string Args::get(const std::string& flag, const std::string& fallback) const {
  check_declared(flag);
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
