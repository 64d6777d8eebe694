// Assimp's corpus of invalid model files (Debian's assimp-testmodels, models/invalid/) through
// `xi render`, each file as the one mesh of a tiny scene: a file the library refuses must fail as a
// user error (exit code 1, one line naming the file, no output written) without exhausting memory;
// a file the library reads (malformed2.obj only names a missing material, which xi ignores) renders.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "cli_test.h"
#include "xi/error.h"
#include "xi/scene.h"

using namespace xi_test;

namespace {

class CliInvalidMeshes : public CliTest {};

TEST_F(CliInvalidMeshes, EveryCorpusFileEndsInOneErrorOrAnImage) {
  const fs::path dir = XI_ASSIMP_INVALID_DIR;
  std::vector<fs::path> corpus;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec))
    if (e.is_regular_file()) corpus.push_back(e.path());
  std::sort(corpus.begin(), corpus.end());
  const fs::path oom = dir / "OutOfMemory.off";
  ASSERT_TRUE(std::count(corpus.begin(), corpus.end(), oom)) << oom << " is missing: scripts/install-deps.sh installs assimp-testmodels";

  std::vector<std::string> refused;
  for (const fs::path& file : corpus) {
    SCOPED_TRACE(file.string());
    const json scene = {{"camera", {{"position", {0, 0, -5}}, {"look_at", {0, 0, 0}}, {"up", {0, 1, 0}}, {"fov", 40}}},
                        {"materials", {{"white", {{"type", "diffuse"}, {"albedo", {0.5, 0.5, 0.5}}}}}},
                        {"shapes", {{{"type", "mesh"}, {"material", "white"}, {"file", file.string()}}}}};
    write_text(work_ / "scene.json", scene.dump(2));
    bool loads = true;  // the library's verdict, which the program must report the same way
    try {
      xi::load_scene(work_ / "scene.json");
    } catch (const xi::Error&) {
      loads = false;
    }
    const auto before = files();
    const Outcome r = run_xi({"render", "scene.json", "-o", "out.exr", "--spp", "1", "--resolution", "8x8", "--quiet"});
    if (loads) {
      EXPECT_EQ(r.code, 0) << r.err;
      EXPECT_TRUE(fs::is_regular_file(work_ / "out.exr"));
      fs::remove(work_ / "out.exr");
      fs::remove(work_ / "out.png");
    } else {
      expect_user_error(r, {file.string()}, before);
      refused.push_back(file.filename().string());
    }
  }
  // The file that used to exhaust memory is refused from its header.
  EXPECT_TRUE(std::count(refused.begin(), refused.end(), "OutOfMemory.off"));
  EXPECT_GE(refused.size(), corpus.size() / 2) << "most of an invalid corpus must be refused";
}

}  // namespace
