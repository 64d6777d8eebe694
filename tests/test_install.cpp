// `cmake --install` and the CMake package: installs this build into a temporary prefix, moves the
// prefix elsewhere, builds tests/install (the README's example: find_package(xi), xi::xi) against
// it, and checks that the program renders with the installed kernels, and the same pixels as the
// installed `xi render`. Also the order in which kernel_dir() looks for the kernels.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>

#include "xi/device.h"
#include "xi/image.h"
#include "fixtures.h"

namespace fs = std::filesystem;

namespace {

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Single-quotes a word for /bin/sh.
std::string quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// Runs a shell command with stdout and stderr appended to `log`; returns its exit status (-1: it
// did not exit normally).
int run(const std::string& command, const fs::path& log) {
  const int status = std::system(("(" + command + ") >>" + quote(log.string()) + " 2>&1").c_str());
  return (status != -1 && WIFEXITED(status)) ? WEXITSTATUS(status) : -1;
}

int cached_binaries(const fs::path& cache) {
  int n = 0;
  if (fs::exists(cache))
    for (const auto& e : fs::directory_iterator(cache)) n += e.path().extension() == ".bin";
  return n;
}

// Sets or unsets XI_KERNEL_DIR for one scope (fixtures.h).
struct KernelDirEnv : xi::test::ScopedEnv {
  explicit KernelDirEnv(const char* value) : ScopedEnv("XI_KERNEL_DIR", value) {}
};

}  // namespace

TEST(Install, PackageBuildsAProgramThatRendersWithTheInstalledKernels) {
  // canonical: the kernel folder is part of the binary cache key, and /proc/self/exe has no symlinks.
  const fs::path root = fs::canonical(fs::temp_directory_path()) / ("xi_install_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "work");
  const fs::path log = root / "log.txt", staged = root / "staged", prefix = root / "prefix";
  const std::string cmake = quote(XI_CMAKE_COMMAND);

  // Installed into one prefix (not the configure-time one) and then moved: nothing may depend on
  // where the build, the source or the install was.
  ASSERT_EQ(run(cmake + " --install " + quote(XI_BUILD_DIR) + " --prefix " + quote(staged.string()), log), 0)
      << read_text(log);
  fs::rename(staged, prefix);
  for (const char* file : {"bin/xi", "lib/libxi.a", "include/xi/renderer.h", "include/xi/device.h",
                           "include/xi/layout.h", "include/xi/sampling.h", "include/xi/compat.h",
                           "lib/cmake/xi/xiConfig.cmake", "lib/cmake/xi/xiConfigVersion.cmake",
                           "lib/cmake/xi/xiTargets.cmake", "share/xi/kernels/shade.cl",
                           "share/xi/kernels/shared/layout.h", "share/xi/scenes/cornell-box.json"})
    EXPECT_TRUE(fs::is_regular_file(prefix / file)) << file << " was not installed";
  const std::string source_dir = fs::path(XI_EXAMPLE_DIR).parent_path().parent_path().string();
  for (const auto& e : fs::directory_iterator(prefix / "lib/cmake/xi")) {
    const std::string text = read_text(e.path());
    for (const std::string& dir : {source_dir, std::string(XI_BUILD_DIR), staged.string()})
      EXPECT_EQ(text.find(dir), std::string::npos) << e.path() << " names " << dir;
  }

  // The README's example, configured and built against the moved prefix.
  const fs::path build = root / "build";
  ASSERT_EQ(run(cmake + " -S " + quote(XI_EXAMPLE_DIR) + " -B " + quote(build.string()) +
                    " -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH=" + quote(prefix.string()) +
                    " -DCMAKE_CXX_COMPILER=" + quote(XI_CXX_COMPILER),
                log),
            0)
      << read_text(log);
  EXPECT_NE(read_text(build / "CMakeCache.txt").find("xi_DIR:PATH=" + (prefix / "lib/cmake/xi").string() + "\n"),
            std::string::npos)
      << "find_package(xi) did not take the package from " << prefix;
  ASSERT_EQ(run(cmake + " --build " + quote(build.string()), log), 0) << read_text(log);

  // The same render through the library and through the installed `xi`, with a fresh kernel cache:
  // the key of a cached binary covers the kernel folder's path, so `xi` adding no binary means both
  // built the kernels from the same folder.
  const fs::path cache = root / "cache";
  const std::string env = "cd " + quote((root / "work").string()) + " && env -u XI_KERNEL_DIR XI_CACHE_DIR=" +
                          quote(cache.string()) + " ";
  const std::string scene = quote((prefix / "share/xi/scenes/cornell-box.json").string());
  const fs::path app_out = root / "app.txt";
  ASSERT_EQ(run(env + quote((build / "app").string()) + " " + scene + " lib.exr 32 4 7 >" + quote(app_out.string()),
                log),
            0)
      << read_text(log);
  const std::string printed = read_text(app_out);
  const size_t at = printed.find("kernels: ");
  ASSERT_NE(at, std::string::npos) << printed;
  const std::string used = printed.substr(at + 9, printed.find('\n', at) - at - 9);
  EXPECT_TRUE(fs::equivalent(used, prefix / "share/xi/kernels")) << "the program's kernels came from " << used;
  const int binaries = cached_binaries(cache);
  EXPECT_GT(binaries, 0);
  ASSERT_EQ(run(env + quote((prefix / "bin/xi").string()) + " render " + scene +
                    " -o cli.exr --resolution 32x32 --spp 4 --seed 7 --quiet",
                log),
            0)
      << read_text(log);
  EXPECT_EQ(cached_binaries(cache), binaries) << "the installed xi built its kernels from another folder";

  const xi::Image lib = xi::read_exr(root / "work/lib.exr"), cli = xi::read_exr(root / "work/cli.exr");
  ASSERT_EQ(lib.width, 32);
  ASSERT_EQ(lib.height, 32);
  ASSERT_EQ(cli.width, 32);
  ASSERT_EQ(cli.height, 32);
  double sum = 0.0;
  int differ = 0;
  for (size_t i = 0; i < lib.pixels.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      ASSERT_TRUE(std::isfinite(lib.pixels[i][c]) && lib.pixels[i][c] >= 0.0f) << "pixel " << i;
      sum += lib.pixels[i][c];
      differ += lib.pixels[i][c] != cli.pixels[i][c];  // same options, same device: the same floats
    }
  EXPECT_EQ(differ, 0) << "values that differ between the library's render and xi render's";
  // The Cornell box's mean radiance over pixels and channels at 32×32 converges to 0.121 (256 spp);
  // at 4 spp, seeds 1 to 11 gave 0.110 to 0.127.
  const double mean = sum / (3.0 * lib.pixels.size());
  EXPECT_GT(mean, 0.08);
  EXPECT_LT(mean, 0.16);

  if (!HasFailure()) fs::remove_all(root);  // kept for inspection when something failed
}

// The README shows the example as it is: both files verbatim, each in its own code block.
TEST(Install, ReadmeQuotesTheExample) {
  const fs::path example = XI_EXAMPLE_DIR;
  const std::string readme = read_text(example.parent_path().parent_path() / "README.md");
  EXPECT_NE(readme.find("```cmake\n" + read_text(example / "CMakeLists.txt") + "```\n"), std::string::npos);
  EXPECT_NE(readme.find("```cpp\n" + read_text(example / "main.cpp") + "```\n"), std::string::npos);
}

TEST(Install, KernelDirOrder) {
  const fs::path root = fs::temp_directory_path() / ("xi_kernel_dir_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "named");
  fs::create_directories(root / "empty");
  std::ofstream(root / "named/shade.cl") << "\n";  // kernel_dir() looks for shade.cl
  {
    KernelDirEnv unset(nullptr);
    xi::set_kernel_dir(root / "named");
    EXPECT_EQ(xi::kernel_dir(), root / "named");
    xi::set_kernel_dir(root / "empty");  // a folder without the kernels is passed over
    EXPECT_TRUE(fs::exists(xi::kernel_dir() / "shade.cl"));
    EXPECT_NE(xi::kernel_dir(), root / "empty");
  }
  {
    KernelDirEnv env(XI_SOURCE_KERNEL_DIR);  // the environment overrides the named folder
    xi::set_kernel_dir(root / "named");
    EXPECT_EQ(xi::kernel_dir(), fs::path(XI_SOURCE_KERNEL_DIR));
  }
  xi::set_kernel_dir("");
  fs::remove_all(root);
}
