#!/usr/bin/env bash
# A batch of three small samples through GNU parallel, one of them killed mid-way (its batch
# process, with SIGKILL, during the fine-tune: the capture dies with it and the lock is left), then
# the same batch again: the killed sample takes over the stale lock, resumes from the estimate's
# check-point and finishes, the finished ones are skipped, and the resumed sample's maps equal an
# uninterrupted capture's bit for bit (the capture's resume is exact).
# Usage: check_batch_parallel.sh ANISOCAP PARALLEL MODELS_FOLDER
set -euo pipefail
program=$1
parallel=$2
models=$3
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
export OMP_NUM_THREADS=1  # two jobs at a time, one thread each

fail() { echo "check_batch_parallel: $*" >&2; exit 1; }
start=$SECONDS

for i in 1 2 3; do "$program" synthesize -o photos/s$i --width 64 --height 64 --images 6 --seed $i >/dev/null 2>&1; done
options="--models $models --finetune-steps 150 --steps 50 --no-also-residual --no-also-models --no-uncertainty --no-view"
for i in 1 2 3; do echo "s$i photos/s$i out/s$i $options"; done >samples.txt

# First run: s2's batch process is killed once its capture is in the fine-tune.
"$program" batch samples.txt --list | "$parallel" --will-cite -j2 "'$program'" batch samples.txt --sample {} '>' run1-{}.txt '2>&1' &
runner=$!
killed=
for _ in $(seq 1200); do
  if [[ -f out/s2/batch.log ]] && grep -q "finetune step" out/s2/batch.log && [[ -f out/s2/batch.lock ]]; then
    pid=$(sed -n 's/.*pid=\([0-9]*\).*/\1/p' out/s2/batch.lock)
    kill -KILL "$pid" && killed=$pid
    break
  fi
  sleep 0.05
done
status=0
wait "$runner" || status=$?
[[ -n "$killed" ]] || fail "s2 never reached the fine-tune"
((status == 1)) || { cat run1-*.txt; fail "GNU parallel should report one failed job, got exit status $status"; }
[[ -f out/s1/report.json && -f out/s3/report.json ]] || { cat run1-*.txt; fail "s1 and s3 finish"; }
[[ ! -f out/s2/report.json ]] || fail "s2 was killed before it finished"
[[ -f out/s2/batch.lock && -d out/s2/.checkpoint/estimate ]] || fail "the killed s2 leaves its lock and the estimate's check-point"
sleep 0.5
if pgrep -f "out/s2 " >/dev/null; then fail "s2's capture outlived its killed batch"; fi
echo "check_batch_parallel: first run (s2 killed) in $((SECONDS - start)) s"

# Again, the same way: s1 and s3 skipped, s2 resumed.
rerun=$SECONDS
"$program" batch samples.txt --list | "$parallel" --will-cite -j2 "'$program'" batch samples.txt --sample {} '>' run2-{}.txt '2>&1' ||
  { cat run2-*.txt out/s2/batch.log; fail "the second run fails"; }
for s in s1 s3; do grep -q "$s: skipped: done already" run2-$s.txt || { cat run2-$s.txt; fail "$s is skipped"; }; done
grep -q "s2: took over the stale lock of host .* pid $killed (that process is gone)" run2-s2.txt || { cat run2-s2.txt; fail "s2 takes over the lock"; }
grep -q "s2: resuming from .*out/s2/.checkpoint" run2-s2.txt || { cat run2-s2.txt; fail "s2 resumes"; }
grep -q "s2: captured in .* s, resumed" run2-s2.txt || { cat run2-s2.txt; fail "s2 finishes"; }
grep -q '"resumed": true' out/s2/report.json || fail "s2's report says the estimate was resumed"
grep -q '"state": "done"' out/s2/batch.json || fail "s2's marker says done"
[[ ! -e out/s2/batch.lock && ! -e out/s2/.checkpoint ]] || fail "s2 leaves no lock or check-point"
[[ $(grep -c "^== batch: sample s2 .*: $program capture" out/s2/batch.log) == 2 ]] || fail "s2's log holds both attempts"
echo "check_batch_parallel: second run (s2 resumed, s1 and s3 skipped) in $((SECONDS - rerun)) s"

# The whole batch once more in one process: nothing to do.
skip=$SECONDS
"$program" batch samples.txt >run3.txt 2>&1 || { cat run3.txt; fail "the third run fails"; }
grep -q "3 samples in .* 0 captured (0 resumed; 0.0 s capturing), 3 skipped (done)" run3.txt || { cat run3.txt; fail "the third run skips all"; }
echo "check_batch_parallel: third run (all skipped) in $((SECONDS - skip)) s"

# The resumed maps equal an uninterrupted capture's.
"$program" capture photos/s2/capture.json -o reference $options >reference.txt 2>&1 || { cat reference.txt; fail "the reference capture"; }
for f in diffuse specular normal lobes rotation fresnel; do
  cmp -s reference/$f.exr out/s2/$f.exr || fail "s2's $f.exr differs from an uninterrupted capture's"
done
echo "check_batch_parallel: ok in $((SECONDS - start)) s"
