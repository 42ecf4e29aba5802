#!/usr/bin/env bash
# Checks that the repository stays a product, not a lab notebook. Exits non-zero and lists every
# offender when
#
#  (a) the user's documents and the code (README.md, models/README.md, docs/, include/, examples/)
#      mention a training run by number, an issue by number, or a date. What it looks for, case
#      insensitive:
#        - "run 29", "runs 57 and 58", "Run 55", "run-18": a run number. "runs 5000 steps" and the
#          like are not run numbers: a number followed by a unit (steps, materials, threads, times,
#          images, photos, photographs, texels, seconds, minutes, hours, epochs, iterations,
#          configurations, rounds, tiles) is left alone, and so is an option such as "--runs 7";
#        - "issue 14", "issue #14";
#        - an ISO date, "2026-11-26".
#      Write what is and why instead; measurements go with the command that made them.
#  (b) a tracked file (git ls-files, as staged) is larger than 1 MB (1 000 000 bytes), other than
#      the shipped network weights listed in SHIPPED_WEIGHTS below.
#
# Runs from anywhere (it works on the repository it lives in); needs bash, GNU grep (-P) and, for
# (b), git. ctest runs it as the test `repository` (tests/CMakeLists.txt).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

SHIPPED_WEIGHTS=(
  models/compact/estimator.safetensors
  models/compact/autoencoder.safetensors
  models/also/compact/autoencoder.safetensors
)
MAX_BYTES=1000000
TEXT_PATHS=(README.md models/README.md docs include examples)
UNITS='steps?|materials?|threads?|times|images?|photos?|photographs?|texels?|seconds?|minutes?|hours?|epochs?|iterations?|configurations?|rounds?|tiles?'
PATTERN="(?<!-)\\bruns?[ -][0-9]+\\b(?![ -](?:${UNITS})\\b)|\\bissue #?[0-9]+\\b|\\b20[0-9]{2}-[01][0-9]-[0-3][0-9]\\b"

status=0

if ! echo x | grep -qP 'x' 2>/dev/null; then
  echo "check-repository: needs grep with -P (GNU grep)" >&2
  exit 2
fi

existing=()
for p in "${TEXT_PATHS[@]}"; do [[ -e "$p" ]] && existing+=("$p"); done
rc=0
matches=$(grep -rnIiP "$PATTERN" "${existing[@]}") || rc=$?
if ((rc > 1)); then
  echo "check-repository: grep failed (exit $rc)" >&2
  exit 2
fi
if ((rc == 0)); then
  count=$(printf '%s\n' "$matches" | wc -l)
  echo "check-repository: $count line(s) name a training run, an issue or a date; say what is and why instead:"
  printf '%s\n' "$matches" | sed 's/^/  /'
  status=1
fi

if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  large=()
  # Index entries "<mode> <object> <stage>\t<path>", and each object's size, in the same order.
  while IFS=$'\t' read -r size path; do
    [[ "$size" =~ ^[0-9]+$ ]] || continue  # a submodule's commit, not a file
    ((size > MAX_BYTES)) || continue
    allowed=0
    for w in "${SHIPPED_WEIGHTS[@]}"; do [[ "$path" == "$w" ]] && allowed=1; done
    ((allowed)) || large+=("$(awk -v s="$size" -v p="$path" 'BEGIN { printf "%6.1f MB  %s", s / 1e6, p }')")
  done < <(paste <(git ls-files -s | awk '{print $2}' | git cat-file --batch-check='%(objectsize)') \
                 <(git ls-files -s | cut -f2-))
  if ((${#large[@]})); then
    echo "check-repository: ${#large[@]} tracked file(s) above 1 MB that are not shipped weights:"
    printf '  %s\n' "${large[@]}"
    status=1
  fi
else
  echo "check-repository: not a git checkout; the tracked-file size check is skipped"
fi

if ((status == 0)); then echo "check-repository: passed"; fi
exit "$status"
