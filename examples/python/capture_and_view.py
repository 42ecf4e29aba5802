#!/usr/bin/env python3
"""Captures a material from its photographs with the anisocap package, then renders it from a view
no photograph had and shows the photograph, the capture's re-rendering and the novel view side by
side (matplotlib).

usage: capture_and_view.py [CAPTURE_JSON] [-o FIGURE.png] [--maps FOLDER]

Without CAPTURE_JSON it synthesizes a 128 x 128 procedural twill with 12 photographs first (as
`anisocap synthesize` would). With -o the figure is saved instead of shown; --maps writes the
captured map set (EXR files) into FOLDER. Run from a build tree with PYTHONPATH=BUILD/python, or
after `cmake --install`.
"""
import argparse

import numpy as np

import anisocap


def to_display(image):
    """Linear radiance to 8-bit-like sRGB for showing (simple gamma, clipped)."""
    return np.clip(image, 0, 1) ** (1 / 2.2)


def main():
    parser = argparse.ArgumentParser(description="capture a material and render a novel view")
    parser.add_argument("capture", nargs="?", help="capture.json (default: synthesize a procedural twill)")
    parser.add_argument("-o", "--out", help="save the figure here instead of showing it")
    parser.add_argument("--maps", help="write the captured map set into this folder")
    args = parser.parse_args()

    if args.capture:
        data = anisocap.read_capture(args.capture)
    else:
        data = anisocap.synthesize(width=128, height=128, images=12, seed=1, kind="twill")
    photos, configurations = data["photos"], data["configurations"]

    def progress(stage, step, steps, loss):  # called after every step: show one in 25
        if step % 25 == 0 or step == steps:
            print(f"\r{stage}: step {step}/{steps}, loss {loss:.4f}   ", end="", flush=True)

    result = anisocap.capture(photos, configurations, masks=data.get("masks"), progress=progress)
    print(f"\nimage loss {result['loss']:.4f}; stages: " +
          ", ".join(f"{s['name']} {s['seconds']:.1f} s" for s in result["stages"] if s["ran"]))
    if args.maps:
        anisocap.write_maps(result["maps"], args.maps)

    # A grazing view from the side, the light opposite: a view the photographs did not have.
    novel = anisocap.Configuration(camera=(1.2, 0.3, 0.8), light=(-0.8, -0.2, 1.0), intensity=(2.0, 2.0, 2.0))
    rerendered = anisocap.render(result["maps"], configurations[:1])[0]
    view = anisocap.render(result["maps"], [novel])[0]

    import matplotlib
    if args.out:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(12, 4))
    for ax, image, title in zip(axes, [photos[0], rerendered, view], ["photograph 0", "capture, re-rendered", "novel view"]):
        ax.imshow(to_display(image))
        ax.set_title(title)
        ax.axis("off")
    fig.tight_layout()
    if args.out:
        fig.savefig(args.out, dpi=100)
        print(f"figure in {args.out}")
    else:
        plt.show()


if __name__ == "__main__":
    main()
