"""An independent implementation of docs/method.md sections 2-5 in array code (numpy or torch).

Written from the method description (docs/method.md) alone, not from the C++ renderer, so that
comparing the two checks both.
Every function takes the array module `xp` (numpy or torch) and works on float64 numpy arrays or on
torch tensors of any float dtype, with autograd (torch) flowing through all of it.

Conventions (decisions documented in the C++ sources, matched here):
- positions in units of the longest side n, origin at the material centre; texel (x, y) centre at
  ((x + 0.5 - W/2)/n, (H/2 - (y + 0.5))/n, 0): row 0 at the top, +y up (docs/method.md section 4);
- the flat geometric frame t_g = (1,0,0); no height map (a map set with height.exr is rejected);
- the specular factor includes (h.h) (docs/method.md section 3, decision);
- F0 clamped below at 1e-4, sigma at 1e-4, h_z at 1e-6; n_z = sqrt(max(1 - nx^2 - ny^2, 1e-6));
- radiance zero unless n.l > 0 and n.v > 0; r^2 = |l_pos - p|^2;
- loss = sum over images of the mean over pixels and the 3 channels of
  |log(R + 0.01) - log(B + 0.01)| (docs/method.md section 5).

Map set arrays (height, width, ...): diffuse (...,3), specular a'_s (...,3), sx, sy, f0, nx, ny,
alpha (each (height, width)). A capture is a list of dicts with 'camera', 'light' (3 floats) and
'intensity' (3 floats).
"""
import json
import math
import os

import numpy as np

try:
    from . import exr  # noqa: F401  (package use)
except ImportError:  # run as a plain module next to exr.py
    import exr

F0_MIN = 1e-4
SIGMA_MIN = 1e-4
HZ_MIN = 1e-6
NZ2_MIN = 1e-6
LOG_EPS = 0.01

MAP_NAMES = ("diffuse", "specular", "sx", "sy", "f0", "nx", "ny", "alpha")


def _is_torch(xp):
    return xp.__name__ == "torch"


def _clamp_min(xp, x, lo):
    return xp.clamp(x, min=lo) if _is_torch(xp) else np.maximum(x, lo)


def _as_array(xp, values, like):
    if _is_torch(xp):
        return xp.as_tensor(np.asarray(values, dtype=np.float64), dtype=like.dtype, device=like.device)
    return np.asarray(values, dtype=like.dtype)


def texel_positions(xp, width, height, like):
    """Texel centres (height, width) x and y in scene units (docs/method.md section 4 decision)."""
    n = float(max(width, height))
    px = (np.arange(width) + 0.5 - 0.5 * width) / n
    py = (0.5 * height - (np.arange(height) + 0.5)) / n
    gx, gy = np.meshgrid(px, py)  # (height, width)
    return _as_array(xp, gx, like), _as_array(xp, gy, like)


def shading_frame(xp, nx, ny, alpha):
    """docs/method.md section 2 with the flat geometric frame: returns the rotated tangent x, bitangent y and
    the normal n, each a tuple of 3 arrays (world components)."""
    nz = xp.sqrt(_clamp_min(xp, 1.0 - nx * nx - ny * ny, NZ2_MIN))
    # t = normalize(t_g - (t_g.n) n) with t_g = (1, 0, 0)
    tx, ty, tz = 1.0 - nx * nx, -nx * ny, -nx * nz
    tl = xp.sqrt(tx * tx + ty * ty + tz * tz)
    tx, ty, tz = tx / tl, ty / tl, tz / tl
    # b = n x t
    bx = ny * tz - nz * ty
    by = nz * tx - nx * tz
    bz = nx * ty - ny * tx
    c, s = xp.cos(alpha), xp.sin(alpha)
    x = (c * tx + s * bx, c * ty + s * by, c * tz + s * bz)
    y = (-s * tx + c * bx, -s * ty + c * by, -s * tz + c * bz)
    return x, y, (nx, ny, nz)


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def render(xp, maps, capture):
    """Renders every image of `capture`: returns an array (images, height, width, 3).

    R_i(p) = f(p; v, l) max(0, n.l) I_i / |l_i - p|^2 (docs/method.md section 4), f the bounded Ward BRDF with
    Schlick Fresnel (docs/method.md section 3), zero unless n.l > 0 and n.v > 0."""
    diffuse, specular = maps["diffuse"], maps["specular"]
    sx = _clamp_min(xp, maps["sx"], SIGMA_MIN)
    sy = _clamp_min(xp, maps["sy"], SIGMA_MIN)
    f0 = _clamp_min(xp, maps["f0"], F0_MIN)
    height, width = sx.shape
    ax, ay, an = shading_frame(xp, maps["nx"], maps["ny"], maps["alpha"])
    px, py = texel_positions(xp, width, height, sx)
    # all images at once: configuration arrays (images, 1, 1) broadcast against texels (height, width)
    cam = _as_array(xp, [[float(c) for c in im["camera"]] for im in capture], sx)[:, :, None, None]
    lig = _as_array(xp, [[float(c) for c in im["light"]] for im in capture], sx)[:, :, None, None]
    intensity = _as_array(xp, [[float(c) for c in im["intensity"]] for im in capture], sx)[:, None, None, :]
    # directions from the texel (z = 0) to camera and light
    vx, vy, vz = cam[:, 0] - px, cam[:, 1] - py, cam[:, 2] + 0.0 * px
    lx, ly, lz = lig[:, 0] - px, lig[:, 1] - py, lig[:, 2] + 0.0 * px
    r2 = lx * lx + ly * ly + lz * lz
    vl, ll = xp.sqrt(vx * vx + vy * vy + vz * vz), xp.sqrt(r2)
    v = (vx / vl, vy / vl, vz / vl)
    l = (lx / ll, ly / ll, lz / ll)
    # local frame coordinates
    hx = _dot(l, ax) + _dot(v, ax)
    hy = _dot(l, ay) + _dot(v, ay)
    nl, nv = _dot(l, an), _dot(v, an)
    hz_raw = nl + nv
    hz = _clamp_min(xp, hz_raw, HZ_MIN)
    hh = hx * hx + hy * hy + hz_raw * hz_raw  # h.h, |h| unclamped
    # Schlick Fresnel at v.h' = v.h / |h| = (1 + v.l) / |h|
    cos_vh = (1.0 + _dot(v, l)) / xp.sqrt(_clamp_min(xp, hh, 1e-30))
    one_minus = _clamp_min(xp, 1.0 - cos_vh, 0.0)
    fresnel = f0 + (1.0 - f0) * one_minus ** 5
    # lobe as one exp(d - 4 log h_z) so narrow lobes and h_z -> 0 stay finite
    d = -(hx * hx / (sx * sx) + hy * hy / (sy * sy)) / (hz * hz)
    lobe = hh * xp.exp(d - 4.0 * xp.log(hz)) / (math.pi * sx * sy)
    spec_scalar = fresnel / f0 * lobe  # (images, height, width)
    f = diffuse / math.pi + specular * spec_scalar[..., None]
    lit = (nl > 0) & (nv > 0)
    shade = xp.where(lit, _clamp_min(xp, nl, 0.0) / r2, xp.zeros_like(r2))
    return f * (shade[..., None] * intensity)


def image_loss(xp, rendered, targets):
    """docs/method.md section 5: sum over images of the mean over pixels and channels of the log L1 distance."""
    per = xp.abs(xp.log(rendered + LOG_EPS) - xp.log(targets + LOG_EPS))
    return per.reshape(per.shape[0], -1).mean(1).sum()


# ---- file access (numpy) ---------------------------------------------------------------------

def read_map_set(folder):
    """Reads a map set folder (docs/method.md section 1 file names) into float64 numpy arrays."""
    if os.path.exists(os.path.join(folder, "height.exr")):
        raise NotImplementedError(f"{folder}: height.exr present; the reference handles flat maps only")
    rd = lambda name: exr.read_rgb(os.path.join(folder, name))  # noqa: E731
    lobes, normal = rd("lobes.exr"), rd("normal.exr")
    return {"diffuse": rd("diffuse.exr"), "specular": rd("specular.exr"),
            "sx": lobes[..., 0], "sy": lobes[..., 1], "f0": rd("fresnel.exr")[..., 0],
            "nx": normal[..., 0], "ny": normal[..., 1], "alpha": rd("rotation.exr")[..., 0]}


def read_capture(path):
    """Reads capture.json: a list of {'file', 'camera', 'light', 'intensity' (3 floats)}."""
    with open(path) as f:
        doc = json.load(f)
    out = []
    for im in doc["images"]:
        inten = im.get("intensity", 1.0)
        if not isinstance(inten, list):
            inten = [inten] * 3
        out.append({"file": im["file"], "camera": im["camera"], "light": im["light"], "intensity": inten})
    return out
