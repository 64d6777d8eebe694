// The `xi` program as a user runs it, for the CLI tests: XI_CLI_PATH started through the shell in a
// fresh folder per test, with its exit code, stdout and stderr captured.
#pragma once
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace xi_test {

namespace fs = std::filesystem;
using json = nlohmann::json;

inline const fs::path kCornell = fs::path(XI_SCENE_DIR) / "cornell-box.json";

inline std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

inline void write_text(const fs::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary);
  out << text;
  ASSERT_TRUE(out.good()) << p;
}

// Single-quotes a word for /bin/sh.
inline std::string quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

struct Outcome {
  int code = -1;  // exit status; -1 if the program did not exit normally (a crash)
  std::string out, err;
};

// Per-test folders: `work` is the program's current folder (only the program and the test write
// there), `capture` holds its stdout and stderr.
class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    root_ = fs::temp_directory_path() /
            (std::string("xi_cli_") + info->test_suite_name() + "_" + info->name() + "_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    work_ = root_ / "work";
    capture_ = root_ / "capture";
    fs::create_directories(work_);
    fs::create_directories(capture_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(root_);  // kept for inspection when something failed
  }

  // Runs `xi ARGS...` in work_, after the shell command `setup` if any (e.g. a ulimit).
  Outcome run_xi(const std::vector<std::string>& args, const std::string& setup = "") {
    std::string cmd = (setup.empty() ? "" : setup + "; ") + "cd " + quote(work_.string()) + " && " + quote(XI_CLI_PATH);
    for (const auto& a : args) cmd += " " + quote(a);
    cmd += " >" + quote((capture_ / "stdout").string()) + " 2>" + quote((capture_ / "stderr").string());
    const int status = std::system(cmd.c_str());
    Outcome r;
    r.code = (status != -1 && WIFEXITED(status)) ? WEXITSTATUS(status) : -1;
    r.out = read_text(capture_ / "stdout");
    r.err = read_text(capture_ / "stderr");
    return r;
  }

  // Starts `xi ARGS...` in work_ without waiting, for tests that signal it; wait_xi collects it.
  pid_t start_xi(const std::vector<std::string>& args) {
    std::vector<std::string> words = {XI_CLI_PATH};
    words.insert(words.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& w : words) argv.push_back(w.data());
    argv.push_back(nullptr);
    const std::string out = (capture_ / "stdout").string(), err = (capture_ / "stderr").string();
    const pid_t pid = fork();
    if (pid == 0) {  // only async-signal-safe calls until exec: the test binary has threads
      const int o = open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      const int e = open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (o < 0 || e < 0 || chdir(work_.c_str()) != 0 || dup2(o, 1) < 0 || dup2(e, 2) < 0) _exit(127);
      execv(argv[0], argv.data());
      _exit(127);
    }
    return pid;
  }

  Outcome wait_xi(pid_t pid) {
    int status = 0;
    Outcome r;
    if (waitpid(pid, &status, 0) == pid && WIFEXITED(status)) r.code = WEXITSTATUS(status);
    r.out = read_text(capture_ / "stdout");
    r.err = read_text(capture_ / "stderr");
    return r;
  }

  // Polls for a file in work_ (written by the program); false after `seconds`.
  bool wait_for(const std::string& name, double seconds = 60.0) const {
    for (int i = 0; i < seconds * 1000; ++i) {
      if (fs::exists(work_ / name)) return true;
      usleep(1000);
    }
    return false;
  }

  std::set<std::string> files() const {
    std::set<std::string> names;
    for (const auto& e : fs::directory_iterator(work_)) names.insert(e.path().filename().string());
    return names;
  }

  // A copy of the Cornell box, changed by `edit`, written to work_/name.
  void write_scene(const std::string& name, const std::function<void(json&)>& edit) {
    json j = json::parse(read_text(kCornell));
    edit(j);
    write_text(work_ / name, j.dump(2));
  }

  // The program failed as a user error should: exit code 1, exactly one line on stderr of the form
  // "xi: error: ...", containing every `needle`, nothing on stdout, and no new file in work_.
  void expect_user_error(const Outcome& r, const std::vector<std::string>& needles, const std::set<std::string>& before) {
    EXPECT_EQ(r.code, 1) << "stderr: " << r.err;
    EXPECT_EQ(r.err.rfind("xi: error: ", 0), 0u) << "stderr: " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
    EXPECT_TRUE(!r.err.empty() && r.err.back() == '\n') << "stderr: " << r.err;
    for (const auto& n : needles) EXPECT_NE(r.err.find(n), std::string::npos) << "'" << n << "' not in: " << r.err;
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(files(), before) << "the failed command left files behind";
  }

  fs::path root_, work_, capture_;
};

// Small and fast: every render here is 32×32 at 2 spp.
inline const std::vector<std::string> kFast = {"--spp", "2", "--resolution", "32x32", "--quiet"};

inline std::vector<std::string> concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}


}  // namespace xi_test
