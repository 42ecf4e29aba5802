#pragma once
/// @file
/// The processes one computation runs on (ranks), and a sum over them whose result does not
/// depend on how many there are.
///
/// `communicator` is the interface the pipeline and the training take; its own implementation is
/// the single process (rank 0 of 1), where every operation is a copy or nothing, so a library user
/// without MPI pays nothing. core/mpi.hpp adds `mpi_communicator` for hosts that include <mpi.h>
/// and link MPI themselves.
///
/// `ordered_sum` adds vectors ("parts", e.g. the gradients of the shards of a fine-tune step) in
/// one fixed pairwise tree over the part indices. Floating-point addition is not associative, so
/// the order of the additions decides the bits of the sum; here the order depends on the part count
/// alone, never on the rank count, and a sum over N ranks equals the sum on one process bit for bit.
/// Its communication is that of a ring all-reduce: each rank sends and receives about
/// 2 (N-1)/N of one vector (a reduce-scatter by element slices, then an all-gather).
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace anisocap {

/// The ranks of one computation and the few collective operations the pipeline and the training
/// need. Every rank must call a collective operation in the same order with matching sizes. This
/// base class is the single process (rank 0 of 1): gathers copy, the rest does nothing;
/// core/mpi.hpp's mpi_communicator overrides the operations with MPI's.
class communicator {
 public:
  virtual ~communicator() = default;
  /// This process's index, 0 to size() - 1.
  virtual int rank() const noexcept { return 0; }
  /// The number of processes.
  virtual int size() const noexcept { return 1; }
  /// True on rank 0, the rank that prints and writes files.
  bool root() const noexcept { return rank() == 0; }
  /// True when more than one process takes part.
  bool distributed() const noexcept { return size() > 1; }

  /// Every rank's `send` bytes, concatenated in rank order, into `receive` on every rank;
  /// `counts[r]` is the byte count rank r sends (the same list on every rank).
  virtual void all_gather_bytes(const void* send, void* receive, const std::vector<std::size_t>& counts) const {
    if (counts.size() != 1) throw std::invalid_argument("communicator: one byte count per rank");
    if (counts[0] > 0) std::memmove(receive, send, counts[0]);
  }
  /// Personalised exchange: rank r sends send_counts[d] bytes (consecutive in `send`, in order of
  /// d) to each rank d and receives receive_counts[s] bytes from each rank s into `receive`, in
  /// order of s.
  virtual void all_to_all_bytes(const void* send, const std::vector<std::size_t>& send_counts, void* receive,
                                const std::vector<std::size_t>& receive_counts) const {
    if (send_counts.size() != 1 || receive_counts.size() != 1 || send_counts[0] != receive_counts[0])
      throw std::invalid_argument("communicator: one byte count per rank");
    if (send_counts[0] > 0) std::memmove(receive, send, send_counts[0]);
  }
  /// Rank `root`'s `bytes` bytes at `data` into `data` on every rank.
  virtual void broadcast_bytes(void* data, std::size_t bytes, int root = 0) const {
    (void)data;
    (void)bytes;
    (void)root;
  }
  /// Returns when every rank has called it.
  virtual void barrier() const {}
  /// Ends every rank of the computation with exit status `code` after printing `message` on
  /// stderr (once, from this rank). On one process: prints and exits.
  [[noreturn]] virtual void abort(const std::string& message, int code = 1) const {
    if (!message.empty()) std::fprintf(stderr, "%s\n", message.c_str());
    std::fflush(stderr);
    std::exit(code);
  }

  /// `data` (any trivially copyable element type) from rank `root` to every rank.
  template <class T>
  void broadcast(std::span<T> data, int root = 0) const {
    broadcast_bytes(data.data(), data.size_bytes(), root);
  }
  /// Rank 0's answer of `decide()` on every rank; the other ranks do not call it. For decisions
  /// that read what rank 0 alone writes (a check-point), so that every rank takes the same path.
  template <class F>
  bool root_decides(F&& decide) const {
    int answer = root() && decide() ? 1 : 0;
    broadcast(std::span<int>(&answer, 1));
    return answer != 0;
  }
  /// Every rank's `send` concatenated in rank order into `receive` (resized); `counts[r]` is the
  /// element count of rank r.
  template <class T>
  void all_gather(std::span<const T> send, std::vector<T>& receive, const std::vector<std::size_t>& counts) const {
    if (counts.size() != std::size_t(size()) || counts[std::size_t(rank())] != send.size())
      throw std::invalid_argument("communicator::all_gather: one count per rank, this rank's its own size");
    std::size_t total = 0;
    std::vector<std::size_t> bytes;
    for (std::size_t c : counts) {
      total += c;
      bytes.push_back(c * sizeof(T));
    }
    receive.resize(total);
    all_gather_bytes(send.data(), receive.data(), bytes);
  }
};

/// The single process: the communicator pipeline and training functions use unless given another.
inline const communicator& serial_communicator() {
  static const communicator one;
  return one;
}

/// The parts [first, last) of `parts` that rank `rank` of `ranks` holds: contiguous, in rank order,
/// sizes differing by at most one.
inline std::pair<int, int> part_range(int parts, int ranks, int rank) {
  if (parts < 0 || ranks < 1 || rank < 0 || rank >= ranks) throw std::invalid_argument("part_range: impossible parts or ranks");
  return {int(std::int64_t(parts) * rank / ranks), int(std::int64_t(parts) * (rank + 1) / ranks)};
}

namespace distributed_detail {

/// The smallest power of two >= n (1 for n <= 1).
inline int padded(int n) {
  int p = 1;
  while (p < n) p *= 2;
  return p;
}

/// A node of the sum's tree: parts [lo, lo + len), len a power of two, lo a multiple of len.
using node = std::pair<int, int>;

/// The tree nodes that cover rank-held parts [first, last) of `parts`, largest first from the
/// left: every node lies inside the range (parts past the last count as absent, so a range that
/// ends at `parts` may take a node that reaches past it).
inline std::vector<node> cover(int first, int last, int parts) {
  std::vector<node> nodes;
  const int top = padded(parts);
  int lo = first;
  while (lo < last) {
    int len = 1;
    while (len < top && lo % (2 * len) == 0 && (lo + 2 * len <= last || (last == parts && lo + 2 * len <= top))) len *= 2;
    nodes.emplace_back(lo, len);
    lo += len;
  }
  return nodes;
}

/// The tree's sum over node (lo, len) of slice [begin, end) of the vectors: a node found by
/// `find` (a pointer to the node's slice, or null) is taken as it is, else its halves are added,
/// left + right, element by element; parts at or past `parts` are absent. Returns false when the
/// node holds no part.
template <class T, class Find>
bool tree_sum(int lo, int len, int parts, std::size_t n, const Find& find, std::vector<T>& out) {
  if (lo >= parts) return false;
  if (const T* v = find(lo, len)) {
    out.assign(v, v + n);
    return true;
  }
  if (len == 1) throw std::logic_error("ordered_sum: a part is held by no rank");
  std::vector<T> right;
  const bool has_left = tree_sum<T>(lo, len / 2, parts, n, find, out);
  const bool has_right = tree_sum<T>(lo + len / 2, len / 2, parts, n, find, right);
  if (!has_left) throw std::logic_error("ordered_sum: a tree node without its left half");
  if (has_right)
    for (std::size_t i = 0; i < n; ++i) out[i] = out[i] + right[i];
  return true;
}

}  // namespace distributed_detail

/// The sum of `parts` vectors of `n` elements each, added in a fixed pairwise tree over the part
/// indices (part 0 + part 1, part 2 + part 3, then those sums, ...; a part count that is not a
/// power of two leaves the last nodes with one half), into `out` (n elements) on every rank. The
/// parts are spread over the ranks as part_range says; `local` holds this rank's, one after
/// another (n elements each). The result is the same bits for every rank count, the single
/// process included. Every rank must call it with the same `parts` and `n`.
template <class T>
void ordered_sum(const communicator& comm, int parts, std::size_t n, std::span<const T> local, std::span<T> out) {
  using distributed_detail::node;
  const int ranks = comm.size(), me = comm.rank();
  // Named variables, not a structured binding: lambdas below capture them (Clang 14 cannot
  // capture structured bindings).
  const auto range = part_range(parts, ranks, me);
  const int first = range.first, last = range.second;
  if (local.size() != std::size_t(last - first) * n) throw std::invalid_argument("ordered_sum: the local parts are not n elements each");
  if (out.size() != n) throw std::invalid_argument("ordered_sum: the sum is not n elements");
  if (parts == 0) {
    std::fill(out.begin(), out.end(), T(0));
    return;
  }
  const int top = distributed_detail::padded(parts);
  // This rank's nodes, each summed from its own parts.
  const std::vector<node> mine = distributed_detail::cover(first, last, parts);
  auto local_part = [&](int lo, int len) -> const T* {
    return len == 1 && lo >= first && lo < last ? local.data() + std::size_t(lo - first) * n : nullptr;
  };
  std::vector<T> node_sums(mine.size() * n), sum;
  for (std::size_t k = 0; k < mine.size(); ++k) {
    distributed_detail::tree_sum<T>(mine[k].first, mine[k].second, parts, n, local_part, sum);
    std::copy(sum.begin(), sum.end(), node_sums.begin() + std::ptrdiff_t(k * n));
  }
  if (ranks == 1) {  // the one node is the root
    std::copy(node_sums.begin(), node_sums.end(), out.begin());
    return;
  }
  // Reduce-scatter by element slices: rank d adds, for elements [n d / N, n (d + 1) / N), every
  // rank's node sums in the tree; then the slices are gathered.
  auto slice = [&](int d) { return std::pair<std::size_t, std::size_t>(n * std::size_t(d) / std::size_t(ranks), n * std::size_t(d + 1) / std::size_t(ranks)); };
  std::vector<std::vector<node>> nodes(std::size_t(ranks), std::vector<node>{});
  for (int r = 0; r < ranks; ++r) {
    const auto [f, l] = part_range(parts, ranks, r);
    nodes[std::size_t(r)] = distributed_detail::cover(f, l, parts);
  }
  const auto [s0, s1] = slice(me);
  const std::size_t my_slice = s1 - s0;
  std::vector<T> send;
  std::vector<std::size_t> send_counts, receive_counts;
  for (int d = 0; d < ranks; ++d) {
    const auto [d0, d1] = slice(d);
    for (std::size_t k = 0; k < mine.size(); ++k)
      send.insert(send.end(), node_sums.begin() + std::ptrdiff_t(k * n + d0), node_sums.begin() + std::ptrdiff_t(k * n + d1));
    send_counts.push_back(mine.size() * (d1 - d0) * sizeof(T));
    receive_counts.push_back(nodes[std::size_t(d)].size() * my_slice * sizeof(T));
  }
  std::size_t received_elements = 0;
  for (std::size_t c : receive_counts) received_elements += c / sizeof(T);
  std::vector<T> received(received_elements);
  comm.all_to_all_bytes(send.data(), send_counts, received.data(), receive_counts);
  std::map<node, const T*> found;
  std::size_t offset = 0;
  for (int r = 0; r < ranks; ++r)
    for (const node& x : nodes[std::size_t(r)]) {
      found[x] = received.data() + offset;
      offset += my_slice;
    }
  std::vector<T> my_sum;
  if (my_slice > 0)  // (an empty slice has no elements to add, and its pointers may be null)
    distributed_detail::tree_sum<T>(0, top, parts, my_slice, [&](int lo, int len) -> const T* {
      const auto it = found.find(node(lo, len));
      return it == found.end() ? nullptr : it->second;
    }, my_sum);
  std::vector<std::size_t> counts;
  for (int d = 0; d < ranks; ++d) {
    const auto [d0, d1] = slice(d);
    counts.push_back((d1 - d0) * sizeof(T));
  }
  comm.all_gather_bytes(my_sum.data(), out.data(), counts);
}

}  // namespace anisocap
