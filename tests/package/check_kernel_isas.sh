#!/usr/bin/env bash
# The program of a dispatching build (-DANISOCAP_KERNEL_ISAS): the launcher loads the best module this
# CPU runs, --kernel-isa and ANISOCAP_KERNEL_ISA force one, a module compiled for AVX2 holds no
# AVX-512 instruction (and the launcher no AVX at all), only the BF16 module holds BF16 dot products
# and runs --network-precision bf16, each module the CPU runs captures the demo material to the
# same errors, and a request the CPU or the installation cannot serve fails with a
# message naming what there is.
#   check_kernel_isas.sh PROGRAM "ISA;ISA;..."
set -euo pipefail
program=$1
IFS=';' read -r -a built <<<"$2"
modules=$(dirname "$program")/anisocap-kernels
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

# What this CPU runs, from the kernel's flags (the launcher asks CPUID; this is an independent reading).
flags=" $(grep -m1 '^flags' /proc/cpuinfo | cut -d: -f2) "
has() { for f in "$@"; do [[ "$flags" == *" $f "* ]] || return 1; done; }
runs() {
  case $1 in
    x86-64-v4-bf16) runs x86-64-v4 && has avx512_bf16 ;;
    x86-64-v4) has avx512f avx512bw avx512cd avx512dq avx512vl avx2 fma bmi2 ;;
    x86-64-v3) has avx2 fma bmi1 bmi2 f16c movbe ;;
    x86-64-v2) has sse4_2 popcnt ssse3 ;;
    x86-64) true ;;
  esac
}
best=""
for isa in x86-64-v4-bf16 x86-64-v4 x86-64-v3 x86-64-v2 x86-64; do
  for b in "${built[@]}"; do
    if [[ $b == "$isa" ]] && runs "$isa" && [[ -z $best ]]; then best=$isa; fi
  done
done
[[ -n $best ]] || { echo "none of the modules ${built[*]} runs on this CPU: nothing to check"; exit 77; }

# The instructions in each module: AVX-512 (zmm registers) only where the instruction set has it.
if objdump --version >/dev/null 2>&1; then
  for isa in "${built[@]}"; do
    zmm=$(objdump -d --no-show-raw-insn "$modules/anisocap-$isa.so" | grep -c zmm || true)
    ymm=$(objdump -d --no-show-raw-insn "$modules/anisocap-$isa.so" | grep -c ymm || true)
    echo "anisocap-$isa.so: $zmm instructions on zmm registers, $ymm on ymm"
    case $isa in
      x86-64-v4-bf16)
        dp=$(objdump -d --no-show-raw-insn "$modules/anisocap-$isa.so" | grep -c vdpbf16ps || true)
        ((zmm > 1000 && dp > 0)) || fail "the x86-64-v4-bf16 module has no AVX-512 BF16 kernels ($zmm zmm, $dp vdpbf16ps instructions)" ;;
      x86-64-v4)
        dp=$(objdump -d --no-show-raw-insn "$modules/anisocap-$isa.so" | grep -c vdpbf16ps || true)
        ((zmm > 1000 && dp == 0)) || fail "the x86-64-v4 module is not a plain AVX-512 build ($zmm zmm, $dp vdpbf16ps instructions)" ;;
      x86-64-v3) ((zmm == 0 && ymm > 1000)) || fail "the x86-64-v3 module is not an AVX2 build ($zmm zmm, $ymm ymm instructions)" ;;
      *) ((zmm == 0 && ymm == 0)) || fail "the $isa module uses AVX registers" ;;
    esac
  done
  launcher_avx=$(objdump -d --no-show-raw-insn "$program" | grep -cE 'ymm|zmm' || true)
  ((launcher_avx == 0)) || fail "the launcher uses AVX registers ($launcher_avx instructions): it must start on any x86-64 CPU"
fi

# The default is the best module the CPU runs; --kernel-isa and the environment choose another.
"$program" --version | tee "$work/version"
grep -q "kernels: $best," "$work/version" || fail "the default module is not $best"
for isa in "${built[@]}"; do
  runs "$isa" || continue
  "$program" --kernel-isa "$isa" --version | grep -q "kernels: $isa," || fail "--kernel-isa $isa did not load it"
  "$program" --version --kernel-isa="$isa" | grep -q "kernels: $isa," || fail "--kernel-isa=$isa did not load it"
  ANISOCAP_KERNEL_ISA=$isa "$program" --version | grep -q "kernels: $isa," || fail "ANISOCAP_KERNEL_ISA=$isa did not load it"
done

# Requests that cannot be served: one message naming the modules there are, a non-zero exit.
expect_error() {  # expect_error PATTERN ARGS...
  local pattern=$1
  shift
  if "$program" "$@" >"$work/out" 2>&1; then fail "anisocap $* succeeded"; fi
  grep -q "$pattern" "$work/out" || { cat "$work/out"; fail "anisocap $*: the message lacks '$pattern'"; }
  grep -q "x86-64-v" "$work/out" || { cat "$work/out"; fail "anisocap $*: the message lists no module"; }
}
expect_error "not an instruction set" --kernel-isa avx9000 --version
for isa in x86-64-v4-bf16 x86-64-v4 x86-64-v3 x86-64-v2 x86-64; do
  [[ " ${built[*]} " == *" $isa "* ]] && continue
  expect_error "no $isa kernels" --kernel-isa "$isa" --version
  break
done

# Every module this CPU runs captures the same material to the same errors (the instruction sets
# round differently, so equal within a tolerance, not bit for bit).
export OMP_NUM_THREADS=2
declare -A loss
for isa in "${built[@]}"; do
  runs "$isa" || continue
  "$program" --kernel-isa "$isa" demo --size 64 --finetune-steps 200 --steps 100 --no-also-models -o "$work/demo-$isa" \
    >"$work/demo-$isa.log" 2>&1 || { cat "$work/demo-$isa.log"; fail "anisocap demo with the $isa kernels"; }
  loss[$isa]="$work/demo-$isa/result/report.json"
done
# The BF16 module runs the networks in bf16; a module without BF16 refuses it, naming what it lacks.
if [[ " ${built[*]} " == *" x86-64-v4-bf16 "* ]] && runs x86-64-v4-bf16; then
  "$program" --kernel-isa x86-64-v4-bf16 --version | grep -q ", bf16)" || fail "the x86-64-v4-bf16 module does not say bf16"
  "$program" --kernel-isa x86-64-v4-bf16 demo --size 64 --finetune-steps 50 --steps 20 --no-also-models --network-precision bf16 \
    -o "$work/demo-bf16" >"$work/demo-bf16.log" 2>&1 || { cat "$work/demo-bf16.log"; fail "anisocap demo --network-precision bf16"; }
fi
for isa in "${built[@]}"; do
  [[ $isa == x86-64-v4-bf16 ]] && continue
  runs "$isa" || continue
  if "$program" --kernel-isa "$isa" demo --size 64 --network-precision bf16 -o "$work/no-bf16" >"$work/no-bf16.log" 2>&1; then
    fail "the $isa module ran --network-precision bf16"
  fi
  grep -q "AVX-512 BF16" "$work/no-bf16.log" || { cat "$work/no-bf16.log"; fail "the $isa module's refusal of bf16 does not say why"; }
  break
done

# The novel-view loss within 5%; each map's error within 10% or 1e-4 (the diffuse error is ~1e-6 here).
python3 - "${loss[@]}" <<'EOF'
import json, sys
errors = [json.load(open(path))["errors"] for path in sys.argv[1:]]
for key in ["novel_view_image_loss", "diffuse", "specular", "normal", "lobes", "rotation", "fresnel"]:
    values = [e[key] for e in errors]
    spread = max(values) - min(values)
    print(f"{key}: {values}")
    allowed = 0.05 * max(values) if key == "novel_view_image_loss" else max(0.1 * max(values), 1e-4)
    if spread > allowed:
        sys.exit(f"FAIL: the modules' {key} differ by {spread:.3g} (more than {allowed:.3g})")
EOF
echo "every module this CPU runs loads on request and captures the demo material alike"
