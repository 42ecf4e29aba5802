#!/usr/bin/env python3
"""studies/widen_latent.py against the C++ library: the chain of files it makes from a
compact-fine one (compact-fine-wide, then compact-fine-wider, compact-fine-widest and
compact-fine-512, each from the one before) reconstructs the validation materials as the
compact-fine file does, read by `anisocap eval-networks` (the C++ network); a file of another
preset, and a narrowing, are refused with the file's name and nothing is written; the port's
presets are the C++ trainers' compact --preset choices; and the port's half-float files
(`widen_latent.py --half`, `train_torch.py train --half`) hold the bits of `anisocap
convert-weights --half`. Exits 77 (a skip) without PyTorch.

    check_widen_latent.py ANISOCAP SOURCE_DIR"""
import os
import re
import subprocess
import sys
import tempfile

try:
    import torch  # noqa: F401
except ImportError:
    print("PyTorch is not installed: skipped")
    sys.exit(77)


def reconstruction(program, weights):
    """The auto-encoder reconstruction row of eval-networks: (preset, [a_d, ..., F0])."""
    out = subprocess.run([program, "--threads", "1", "eval-networks", "--count", "2", "--size", "64", "--autoencoder", weights],
                         capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        if line.startswith("| auto-encoder reconstruction ("):
            cells = [c.strip() for c in line.strip("|").split("|")]
            return cells[0].split("(")[1].rstrip(")"), [float(c) for c in cells[1:]]
    raise SystemExit(f"eval-networks printed no reconstruction row for {weights}:\n{out}")


def trainer_presets(program, command):
    """The compact presets the C++ trainer takes (its --preset choices less "paper")."""
    out = subprocess.run([program, command, "--help"], capture_output=True, text=True, check=True).stdout
    match = re.search(r"--preset TEXT:\{([^}]*)\}", out)
    if not match:
        raise SystemExit(f"{command} --help lists no --preset choices:\n{out}")
    return set(match.group(1).split(",")) - {"paper"}


def main():
    program, source_dir = sys.argv[1], sys.argv[2]
    script = os.path.join(source_dir, "studies", "widen_latent.py")
    # A compact-fine file to widen: ANISOCAP_COMPACT_FINE names one (none is shipped; a skip without it).
    fine = os.environ.get("ANISOCAP_COMPACT_FINE", "")
    if not os.path.isfile(fine):
        print("no compact-fine weight file (ANISOCAP_COMPACT_FINE): skipped")
        sys.exit(77)
    failures = []
    # The PyTorch port knows the compact presets the C++ library knows (networks/presets.hpp's lists).
    sys.path.insert(0, os.path.join(source_dir, "studies"))
    import train_torch
    for command, port in (("train-autoencoder", train_torch.AUTOENCODER_PRESETS), ("train-estimator", train_torch.ESTIMATOR_PRESETS)):
        presets = trainer_presets(program, command)
        if presets != set(port):
            failures.append(f"{command}'s compact presets {sorted(presets)} are not the port's {sorted(port)}")
    with tempfile.TemporaryDirectory() as tmp:
        wide = os.path.join(tmp, "wide.safetensors")
        wider = os.path.join(tmp, "wider.safetensors")
        widest = os.path.join(tmp, "widest.safetensors")
        w512 = os.path.join(tmp, "w512.safetensors")
        subprocess.run([sys.executable, script, fine, wide], check=True)
        subprocess.run([sys.executable, script, wide, wider, "--to", "compact-fine-wider"], check=True)
        subprocess.run([sys.executable, script, wider, widest, "--to", "compact-fine-widest"], check=True)
        subprocess.run([sys.executable, script, widest, w512, "--to", "compact-fine-512"], check=True)
        (p_fine, e_fine), (p_wide, e_wide), (p_wider, e_wider), (p_widest, e_widest), (p_512, e_512) = (
            reconstruction(program, f) for f in (fine, wide, wider, widest, w512))
        if (p_fine, p_wide, p_wider, p_widest, p_512) != ("compact-fine", "compact-fine-wide", "compact-fine-wider", "compact-fine-widest",
                                                           "compact-fine-512"):
            failures.append(f"presets {p_fine}, {p_wide}, {p_wider}, {p_widest}, {p_512}")
        # eval-networks prints 4 significant digits; the sums over the extra zero-weighted channels
        # may round differently in the last one.
        for name, errors in (("compact-fine-wide", e_wide), ("compact-fine-wider", e_wider), ("compact-fine-widest", e_widest),
                             ("compact-fine-512", e_512)):
            if any(abs(a - b) > 2e-3 * max(abs(a), 1e-12) for a, b in zip(e_fine, errors)):
                failures.append(f"{name}: reconstruction errors differ: {e_fine} against {errors}")
        # Half floats: the port's file and the library's conversion of the float file hold the same
        # tensors, dtypes and bits (kernels F16, biases and batch-norm statistics F32).
        port_half, library_half = os.path.join(tmp, "port_half.safetensors"), os.path.join(tmp, "library_half.safetensors")
        subprocess.run([sys.executable, script, widest, port_half, "--to", "compact-fine-512", "--half"], check=True)
        subprocess.run([program, "convert-weights", w512, library_half, "--half"], check=True, capture_output=True)
        a, b = train_torch.read_raw_safetensors(port_half)[0], train_torch.read_raw_safetensors(library_half)[0]
        dtypes = {dtype for dtype, _, _ in a.values()}
        if a.keys() != b.keys() or any(a[k] != b[k] for k in a) or dtypes != {"F16", "F32"}:
            differing = [k for k in a if k not in b or a[k] != b[k]]
            failures.append(f"the port's half-float file differs from convert-weights --half in {differing[:5]} (dtypes {dtypes})")
        if os.path.getsize(port_half) > 0.55 * os.path.getsize(w512):
            failures.append(f"the half-float file is {os.path.getsize(port_half)} bytes, the float one {os.path.getsize(w512)}")
        # The shipped compact auto-encoder is not compact-fine: refused, naming the file, no output.
        compact = os.path.join(source_dir, "models", "compact", "autoencoder.safetensors")
        refused = os.path.join(tmp, "refused.safetensors")
        r = subprocess.run([sys.executable, script, compact, refused], capture_output=True, text=True)
        if r.returncode == 0 or compact not in r.stderr or os.path.exists(refused) or os.path.exists(refused + ".partial"):
            failures.append(f"a compact file was not refused as it should be: exit {r.returncode}, {r.stderr!r}")
        # Nor is a wider file narrowed: compact-fine-wider and compact-fine-widest to compact-fine-wide,
        # compact-fine-widest to compact-fine-wider and compact-fine-512 to compact-fine-widest, are refused.
        for source, to in ((wider, "compact-fine-wide"), (widest, "compact-fine-wide"), (widest, "compact-fine-wider"),
                           (w512, "compact-fine-widest")):
            r = subprocess.run([sys.executable, script, source, refused, "--to", to], capture_output=True, text=True)
            if r.returncode == 0 or source not in r.stderr or os.path.exists(refused) or os.path.exists(refused + ".partial"):
                failures.append(f"{source} to {to} was not refused as it should be: exit {r.returncode}, {r.stderr!r}")
    print(f"compact-fine {e_fine}\ncompact-fine-wide {e_wide}\ncompact-fine-wider {e_wider}\ncompact-fine-widest {e_widest}\n"
          f"compact-fine-512 {e_512}")
    if failures:
        raise SystemExit("FAILED: " + "; ".join(failures))
    print("passed")


if __name__ == "__main__":
    main()
