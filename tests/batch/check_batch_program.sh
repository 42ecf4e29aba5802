#!/usr/bin/env bash
# `anisocap batch` as a user runs it: bad input refused with one message naming the file and line
# and nothing written; --list, --status and the selection of one sample; the Slurm job-array
# script run as one array task (SLURM_ARRAY_TASK_ID set, no Slurm needed) capturing exactly its
# sample, then skipping it; a failing sample's message and exit status; a batch stopped by SIGTERM.
# Usage: check_batch_program.sh ANISOCAP SBATCH_SCRIPT
set -euo pipefail
program=$1
script=$2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
export OMP_NUM_THREADS=1

fail() { echo "check_batch_program: $*" >&2; exit 1; }
# expect_refused MESSAGE ARGS...: a non-zero exit whose output contains MESSAGE.
expect_refused() {
  local message=$1
  shift
  if "$program" "$@" >out.txt 2>&1; then cat out.txt; fail "'$*' should fail"; fi
  grep -qF -- "$message" out.txt || { cat out.txt; fail "'$*' should say: $message"; }
}

for s in a b; do "$program" synthesize -o photos/$s --width 24 --height 24 --images 4 --seed 3 >/dev/null 2>&1; done
quick="--stages refine --steps 20 --no-uncertainty --no-view"
printf '# name  capture  output  capture options\na photos/a out/a %s\nb photos/b/capture.json out/b %s\n' "$quick" "$quick" >m.txt

# Bad input: one message naming the file and line, a non-zero exit, nothing written.
expect_refused "nothing.txt: no such manifest file" batch nothing.txt
printf 'a photos/a out/a\nb photos/b\n' >short.txt
expect_refused "short.txt:2: expected NAME CAPTURE OUT [capture options...], got 2 fields" batch short.txt
printf 'a photos/a out/a\n\na photos/b out/b\n' >dup.txt
expect_refused "dup.txt:3: duplicate sample name 'a' (first on line 1)" batch dup.txt
mkdir -p photos/c && cp photos/b/capture.json photos/c/
printf 'a photos/a out/a %s\nc photos/c out/c\n' "$quick" >missing.txt
expect_refused "missing.txt:2: sample 'c': $work/photos/c/" batch missing.txt
grep -qF "no such photograph (named by $work/photos/c/capture.json)" out.txt || { cat out.txt; fail "names the missing photograph"; }
[[ ! -e out ]] || fail "bad input left output: $(ls -R out)"
expect_refused "no sample named 'z' (its samples: a, b)" batch m.txt --sample z
expect_refused "--count divides the samples between tasks: give this task's --index too" batch m.txt --count 2
expect_refused "--sample and --index both choose samples" batch m.txt --sample a --index 1
expect_refused "--index 2 is out of range: the manifest has 2 samples, indices 0 to 1" batch m.txt --index 2

[[ "$("$program" batch m.txt --list)" == $'a\nb' ]] || fail "--list prints the names"
[[ "$("$program" batch m.txt --list --index 1)" == "b" ]] || fail "--list --index 1 prints b"

# The Slurm script as array task 1: captures b alone.
SLURM_ARRAY_TASK_ID=1 ANISOCAP=$program bash "$script" m.txt >task.txt 2>&1 || { cat task.txt; fail "the array task failed"; }
grep -q "\[1/1\] b: captured" task.txt || { cat task.txt; fail "task 1 captures b"; }
[[ -f out/b/report.json && -f out/b/batch.log && -f out/b/batch.json ]] || fail "b's report, log and marker"
[[ ! -e out/a && ! -e out/b/batch.lock ]] || fail "task 1 touches only b and releases its lock"
grep -q '"state": "done"' out/b/batch.json || fail "b's marker says done"
"$program" batch m.txt --status >status.txt
grep -Eq '^a +new ' status.txt && grep -Eq '^b +done ' status.txt || { cat status.txt; fail "--status: a new, b done"; }
# Again: skipped. Two tasks over the two samples (SLURM_ARRAY_TASK_COUNT): task 0 runs a.
SLURM_ARRAY_TASK_ID=1 ANISOCAP=$program bash "$script" m.txt >task.txt 2>&1
grep -q "b: skipped: done already" task.txt || { cat task.txt; fail "task 1 again skips b"; }
SLURM_ARRAY_TASK_ID=0 SLURM_ARRAY_TASK_COUNT=2 ANISOCAP=$program bash "$script" m.txt >task.txt 2>&1
grep -q "\[1/1\] a: captured" task.txt || { cat task.txt; fail "task 0 of 2 captures a"; }
"$program" batch m.txt --summary summary.json >all.txt 2>&1
grep -q "2 samples in .* 0 captured .* 2 skipped (done), 0 busy (running elsewhere), 0 failed" all.txt || { cat all.txt; fail "the summary"; }

# Options changed: captured again. A capture that fails: its message, the exit status, the others run.
printf 'a photos/a out/a %s --refine-stop 0.5\nb photos/b out/b %s --lr -1\n' "$quick" "$quick" >m.txt
if "$program" batch m.txt >fail.txt 2>&1; then cat fail.txt; fail "a failed sample gives a non-zero exit"; fi
grep -q "a: captured again: options changed" fail.txt || { cat fail.txt; fail "a is captured again"; }
grep -q "b: FAILED: the capture failed (exit status" fail.txt || { cat fail.txt; fail "b fails"; }
grep -q "see $work/out/b/batch.log: --lr: must be positive, got -1" fail.txt || { cat fail.txt; fail "b's failure quotes its log"; }
grep -q "1 captured .* 1 failed" fail.txt || { cat fail.txt; fail "the summary counts the failure"; }

# SIGTERM (Slurm's time limit, scancel): the batch stops its capture, keeps the check-point, releases
# the lock and exits with 128 + 15; the next run resumes the sample.
printf 'long photos/a out/long --stages refine --steps 100000 --refine-stop 0 --freeze 0 --no-uncertainty --no-view\n' >long.txt
"$program" batch long.txt >term.txt 2>&1 &
batch=$!
for _ in $(seq 600); do grep -q "refine step" out/long/batch.log 2>/dev/null && break; sleep 0.05; done
kill -TERM "$batch"
status=0
wait "$batch" || status=$?
((status == 143)) || { cat term.txt; fail "SIGTERM: exit status 143, got $status"; }
grep -q "long: stopped: stopped by signal 15; its check-point is kept" term.txt || { cat term.txt; fail "SIGTERM: the stop is reported"; }
[[ ! -e out/long/batch.lock && -d out/long/.checkpoint ]] || fail "SIGTERM: the lock is released and the check-point kept"
grep -q '"state": "stopped"' out/long/batch.json || fail "SIGTERM: the marker says stopped"
"$program" batch long.txt --status | grep -Eq '^long +interrupted ' || fail "SIGTERM: the sample is interrupted"
echo "check_batch_program: ok"
