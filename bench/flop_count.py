#!/usr/bin/env python3
"""Executed floating-point operations per evaluation of a function, from a callgrind profile.

Usage: flop_count.py BINARY CALLGRIND_OUT FUNCTION_SUBSTRING EVALUATIONS_PER_CALL

The profile must come from `valgrind --tool=callgrind --dump-instr=yes --compress-pos=no
--compress-strings=no --toggle-collect='*FUNCTION_SUBSTRING*'` (valgrind does not run AVX-512:
profile an x86-64-v3 build), so that it holds only the function and what it calls. Every executed
instruction in the profile is classified from `objdump -d`:
FMA counts 2 operations per lane, add/sub/mul/div/sqrt/min/max/reciprocal estimates 1 per lane
(xmm: 4 float lanes, ymm: 8, scalar ss: 1); compares, blends, logic and integer ops are counted
apart. EVALUATIONS_PER_CALL: texel-image evaluations per call of the function (calls are counted as the
calls of the function's OpenMP outlined body, which runs once per call on one thread).
"""
import collections
import re
import subprocess
import sys

binary, profile, needle, per_call = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])

# Executed count per instruction address inside the matching functions.
counts = collections.Counter()
calls_into = 0
fn = ''
skip_next = False
pending_call_target = None
fields = 1  # position columns before the cost: 'instr' or 'instr line'
with open(profile) as f:
    for line in f:
        line = line.rstrip('\n')
        if line.startswith('positions:'):
            fields = len(line.split()) - 1
            continue
        if line.startswith('fn='):
            fn = line[3:]
            continue
        if line.startswith('cfn='):
            pending_call_target = line[4:]
            continue
        if line.startswith('calls='):
            if pending_call_target and needle in pending_call_target and '_omp_fn' in pending_call_target \
                    and needle not in fn:
                calls_into += int(line.split('=')[1].split()[0])
            skip_next = True
            continue
        if skip_next:
            skip_next = False
            continue
        if line.startswith('0x'):
            parts = line.split()
            counts[int(parts[0], 16)] += int(parts[fields])

dis = subprocess.run(['objdump', '-d', '--no-show-raw-insn', '-M', 'att', binary], capture_output=True, text=True).stdout
insn = {}
for line in dis.splitlines():
    m = re.match(r'\s*([0-9a-f]+):\s+(\S+)\s*(.*)', line)
    if m:
        insn[int(m.group(1), 16)] = (m.group(2), m.group(3))

flops = collections.Counter()
other = collections.Counter()
total_insn = 0
for addr, n in counts.items():
    total_insn += n
    mnem, ops = insn.get(addr, ('?', ''))
    lanes = 8 if '%ymm' in ops else 16 if '%zmm' in ops else 4
    if mnem.endswith('ss'):
        lanes = 1
    base = re.sub(r'(ps|ss)$', '', mnem)
    if not (mnem.endswith('ps') or mnem.endswith('ss')):
        other['non-float'] += n
        continue
    if re.match(r'vf(n?)m(add|sub)', base):
        flops['fma'] += 2 * lanes * n
    elif base in ('vadd', 'vsub', 'vmul', 'vdiv', 'vsqrt', 'vmin', 'vmax', 'vrcp', 'vrsqrt'):
        flops[base[1:]] += lanes * n
    else:
        other[mnem] += n

evals = calls_into * per_call
total = sum(flops.values())
print(f'calls {calls_into}, evaluations {evals:.0f}, instructions/eval {total_insn / evals:.2f}')
print(f'floating-point operations/eval {total / evals:.2f}: ' +
      ', '.join(f'{k} {v / evals:.2f}' for k, v in flops.most_common()))
print('other instructions/eval: ' + ', '.join(f'{k} {v / evals:.2f}' for k, v in other.most_common(8)))
