#pragma once
/// @file
/// MPI for the communicator of core/distributed.hpp: `mpi_communicator` over an MPI communicator
/// and `mpi_session`, which initialises and finalises MPI. This header includes <mpi.h>; a host
/// that includes it links MPI itself (CMake: find_package(MPI COMPONENTS CXX), MPI::MPI_CXX).
/// Nothing else in the library includes it, so the library builds and runs without MPI.
#include <mpi.h>

#include <climits>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/core/distributed.hpp"

namespace anisocap {

/// Initialises MPI (MPI_Init_thread, threads funnelled: OpenMP threads run between MPI calls of
/// the main thread) unless it already is, and finalises it on destruction where it initialised it.
class mpi_session {
 public:
  /// `argc`, `argv`: main's, or null.
  mpi_session(int* argc = nullptr, char*** argv = nullptr) {
    int initialised = 0;
    MPI_Initialized(&initialised);
    if (!initialised) {
      int provided = 0;
      if (MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) throw std::runtime_error("MPI_Init_thread failed");
      owner_ = true;
    }
  }
  mpi_session(const mpi_session&) = delete;
  mpi_session& operator=(const mpi_session&) = delete;
  ~mpi_session() {
    int finalised = 0;
    MPI_Finalized(&finalised);
    if (owner_ && !finalised) MPI_Finalize();
  }

 private:
  bool owner_ = false;
};

/// The ranks of an MPI communicator (MPI_COMM_WORLD unless given another); MPI must be
/// initialised (mpi_session) for as long as it is used.
class mpi_communicator : public communicator {
 public:
  explicit mpi_communicator(MPI_Comm comm = MPI_COMM_WORLD) : comm_(comm) {
    MPI_Comm_rank(comm_, &rank_);
    MPI_Comm_size(comm_, &size_);
  }
  int rank() const noexcept override { return rank_; }
  int size() const noexcept override { return size_; }

  void all_gather_bytes(const void* send, void* receive, const std::vector<std::size_t>& counts) const override {
    std::vector<int> c, d;
    displacements(counts, c, d);
    check(MPI_Allgatherv(send, c[std::size_t(rank_)], MPI_BYTE, receive, c.data(), d.data(), MPI_BYTE, comm_), "MPI_Allgatherv");
  }
  void all_to_all_bytes(const void* send, const std::vector<std::size_t>& send_counts, void* receive,
                        const std::vector<std::size_t>& receive_counts) const override {
    std::vector<int> sc, sd, rc, rd;
    displacements(send_counts, sc, sd);
    displacements(receive_counts, rc, rd);
    check(MPI_Alltoallv(send, sc.data(), sd.data(), MPI_BYTE, receive, rc.data(), rd.data(), MPI_BYTE, comm_), "MPI_Alltoallv");
  }
  void broadcast_bytes(void* data, std::size_t bytes, int root = 0) const override {
    if (bytes > std::size_t(INT_MAX)) throw std::length_error("mpi_communicator: a broadcast above 2 GiB");
    check(MPI_Bcast(data, int(bytes), MPI_BYTE, root, comm_), "MPI_Bcast");
  }
  void barrier() const override { check(MPI_Barrier(comm_), "MPI_Barrier"); }
  /// Prints `message` on stderr (prefixed with this rank where there are several) and ends every
  /// rank with MPI_Abort(code).
  [[noreturn]] void abort(const std::string& message, int code = 1) const override {
    if (!message.empty()) {
      if (size_ > 1) std::fprintf(stderr, "[rank %d of %d] %s\n", rank_, size_, message.c_str());
      else std::fprintf(stderr, "%s\n", message.c_str());
    }
    std::fflush(stderr);
    MPI_Abort(comm_, code);
    std::exit(code);  // MPI_Abort does not return; this is for the compiler
  }

 private:
  static void displacements(const std::vector<std::size_t>& counts, std::vector<int>& c, std::vector<int>& d) {
    std::size_t at = 0;
    for (std::size_t n : counts) {
      if (n > std::size_t(INT_MAX) || at > std::size_t(INT_MAX)) throw std::length_error("mpi_communicator: a message above 2 GiB");
      c.push_back(int(n));
      d.push_back(int(at));
      at += n;
    }
  }
  static void check(int status, const char* what) {
    if (status != MPI_SUCCESS) throw std::runtime_error(std::string(what) + " failed");
  }
  MPI_Comm comm_;
  int rank_ = 0, size_ = 1;
};

/// True when this process was started by an MPI launcher (mpirun, mpiexec, srun with PMI/PMIx):
/// the launchers' environment variables (Open MPI, MPICH/Hydra, Slurm's PMI and PMIx).
inline bool launched_by_mpi() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "PMI_RANK", "MPI_LOCALNRANKS"})
    if (std::getenv(name)) return true;
  return false;
}

}  // namespace anisocap
