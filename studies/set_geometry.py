#!/usr/bin/env python3
"""What the configurations of set alpha and set beta let a texel see (docs/method.md section 6), from capture.json files.

For every texel of a 33 x 33 grid over the material (flat, normal up) and every capture it prints
the means over texels and captures of:
- light conditioning: the smallest eigenvalue of the mean of l l^T over the images (l the unit
  direction to the light). Diffuse shading pins the normal down when the lights come from
  directions spanning 3-D (photometric stereo); 0 means a direction the lights never probe.
- highlight count: images in which the texel is near the mirror direction (h_z > cos 15 deg),
  where the specular lobe, its width and the normal's tilt are seen.
- Fresnel highlights: images in which the texel is near the mirror direction AND the view is
  grazing enough that Schlick's term adds at least 10% of 1 - F0 ((1 - h.v)^5 > 0.1, h.v < 0.37):
  the observations that separate F0 from the specular albedo.

    for i in $(seq 0 19); do for set in alpha beta; do
      build/anisocap synthesize -o cond/$set$i --width 32 --height 32 --images 12 --set $set --seed $((900000+i))
    done; done
    python3 studies/set_geometry.py cond/alpha* cond/beta*

usage: python3 studies/set_geometry.py DIR [DIR ...]  (each DIR holds a capture.json; DIR names
       that start with "alpha" or "beta" are grouped by set). Needs numpy.
"""
import json
import pathlib
import sys

import numpy as np


def texel_stats(capture_path):
    images = json.loads(pathlib.Path(capture_path).read_text())["images"]
    g = np.linspace(-0.5, 0.5, 33)
    x, y = np.meshgrid(g, g)
    p = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3)
    scatter = np.zeros((p.shape[0], 3, 3))
    highlights = np.zeros(p.shape[0])
    fresnel = np.zeros(p.shape[0])
    for im in images:
        l = np.asarray(im["light"], float) - p
        v = np.asarray(im["camera"], float) - p
        l /= np.linalg.norm(l, axis=1, keepdims=True)
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        h = l + v
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        scatter += l[:, :, None] * l[:, None, :]
        near = h[:, 2] > np.cos(np.radians(15))
        highlights += near
        fresnel += near & ((1 - np.sum(h * v, axis=1)) ** 5 > 0.1)
    scatter /= len(images)
    lam = np.linalg.eigvalsh(scatter)[:, 0]
    return lam.mean(), highlights.mean(), fresnel.mean(), (fresnel > 0).mean()


def main():
    groups = {}
    for d in sys.argv[1:]:
        name = pathlib.Path(d).name
        key = "alpha" if name.startswith("alpha") else "beta" if name.startswith("beta") else name
        groups.setdefault(key, []).append(texel_stats(pathlib.Path(d) / "capture.json"))
    print("| set | captures | light conditioning (min eigenvalue) | highlights per texel | Fresnel highlights per texel | texels with a Fresnel highlight |")
    print("|---|---|---|---|---|---|")
    for key, rows in groups.items():
        m = np.mean(np.asarray(rows), axis=0)
        print(f"| {key} | {len(rows)} | {m[0]:.4f} | {m[1]:.2f} | {m[2]:.3f} | {100 * m[3]:.1f} % |")


if __name__ == "__main__":
    main()
