// xi: a Monte Carlo path tracer on OpenCL. `xi help` lists the commands.
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "cli.h"
#include "team.h"
#include "xi/error.h"

static bool is_help_flag(const std::string& a) { return a == "--help" || a == "-h"; }

// Prints one command's usage; false for a command the text does not know.
static bool print_command_usage(const std::string& command) {
  const std::string part = xi::cli::command_usage(command);
  if (part.empty()) return false;
  std::printf("usage: xi %s [options]\n\n%s", command.c_str(), part.c_str());
  return true;
}

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty() || args[0] == "help" || is_help_flag(args[0])) {
    if (args.size() > 1 && print_command_usage(args[1])) return 0;  // `xi help COMMAND`
    std::fputs(xi::cli::usage_text().c_str(), args.empty() ? stderr : stdout);
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
    for (const xi::cli::Command* c : xi::cli::commands())
      if (c->run && command == c->name) return c->run(args);
    throw xi::Error("unknown command '" + command + "'", "xi help lists the commands");
  } catch (const xi::cli::Team::QuietExit&) {
    // a rank of an MPI job whose setup error rank 0 reports
  } catch (const std::exception& e) {
    std::fprintf(stderr, "xi: error: %s\n", xi::cli::describe_error(e).c_str());
  }
  return 1;
}
