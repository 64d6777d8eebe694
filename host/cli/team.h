// The processes that make one render: this process alone, or the ranks of an MPI job started by
// `mpirun -np N xi render ...`. Rank r renders the frame's rows r, r + N, r + 2N, ... (FilmRows), so
// each pixel is one process's, its samples summed in sample order as in a one-process render, and
// the image rank 0 puts together is bitwise the one-process image whatever N is. Everything here
// is collective: every rank calls it, in the same order.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "xi/renderer.h"

namespace xi::cli {

class Team {
 public:
  // Joins the MPI job when the process was started by an MPI launcher (and xi was built with MPI),
  // else a team of one. Leaves the job on destruction.
  Team();
  ~Team();
  Team(const Team&) = delete;
  Team& operator=(const Team&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }
  int local_rank() const { return local_rank_; }  // among the ranks on this host
  int local_size() const { return local_size_; }
  bool leader() const { return rank_ == 0; }
  std::string host() const { return host_; }
  FilmRows rows() const { return FilmRows{rank_, size_}; }

  // Setup is checked by all together: each rank gives its error ("" if none); if any rank failed,
  // rank 0 prints the error, naming each failing rank (one line if all failed alike), and every rank
  // throws QuietExit once it is printed. A team of one throws the xi::Error itself.
  void agree_setup(const std::string& error);
  struct QuietExit {};

  // Waits for every rank.
  void barrier();
  // Every rank's text, on rank 0 (others: an empty list).
  std::vector<std::string> gather_strings(const std::string& text);
  // The largest of each element over the ranks (stop requests, flags).
  std::vector<int> max(std::vector<int> values);
  int min(int value);
  uint64_t sum(uint64_t value);
  // The whole frame's state on rank 0 from every rank's share of rows (counters summed, spp and
  // passes rank 0's); other ranks get an empty state.
  RenderState gather(const RenderState& share, int width, int height);
  // Each rank's share of rows of the whole frame's state held by rank 0 (a checkpoint it read);
  // the counters stay with rank 0, so that gathering sums them back.
  RenderState scatter(const RenderState& frame, int width, int height);
  // The whole frame's mean image on rank 0 (others: an empty image).
  Image gather(const Image& share, int height);

  // Ends the job from a rank that cannot go on (after printing why): MPI_Abort, exit code `code`.
  [[noreturn]] void abort(int code);

 private:
  void send(int to, const void* data, size_t bytes);
  void receive(int from, void* data, size_t bytes);

  int rank_ = 0, size_ = 1, local_rank_ = 0, local_size_ = 1;
  bool joined_ = false;
  std::string host_;
};

// Whether xi was built with MPI (XI_WITH_MPI) and this process was started by an MPI launcher.
bool launched_by_mpi();

}  // namespace xi::cli
