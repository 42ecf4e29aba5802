#pragma once
// The processes `anisocap capture` and the training commands run on: MPI's world where the program
// is built with MPI (ANISOCAP_WITH_MPI, CMake's ANISOCAP_MPI) and started by an MPI launcher
// (mpirun, mpiexec, srun), else this process alone. Ranks other than 0 print nothing and write no
// file; a rank that fails ends every rank with one message (docs/program.md "Over several processes").
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <exception>
#include <string>
#include <thread>

#include "anisocap/core/distributed.hpp"
#ifdef ANISOCAP_WITH_MPI
#include "anisocap/core/mpi.hpp"
#endif

namespace anisocap::commands {

namespace ranks_detail {
/// stderr as it was before program_ranks silenced a rank other than 0 (-1: not silenced).
inline int& saved_stderr() {
  static int fd = -1;
  return fd;
}
}  // namespace ranks_detail

/// The ranks of this run. The first call initialises MPI where the program runs under an MPI
/// launcher (finalised at exit), and silences stdout and stderr on ranks other than 0.
inline const communicator& program_ranks() {
#ifdef ANISOCAP_WITH_MPI
  static const communicator* ranks = []() -> const communicator* {
    if (!launched_by_mpi()) return &serial_communicator();
    static mpi_session session;
    static const mpi_communicator world;
    if (!world.root()) {
      std::fflush(stdout);
      std::fflush(stderr);
      ranks_detail::saved_stderr() = dup(2);
      if (std::freopen("/dev/null", "w", stdout) == nullptr || std::freopen("/dev/null", "w", stderr) == nullptr) {
        // keep the streams as they are: output from every rank is noisy, not wrong
      }
    }
    return &world;
  }();
  return *ranks;
#else
  return serial_communicator();
#endif
}

/// True when this run is an MPI job (even of one rank): the fine-tune then shards its steps so that
/// every rank count gives the same maps (finetune_options::shard_cells).
inline bool mpi_job() {
#ifdef ANISOCAP_WITH_MPI
  program_ranks();
  return launched_by_mpi();
#else
  return false;
#endif
}

/// Runs `work` (a command's body) on every rank. On one rank an exception goes on as it would
/// without MPI; on several, the failing rank prints "anisocap: error: ..." (rank 0 first where every
/// rank fails alike) and ends every rank with a non-zero exit (MPI_Abort), so no rank waits
/// forever and rank 0 writes nothing more.
template <class Work>
void run_on_ranks(Work&& work) {
  const communicator& ranks = program_ranks();
  if (!ranks.distributed()) {
    work();
    return;
  }
  try {
    work();
  } catch (const std::exception& e) {
    if (!ranks.root()) {
      std::this_thread::sleep_for(std::chrono::seconds(2));  // where rank 0 fails too, its abort comes first
      if (ranks_detail::saved_stderr() >= 0) dup2(ranks_detail::saved_stderr(), 2);
    }
    ranks.abort(std::string("anisocap: error: ") + e.what(), 1);
  }
}

}  // namespace anisocap::commands
