// The `xi` program as a user runs it, for the CLI tests: XI_CLI_PATH started through the shell in a
// fresh folder per test, with its exit code, stdout and stderr captured.
#pragma once
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "xi/image.h"

#ifndef XI_MPIEXEC
#define XI_MPIEXEC ""  // mpirun, when xi was built with MPI (CMake defines it for xi_tests)
#endif

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

// The processes below `pid` (children, their children...), from /proc.
inline std::vector<pid_t> descendants(pid_t pid) {
  std::vector<std::pair<pid_t, pid_t>> parent_of;  // (pid, ppid)
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc", ec)) {
    const std::string name = e.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream in(e.path() / "stat");
    std::string stat;
    std::getline(in, stat);
    const size_t close = stat.rfind(')');  // "pid (comm) state ppid ...": comm may hold anything
    if (close == std::string::npos) continue;
    char state = 0;
    int ppid = 0;
    if (std::sscanf(stat.c_str() + close + 1, " %c %d", &state, &ppid) == 2) parent_of.push_back({std::stoi(name), ppid});
  }
  std::vector<pid_t> found = {pid};
  for (size_t i = 0; i < found.size(); ++i)
    for (const auto& [child, parent] : parent_of)
      if (parent == found[i]) found.push_back(child);
  found.erase(found.begin());
  return found;
}

// Base64 (RFC 4648, padded), for data URIs in the glTF files the tests write.
inline std::string base64(const std::string& bytes) {
  static const char* t = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (size_t i = 0; i < bytes.size(); i += 3) {
    uint32_t v = uint32_t((unsigned char)bytes[i]) << 16;
    if (i + 1 < bytes.size()) v |= uint32_t((unsigned char)bytes[i + 1]) << 8;
    if (i + 2 < bytes.size()) v |= uint32_t((unsigned char)bytes[i + 2]);
    out += t[v >> 18 & 63];
    out += t[v >> 12 & 63];
    out += i + 1 < bytes.size() ? t[v >> 6 & 63] : '=';
    out += i + 2 < bytes.size() ? t[v & 63] : '=';
  }
  return out;
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
    for (const auto& a : args) {
      cmd += ' ';
      cmd += quote(a);
    }
    cmd += " >" + quote((capture_ / "stdout").string()) + " 2>" + quote((capture_ / "stderr").string());
    const int status = std::system(cmd.c_str());
    Outcome r;
    r.code = (status != -1 && WIFEXITED(status)) ? WEXITSTATUS(status) : -1;
    r.out = read_text(capture_ / "stdout");
    r.err = read_text(capture_ / "stderr");
    return r;
  }

  // Starts `xi ARGS...` in work_ without waiting, for tests that signal it; wait_xi collects it.
  pid_t start_xi(const std::vector<std::string>& args) { return start(concat_words({XI_CLI_PATH}, args), {}, false); }

  // Starts `mpirun -np N xi ARGS...` in work_ without waiting, in a process group of its own (the
  // ranks are mpirun's children); wait_xi collects it. Root may run Open MPI only when told so, and
  // a machine with fewer cores than N needs --oversubscribe (Open MPI's flag).
  pid_t start_mpi(int processes, const std::vector<std::string>& args) {
    std::vector<std::string> words = {XI_MPIEXEC};
    if (open_mpi()) words.push_back("--oversubscribe");
    words.insert(words.end(), {"-np", std::to_string(processes), XI_CLI_PATH});
    return start(concat_words(words, args), {"OMPI_ALLOW_RUN_AS_ROOT=1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1"}, true);
  }
  Outcome run_mpi(int processes, const std::vector<std::string>& args, double timeout = 120.0) {
    return wait_xi(start_mpi(processes, args), timeout);
  }

  // Waits for a started program; after `timeout` seconds it fails the test and kills the program,
  // its process group and every process below it (an MPI job's ranks have groups of their own).
  Outcome wait_xi(pid_t pid, double timeout = 600.0) {
    int status = 0;
    Outcome r;
    pid_t got = 0;
    for (int i = 0; (got = waitpid(pid, &status, WNOHANG)) == 0 && i < timeout * 1000; ++i) usleep(1000);
    if (got == 0) {
      ADD_FAILURE() << "still running after " << timeout << " s: killed";
      for (pid_t p : descendants(pid)) kill(p, SIGKILL);
      kill(-pid, SIGKILL);  // a group of its own (start_mpi), else no such group
      kill(pid, SIGKILL);
      got = waitpid(pid, &status, 0);
    }
    if (got == pid && WIFEXITED(status)) r.code = WEXITSTATUS(status);
    r.out = read_text(capture_ / "stdout");
    r.err = read_text(capture_ / "stderr");
    return r;
  }

  // The pid of rank `rank` of the MPI job that mpirun `pid` runs, once it is running xi (0 if none
  // appears within `seconds`): the xi process below mpirun whose environment names that rank.
  pid_t rank_pid(pid_t pid, int rank, double seconds = 60.0) const {
    const fs::path xi = fs::canonical(XI_CLI_PATH);
    const std::string r = std::to_string(rank);
    for (int i = 0; i < seconds * 100; ++i, usleep(10000)) {
      for (pid_t p : descendants(pid)) {
        const fs::path proc = "/proc/" + std::to_string(p);
        std::error_code ec;
        if (fs::read_symlink(proc / "exe", ec) != xi) continue;
        std::string env = read_text(proc / "environ");
        std::replace(env.begin(), env.end(), '\0', '\n');
        env.insert(env.begin(), '\n');
        for (const char* var : {"OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK"})
          if (env.find(std::string("\n") + var + "=" + r + "\n") != std::string::npos) return p;
      }
    }
    return 0;
  }

  // Polls for a file in work_ (written by the program); false after `seconds`.
  bool wait_for(const std::string& name, double seconds = 60.0) const {
    for (int i = 0; i < seconds * 1000; ++i) {
      if (fs::exists(work_ / name)) return true;
      usleep(1000);
    }
    return false;
  }

  // Waits until the program's stdout holds `text` (it prints its setup before the first pass).
  bool wait_for_output(const std::string& text, double seconds = 60.0) const {
    for (int i = 0; i < seconds * 1000; ++i, usleep(1000))
      if (read_text(capture_ / "stdout").find(text) != std::string::npos) return true;
    return false;
  }

  // Every layer xi writes to an EXR in work_, bit for bit.
  void expect_same_image(const std::string& a, const std::string& b) {
    for (const char* layer : {"", "variance", "albedo", "normal"}) {
      SCOPED_TRACE(std::string("layer '") + layer + "' of " + a + " and " + b);
      const xi::Image x = xi::read_exr(work_ / a, layer), y = xi::read_exr(work_ / b, layer);
      ASSERT_EQ(x.width, y.width);
      ASSERT_EQ(x.pixels.size(), y.pixels.size());
      EXPECT_EQ(std::memcmp(x.pixels.data(), y.pixels.data(), x.pixels.size() * sizeof(glm::vec3)), 0);
    }
  }
  int attr_int(const std::string& exr, const std::string& name) {
    return std::get<int>(xi::read_exr_attributes(work_ / exr).at(name));
  }
  bool has_temp_files() const {
    for (auto& f : files())
      if (f.find(".tmp") != std::string::npos) return true;
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

  // The Cornell box with a wavy 100 × 100 grid (20,000 triangles, grid.obj) on its floor: enough
  // for the BVH build to fork subtrees onto threads (it forks at 4096 references).
  void write_grid_scene(const std::string& name) {
    std::string obj;
    for (int i = 0; i <= 100; ++i)
      for (int j = 0; j <= 100; ++j)
        obj += "v " + std::to_string(50 + 4.5 * i) + " " + std::to_string(20 + 10 * std::sin(0.7 * i + 0.3 * j)) +
               " " + std::to_string(50 + 4.5 * j) + "\n";
    for (int i = 0; i < 100; ++i)
      for (int j = 0; j < 100; ++j) {
        const int a = i * 101 + j + 1, b = a + 1, c = a + 101, d = c + 1;  // OBJ counts from 1
        obj += "f " + std::to_string(a) + " " + std::to_string(c) + " " + std::to_string(d) + "\n";
        obj += "f " + std::to_string(a) + " " + std::to_string(d) + " " + std::to_string(b) + "\n";
      }
    write_text(work_ / "grid.obj", obj);
    write_scene(name, [](json& j) {
      j["shapes"].push_back({{"type", "mesh"}, {"material", "white"}, {"file", "grid.obj"}});
    });
  }

  // The threads `xi render` printed that its BVH build ran on ("built in X ms on N threads"); -1 if
  // the line is missing.
  static long build_threads(const std::string& out) {
    const size_t at = out.find(" ms on ");
    return at == std::string::npos ? -1L : std::stol(out.substr(at + 7));
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

 private:
  static std::vector<std::string> concat_words(std::vector<std::string> a, const std::vector<std::string>& b) {
    a.insert(a.end(), b.begin(), b.end());
    return a;
  }

  // Whether XI_MPIEXEC is Open MPI's (which takes --oversubscribe; MPICH's does not).
  static bool open_mpi() {
    static const bool is = [] {
      std::string text;
      if (std::FILE* p = popen((quote(XI_MPIEXEC) + " --version 2>&1").c_str(), "r")) {
        char buf[256];
        while (std::fgets(buf, sizeof buf, p)) text += buf;
        pclose(p);
      }
      return text.find("Open MPI") != std::string::npos || text.find("OpenRTE") != std::string::npos;
    }();
    return is;
  }

  // Starts `words` (words[0] a path) in work_ with `env` added to the environment, stdin from
  // /dev/null, stdout and stderr to capture_; in a process group of its own if `own_group`.
  pid_t start(const std::vector<std::string>& words, const std::vector<std::string>& env, bool own_group) {
    std::vector<std::string> w = words, e = env;
    std::vector<char*> argv, envp;
    for (auto& x : w) argv.push_back(x.data());
    argv.push_back(nullptr);
    for (auto& x : e) envp.push_back(x.data());  // first: getenv finds the first of a name
    for (char** v = environ; *v; ++v) envp.push_back(*v);
    envp.push_back(nullptr);
    const std::string out = (capture_ / "stdout").string(), err = (capture_ / "stderr").string();
    const pid_t pid = fork();
    if (pid == 0) {  // only async-signal-safe calls until exec: the test binary has threads
      if (own_group) setpgid(0, 0);
      const int i = open("/dev/null", O_RDONLY);
      const int o = open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      const int r = open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (i < 0 || o < 0 || r < 0 || chdir(work_.c_str()) != 0 || dup2(i, 0) < 0 || dup2(o, 1) < 0 || dup2(r, 2) < 0)
        _exit(127);
      for (int fd : {i, o, r})
        if (fd > 2) close(fd);
      execve(argv[0], argv.data(), envp.data());
      _exit(127);
    }
    if (own_group) setpgid(pid, pid);  // also from here, so that it holds before wait_xi might kill the group
    return pid;
  }
};

// Small and fast: every render here is 32×32 at 2 spp.
inline const std::vector<std::string> kFast = {"--spp", "2", "--resolution", "32x32", "--quiet"};

inline std::vector<std::string> concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}


}  // namespace xi_test
