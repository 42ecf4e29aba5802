#!/usr/bin/env python3
"""Trains anisocap's compact networks with PyTorch on a GPU and writes weight files that the C++
library loads (models/README.md, "Training on a GPU").

The networks are ports of networks/estimator.hpp (`compact`, `compact-orientation`) and
networks/auto_encoder.hpp (`compact`, `compact-wide`, `compact-fine`, `compact-fine-wide`,
`compact-fine-wider`, `compact-fine-widest`), layer for layer and with the C++ weight names; `--check` runs a weight file through both and compares the
outputs. The losses are those of training/training.hpp: the L1 in network space with
training::lobe_l1's symmetries, plus `--render-weight` times the render loss over the 4 render-loss
configurations (renders by studies/reference/ward_reference.py, written independently of the C++
renderer), plus the auto-encoder's latent smoothness term. Training materials come from the C++
procedural generator: studies/torch_training_data.cpp writes chunks of network-space maps and the
configurations training::make_sample draws for them, on every CPU core, while the GPU trains; the 5
input photographs and the render-loss targets are rendered on the GPU. A material is used again
(flipped at random) when the GPU outruns the generators.

    python3 studies/train_torch.py train --network autoencoder --init W.safetensors --out DIR
        --tool build/anisocap_study_torch_training_data [--minutes 9] [--batch 32] [--lr 4e-4]
    python3 studies/train_torch.py check --network estimator --weights W --tool TOOL

Weights are written as DIR/<network>.safetensors (the C++ layout and metadata, so `anisocap
eval-networks`, `capture` and `--init` read them) every --save-minutes and at the end, and the
validation rows to DIR/validation.csv.
"""
import argparse
import csv
import json
import math
import os
import queue
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference"))
import ward_reference as ward  # noqa: E402

SLOPE = 0.2
LOG_MIN_LOBE = math.log(1e-4)
MAX_NORMAL_XY = 0.999
ROTATION_RAMP = 2 * math.log(1.25) / (-LOG_MIN_LOBE)
VALIDATION_BASE = 1 << 62

ESTIMATOR_PRESETS = {
    "compact": dict(encoder=[16, 32, 64, 64, 64, 64], track1=[64, 64, 64, 32, 16, 16], track2=[32, 32, 32, 16, 8, 8], inputs=3),
    "compact-orientation": dict(encoder=[16, 32, 64, 64, 64, 64], track1=[64, 64, 64, 32, 16, 16],
                                track2=[32, 32, 32, 16, 8, 8], inputs=6),
}
# The doubled-angle presets: track 2's head has 4 raw outputs (n_x, n_y, c, s) and alpha / (pi/2)
# is atan2(s, c) / pi (network_detail::normals_and_doubled_angle).
ESTIMATOR_PRESETS["compact-doubled-angle"] = dict(ESTIMATOR_PRESETS["compact"], doubled_angle=True)
ESTIMATOR_PRESETS["compact-orientation-doubled-angle"] = dict(ESTIMATOR_PRESETS["compact-orientation"], doubled_angle=True)
AUTOENCODER_PRESETS = {"compact": [32, 64, 128, 128, 128], "compact-wide": [32, 64, 128, 256, 256],
                       "compact-fine": [32, 64, 128, 128],  # four levels: latent (H/16) x (W/16)
                       "compact-fine-wide": [32, 64, 128, 256], "compact-fine-wider": [64, 128, 256, 256],
                       "compact-fine-widest": [64, 128, 256, 384], "compact-fine-512": [64, 128, 256, 512]}


# ---- safetensors in the C++ layout -------------------------------------------------------------

def read_raw_safetensors(path):
    """A weight file as stored: ({name: (dtype, shape, bytes)} in header order, metadata)."""
    with open(path, "rb") as f:
        n = struct.unpack("<Q", f.read(8))[0]
        header = json.loads(f.read(n))
        data = f.read()
    meta = header.pop("__metadata__", {})
    return {name: (info["dtype"], info["shape"], data[info["data_offsets"][0]:info["data_offsets"][1]])
            for name, info in header.items()}, meta


def read_safetensors(path):
    raw, meta = read_raw_safetensors(path)
    tensors = {}
    for name, (dtype, shape, blob) in raw.items():
        # F16: the half-float weight files of `anisocap convert-weights --half`, read as float32.
        assert dtype in ("F32", "F16"), f"{path}: {name} is {dtype}"
        tensors[name] = np.frombuffer(blob, dtype="<f4" if dtype == "F32" else "<f2").astype(np.float32).reshape(shape)
    return tensors, meta, list(raw.keys())


# The smallest tensor written as half floats with half=True: as the library's half_storage_min_elements
# (nn/safetensors.hpp), so the biases and batch-norm statistics stay in floats.
HALF_MIN_ELEMENTS = 1024
HALF_MAX = 65504.0


def write_safetensors(path, tensors, names, meta, half=False):
    """Writes a weight file in the library's layout through a temporary name. half: tensors of
    HALF_MIN_ELEMENTS or more values as IEEE half floats rounded to nearest even, the file
    `anisocap convert-weights --half` makes of the float one."""
    header, offset, blobs = {"__metadata__": meta}, 0, []
    for name in names:
        value = np.asarray(tensors[name], dtype=np.float32)
        if half and value.size >= HALF_MIN_ELEMENTS:
            if not np.all(np.abs(value) <= HALF_MAX):
                raise SystemExit(f"{path}: tensor '{name}' holds a value beyond the half floats' range (65504): write it without --half")
            blob, dtype = np.ascontiguousarray(value, dtype="<f2").tobytes(), "F16"
        else:
            blob, dtype = np.ascontiguousarray(value, dtype="<f4").tobytes(), "F32"
        header[name] = {"dtype": dtype, "shape": list(value.shape), "data_offsets": [offset, offset + len(blob)]}
        offset += len(blob)
        blobs.append(blob)
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * ((8 - len(text) % 8) % 8)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for blob in blobs:
            f.write(blob)
    os.replace(tmp, path)


# Axis orders between the library's [K][K][Cin][Cout] and PyTorch's layouts (Conv2d [Cout][Cin][K][K],
# ConvTranspose2d [Cin][Cout][K][K]): (to PyTorch, back to the library).
AXES = {nn.ConvTranspose2d: ((2, 3, 0, 1), (2, 3, 0, 1)), nn.Conv2d: ((3, 2, 0, 1), (2, 3, 1, 0))}


def layout(module, value, to_torch):
    """A convolution weight in the other layout; linears and vectors are the same in both."""
    if value.ndim != 4:
        return value
    for kind, (forward, backward) in AXES.items():
        if isinstance(module, kind):
            return value.transpose(forward if to_torch else backward)
    return value


def owner(net, name):
    return net.get_submodule(name.rsplit(".", 1)[0])


def load_cpp(net, path):
    tensors, meta, names = read_safetensors(path)
    state = net.state_dict()
    for name, value in tensors.items():
        if name not in state:
            raise SystemExit(f"{path}: {name} is not in the PyTorch port")
        v = torch.from_numpy(np.ascontiguousarray(layout(owner(net, name), value, True)))
        if tuple(v.shape) != tuple(state[name].shape):
            raise SystemExit(f"{path}: {name} has shape {tuple(value.shape)}, the port {tuple(state[name].shape)}")
        state[name].copy_(v)
    missing = [k for k in state if k not in tensors and not k.endswith("num_batches_tracked")]
    if missing:
        raise SystemExit(f"{path}: lacks {missing}")
    return meta, names


def save_cpp(net, path, names, meta, half=False):
    state = net.state_dict()
    tensors = {n: layout(owner(net, n), state[n].detach().float().cpu().numpy(), False) for n in names}
    write_safetensors(path, tensors, names, meta, half)


# ---- the networks ------------------------------------------------------------------------------

def lrelu(x):
    return F.leaky_relu(x, SLOPE)


def conv(cin, cout):
    return nn.Conv2d(cin, cout, 4, 2, 1)


def up(cin, cout):
    return nn.ConvTranspose2d(cin, cout, 4, 2, 1)


class AutoEncoder(nn.Module):
    """auto_encoder<Preset>: one stride-2 level per encoder width (enc0..., dec0...)."""

    def __init__(self, preset):
        super().__init__()
        e = AUTOENCODER_PRESETS[preset]
        self.levels = len(e)
        for i in range(self.levels):
            setattr(self, f"enc{i}", conv(12 if i == 0 else e[i - 1], e[i]))
            setattr(self, f"dec{i}", up(e[-1 - i], 12 if i + 1 == self.levels else e[-2 - i]))
        self.latent_norm = nn.BatchNorm2d(e[-1], eps=1e-5, momentum=0.1)

    def decoder_layers(self):
        return [getattr(self, f"dec{i}") for i in range(self.levels)]

    def encode(self, x):
        for i in range(self.levels - 1):
            x = lrelu(getattr(self, f"enc{i}")(x))
        return self.latent_norm(getattr(self, f"enc{self.levels - 1}")(x))

    def decode(self, z):
        layers = self.decoder_layers()
        for layer in layers[:-1]:
            z = lrelu(layer(z))
        return torch.tanh(layers[-1](z))


class Track(nn.Module):
    """network_detail::decoder_track and reducing_head of one track."""

    def __init__(self, e, d, out, doubled_angle=False):
        super().__init__()
        self.doubled_angle = doubled_angle
        skips = [None, e[4], e[3], e[2], e[1], e[0]]
        for i in range(6):
            cin = e[5] if i == 0 else d[i - 1] + skips[i]
            setattr(self, f"up{i}", up(cin, d[i]))
            setattr(self, f"norm{i}", nn.InstanceNorm2d(d[i], eps=1e-5, affine=True))
            setattr(self, f"global{i}", nn.Linear(e[5], d[i]))
        self.reduce0 = nn.Conv2d(d[5], d[5], 3, 1, 1)
        self.reduce1 = nn.Conv2d(d[5], d[5], 3, 1, 1)
        self.reduce2 = nn.Conv2d(d[5], out, 1, 1, 0)
        self.reduce_global = nn.Linear(e[5], d[5])

    def features(self, a, g):
        h = None
        for i in range(6):
            x = a[5] if i == 0 else torch.cat([h, a[5 - i]], 1)
            h = getattr(self, f"norm{i}")(getattr(self, f"up{i}")(x)) + getattr(self, f"global{i}")(g)[:, :, None, None]
            h = lrelu(h)
        return h

    def head(self, f, g):
        h = lrelu(self.reduce0(f) + self.reduce_global(g)[:, :, None, None])
        h = lrelu(self.reduce1(h))
        z = self.reduce2(h)
        if self.doubled_angle:  # (tanh z_x, tanh z_y, atan2(s, c) / pi)
            return torch.cat([torch.tanh(z[:, 0:2]), torch.atan2(z[:, 3:4], z[:, 2:3]) / math.pi], 1)
        return torch.tanh(z)


class Estimator(nn.Module):
    def __init__(self, preset):
        super().__init__()
        p = ESTIMATOR_PRESETS[preset]
        e = p["encoder"]
        self.inputs = p["inputs"]
        self.enc0 = conv(self.inputs, e[0])
        for i in range(1, 6):
            setattr(self, f"enc{i}", conv(e[i - 1], e[i]))
            setattr(self, f"enc_norm{i}", nn.InstanceNorm2d(e[i], eps=1e-5, affine=True))
            setattr(self, f"global_bias{i}", nn.Linear(e[i - 1], e[i]))
        self.global0 = nn.Linear(e[0], e[0])
        for i in range(1, 6):
            setattr(self, f"global{i}", nn.Linear(e[i - 1] + e[i], e[i]))
        self.track1 = Track(e, p["track1"], 9)
        doubled = p.get("doubled_angle", False)
        self.track2 = Track(e, p["track2"], 4 if doubled else 3, doubled)

    def forward(self, x, images_per_set):
        h0 = self.enc0(x)
        g = F.selu(self.global0(h0.mean((2, 3))))
        a = [lrelu(h0)]
        for i in range(1, 6):
            h = getattr(self, f"enc{i}")(a[-1])
            m = h.mean((2, 3))
            h = getattr(self, f"enc_norm{i}")(h) + getattr(self, f"global_bias{i}")(g)[:, :, None, None]
            g = F.selu(getattr(self, f"global{i}")(torch.cat([g, m], 1)))
            a.append(lrelu(h))

        def pool(t):
            return t.reshape(t.shape[0] // images_per_set, images_per_set, *t.shape[1:]).amax(1)

        gp = pool(g)
        out1 = self.track1.head(pool(self.track1.features(a, g)), gp)
        out2 = self.track2.head(pool(self.track2.features(a, g)), gp)
        return torch.cat([out1, out2], 1)


# ---- network space, inputs, renders ------------------------------------------------------------

def network_to_maps(u):
    """network_space::network_to_maps on (B, 12, H, W): the reference renderer's map dict."""
    half = lambda t: (t + 1) / 2  # noqa: E731
    lobe = lambda t: torch.exp(LOG_MIN_LOBE + (t + 1) / 2 * (-LOG_MIN_LOBE))  # noqa: E731
    nx, ny = u[:, 9], u[:, 10]
    r = torch.sqrt(nx * nx + ny * ny)
    scale = torch.where(r > MAX_NORMAL_XY, MAX_NORMAL_XY / torch.clamp(r, min=1e-12), torch.ones_like(r))
    return {"diffuse": half(u[:, 0:3]).permute(0, 2, 3, 1), "specular": half(u[:, 3:6]).permute(0, 2, 3, 1),
            "sx": lobe(u[:, 6]), "sy": lobe(u[:, 7]), "f0": half(u[:, 8]), "nx": nx * scale, "ny": ny * scale,
            "alpha": u[:, 11] * (math.pi / 2)}


def render_batch(maps, conf):
    """ward_reference.render over a batch: maps (B, H, W[, 3]), conf (B, n, 9) -> (B, n, H, W, 3)."""
    B, n = conf.shape[0], conf.shape[1]
    H, W = maps["sx"].shape[1:]
    m = {k: v[:, None] for k, v in maps.items()}  # (B, 1, H, W[, 3]) broadcast against configurations
    sx = torch.clamp(m["sx"], min=ward.SIGMA_MIN)
    sy = torch.clamp(m["sy"], min=ward.SIGMA_MIN)
    f0 = torch.clamp(m["f0"], min=ward.F0_MIN)
    ax, ay, an = ward.shading_frame(torch, m["nx"], m["ny"], m["alpha"])
    size = float(max(W, H))
    px = ((torch.arange(W, device=conf.device, dtype=conf.dtype) + 0.5 - 0.5 * W) / size)[None, None, None, :]
    py = ((0.5 * H - (torch.arange(H, device=conf.device, dtype=conf.dtype) + 0.5)) / size)[None, None, :, None]
    c = conf[:, :, :, None, None]
    vx, vy, vz = c[:, :, 0] - px, c[:, :, 1] - py, c[:, :, 2] + 0.0 * px
    lx, ly, lz = c[:, :, 3] - px, c[:, :, 4] - py, c[:, :, 5] + 0.0 * px
    r2 = lx * lx + ly * ly + lz * lz
    vl, ll = torch.sqrt(vx * vx + vy * vy + vz * vz), torch.sqrt(r2)
    v = (vx / vl, vy / vl, vz / vl)
    l = (lx / ll, ly / ll, lz / ll)
    dot = lambda p, q: p[0] * q[0] + p[1] * q[1] + p[2] * q[2]  # noqa: E731
    hx, hy = dot(l, ax) + dot(v, ax), dot(l, ay) + dot(v, ay)
    nl, nv = dot(l, an), dot(v, an)
    hz_raw = nl + nv
    hz = torch.clamp(hz_raw, min=ward.HZ_MIN)
    hh = hx * hx + hy * hy + hz_raw * hz_raw
    cos_vh = (1.0 + dot(v, l)) / torch.sqrt(torch.clamp(hh, min=1e-30))
    fresnel = f0 + (1.0 - f0) * torch.clamp(1.0 - cos_vh, min=0.0) ** 5
    d = -(hx * hx / (sx * sx) + hy * hy / (sy * sy)) / (hz * hz)
    lobe = hh * torch.exp(d - 4.0 * torch.log(hz)) / (math.pi * sx * sy)
    f = m["diffuse"] / math.pi + m["specular"] * (fresnel / f0 * lobe)[..., None]
    shade = torch.where((nl > 0) & (nv > 0), torch.clamp(nl, min=0.0) / r2, torch.zeros_like(r2))
    intensity = conf[:, :, 6:9][:, :, None, None, :]
    return f * (shade[..., None] * intensity)


def input_value(radiance):
    l0, rng = math.log(0.01), math.log(1.01) - math.log(0.01)
    return 2 * (torch.log(torch.clamp(radiance, min=0.0) + 0.01) - l0) / rng - 1


def orientation_channels(x):
    """network_space::orientation_channels on (N, 3, H, W) eq.-7 images -> (N, 3, H, W)."""
    v = x.mean(1, keepdim=True)
    p = F.pad(v, (1, 1, 1, 1), mode="replicate")
    gx = (p[:, :, 1:-1, 2:] - p[:, :, 1:-1, :-2]) / 2
    gy = (p[:, :, 2:, 1:-1] - p[:, :, :-2, 1:-1]) / 2
    j = torch.cat([gx * gx, gx * gy, gy * gy], 1)
    j = F.avg_pool2d(F.pad(j, (3, 3, 3, 3), mode="replicate"), 7, stride=1) * 49
    trace = j[:, 0:1] + j[:, 2:3]
    c5 = 2 * (torch.log(trace + 1e-4) - math.log(1e-4)) / (-math.log(1e-4)) - 1
    return torch.cat([(j[:, 0:1] - j[:, 2:3]) / (trace + 1e-6), 2 * j[:, 1:2] / (trace + 1e-6), c5], 1)


def add_sensor_noise(photos, shot, read):
    """render/sensor_noise.hpp's model on a batch of photographs (B, n, H, W, 3), at a fraction of
    the levels drawn uniformly in [0, 1) per material as training_input_noise does: each pixel gets
    a normal deviate of standard deviation sqrt(shot^2 max(v, 0) + read^2), and the result is
    clamped at 0. (PyTorch's random stream, not the library's: the same distribution.)"""
    f = torch.rand(photos.shape[0], 1, 1, 1, 1, device=photos.device, dtype=photos.dtype)
    sigma = torch.sqrt((shot * f) ** 2 * torch.clamp(photos, min=0.0) + (read * f) ** 2)
    return torch.clamp(photos + sigma * torch.randn_like(photos), min=0.0)


def estimator_inputs(photos, channels):
    """photos (B, n, H, W, 3) radiance -> (B * n, channels, H, W) as photo_to_network writes them."""
    B, n, H, W, _ = photos.shape
    x = input_value(photos.reshape(B * n, H, W, 3).permute(0, 3, 1, 2))
    return torch.cat([x, orientation_channels(x)], 1) if channels == 6 else x


# ---- losses ------------------------------------------------------------------------------------

def wrap(d):
    return d - 2 * torch.round(d / 2)


def map_l1(u, truth, lobe_weight=1.0, sigma_weight=0.0, mse_weight=0.0, diffuse_weight=1.0, normal_weight=1.0):
    """training::map_losses' L1 term (lobe_l1 for the lobes and the rotation, weighted by
    lobe_weight as train --lobe-weight does), batch mean; with sigma_weight > 0 plus sigma_weight
    times the lobe widths' squared error in the original range against lobe_l1's form of the truth
    (training::lobe_width_squared_error, mean over texels and the two widths; train --sigma-weight);
    with mse_weight > 0 plus mse_weight times the squared error of a_d, a'_s, F0 and the normal's x
    and y in the original ranges (training::map_squared_error; train --mse-weight). a_d's L1 and
    squared error are weighted by diffuse_weight, the normal's by normal_weight (train
    --diffuse-weight, --normal-weight)."""
    weight = torch.tensor([diffuse_weight] * 3 + [1.0] * 3 + [1.0, normal_weight, normal_weight], dtype=u.dtype, device=u.device)
    other = [0, 1, 2, 3, 4, 5, 8, 9, 10]
    total = ((u[:, other] - truth[:, other]).abs() * weight.view(1, -1, 1, 1)).sum((1, 2, 3))
    px, py, pa = u[:, 6], u[:, 7], u[:, 11]
    qx, qy, qa = truth[:, 6], truth[:, 7], truth[:, 11]
    w = torch.clamp((qx - qy).abs() / ROTATION_RAMP, max=1.0)
    c0 = (px - qx).abs() + (py - qy).abs() + w * wrap(pa - qa).abs()
    c1 = (px - qy).abs() + (py - qx).abs() + w * wrap(pa - qa - 1).abs()
    total = total + lobe_weight * torch.minimum(c0, c1).sum((1, 2))
    result = (total / (u.shape[2] * u.shape[3] * 12)).mean()
    if sigma_weight > 0:
        width = lambda t: torch.exp(LOG_MIN_LOBE + (t + 1) / 2 * (-LOG_MIN_LOBE))  # noqa: E731
        swap = (c1 < c0).detach()
        tx, ty = torch.where(swap, qy, qx), torch.where(swap, qx, qy)
        sq = (width(px) - width(tx)) ** 2 + (width(py) - width(ty)) ** 2
        result = result + sigma_weight * sq.mean() / 2
    if mse_weight > 0:
        p, q = network_to_maps(u), network_to_maps(truth)
        sq = (diffuse_weight * ((p["diffuse"] - q["diffuse"]) ** 2).mean((1, 2, 3)) + ((p["specular"] - q["specular"]) ** 2).mean((1, 2, 3))
              + ((p["f0"] - q["f0"]) ** 2).mean((1, 2))
              + normal_weight * ((p["nx"] - q["nx"]) ** 2 + (p["ny"] - q["ny"]) ** 2).mean((1, 2)) / 3)
        result = result + mse_weight * sq.mean()
    return result


def render_loss(u, conf_loss, targets_log):
    """Sum over the 4 render-loss images of the mean |log(R + 0.01) - log(T + 0.01)|, batch mean."""
    r = render_batch(network_to_maps(u), conf_loss)
    per = (torch.log(r + ward.LOG_EPS) - targets_log).abs()
    return per.mean((2, 3, 4)).sum(1).mean()


def per_parameter_mse(u, truth):
    """render/evaluate.hpp's compare_maps on a batch (original ranges): a_d, a'_s, n_s (unit vectors),
    sigma and alpha (as is or in the swapped equivalent form, whichever is nearer), F0, and alpha
    over the anisotropic texels."""
    mu, mt = network_to_maps(u), network_to_maps(truth)
    mse = lambda a, b: ((a - b) ** 2).mean().item()  # noqa: E731
    nz = lambda m: torch.sqrt(torch.clamp(1 - m["nx"] ** 2 - m["ny"] ** 2, min=0))  # noqa: E731
    normal = (((mu["nx"] - mt["nx"]) ** 2 + (mu["ny"] - mt["ny"]) ** 2 + (nz(mu) - nz(mt)) ** 2) / 3).mean().item()

    def rot(d):
        d = d / math.pi
        return (d - torch.round(d)) * math.pi

    ex, ey, ea, tx, ty, ta = mu["sx"], mu["sy"], mu["alpha"], mt["sx"], mt["sy"], mt["alpha"]
    lob0, rot0 = (ex - tx) ** 2 + (ey - ty) ** 2, rot(ea - ta) ** 2
    lob1, rot1 = (ey - tx) ** 2 + (ex - ty) ** 2, rot(ea + math.pi / 2 - ta) ** 2
    swap = lob1 + rot1 < lob0 + rot0
    lobes, r = torch.where(swap, lob1, lob0) / 2, torch.where(swap, rot1, rot0)
    aniso = torch.maximum(tx, ty) >= 1.25 * torch.minimum(tx, ty)
    return [mse(mu["diffuse"], mt["diffuse"]), mse(mu["specular"], mt["specular"]), normal, lobes.mean().item(),
            r.mean().item(), mse(mu["f0"], mt["f0"]), (r[aniso].mean().item() if aniso.any() else float("nan"))]


# ---- data --------------------------------------------------------------------------------------

def record_dtype(size, reference=False):
    fields = [("seed", "<u8"), ("kind", "<i4"), ("maps", "<f2", (size, size, 12)), ("conf", "<f4", (9, 9))]
    if reference:
        fields.append(("renders", "<f4", (9, 3, size, size)))
    return np.dtype(fields)


def read_chunk(path):
    with open(path, "rb") as f:
        magic, version, count, size, flags = struct.unpack("<5i", f.read(20))
        if magic != 0x41435444 or version != 1:
            raise SystemExit(f"{path}: not a torch_training_data file")
        return np.frombuffer(f.read(), dtype=record_dtype(size, flags & 1), count=count)


class Producer:
    """Keeps `workers` generator processes writing chunks of fresh materials; chunks() yields them."""

    def __init__(self, tool, seed, size, chunk, workers, extra, first=0):
        self.tool, self.seed, self.size, self.chunk, self.extra = tool, seed, size, chunk, extra
        self.next_first = first
        self.dir = tempfile.mkdtemp(prefix="anisocap_chunks_", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
        self.ready = queue.Queue(maxsize=2 * workers)
        self.stop = False
        self.failed = None
        self.lock = threading.Lock()
        self.generated = 0
        self.threads = [threading.Thread(target=self.work, daemon=True) for _ in range(workers)]
        for t in self.threads:
            t.start()

    def work(self):
        env = dict(os.environ, OMP_NUM_THREADS="1")
        while not self.stop:
            with self.lock:
                first = self.next_first
                self.next_first += self.chunk
            out = os.path.join(self.dir, f"c{first}.bin")
            cmd = [self.tool, "materials", "--out", out, "--seed", str(self.seed), "--first", str(first),
                   "--count", str(self.chunk), "--size", str(self.size)] + self.extra
            r = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            if r.returncode != 0:
                self.failed = f"generator failed: {' '.join(cmd)}: {r.stderr.strip()}"
                self.stop = True
                return
            records = read_chunk(out)
            os.remove(out)
            self.ready.put(records)

    def take(self, block):
        deadline = time.time() + 600
        while True:
            if self.failed:
                raise SystemExit(self.failed)
            try:
                records = self.ready.get(block=block, timeout=1 if block else None)
                break
            except queue.Empty:
                if not block or time.time() > deadline:
                    return None
        self.generated += len(records)
        return records


class Pool:
    """A ring of the most recent `capacity` materials on the GPU (network-space maps in float16);
    batches take fresh materials first and draw at random from the ring when none are left. A batch
    takes finished chunks from the generators only while fewer than two batches of fresh materials
    are waiting: where the generators outpace the training step, the rest wait in the producer's
    queue (and the generators for room in it) instead of costing the training loop their copies to
    the GPU and then being overwritten unseen (models/README.md, "Run 30")."""

    def __init__(self, producer, capacity, size, device):
        self.producer, self.capacity, self.device = producer, capacity, device
        self.maps = torch.empty((capacity, 12, size, size), dtype=torch.float16, device=device)
        self.conf = torch.empty((capacity, 9, 9), dtype=torch.float32, device=device)
        self.write = 0    # next slot
        self.filled = 0   # slots holding a material
        self.fresh = 0    # materials not yet drawn (the ones just before `write`)
        self.used = 0

    def add(self, records):
        n = min(len(records), self.capacity)
        maps = torch.from_numpy(records["maps"][:n].copy()).to(self.device).permute(0, 3, 1, 2)
        conf = torch.from_numpy(records["conf"][:n].copy()).to(self.device)
        idx = (self.write + torch.arange(n, device=self.device)) % self.capacity
        self.maps[idx] = maps
        self.conf[idx] = conf
        self.write = (self.write + n) % self.capacity
        self.filled = min(self.filled + n, self.capacity)
        self.fresh = min(self.fresh + n, self.capacity)

    def batch(self, n):
        while self.filled < n:
            self.add(self.producer.take(True))
        for _ in range(4):  # what the generators finished since the last batch, a few chunks at most
            if self.fresh >= 2 * n:
                break
            r = self.producer.take(False)
            if r is None:
                break
            self.add(r)
        if self.fresh >= n:
            idx = (self.write - self.fresh + torch.arange(n, device=self.device)) % self.capacity
            self.fresh -= n
        else:
            idx = torch.randint(0, self.filled, (n,), device=self.device)
        self.used += n
        maps, conf = self.maps[idx].float(), self.conf[idx]
        # Random flips (a flipped material is another valid one): x flips n_x and alpha, y flips n_y and alpha.
        fx = torch.rand(n, device=self.device) < 0.5
        fy = torch.rand(n, device=self.device) < 0.5
        maps[fx] = maps[fx].flip(3)
        maps[fx, 9] = -maps[fx, 9]
        maps[fx, 11] = -maps[fx, 11]
        maps[fy] = maps[fy].flip(2)
        maps[fy, 10] = -maps[fy, 10]
        maps[fy, 11] = -maps[fy, 11]
        return maps, conf


# ---- training ----------------------------------------------------------------------------------

def make_net(network, preset):
    return AutoEncoder(preset) if network == "autoencoder" else Estimator(preset)


def losses(net, network, maps, conf, render_weight, smoothness=0.1, latent_noise=0.1, channels=3, source=None, lobe_weight=1.0,
           sigma_weight=0.0, noise=(0.0, 0.0), mse_weight=0.0, diffuse_weight=1.0, normal_weight=1.0):
    """Returns (total, l1, render) for one batch of network-space truth maps and configurations.
    For the auto-encoder, `source` (an estimator, not trained) replaces the encoder's input by its
    estimate from the 5 training inputs (train-autoencoder --inputs estimates). `lobe_weight`
    weighs the lobe widths' and rotation's L1 (train --lobe-weight; validation uses 1), `sigma_weight`
    the lobe widths' squared error (train --sigma-weight; validation uses 0), `mse_weight` the other
    maps' (train --mse-weight; validation uses 0), `diffuse_weight` and `normal_weight` a_d's and the
    normal's terms (train --diffuse-weight, --normal-weight; validation uses 1). `noise` (shot, read)
    puts add_sensor_noise on the estimator's 5 inputs (train-estimator --shot-noise/--read-noise;
    validation uses none)."""
    with torch.no_grad():
        truth_maps = network_to_maps(maps)
        targets = torch.log(render_batch(truth_maps, conf[:, 5:9]) + ward.LOG_EPS)
    if network == "autoencoder":
        x = maps
        if source is not None:
            with torch.no_grad():
                x = source(estimator_inputs(render_batch(truth_maps, conf[:, 0:5]), source.inputs), 5)
        z = net.encode(x)
        y = net.decode(z)
        l1, rl = map_l1(y, maps, lobe_weight, sigma_weight, mse_weight, diffuse_weight, normal_weight), render_loss(y, conf[:, 5:9], targets)
        total = l1 + render_weight * rl
        if smoothness > 0 and net.training:
            y2 = net.decode(z + latent_noise * torch.randn_like(z))
            total = total + smoothness * (y - y2).abs().mean()
    else:
        with torch.no_grad():
            photos = render_batch(truth_maps, conf[:, 0:5])
            if noise[0] > 0 or noise[1] > 0:
                photos = add_sensor_noise(photos, noise[0], noise[1])
            x = estimator_inputs(photos, channels)
        y = net(x, 5)
        l1, rl = map_l1(y, maps, lobe_weight, sigma_weight, mse_weight, diffuse_weight, normal_weight), render_loss(y, conf[:, 5:9], targets)
        total = l1 + render_weight * rl
    return total, l1, rl, y


def validate(net, network, val, render_weight, channels, batch=8, source=None):
    net.eval()
    rows = []
    with torch.no_grad():
        for i in range(0, len(val[0]), batch):
            maps, conf = val[0][i:i + batch], val[1][i:i + batch]
            _, l1, rl, y = losses(net, network, maps, conf, render_weight, channels=channels, source=source)
            rows.append([l1.item(), rl.item()] + per_parameter_mse(y, maps))
    net.train()
    return np.mean(np.array(rows), 0)


def learning_rate(args, step, fraction):
    """Linear warm-up from 10% over --warmup steps, then constant, then cosine down to --lr-end x
    --lr over the last --decay share of the time budget."""
    lr = args.lr * min(1.0, 0.1 + 0.9 * step / max(1, args.warmup))
    start = 1 - args.decay
    if fraction > start:
        t = min(1.0, (fraction - start) / args.decay)
        lr *= args.lr_end + (1 - args.lr_end) * 0.5 * (1 + math.cos(math.pi * t))
    return lr


def train(args):
    device = torch.device("cuda" if torch.cuda.is_available() and not args.cpu else "cpu")
    torch.backends.cudnn.benchmark = True
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    torch.manual_seed(args.seed)
    if not (args.shot_noise >= 0 and args.read_noise >= 0 and math.isfinite(args.shot_noise + args.read_noise)):
        raise SystemExit("--shot-noise and --read-noise must be finite and not negative")
    if args.network != "estimator" and (args.shot_noise > 0 or args.read_noise > 0):
        raise SystemExit("--shot-noise/--read-noise are for the estimator's photographs")
    _, meta, _ = read_safetensors(args.init)
    if meta.get("network") != args.network:
        raise SystemExit(f"{args.init}: holds {meta.get('network')} weights, not {args.network}")
    preset = meta.get("preset", "compact")
    net = make_net(args.network, preset).to(device)
    meta, names = load_cpp(net, args.init)
    channels = net.inputs if args.network == "estimator" else 12
    source = None
    if args.network == "autoencoder" and args.inputs == "estimates":
        if not args.input_estimator:
            raise SystemExit("--inputs estimates needs --input-estimator FILE")
        _, source_meta, _ = read_safetensors(args.input_estimator)
        if source_meta.get("network") != "estimator":
            raise SystemExit(f"{args.input_estimator}: holds {source_meta.get('network')} weights, not estimator weights")
        source = Estimator(source_meta.get("preset", "compact")).to(device)
        load_cpp(source, args.input_estimator)
        source.eval()
        source.requires_grad_(False)
    trained = net.parameters()
    if args.trainable == "encoder":
        if args.network != "autoencoder":
            raise SystemExit("--trainable encoder is for the auto-encoder")
        for layer in net.decoder_layers():
            layer.requires_grad_(False)
        trained = [p for p in net.parameters() if p.requires_grad]
    os.makedirs(args.out, exist_ok=True)
    extra = ["--materials", "training"] + (["--emphasis", args.emphasis, "--emphasis-share", str(args.emphasis_share)] if args.emphasis else [])
    val_records = None
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "val.bin")
        subprocess.run([args.tool, "materials", "--out", path, "--validation", "--first", "0", "--count", str(args.validation_count),
                        "--size", str(args.size)] + extra, check=True)
        val_records = read_chunk(path)
    val = (torch.from_numpy(val_records["maps"].astype(np.float32)).to(device).permute(0, 3, 1, 2).contiguous(),
           torch.from_numpy(val_records["conf"].copy()).to(device))
    producer = Producer(args.tool, args.seed, args.size, args.chunk, args.workers, extra, first=args.first)
    pool = Pool(producer, args.pool, args.size, device)
    opt = torch.optim.Adam(trained, lr=args.lr)
    csv_path = os.path.join(args.out, "validation.csv")
    header = ["step", "materials_drawn", "materials_generated", "seconds", "lr", "train_loss", "val_l1", "val_render",
              "mse_diffuse", "mse_specular", "mse_normal", "mse_lobes", "mse_rotation", "mse_fresnel",
              "mse_rotation_anisotropic"]
    with open(csv_path, "w", newline="") as f:
        csv.writer(f).writerow(header)

    def log_validation(step, seconds, lr, train_loss):
        v = validate(net, args.network, val, args.render_weight, channels, source=source)
        row = [step, pool.used, producer.generated, round(seconds, 1), lr, train_loss] + [float(x) for x in v]
        with open(csv_path, "a", newline="") as f:
            csv.writer(f).writerow(row)
        print(f"{args.network} validation step {step}: L1 {v[0]:.4f} render {v[1]:.4f} mse a_d {v[2]:.5f} a_s {v[3]:.5f} "
              f"n {v[4]:.5f} sigma {v[5]:.5f} alpha {v[6]:.4f} F0 {v[7]:.5f} alpha aniso {v[8]:.4f}", flush=True)

    log_validation(0, 0.0, 0.0, float("nan"))
    start = time.time()
    step, window, last_print, last_save = 0, [], start, start
    out_file = os.path.join(args.out, f"{args.network}.safetensors")
    meta = dict(meta, trained_with="studies/train_torch.py")
    while True:
        elapsed = time.time() - start
        fraction = elapsed / (60 * args.minutes)
        if fraction >= 1:
            break
        lr = learning_rate(args, step, fraction)
        for g in opt.param_groups:
            g["lr"] = lr
        maps, conf = pool.batch(args.batch)
        total, l1, rl, _ = losses(net, args.network, maps, conf, args.render_weight, channels=channels, source=source,
                                   lobe_weight=args.lobe_weight, sigma_weight=args.sigma_weight, mse_weight=args.mse_weight,
                                   diffuse_weight=args.diffuse_weight, normal_weight=args.normal_weight,
                                   noise=(args.shot_noise, args.read_noise))
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()
        step += 1
        window.append(total.item() if step % 10 == 0 else None)
        now = time.time()
        if now - last_print > 30:
            done = [w for w in window if w is not None]
            print(f"{args.network}: step {step} ({step / (now - start):.1f} steps/s, {pool.used / (now - start):.0f} materials/s drawn, "
                  f"{producer.generated} generated) loss {np.mean(done) if done else float('nan'):.4f} lr {lr:.2e}", flush=True)
            last_print = now
        if step % args.validate_every == 0:
            done = [w for w in window if w is not None]
            log_validation(step, now - start, lr, float(np.mean(done)) if done else float("nan"))
            window = []
        if now - last_save > 60 * args.save_minutes:
            save_cpp(net, out_file, names, meta, args.half)
            last_save = now
    producer.stop = True
    done = [w for w in window if w is not None]
    log_validation(step, time.time() - start, lr, float(np.mean(done)) if done else float("nan"))
    save_cpp(net, out_file, names, meta, args.half)
    with open(os.path.join(args.out, "run.json"), "w") as f:
        json.dump({"network": args.network, "preset": preset, "init": args.init, "steps": step, "batch": args.batch,
                   "materials_drawn": pool.used, "materials_generated": producer.generated, "seconds": time.time() - start,
                   "lr": args.lr, "lr_end": args.lr_end, "decay": args.decay, "warmup": args.warmup, "seed": args.seed,
                   "first": args.first, "half": args.half, "render_weight": args.render_weight, "lobe_weight": args.lobe_weight, "sigma_weight": args.sigma_weight,
                   "mse_weight": args.mse_weight, "diffuse_weight": args.diffuse_weight, "normal_weight": args.normal_weight,
                   "shot_noise": args.shot_noise, "read_noise": args.read_noise, "emphasis": args.emphasis,
                   "emphasis_share": args.emphasis_share, "trainable": args.trainable, "inputs": args.inputs,
                   "input_estimator": args.input_estimator, "device": torch.cuda.get_device_name() if device.type == "cuda" else "cpu",
                   "torch": torch.__version__}, f, indent=1)
    print(f"{args.network}: {step} steps, {pool.used} materials drawn ({producer.generated} generated) in {time.time() - start:.0f} s; "
          f"weights in {out_file}", flush=True)


# ---- checks against the C++ library ------------------------------------------------------------

def write_tensor(path, t):
    """(N, C, H, W) -> the NHWC float32 file of torch_training_data forward."""
    a = t.permute(0, 2, 3, 1).contiguous().float().cpu().numpy()
    with open(path, "wb") as f:
        f.write(struct.pack("<4i", *a.shape))
        f.write(a.tobytes())


def read_tensor(path):
    with open(path, "rb") as f:
        shape = struct.unpack("<4i", f.read(16))
        return torch.from_numpy(np.frombuffer(f.read(), dtype="<f4").reshape(shape).copy()).permute(0, 3, 1, 2)


def check(args):
    """The port against the C++ network on the same weights and inputs, and the GPU renders and
    orientation channels against the C++ renders of the same materials."""
    torch.set_default_dtype(torch.float64)
    _, meta, _ = read_safetensors(args.weights)
    net = make_net(args.network, meta.get("preset", "compact")).double()
    load_cpp(net, args.weights)
    net.eval()
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "m.bin")
        subprocess.run([args.tool, "materials", "--out", data, "--seed", "7", "--count", "4", "--size", "128", "--reference"], check=True)
        rec = read_chunk(data)
        maps = torch.from_numpy(rec["maps"].astype(np.float64)).permute(0, 3, 1, 2)
        conf = torch.from_numpy(rec["conf"].astype(np.float64))
        ours = render_batch(network_to_maps(maps), conf)  # (B, 9, H, W, 3)
        theirs = torch.from_numpy(rec["renders"].astype(np.float64)).permute(0, 1, 3, 4, 2)
        log_diff = (torch.log(ours + 0.01) - torch.log(theirs + 0.01)).abs()
        print(f"renders (9 configurations x 4 materials, 128 x 128; maps through float16): |log difference| "
              f"mean {log_diff.mean().item():.2e}, 99.9th percentile {torch.quantile(log_diff.flatten()[::7], 0.999).item():.2e}, "
              f"max {log_diff.max().item():.2e}")
        if args.network == "estimator":
            x = estimator_inputs(theirs[:1, 0:5], net.inputs)
            src = "the C++ renders of one material's 5 inputs"
        else:
            x = maps
            src = "4 materials' maps"
        inp, out = os.path.join(tmp, "in.bin"), os.path.join(tmp, "out.bin")
        write_tensor(inp, x)
        subprocess.run([args.tool, "forward", "--network", args.network, "--weights", args.weights, "--input", inp, "--out", out],
                       check=True)
        ref = read_tensor(out).double()
        with torch.no_grad():
            y = net(x, x.shape[0]) if args.network == "estimator" else net.decode(net.encode(x))
        diff = (y - ref).abs().max().item()
        print(f"{args.network} ({meta.get('preset')}) on {src}: max |PyTorch - C++| {diff:.2e} (outputs in [-1, 1])")
        if diff > args.tolerance or log_diff.mean().item() > 0.01:
            raise SystemExit("check FAILED")
        print("check passed")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--network", choices=["estimator", "autoencoder"], required=True)
    t.add_argument("--init", required=True, help="C++ weight file to start from (its preset is used)")
    t.add_argument("--out", required=True)
    t.add_argument("--tool", required=True, help="anisocap_study_torch_training_data")
    t.add_argument("--minutes", type=float, default=9)
    t.add_argument("--batch", type=int, default=32)
    t.add_argument("--size", type=int, default=128)
    t.add_argument("--lr", type=float, default=3e-4)
    t.add_argument("--lr-end", type=float, default=0.05, help="final rate as a fraction of --lr")
    t.add_argument("--decay", type=float, default=0.5, help="share of the time budget spent in the cosine decay")
    t.add_argument("--warmup", type=int, default=300)
    t.add_argument("--render-weight", type=float, default=0.1)
    t.add_argument("--lobe-weight", type=float, default=1.0, help="weight of the lobe widths' and rotation's L1 (validation: 1)")
    t.add_argument("--sigma-weight", type=float, default=0.0, help="weight of the lobe widths' squared error, original range (validation: 0)")
    t.add_argument("--mse-weight", type=float, default=0.0,
                   help="weight of a_d's, a'_s', F0's and the normal's squared error, original ranges (validation: 0)")
    t.add_argument("--diffuse-weight", type=float, default=1.0, help="weight of a_d's L1 and squared error (validation: 1)")
    t.add_argument("--normal-weight", type=float, default=1.0, help="weight of the normal's L1 and squared error (validation: 1)")
    t.add_argument("--shot-noise", type=float, default=0.0,
                   help="sensor noise on the estimator's training inputs (as train-estimator --shot-noise)")
    t.add_argument("--read-noise", type=float, default=0.0, help="as train-estimator --read-noise")
    t.add_argument("--seed", type=int, default=1013)
    t.add_argument("--first", type=int, default=0, help="first material index (a continued run takes new materials)")
    t.add_argument("--half", action="store_true",
                   help="write the weights with the kernels as half floats (as anisocap convert-weights --half): half the size, "
                        "under the device machine's 16 MiB a file for every compact preset")
    t.add_argument("--emphasis", default="")
    t.add_argument("--emphasis-share", type=float, default=0.5)
    t.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) - 2))
    t.add_argument("--chunk", type=int, default=128)
    t.add_argument("--pool", type=int, default=16384, help="materials kept on the GPU for re-use")
    t.add_argument("--validation-count", type=int, default=64)
    t.add_argument("--validate-every", type=int, default=500)
    t.add_argument("--save-minutes", type=float, default=2)
    t.add_argument("--cpu", action="store_true")
    t.add_argument("--trainable", choices=["all", "encoder"], default="all",
                   help="auto-encoder: train everything, or the encoder only against the --init decoder")
    t.add_argument("--inputs", choices=["truth", "estimates"], default="truth",
                   help="auto-encoder: the encoder reads the true maps or --input-estimator's estimates of the 5 inputs")
    t.add_argument("--input-estimator", default="", help="estimator weights (C++ file) for --inputs estimates")
    c = sub.add_parser("check")
    c.add_argument("--network", choices=["estimator", "autoencoder"], required=True)
    c.add_argument("--weights", required=True)
    c.add_argument("--tool", required=True)
    c.add_argument("--tolerance", type=float, default=1e-3)
    args = parser.parse_args()
    train(args) if args.command == "train" else check(args)


if __name__ == "__main__":
    main()
