// `mpirun -np N xi render`: the ranks split the frame's rows and rank 0 writes the image, which
// must be bitwise the one-process render whatever N is, however the render stops (a signal to any
// rank, the time budget) and whatever number of processes resumes its checkpoint. Setup errors on
// any rank end the job with one error line and no file; a rank that dies ends the job, no file.
// Frames are tiny: each mpirun costs most of a second to start on its own.
#include <gtest/gtest.h>

#include <signal.h>

#include <optional>
#include <regex>
#include <thread>

#include "cli_test.h"
#include "xi/image.h"

using namespace xi_test;

namespace {

class MpiRender : public CliTest {
 protected:
  void SetUp() override {
    CliTest::SetUp();
    if (std::string(XI_MPIEXEC).empty())
      GTEST_SKIP() << "xi was built without MPI (XI_WITH_MPI off or no MPI found): install Open MPI and rebuild";
  }

  // The lines of stderr that are xi's errors (mpirun adds its own text about the job's end).
  static std::vector<std::string> error_lines(const std::string& err) {
    std::vector<std::string> lines;
    std::istringstream in(err);
    for (std::string line; std::getline(in, line);)
      if (line.rfind("xi: error: ", 0) == 0) lines.push_back(line);
    return lines;
  }

  // A setup error: exit code 1, one error line holding every needle, nothing rendered or written.
  void expect_setup_error(const Outcome& r, const std::vector<std::string>& needles) {
    EXPECT_EQ(r.code, 1) << r.err;
    const std::vector<std::string> lines = error_lines(r.err);
    ASSERT_EQ(lines.size(), 1u) << r.err;
    for (const auto& n : needles) EXPECT_NE(lines[0].find(n), std::string::npos) << "'" << n << "' not in: " << r.err;
    EXPECT_EQ(r.out.find("wrote"), std::string::npos) << r.out;
    EXPECT_EQ(files(), std::set<std::string>{}) << "the failed job left files behind";
  }

  double attr_double(const std::string& exr, const std::string& name) {
    return std::get<double>(xi::read_exr_attributes(work_ / exr).at(name));
  }

  // Starts `args` on 2 ranks, waits until the file `ready` shows that passes are done (mpirun may
  // hold rank 0's stdout back until the job ends), sends `sig` to rank 1 alone and waits for the
  // job; nothing if it did not start or has no rank 1 (a failure already recorded).
  std::optional<Outcome> signal_rank_1(const std::vector<std::string>& args, const std::string& ready, int sig) {
    const pid_t pid = start_mpi(2, args);
    const bool started = wait_for(ready);
    const pid_t rank1 = rank_pid(pid, 1);
    EXPECT_TRUE(started);
    EXPECT_NE(rank1, 0) << "no rank 1 below mpirun " << pid;
    const bool signalled = started && rank1 > 0;
    if (signalled) kill(rank1, sig);
    const Outcome r = wait_xi(pid, signalled ? 60.0 : 0.0);
    if (!signalled) return std::nullopt;
    return r;
  }
};

// Many 1-spp passes of a tiny frame: a render that a signal or the time budget cuts short.
const std::vector<std::string> kLong = {"render", kCornell.string(), "--resolution", "16x16", "--samples-per-pass",
                                        "1",      "--seed",          "3",            "--quiet"};

}  // namespace

TEST_F(MpiRender, AnyNumberOfProcessesGivesTheOneProcessImage) {
  // An odd size, so that 2 and 3 processes get shares of different heights; glass for caustics.
  for (const char* scene : {"cornell-box.json", "caustics.json"}) {
    SCOPED_TRACE(scene);
    const std::vector<std::string> base = {"render", (fs::path(XI_SCENE_DIR) / scene).string(), "--resolution", "33x21",
                                           "--spp", "8", "--seed", "5"};
    const Outcome one = run_xi(concat(base, {"-o", "one.exr", "--quiet"}));
    ASSERT_EQ(one.code, 0) << one.err;
    struct Case {
      int processes;
      std::vector<std::string> flags;
    };
    // Passes of every spp (default), of 3 (the last one short) and of 1.
    const std::vector<Case> cases = {{1, {}}, {2, {}}, {3, {}}, {2, {"--samples-per-pass", "3"}},
                                     {3, {"--samples-per-pass", "1"}}};
    for (const Case& c : cases) {
      const std::string out = "mpi" + std::to_string(c.processes) + "_" + std::to_string(c.flags.size()) + ".exr";
      SCOPED_TRACE(out);
      const Outcome r = run_mpi(c.processes, concat(concat(base, c.flags), {"-o", out}));
      ASSERT_EQ(r.code, 0) << r.out << r.err;
      expect_same_image(out, "one.exr");
      EXPECT_EQ(attr_int(out, "spp"), 8);
      const auto attrs = xi::read_exr_attributes(work_ / out);
      EXPECT_EQ(attrs.count("sppTarget"), 0u);
      if (c.processes == 1) {
        EXPECT_EQ(attrs.count("processes"), 0u);
        EXPECT_EQ(r.out.find("processes"), std::string::npos) << r.out;
      } else {
        EXPECT_EQ(attr_int(out, "processes"), c.processes);
        EXPECT_NE(r.out.find("processes: " + std::to_string(c.processes) + ", each rendering every"), std::string::npos)
            << r.out;
        EXPECT_NE(r.out.find("8 spp"), std::string::npos) << r.out;
        EXPECT_NE(r.out.find(", " + std::to_string(c.processes) + " processes\n"), std::string::npos) << r.out;
      }
    }
  }
}

// Adaptive sampling across ranks: each rank stops its own pixels by their own sums, so the job's
// image and its spp layer are the one process's bit for bit, though one rank's pixels may all stop
// before the other's (its passes then do nothing until the job is done); snapshots and the error
// against a reference, which every rank takes part in, go on until all are done.
TEST_F(MpiRender, AdaptiveSamplingIsTheOneProcessImage) {
  const std::vector<std::string> base = {"render", "--resolution", "24x16", "--spp", "64", "--noise-threshold",
                                         "0.15", "--min-spp", "8", "--seed", "4", "--quiet", "--samples-per-pass", "4"};
  ASSERT_EQ(run_xi(concat(base, {"-o", "one.exr"})).code, 0);
  const Outcome r = run_mpi(3, concat(base, {"-o", "three.exr", "--snapshot-every", "2", "--reference", "one.exr",
                                             "--convergence", "three.csv"}));
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  expect_same_image("three.exr", "one.exr");
  const xi::Image a = xi::read_exr(work_ / "three.exr", "spp"), b = xi::read_exr(work_ / "one.exr", "spp");
  EXPECT_EQ(std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(glm::vec3)), 0);
}

// Ranks on one host share its cores: each rank's PoCL gets cores / ranks threads, and so does its
// BVH build (forking to about four subtrees per core: fewer than 8 × share threads; one for one core).
TEST_F(MpiRender, RanksShareTheCoresOfTheBvhBuild) {
  write_grid_scene("grid.json");
  const std::vector<std::string> base = {"render", "grid.json", "--spp", "1", "--resolution", "16x16"};
  const Outcome r = run_mpi(2, concat(base, {"-o", "two.exr"}));
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  const long share = std::max(1u, std::thread::hardware_concurrency() / 2), threads = build_threads(r.out);
  ASSERT_GE(threads, 1) << r.out;
  EXPECT_LT(threads, 8 * share) << r.out;
  if (share == 1) EXPECT_EQ(threads, 1) << r.out;
  ASSERT_EQ(run_xi(concat(base, {"-o", "one.exr", "--quiet"})).code, 0);
  expect_same_image("two.exr", "one.exr");
}

TEST_F(MpiRender, ConvergenceLogIsTheOneProcessLog) {
  // Every rank takes part in measuring the error (the mean image is gathered each pass), although
  // rank 0 alone reads the reference: the job once waited forever here.
  const std::vector<std::string> base = {"render", kCornell.string(), "--resolution", "33x21", "--spp", "4",
                                         "--seed", "2", "--quiet"};
  ASSERT_EQ(run_xi(concat(base, {"--spp", "2", "-o", "ref.exr"})).code, 0);  // any image of the size
  const std::vector<std::string> measured = concat(base, {"--reference", "ref.exr", "--convergence"});
  ASSERT_EQ(run_xi(concat(measured, {"one.csv", "-o", "one.exr"})).code, 0);
  const Outcome r = run_mpi(2, concat(measured, {"two.csv", "-o", "two.exr"}), 60.0);
  ASSERT_EQ(r.code, 0) << r.err;
  expect_same_image("two.exr", "one.exr");
  // The logs without their seconds column: one row per pass, the same errors.
  auto without_seconds = [&](const std::string& name) {
    std::istringstream in(read_text(work_ / name));
    std::string text;
    for (std::string line; std::getline(in, line);) {
      const size_t a = line.find(',', line.find(',') + 1), b = line.find(',', a + 1);
      text += line.substr(0, a) + line.substr(b) + "\n";
    }
    return text;
  };
  const std::string two_log = without_seconds("two.csv");
  EXPECT_EQ(std::count(two_log.begin(), two_log.end(), '\n'), 5) << two_log;  // a header, 4 passes
  EXPECT_EQ(two_log, without_seconds("one.csv"));
  const auto one = xi::read_exr_attributes(work_ / "one.exr"), two = xi::read_exr_attributes(work_ / "two.exr");
  ASSERT_EQ(one.count("error.rmse"), 1u);
  EXPECT_EQ(two.count("error.rmse"), 1u);
  for (const auto& [name, value] : one)
    if (name.rfind("error.", 0) == 0) EXPECT_TRUE(two.count(name) && two.at(name) == value) << name;
}

TEST_F(MpiRender, MoreProcessesThanRowsIsAnError) {
  const Outcome r = run_mpi(3, {"render", kCornell.string(), "--spp", "4", "--resolution", "8x2", "-o", "e.exr"});
  // Every rank fails alike: one line, naming no rank.
  expect_setup_error(r, {"3 processes but the frame has 2 rows", "use at most 2"});
  EXPECT_EQ(r.err.find("rank "), std::string::npos) << r.err;
}

TEST_F(MpiRender, WhatRankZeroAloneChecksIsOnePlainLine) {
  // Rank 0 alone reads the checkpoint and writes the files: its errors are the job's, unnamed.
  for (const std::vector<std::string>& flags :
       {std::vector<std::string>{"--resume", "missing.ckpt", "-o", "e.exr"}, {"-o", "no-such-folder/e.exr"}}) {
    const Outcome r =
        run_mpi(2, concat({"render", kCornell.string(), "--spp", "4", "--resolution", "8x8"}, flags));
    expect_setup_error(r, {flags[0] == "--resume" ? "no such checkpoint" : "output folder does not exist"});
    EXPECT_EQ(r.err.find("rank "), std::string::npos) << r.err;
  }
}

TEST_F(MpiRender, AnUnusableDeviceOnOneRankIsNamed) {
  // A comma list gives local rank i item i: rank 0 gets device 0, rank 1 device 99.
  const Outcome r =
      run_mpi(2, {"render", kCornell.string(), "--spp", "4", "--resolution", "8x8", "--device", "0,99", "-o", "e.exr"});
  expect_setup_error(r, {"xi: error: rank 1 of 2 (", "'99'"});
  EXPECT_EQ(r.err.find("rank 0 of"), std::string::npos) << r.err;
}

TEST_F(MpiRender, SignalToAnotherRankStopsAllAndRankZeroWritesThePassesDone) {
  // A snapshot after every pass tells the test that passes are done (a signal before the first
  // one would leave no image).
  const std::optional<Outcome> job =
      signal_rank_1(concat(kLong, {"--spp", "100000", "-o", "cut.exr", "--snapshot-every", "1"}), "cut.exr", SIGTERM);
  ASSERT_TRUE(job);
  const Outcome& r = *job;
  EXPECT_EQ(r.code, 143) << r.err;  // 128 + SIGTERM, rank 0's code although rank 1 was signalled
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.err, m, std::regex("xi: stopped by SIGTERM after pass (\\d+): (\\d+) of 100000 spp")))
      << r.err;
  const int spp = std::stoi(m[2]);
  EXPECT_GE(spp, 1);
  EXPECT_LT(spp, 100000);
  EXPECT_EQ(attr_int("cut.exr", "spp"), spp);
  EXPECT_EQ(attr_int("cut.exr", "sppTarget"), 100000);
  EXPECT_EQ(attr_int("cut.exr", "processes"), 2);
  EXPECT_EQ(files(), (std::set<std::string>{"cut.exr", "cut.png"}));  // no temporary file
  ASSERT_EQ(run_xi(concat(kLong, {"--spp", std::to_string(spp), "-o", "straight.exr"})).code, 0);
  expect_same_image("cut.exr", "straight.exr");
}

TEST_F(MpiRender, TimeBudgetOnRankZerosClockStopsAll) {
  const Outcome r = run_mpi(2, concat(kLong, {"--spp", "100000", "--time", "1", "-o", "out.exr"}));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("xi: stopped by the time budget after pass"), std::string::npos) << r.err;
  const int spp = attr_int("out.exr", "spp");
  EXPECT_GE(spp, 1);
  EXPECT_LT(spp, 100000);
  EXPECT_EQ(attr_int("out.exr", "sppTarget"), 100000);
  EXPECT_GE(attr_double("out.exr", "renderSeconds"), 1.0);  // it stops after the pass that crosses it
  EXPECT_LT(attr_double("out.exr", "renderSeconds"), 30.0);
  ASSERT_EQ(run_xi(concat(kLong, {"--spp", std::to_string(spp), "-o", "straight.exr"})).code, 0);
  expect_same_image("out.exr", "straight.exr");
}

TEST_F(MpiRender, CheckpointResumesWithAnyNumberOfProcesses) {
  const std::vector<std::string> base = {"render", kCornell.string(), "--resolution", "33x21", "--spp", "12",
                                         "--seed", "7",               "--quiet"};
  ASSERT_EQ(run_xi(concat(base, {"-o", "straight.exr"})).code, 0);
  // A budget shorter than any pass: exactly one pass of 2 spp, then the whole frame's checkpoint.
  Outcome r = run_mpi(2, concat(base, {"--samples-per-pass", "2", "--time", "1e-9", "--checkpoint", "ck.bin", "-o",
                                       "cut.exr"}));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(attr_int("cut.exr", "spp"), 2);
  EXPECT_EQ(attr_int("cut.exr", "sppTarget"), 12);
  ASSERT_TRUE(fs::exists(work_ / "ck.bin"));
  fs::copy_file(work_ / "ck.bin", work_ / "ck3.bin");
  fs::copy_file(work_ / "ck.bin", work_ / "ck1.bin");

  // Resumed to the end by 3 processes, and by one (passes of another size: the image does not
  // depend on them); each removes its checkpoint once the image holds the result.
  r = run_mpi(3, concat(base, {"--samples-per-pass", "3", "--resume", "ck3.bin", "-o", "resumed3.exr"}));
  ASSERT_EQ(r.code, 0) << r.err;
  expect_same_image("resumed3.exr", "straight.exr");
  EXPECT_EQ(attr_int("resumed3.exr", "spp"), 12);
  EXPECT_FALSE(fs::exists(work_ / "ck3.bin"));
  // One process resumes `checkpoint` to the end: the straight render's image, the checkpoint gone.
  auto finish_alone = [&](const std::string& checkpoint, const std::string& out) {
    const Outcome done = run_xi(concat(base, {"--resume", checkpoint, "-o", out}));
    ASSERT_EQ(done.code, 0) << done.err;
    expect_same_image(out, "straight.exr");
    EXPECT_FALSE(fs::exists(work_ / checkpoint));
  };
  finish_alone("ck1.bin", "resumed1.exr");

  // 2 processes, then 3 for one more pass, then one to the end.
  r = run_mpi(3, concat(base, {"--samples-per-pass", "2", "--time", "1e-9", "--resume", "ck.bin", "-o", "cut.exr"}));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(attr_int("cut.exr", "spp"), 4);
  ASSERT_TRUE(fs::exists(work_ / "ck.bin"));
  finish_alone("ck.bin", "chained.exr");
}

TEST_F(MpiRender, KilledRankEndsTheJobWithoutAnImage) {
  // A checkpoint every 0.5 s tells the test that passes are done (mpirun may hold rank 0's stdout
  // back until the job ends, so its setup lines cannot) and leaves the state of a finished pass.
  const std::vector<std::string> args =
      concat(kLong, {"--spp", "100000", "-o", "out.exr", "--checkpoint", "ck.bin", "--checkpoint-every", "0.5"});
  const std::optional<Outcome> job = signal_rank_1(args, "ck.bin", SIGKILL);
  ASSERT_TRUE(job);
  const Outcome& r = *job;
  EXPECT_NE(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("xi: stopped by"), std::string::npos) << r.err;
  // No image, no temporary file: the job ended mid-render. The last checkpoint is whole: one
  // process resumes it for one more pass, and that is the one-process render of its spp.
  ASSERT_EQ(files(), std::set<std::string>{"ck.bin"}) << r.err;
  const Outcome resumed = run_xi(concat(args, {"--resume", "ck.bin", "--time", "1e-9", "-o", "resumed.exr"}));
  ASSERT_EQ(resumed.code, 0) << resumed.err;
  const int spp = attr_int("resumed.exr", "spp");
  EXPECT_GE(spp, 2);
  ASSERT_EQ(run_xi(concat(kLong, {"--spp", std::to_string(spp), "-o", "straight.exr"})).code, 0);
  expect_same_image("resumed.exr", "straight.exr");
}
