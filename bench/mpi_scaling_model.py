#!/usr/bin/env python3
"""Strong scaling of the fine-tune of one capture over nodes, modelled (docs/scaling.md).

Per step, each of n nodes computes its share of the step's shards, then the ranks add the
decoder's gradient (ordered_sum: a reduce-scatter and an all-gather, the volume of a ring
all-reduce):

  compute(n) = ceil(shards / n) * core-seconds per shard / cores per node
  comm(n)    = 2 (n - 1) / n * 4 * params / bandwidth + 2 (n - 1) * latency

Inputs (arguments, with the measured defaults of docs/scaling.md):
  --step      seconds of one sharded fine-tune step of SIZE_MEASURED^2 texels on CORES_MEASURED cores
  --size      side of the modelled capture in texels (4096)
  --shard     shard side in latent cells (16; 32 texels a cell)
  --params    decoder parameters (694636 for the compact preset), 4 bytes each per all-reduce
  --latency   seconds per message of the network (10 Gbit/s Ethernet: 30e-6; 100 Gbit/s: 3e-6)
Compute is taken to scale with texels and with cores (16 a node) from the measurement, and a node
runs one rank with 16 threads; a node holds whole shards, so beyond one shard per node more nodes
do not help.
"""
import argparse
import math

p = argparse.ArgumentParser()
p.add_argument("--step", type=float, required=True, help="seconds per sharded step of the measured capture")
p.add_argument("--size-measured", type=int, default=1024)
p.add_argument("--cores-measured", type=int, default=2)
p.add_argument("--size", type=int, default=4096)
p.add_argument("--shard", type=int, default=16)
p.add_argument("--params", type=int, default=694636)
p.add_argument("--cores", type=int, default=16)
a = p.parse_args()

cell = 32
shards = math.ceil(a.size / cell / a.shard) ** 2
# Core-seconds per shard of the modelled capture, from the measurement (texels and cores scale it).
shard_core_seconds = a.step * a.cores_measured * (a.size / a.size_measured) ** 2 / shards
volume = 4 * a.params
print(f"capture {a.size} x {a.size}: {shards} shards of {a.shard} x {a.shard} cells; all-reduce of {volume / 1e6:.2f} MB;"
      f" one node ({a.cores} cores) computes a step in {shards * shard_core_seconds / a.cores:.3f} s")
print()
print("| nodes | compute s/step | 10 Gbit/s: comm | 10 Gbit/s: speed-up | 100 Gbit/s: comm | 100 Gbit/s: speed-up |")
print("|---:|---:|---:|---:|---:|---:|")
one = shards * shard_core_seconds / a.cores
for n in [1, 2, 4, 8, 16, 32, 64]:
    compute = math.ceil(shards / n) * shard_core_seconds / a.cores
    row = [f"{n}", f"{compute:.4f}"]
    for gbits, latency in [(10, 30e-6), (100, 3e-6)]:
        bandwidth = gbits * 1e9 / 8
        # reduce-scatter + all-gather: 2 (n-1)/n of the volume, and 2 (n-1) message latencies
        comm = 0.0 if n == 1 else 2 * (n - 1) / n * volume / bandwidth + 2 * (n - 1) * latency
        mark = " (comm > compute)" if comm > compute else ""
        row += [f"{comm:.4f}{mark}", f"{one / (compute + comm):.1f}x"]
    print("| " + " | ".join(row) + " |")

# Where communication would overtake compute with shards small enough for every node (the shard
# count no limit): compute(n) = one / n.
for gbits, latency in [(10, 30e-6), (100, 3e-6)]:
    bandwidth = gbits * 1e9 / 8
    n = 2
    while one / n >= 2 * (n - 1) / n * volume / bandwidth + 2 * (n - 1) * latency and n < 1 << 20:
        n *= 2
    print(f"{gbits} Gbit/s: communication passes compute at about {n} nodes (with at least as many shards as nodes)")
