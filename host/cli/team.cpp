// Team: one process, or the ranks of an MPI job (see team.h). Without XI_WITH_MPI only the team of
// one exists.
#include "team.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#ifdef XI_WITH_MPI
#include <mpi.h>
#endif

#include "xi/error.h"

namespace xi::cli {

bool launched_by_mpi() {
#ifdef XI_WITH_MPI
  // Open MPI's mpirun, and PMI/PMIx launchers (MPICH's Hydra, Slurm's srun), set these.
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_SIZE"})
    if (std::getenv(v)) return true;
#endif
  return false;
}

Team::Team() {
  char name[256] = {};
  gethostname(name, sizeof name - 1);
  host_ = name;
#ifdef XI_WITH_MPI
  if (!launched_by_mpi()) return;
  MPI_Init(nullptr, nullptr);
  joined_ = true;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
  MPI_Comm node;  // the ranks that share this host's memory
  MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, rank_, MPI_INFO_NULL, &node);
  MPI_Comm_rank(node, &local_rank_);
  MPI_Comm_size(node, &local_size_);
  MPI_Comm_free(&node);
#endif
}

Team::~Team() {
#ifdef XI_WITH_MPI
  if (joined_) MPI_Finalize();
#endif
}

void Team::abort(int code) {
  std::fflush(stdout);
  std::fflush(stderr);
#ifdef XI_WITH_MPI
  if (joined_ && size_ > 1) MPI_Abort(MPI_COMM_WORLD, code);
#endif
  std::exit(code);
}

#ifdef XI_WITH_MPI
constexpr size_t kPiece = size_t(1) << 30;

// Messages in pieces of at most 1 GiB (MPI counts are ints); an empty message is one empty piece.
void Team::send(int to, const void* data, size_t bytes) {
  size_t at = 0;
  do {
    const size_t n = std::min(kPiece, bytes - at);
    MPI_Send(static_cast<const char*>(data) + at, (int)n, MPI_BYTE, to, 0, MPI_COMM_WORLD);
    at += n;
  } while (at < bytes);
}

void Team::receive(int from, void* data, size_t bytes) {
  size_t at = 0;
  do {
    const size_t n = std::min(kPiece, bytes - at);
    MPI_Recv(static_cast<char*>(data) + at, (int)n, MPI_BYTE, from, 0, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
    at += n;
  } while (at < bytes);
}
#else
void Team::send(int, const void*, size_t) {}
void Team::receive(int, void*, size_t) {}
#endif

std::vector<std::string> Team::gather_strings(const std::string& text) {
  if (size_ == 1) return {text};
  if (!leader()) {
    const uint64_t n = text.size();
    send(0, &n, sizeof n);
    send(0, text.data(), n);
    return {};
  }
  std::vector<std::string> all(size_);
  all[0] = text;
  for (int r = 1; r < size_; ++r) {
    uint64_t n = 0;
    receive(r, &n, sizeof n);
    all[r].resize(n);
    receive(r, all[r].data(), n);
  }
  return all;
}

void Team::agree_setup(const std::string& error) {
  if (size_ == 1) {
    if (!error.empty()) throw Error(error);
    return;
  }
  const std::vector<std::string> errors = gather_strings(error), hosts = gather_strings(host_);
  if (!max({error.empty() ? 0 : 1})[0]) return;
  if (leader()) {
    // One plain line when every rank failed alike, or when rank 0 alone failed (what it alone checks:
    // the output folder, the reference, the checkpoint); else a line per failing rank, named.
    const bool all_alike =
        std::all_of(errors.begin(), errors.end(), [&](const std::string& e) { return e == errors[0]; });
    const bool only_rank_0 =
        std::all_of(errors.begin() + 1, errors.end(), [](const std::string& e) { return e.empty(); });
    const bool plain = all_alike || only_rank_0;
    std::string text;
    for (int r = 0; r < size_; ++r)
      if (!errors[r].empty() && !(plain && r > 0))
        text += "xi: error: " + (plain ? "" : "rank " + std::to_string(r) + " of " + std::to_string(size_) + " (" +
                                                 hosts[r] + "): ") +
                errors[r] + "\n";
    std::fputs(text.c_str(), stderr);
    std::fflush(stderr);
  }
  // Rank 0 prints here, not in main: every rank exits with code 1, and mpirun ends the whole job when
  // the first does, maybe before rank 0 had printed. So no rank ends before the error is out.
  barrier();
  throw QuietExit{};
}

void Team::barrier() {
#ifdef XI_WITH_MPI
  if (size_ > 1) MPI_Barrier(MPI_COMM_WORLD);
#endif
}

std::vector<int> Team::max(std::vector<int> values) {
#ifdef XI_WITH_MPI
  if (size_ > 1) MPI_Allreduce(MPI_IN_PLACE, values.data(), (int)values.size(), MPI_INT, MPI_MAX, MPI_COMM_WORLD);
#endif
  return values;
}

int Team::min(int value) {
#ifdef XI_WITH_MPI
  if (size_ > 1) MPI_Allreduce(MPI_IN_PLACE, &value, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
#endif
  return value;
}

uint64_t Team::sum(uint64_t value) {
#ifdef XI_WITH_MPI
  if (size_ > 1) MPI_Allreduce(MPI_IN_PLACE, &value, 1, MPI_UINT64_T, MPI_SUM, MPI_COMM_WORLD);
#endif
  return value;
}

RenderState Team::scatter(const RenderState& frame, int width, int height) {
  if (size_ == 1) return frame;
  RenderState share;
  if (leader()) {
    for (int r = 1; r < size_; ++r) {
      const RenderState theirs = select_rows(frame, FilmRows{r, size_}, width, height);
      const int scalars[] = {frame.spp_done, frame.passes};
      send(r, scalars, sizeof scalars);
      send(r, &frame.seconds, sizeof frame.seconds);
      for (auto* v : film_buffers(theirs))
        send(r, v->data(), sizeof(glm::vec4) * v->size());
    }
    return select_rows(frame, rows(), width, height);
  }
  int scalars[2] = {};
  receive(0, scalars, sizeof scalars);
  receive(0, &share.seconds, sizeof share.seconds);
  share.spp_done = scalars[0];
  share.passes = scalars[1];
  for (auto* v : film_buffers(share)) {
    v->resize((size_t)width * rows().count(height));
    receive(0, v->data(), sizeof(glm::vec4) * v->size());
  }
  return share;
}

RenderState Team::gather(const RenderState& share, int width, int height) {
  if (size_ == 1) return share;
  RenderState frame;
  frame.extend_rays = sum(share.extend_rays);
  frame.shadow_rays = sum(share.shadow_rays);
  frame.nonfinite = (uint32_t)sum(share.nonfinite);
  if (!leader()) {
    for (auto* v : film_buffers(share))
      send(0, v->data(), sizeof(glm::vec4) * v->size());
    return RenderState{};
  }
  frame.spp_done = share.spp_done;
  frame.passes = share.passes;
  frame.seconds = share.seconds;
  const size_t pixels = (size_t)width * height;
  for (auto* v : film_buffers(frame)) v->resize(pixels);
  insert_rows(&frame, share, rows(), width, height);
  for (int r = 1; r < size_; ++r) {
    const FilmRows their{r, size_};
    RenderState theirs;
    for (auto* v : film_buffers(theirs)) {
      v->resize((size_t)width * their.count(height));
      receive(r, v->data(), sizeof(glm::vec4) * v->size());
    }
    insert_rows(&frame, theirs, their, width, height);
  }
  return frame;
}

Image Team::gather(const Image& share, int height) {
  if (size_ == 1) return share;
  if (!leader()) {
    send(0, share.pixels.data(), sizeof(glm::vec3) * share.pixels.size());
    return Image{};
  }
  Image frame(share.width, height);
  for (int r = 0; r < size_; ++r) {
    const FilmRows their{r, size_};
    std::vector<glm::vec3> rows_of_r((size_t)share.width * their.count(height));
    if (r == 0) rows_of_r = share.pixels;
    else receive(r, rows_of_r.data(), sizeof(glm::vec3) * rows_of_r.size());
    their.insert(rows_of_r, &frame.pixels, share.width, height);
  }
  return frame;
}

}  // namespace xi::cli
