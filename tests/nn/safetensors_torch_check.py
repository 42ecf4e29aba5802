#!/usr/bin/python3
"""Checks that anisocap's safetensors files and PyTorch agree, without the `safetensors` package:
the format (8-byte little-endian header length, JSON header, raw little-endian data) is written
and read here by hand with struct/json and torch tensors.

  safetensors_torch_check.py IN OUT   loads anisocap's linear and batch-norm weights from IN into
                                      torch modules and compares with anisocap's outputs stored
                                      there, then writes OUT: tensors of known values and a
                                      torch.nn.Linear with its input and output
One process does both directions (importing torch takes seconds). Exit status 77 when torch is
not available (the C++ test then skips), 1 on a mismatch.
"""
import json
import struct
import sys

try:
    import torch
except ImportError:
    print("no torch")
    sys.exit(77)

DTYPES = {torch.float32: "F32", torch.float64: "F64", torch.int64: "I64"}
TORCH = {v: k for k, v in DTYPES.items()}


def write(path, tensors, metadata=None):
    header, chunks, offset = {}, [], 0
    if metadata:
        header["__metadata__"] = metadata
    for name, t in tensors.items():
        data = t.contiguous().numpy().tobytes()  # numpy on x86: little-endian
        header[name] = {"dtype": DTYPES[t.dtype], "shape": list(t.shape), "data_offsets": [offset, offset + len(data)]}
        chunks.append(data)
        offset += len(data)
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(text)) + text + b"".join(chunks))


def read(path):
    with open(path, "rb") as f:
        blob = f.read()
    (n,) = struct.unpack("<Q", blob[:8])
    header = json.loads(blob[8:8 + n])
    data = blob[8 + n:]
    out = {}
    for name, e in header.items():
        if name == "__metadata__":
            continue
        b, end = e["data_offsets"]
        t = torch.frombuffer(bytearray(data[b:end]), dtype=TORCH[e["dtype"]]) if end > b else torch.empty(0, dtype=TORCH[e["dtype"]])
        out[name] = t.reshape(e["shape"])
    return out


def write_torch_file(path):
    torch.manual_seed(0)
    fc = torch.nn.Linear(5, 3)
    bn = torch.nn.BatchNorm2d(3)
    x = torch.randn(2, 5)
    with torch.no_grad():
        y = fc(x)
    tensors = {"a": torch.arange(12, dtype=torch.float32).reshape(3, 4) * 0.5 - 1}
    tensors.update({"fc." + k: v for k, v in fc.state_dict().items()})
    tensors.update({"bn." + k: v for k, v in bn.state_dict().items()})  # includes I64 num_batches_tracked
    tensors["fc.input"] = x
    tensors["fc.output"] = y
    write(path, tensors, {"format": "pt"})


def check_anisocap_file(path):
    t = read(path)
    fc = torch.nn.Linear(5, 3)
    fc.load_state_dict({"weight": t["fc.weight"], "bias": t["fc.bias"]})
    bn = torch.nn.BatchNorm2d(3).eval()
    bn.load_state_dict({k: t["bn." + k] for k in ["weight", "bias", "running_mean", "running_var"]}, strict=False)
    x = t["input_nhwc"]
    with torch.no_grad():
        h = fc(x)  # Linear acts on the last (channel) axis: NHWC as it is
        z = bn(h.permute(0, 3, 1, 2)).permute(0, 2, 3, 1)
    ok = torch.allclose(h, t["fc_output_nhwc"], rtol=1e-5, atol=1e-6) and torch.allclose(z, t["bn_output_nhwc"], rtol=1e-5, atol=1e-5)
    if not ok:
        print("mismatch: fc", (h - t["fc_output_nhwc"]).abs().max().item(), "bn", (z - t["bn_output_nhwc"]).abs().max().item())
    return ok


def main():
    if not check_anisocap_file(sys.argv[1]):
        return 1
    write_torch_file(sys.argv[2])
    return 0


if __name__ == "__main__":
    sys.exit(main())
