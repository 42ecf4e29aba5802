"""What the studies that drive the `anisocap` program share: running a command, the procedural
families in their seed order, and the command line every such study takes."""
import argparse
import pathlib
import subprocess
import sys

FAMILIES = ["plain", "basket", "twill", "herringbone", "satin", "velvet", "brushed", "spun"]


def run(args, cwd):
    """Runs a command in `cwd`; ends the study with its output if it fails."""
    r = subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{pathlib.Path(sys.argv[0]).name}: {' '.join(map(str, args))} failed:\n{r.stdout}{r.stderr}")
    return r.stdout + r.stderr


def parse_arguments(doc, seeds, extra=lambda p: None):
    """The study's arguments: the program, the output folder (created), --size, --seeds (default
    `seeds`), --families and whatever `extra` adds. Returns (arguments, program path, output folder)."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("binary")
    p.add_argument("out")
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--seeds", type=int, default=seeds)
    p.add_argument("--families", default=",".join(FAMILIES))
    extra(p)
    a = p.parse_args()
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    return a, pathlib.Path(a.binary).resolve(), out
