"""Lightmap image files (no bpy): OpenEXR and PNG writers, the sRGB transfer curve, and a
structure check of written files.

Only writers ship: Blender reads the files (image sequences in the helper material), the tests
decode them with Blender's own image loader. image_file_problem() reads headers and chunk tables,
not pixels: playback and the bake use it to find frames that a crash or a full disk left
truncated, without decoding megabytes per frame change.

Pixel order is Blender's: (H, W, 3), row 0 at the bottom.
"""

import struct
import zlib

import numpy as np

EXR_MAGIC = 20000630
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_EXR_LINES = {0: 1, 2: 1, 3: 16}  # scanlines per chunk: NONE, ZIPS, ZIP


def linear_to_srgb(x):
    """sRGB transfer curve (IEC 61966-2-1) of linear values, clipped to [0, 1]."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_to_linear(x):
    """Inverse of linear_to_srgb: linear values of sRGB-encoded ones in [0, 1]."""
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


# --- OpenEXR -------------------------------------------------------------------------------------


def _attr(name, typ, data):
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(data)) + data


def _exr_zip(raw):
    """OpenEXR ZIP block coding: byte interleave, delta predictor, zlib (raw if that is not smaller)."""
    a = np.frombuffer(raw, np.uint8)
    t = np.concatenate([a[0::2], a[1::2]])
    p = t.copy()
    p[1:] = (np.diff(t.astype(np.int16)) + 384) & 0xFF
    z = zlib.compress(p.tobytes(), 4)
    return z if len(z) < len(raw) else raw


def encode_exr(rgb, compression="ZIP"):
    """(H, W, 3) linear RGB -> scanline OpenEXR bytes, channels B, G, R as 32-bit float,
    compression "ZIP" (16 lines per chunk) or "NONE"."""
    img = np.ascontiguousarray(np.asarray(rgb, np.float32)[::-1])  # EXR stores the top row first
    H, W = img.shape[:2]
    comp, lines = (3, 16) if compression == "ZIP" else (0, 1)
    ch = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<iiii", 0, 0, W - 1, H - 1)
    header = (
        struct.pack("<ii", EXR_MAGIC, 2)
        + _attr("channels", "chlist", ch)
        + _attr("compression", "compression", bytes([comp]))
        + _attr("dataWindow", "box2i", box)
        + _attr("displayWindow", "box2i", box)
        + _attr("lineOrder", "lineOrder", b"\0")
        + _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
        + _attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    planar = img[:, :, ::-1].transpose(0, 2, 1).astype("<f4")  # (H, [B, G, R], W)
    chunks = []
    for y in range(0, H, lines):
        raw = np.ascontiguousarray(planar[y : y + lines]).tobytes()
        data = _exr_zip(raw) if comp else raw
        chunks.append(struct.pack("<ii", y, len(data)) + data)
    pos = len(header) + 8 * len(chunks)
    offsets = []
    for c in chunks:
        offsets.append(pos)
        pos += len(c)
    return header + struct.pack(f"<{len(offsets)}Q", *offsets) + b"".join(chunks)


def _exr_problem(data):
    """(W, H, '') of a scanline EXR whose chunk table points inside the file, else (0, 0, why)."""
    if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != EXR_MAGIC:
        return 0, 0, "not an OpenEXR file"
    pos, attrs = 8, {}
    while data[pos] != 0:  # name \0 type \0 size value
        e = data.index(b"\0", pos)
        e2 = data.index(b"\0", e + 1)
        size = struct.unpack_from("<i", data, e2 + 1)[0]
        attrs[data[pos:e].decode()] = data[e2 + 5 : e2 + 5 + size]
        pos = e2 + 5 + size
    x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
    W, H = x1 - x0 + 1, y1 - y0 + 1
    n = -(-H // _EXR_LINES.get(attrs["compression"][0], 1))
    for off in struct.unpack_from(f"<{n}Q", data, pos + 1):
        _, size = struct.unpack_from("<ii", data, off)
        if off + 8 + size > len(data):
            return W, H, "truncated"
    return W, H, ""


# --- PNG -----------------------------------------------------------------------------------------


def _png_chunk(tag, data):
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


PNG_END = _png_chunk(b"IEND", b"")


def encode_png16(rgb):
    """(H, W, 3) linear RGB -> 16-bit sRGB-encoded PNG bytes (values clipped to [0, 1])."""
    img = np.asarray(rgb, np.float64)[::-1]
    H, W = img.shape[:2]
    q = np.round(linear_to_srgb(img) * 65535).astype(">u2").reshape(H, W * 3).view(np.uint8)
    raw = np.concatenate([np.zeros((H, 1), np.uint8), q], 1).tobytes()  # filter type 0 per row
    return (
        PNG_MAGIC
        + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 16, 2, 0, 0, 0))
        + _png_chunk(b"sRGB", b"\0")
        + _png_chunk(b"IDAT", zlib.compress(raw, 6))
        + PNG_END
    )


def _png_problem(data):
    if data[:8] != PNG_MAGIC:
        return 0, 0, "not a PNG file"
    if len(data) < 45 or data[-12:] != PNG_END:
        return 0, 0, "truncated"
    W, H = struct.unpack_from(">II", data, 16)
    return W, H, ""


def image_file_problem(path, res=None):
    """'' if the texture file at `path` is a complete EXR (chunk table and chunks within the file)
    or PNG (ends with IEND) of res x res texels, else what is wrong ('missing', 'truncated', ...)."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    try:
        W, H, why = (_png_problem if str(path).lower().endswith(".png") else _exr_problem)(data)
    except (struct.error, ValueError, KeyError, IndexError, UnicodeDecodeError):
        return "truncated or not an image of a bake"
    if why:
        return why
    if res is not None and (W, H) != (res, res):
        return f"is {W} x {H} texels, not {res} x {res}"
    return ""
