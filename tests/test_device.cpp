// Devices and kernel programs: selection, the on-disk binary cache, and build errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <unistd.h>

#include "xi/compiled_scene.h"
#include "xi/device.h"
#include "xi/kernel_config.h"
#include "xi/error.h"
#include "fixtures.h"

namespace fs = std::filesystem;

namespace {

// Points XI_CACHE_DIR (and optionally XI_KERNEL_DIR) at fresh folders for one test.
struct TempEnv {
  fs::path root = fs::temp_directory_path() / ("xi-device-test-" + std::to_string(::getpid()));
  TempEnv() {
    fs::remove_all(root);
    fs::create_directories(root / "cache");
    setenv("XI_CACHE_DIR", (root / "cache").c_str(), 1);
  }
  ~TempEnv() {
    unsetenv("XI_CACHE_DIR");
    unsetenv("XI_KERNEL_DIR");
    fs::remove_all(root);
  }
};

const std::vector<std::string> kStages = {"generate.cl", "extend.cl", "shade.cl", "shadow.cl", "accumulate.cl"};

std::vector<std::string> cornell_defines() {
  xi::KernelConfig c;
  c.sampler = XI_SAMPLER_RANDOM;
  return c.defines();
}

}  // namespace

// Sets or unsets XI_DEVICE for one scope (fixtures.h).
struct DeviceEnv : xi::test::ScopedEnv {
  explicit DeviceEnv(const char* value) : ScopedEnv("XI_DEVICE", value) {}
};

TEST(Device, ListsAndSelects) {
  auto list = xi::list_devices();
  ASSERT_FALSE(list.empty());  // PoCL is a dependency of the project
  {
    DeviceEnv unset(nullptr);  // the default is the first CPU device, else the first device
    auto cpu = std::find_if(list.begin(), list.end(), [](const xi::DeviceInfo& d) { return d.type == "CPU"; });
    EXPECT_EQ(xi::Device::open("").info().name, cpu != list.end() ? cpu->name : list[0].name);
  }
  EXPECT_EQ(xi::Device::open("0").info().name, list[0].name);
  EXPECT_EQ(xi::Device::open(list[0].name.substr(0, 6)).info().name, list[0].name);  // name substring
  EXPECT_THROW(xi::Device::open("no-such-device-anywhere"), xi::Error);
  EXPECT_THROW(xi::Device::open(std::to_string(list.size())), xi::Error);  // one past the last index
}

TEST(Device, XiDeviceVariablePicksTheDefault) {
  auto list = xi::list_devices();
  const std::string last = std::to_string(list.size() - 1);
  {
    DeviceEnv env(last.c_str());
    EXPECT_EQ(xi::Device::open("").info().name, list.back().name);
    EXPECT_EQ(xi::Device::open("0").info().name, list[0].name);  // an explicit selector wins
  }
  DeviceEnv env("no-such-device-anywhere");
  try {
    xi::Device::open("");
    ADD_FAILURE() << "an unknown XI_DEVICE opened a device";
  } catch (const xi::Error& e) {
    EXPECT_NE(std::string(e.what()).find("no-such-device-anywhere"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("XI_DEVICE"), std::string::npos) << e.what();
  }
}

// PoCL is told to build one work-group function per kernel, unless the user said otherwise.
TEST(Device, PoclWorkGroupSpecializationOffUnlessSet) {
  {
    xi::test::ScopedEnv unset("POCL_WORK_GROUP_SPECIALIZATION", nullptr);
    xi::list_devices();
    const char* v = std::getenv("POCL_WORK_GROUP_SPECIALIZATION");
    ASSERT_NE(v, nullptr);
    EXPECT_STREQ(v, "0");
  }
  xi::test::ScopedEnv user("POCL_WORK_GROUP_SPECIALIZATION", "1");
  xi::list_devices();
  EXPECT_STREQ(std::getenv("POCL_WORK_GROUP_SPECIALIZATION"), "1");
}

TEST(Device, SecondBuildComesFromTheCache) {
  TempEnv env;
  xi::Device device = xi::Device::open("");
  xi::Program first = xi::build_program(device, kStages, cornell_defines());
  EXPECT_FALSE(first.from_cache);
  ASSERT_TRUE(fs::exists(first.cache_file));
  xi::Program second = xi::build_program(device, kStages, cornell_defines());
  EXPECT_TRUE(second.from_cache);
  EXPECT_EQ(second.cache_file, first.cache_file);
  // Other options are another binary.
  xi::Program other = xi::build_program(device, kStages, xi::KernelConfig{}.defines());
  EXPECT_FALSE(other.from_cache);
  EXPECT_NE(other.cache_file, first.cache_file);
  cl::Kernel k(second.program, "extend");  // the cached binary is a working program
  EXPECT_EQ(k.getInfo<CL_KERNEL_FUNCTION_NAME>(), "extend");
}

TEST(Device, CorruptCacheEntryIsRebuilt) {
  TempEnv env;
  xi::Device device = xi::Device::open("");
  xi::Program first = xi::build_program(device, kStages, cornell_defines());
  auto size = fs::file_size(first.cache_file);
  {  // flip a byte in the middle of the payload: the checksum must catch it
    std::fstream f(first.cache_file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp((std::streamoff)(size / 2));
    char c = 0;
    f.read(&c, 1);
    f.seekp((std::streamoff)(size / 2));
    c = (char)~c;
    f.write(&c, 1);
  }
  xi::Program rebuilt = xi::build_program(device, kStages, cornell_defines());
  EXPECT_FALSE(rebuilt.from_cache);
  EXPECT_TRUE(xi::build_program(device, kStages, cornell_defines()).from_cache);  // and rewritten
  fs::resize_file(first.cache_file, 20);  // truncated
  EXPECT_FALSE(xi::build_program(device, kStages, cornell_defines()).from_cache);
}

TEST(Device, EditingAHeaderInvalidatesTheCache) {
  TempEnv env;
  fs::copy(XI_SOURCE_KERNEL_DIR, env.root / "kernels", fs::copy_options::recursive);
  setenv("XI_KERNEL_DIR", (env.root / "kernels").c_str(), 1);
  xi::Device device = xi::Device::open("");
  xi::Program a = xi::build_program(device, kStages, cornell_defines());
  std::ofstream(env.root / "kernels/shared/rng.h", std::ios::app) << "\n// edited\n";
  xi::Program b = xi::build_program(device, kStages, cornell_defines());
  EXPECT_FALSE(b.from_cache);
  EXPECT_NE(a.cache_file, b.cache_file);
}

TEST(Device, BuildErrorShowsTheLogWithFileAndLine) {
  TempEnv env;
  fs::create_directories(env.root / "kernels/shared");
  std::ofstream(env.root / "kernels/shade.cl") << "\n";  // kernel_dir() looks for shade.cl
  std::ofstream(env.root / "kernels/broken.cl") << "__kernel void k(__global int* x) {\n  x[0] = undeclared_name;\n}\n";
  setenv("XI_KERNEL_DIR", (env.root / "kernels").c_str(), 1);
  xi::Device device = xi::Device::open("");
  try {
    xi::build_program(device, {"broken.cl"}, {});
    FAIL() << "a broken kernel must not build";
  } catch (const xi::Error& e) {
    std::string what = e.what();
    EXPECT_NE(what.find("broken.cl:2"), std::string::npos) << what;  // file and line of the error
    EXPECT_NE(what.find("undeclared_name"), std::string::npos) << what;
  }
}
