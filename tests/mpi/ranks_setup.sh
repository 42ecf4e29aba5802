# The start the MPI test scripts share (sourced with their arguments PROGRAM MPIEXEC): `program`
# and `mpiexec` from them, a scratch folder as the working directory (removed on exit), one OpenMP
# thread per rank, and `mpirun` for several ranks on this machine.
set -euo pipefail
program=$(realpath "$1")
mpiexec=$2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
# The same threads per rank in every run: the convolutions split their weight-gradient sums by
# thread, so the thread count (unlike the rank count) changes the bits (docs/scaling.md).
export OMP_NUM_THREADS=1
mpirun() { "$mpiexec" --allow-run-as-root --oversubscribe "$@"; }
