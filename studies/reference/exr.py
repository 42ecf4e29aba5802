"""A tiny OpenEXR reader and writer in pure Python + numpy (no OpenEXR module needed).

Reads single-part scanline images with UINT, HALF and FLOAT channels, compressed with NONE, ZIPS
(one scanline per chunk) or ZIP (16 scanlines per chunk): the zlib stream is inflated, then EXR's
predictor (byte deltas + 128) and its byte interleave (even bytes first, odd bytes second) are
undone. Tiled, multi-part and deep files and the other compressions are rejected with a clear
error. Writes uncompressed float32 images (B, G, R or any channel names). It exists so that the
independent reference renderer (ward_reference.py) can read what `anisocap` writes without sharing
any of its code (tinyexr).
"""
import struct
import zlib

import numpy as np

_MAGIC = 20000630
_PIXEL_DTYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}
_COMPRESSIONS = {0: ("NONE", 1), 2: ("ZIPS", 1), 3: ("ZIP", 16)}
_COMPRESSION_NAMES = {0: "NONE", 1: "RLE", 2: "ZIPS", 3: "ZIP", 4: "PIZ", 5: "PXR24", 6: "B44",
                      7: "B44A", 8: "DWAA", 9: "DWAB"}


class ExrError(RuntimeError):
    """A file that is not an EXR this reader understands; the message names the file."""


def _read_cstring(data, pos, path):
    end = data.find(b"\0", pos)
    if end < 0:
        raise ExrError(f"{path}: truncated header")
    return data[pos:end].decode("latin-1"), end + 1


def _parse_channels(value, path):
    channels = []
    pos = 0
    while pos < len(value) and value[pos] != 0:
        name, pos = _read_cstring(value, pos, path)
        pixel_type, _plinear, xs, ys = struct.unpack_from("<iB3xii", value, pos)
        pos += 16
        if pixel_type not in _PIXEL_DTYPES:
            raise ExrError(f"{path}: channel {name} has unknown pixel type {pixel_type}")
        if xs != 1 or ys != 1:
            raise ExrError(f"{path}: channel {name} is subsampled ({xs}x{ys}), not supported")
        channels.append((name, _PIXEL_DTYPES[pixel_type]))
    return sorted(channels, key=lambda c: c[0].encode("latin-1"))  # stored in byte order of names


def _undo_zip(raw, expected, path):
    try:
        t = np.frombuffer(zlib.decompress(raw), dtype=np.uint8)
    except zlib.error as e:
        raise ExrError(f"{path}: corrupt ZIP chunk ({e})") from None
    if t.size != expected:
        raise ExrError(f"{path}: ZIP chunk inflates to {t.size} bytes, expected {expected}")
    # Predictor: t[i] = t[i-1] + stored[i] - 128 (mod 256); a cumulative sum does it in one go.
    deltas = t.astype(np.int64)
    deltas[1:] -= 128
    t = (np.cumsum(deltas) & 0xFF).astype(np.uint8)
    # Interleave: the first half holds the even bytes, the second half the odd bytes.
    out = np.empty_like(t)
    half = (t.size + 1) // 2
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out.tobytes()


def read_exr(path):
    """Reads an EXR file; returns {channel name: float64 array of shape (height, width)}."""
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 8:
        raise ExrError(f"{path}: too short for an EXR file")
    magic, version = struct.unpack_from("<ii", data, 0)
    if magic != _MAGIC:
        raise ExrError(f"{path}: not an EXR file (bad magic number)")
    if version & 0x200:
        raise ExrError(f"{path}: tiled EXR files are not supported by this reader")
    if version & 0x1800:
        raise ExrError(f"{path}: multi-part or deep EXR files are not supported")
    pos = 8
    header = {}
    while True:
        if pos >= len(data):
            raise ExrError(f"{path}: truncated header")
        if data[pos] == 0:
            pos += 1
            break
        name, pos = _read_cstring(data, pos, path)
        typ, pos = _read_cstring(data, pos, path)
        (size,) = struct.unpack_from("<i", data, pos)
        pos += 4
        header[name] = (typ, data[pos:pos + size])
        pos += size
    for required in ("channels", "compression", "dataWindow"):
        if required not in header:
            raise ExrError(f"{path}: header lacks '{required}'")
    channels = _parse_channels(header["channels"][1], path)
    compression = header["compression"][1][0]
    if compression not in _COMPRESSIONS:
        name = _COMPRESSION_NAMES.get(compression, str(compression))
        raise ExrError(f"{path}: compression {name} is not supported (NONE, ZIPS, ZIP are)")
    lines_per_chunk = _COMPRESSIONS[compression][1]
    xmin, ymin, xmax, ymax = struct.unpack("<iiii", header["dataWindow"][1])
    width, height = xmax - xmin + 1, ymax - ymin + 1
    if width <= 0 or height <= 0:
        raise ExrError(f"{path}: empty data window")
    chunks = (height + lines_per_chunk - 1) // lines_per_chunk
    offsets = struct.unpack_from(f"<{chunks}Q", data, pos)
    planes = {name: np.empty((height, width), dtype=dt) for name, dt in channels}
    line_bytes = sum(dt.itemsize for _, dt in channels) * width
    for offset in offsets:
        if offset + 8 > len(data):
            raise ExrError(f"{path}: chunk offset {offset} beyond the end of the file")
        y, size = struct.unpack_from("<ii", data, offset)
        raw = data[offset + 8: offset + 8 + size]
        if len(raw) != size:
            raise ExrError(f"{path}: truncated chunk at line {y}")
        row0 = y - ymin
        lines = min(lines_per_chunk, height - row0)
        if row0 < 0 or lines <= 0:
            raise ExrError(f"{path}: chunk line {y} outside the data window")
        expected = lines * line_bytes
        if compression != 0 and size < expected:
            raw = _undo_zip(raw, expected, path)
        elif size != expected:
            raise ExrError(f"{path}: chunk at line {y} has {size} bytes, expected {expected}")
        p = 0
        for r in range(lines):  # per scanline: every channel's row in turn
            for name, dt in channels:
                n = width * dt.itemsize
                planes[name][row0 + r] = np.frombuffer(raw, dtype=dt, count=width, offset=p)
                p += n
    return {name: plane.astype(np.float64) for name, plane in planes.items()}


def read_rgb(path):
    """Reads an EXR as an (height, width, 3) float64 array: R, G, B, or a lone Y channel repeated."""
    ch = read_exr(path)
    if all(c in ch for c in "RGB"):
        return np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    if "Y" in ch:
        return np.repeat(ch["Y"][..., None], 3, axis=-1)
    raise ExrError(f"{path}: has channels {sorted(ch)}, expected R, G, B or Y")


def _attr(name, typ, value):
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value


def write_exr(path, channels):
    """Writes {name: (height, width) array} as an uncompressed float32 scanline EXR."""
    names = sorted(channels, key=lambda s: s.encode("latin-1"))
    planes = [np.asarray(channels[n], dtype="<f4") for n in names]
    height, width = planes[0].shape
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in names) + b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = (struct.pack("<ii", _MAGIC, 2) + _attr("channels", "chlist", chlist)
              + _attr("compression", "compression", b"\0") + _attr("dataWindow", "box2i", box)
              + _attr("displayWindow", "box2i", box) + _attr("lineOrder", "lineOrder", b"\0")
              + _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
              + _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
              + _attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0")
    line = 4 * width * len(names)
    start = len(header) + 8 * height
    offsets = struct.pack(f"<{height}Q", *[start + y * (8 + line) for y in range(height)])
    body = b"".join(struct.pack("<ii", y, line) + b"".join(p[y].tobytes() for p in planes)
                    for y in range(height))
    with open(path, "wb") as f:
        f.write(header + offsets + body)


def write_rgb(path, image):
    """Writes an (height, width, 3) array as an uncompressed float32 RGB EXR."""
    image = np.asarray(image)
    write_exr(path, {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2]})
