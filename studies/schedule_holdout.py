#!/usr/bin/env python3
"""The capture schedules (fast, auto, thorough) judged on a photograph the fit did not see.

Per material: `anisocap photograph` takes 9 flash photographs (perspective 8-bit JPEGs with sensor
noise, as a phone takes them), `rectify` puts them in texture space, and `capture --schedule S`
fits the first 8. The fitted maps are rendered (`anisocap render`) under the 9th photograph's
configuration and compared with it as the image loss compares (mean of
|log(max(R, f) + 0.01) - log(max(B, f) + 0.01)| over its mask, f its noise floor). Also the map
error against the truth (the mean of report.json's five map errors) and the capture's time.
Prints one line per material and a markdown table of the means per family group.

    studies/schedule_holdout.py build/anisocap OUT [--size 64] [--seeds 2] [--families plain,...]
"""
import json
import pathlib
import struct
import sys
import zlib

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent / "reference"))
from exr import read_rgb  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from program_runs import FAMILIES, parse_arguments, run  # noqa: E402

METALS = {"brushed", "spun"}
SCHEDULES = ["fast", "auto", "thorough"]


def read_png_gray(path):
    """An 8-bit greyscale or RGB(A) PNG (non-interlaced) as floats in [0, 1], its first channel."""
    data = pathlib.Path(path).read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, header = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    w, h, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
    if depth != 8 or interlace:
        raise ValueError(f"{path}: only 8-bit non-interlaced PNGs are read here")
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8)
    stride = w * channels
    out = np.zeros((h, stride), dtype=np.int32)
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)].astype(np.int32)
        prev = out[y - 1] if y > 0 else np.zeros(stride, dtype=np.int32)
        cur = np.zeros(stride, dtype=np.int32)
        for x in range(stride):
            a = cur[x - channels] if x >= channels else 0
            b = prev[x]
            c = prev[x - channels] if x >= channels else 0
            if f == 0:
                p = 0
            elif f == 1:
                p = a
            elif f == 2:
                p = b
            elif f == 3:
                p = (a + b) // 2
            else:
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            cur[x] = (line[x] + p) & 255
        out[y] = cur
    return out.reshape(h, w, channels)[:, :, 0] / 255.0


def heldout_error(rendered, photo, mask, floor):
    r = np.maximum(read_rgb(rendered), floor)
    b = np.maximum(read_rgb(photo), floor)
    m = read_png_gray(mask)[:, :, None]
    d = np.abs(np.log(r + 0.01) - np.log(b + 0.01)) * m
    return float(d.sum() / (3 * m.sum()))


def main():
    a, binary, out = parse_arguments(__doc__, 2)
    rows = []
    for family in a.families.split(","):
        for s in range(a.seeds):
            seed = 900 + FAMILIES.index(family) + 100 * s
            d = out / f"{family}_{seed}"
            d.mkdir(exist_ok=True)
            run([binary, "photograph", "-o", "shoot", "--size", a.size, "--kind", family, "--seed", seed, "--images", 9, "--flash",
                 "--shot-noise", 0.01, "--read-noise", 0.002], d)
            run([binary, "rectify", "shoot/photos/photos.json", "-o", "rect", "--resolution", a.size], d)
            description = json.loads((d / "rect/capture.json").read_text())
            held = description["images"][8]
            (d / "rect/fit.json").write_text(json.dumps({"images": description["images"][:8]}, indent=2) + "\n")
            view = {k: v for k, v in held.items() if k not in ("file", "mask", "floor")}
            view["file"] = "heldout.exr"
            (d / "heldout.json").write_text(json.dumps({"images": [view]}, indent=2) + "\n")
            result = {}
            for schedule in SCHEDULES:
                res = f"result-{schedule}"
                run([binary, "capture", "rect/fit.json", "-o", res, "--truth", "shoot/truth", "--schedule", schedule, "--no-view"], d)
                report = json.loads((d / res / "report.json").read_text())
                e = report["errors"]
                maps = (e["diffuse"] + e["specular"] + e["normal"] + e["lobes"] + e["fresnel"]) / 5
                run([binary, "render", "--maps", res, "--capture", "heldout.json", "-o", f"heldout-{schedule}"], d)
                held_error = heldout_error(d / f"heldout-{schedule}/heldout.exr", d / "rect" / held["file"], d / "rect" / held["mask"],
                                           held.get("floor", 0.0))
                result[schedule] = (held_error, maps, report["timings"]["total"], report["loss"])
            rows.append((family, seed, result))
            print(f"{family} {seed}: " + "  ".join(f"{t} {result[t][0]:.4f}/{result[t][1]:.4f}/{result[t][2]:.1f}s" for t in SCHEDULES),
                  flush=True)
    print("\n| materials | schedule | held-out photograph | fitted photographs (loss) | map error | seconds |\n|---|---|---|---|---|---|")
    for name, keep in [("fabrics", lambda f: f not in METALS), ("metals", lambda f: f in METALS), ("all", lambda f: True)]:
        chosen = [r for r in rows if keep(r[0])]
        if not chosen:
            continue
        for t in SCHEDULES:
            m = np.mean([[r[2][t][0], r[2][t][3], r[2][t][1], r[2][t][2]] for r in chosen], axis=0)
            print(f"| {name} ({len(chosen)}) | {t} | {m[0]:.4f} | {m[1]:.4f} | {m[2]:.4f} | {m[3]:.1f} |")


if __name__ == "__main__":
    main()
