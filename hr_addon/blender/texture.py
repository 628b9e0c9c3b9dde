"""Baked textures: lightmap UVs, texel evaluation of the HR solution, image sequences, material helper.

Per participating object:
- a UV map "HR_Lightmap" (made here by packing planar charts if the mesh has none; the user's own UV
  maps, the active one and the active render one are left as they are). A map the user made and
  named HR_Lightmap is used as is; one made here is re-packed when the mesh or resolution changes;
- one float image per distinct frame: the HR solution evaluated (core.output.radiance_at) at the
  texel centres inside the UV triangles of the object's patches, plus a ring of texels just outside the
  islands evaluated at the nearest island point, then a few texels of dilation so that bilinear
  filtering and mip-maps do not pull in black. Frames whose light state is unchanged are hard links
  (or copies) of the previous frame's file, so the sequence has one file per frame number;
- files <cache>/textures/<object>_<frame:06d>.exr (32-bit float, linear, ZIP) or .png (16-bit,
  sRGB-encoded, values above 1 clipped), written into the bake's temporary directory that replaces
  the cache at the end (see cache.CacheWriter), so a cancelled bake keeps the previous one.
The material helper (add_material) gives each object object-level copies of its materials with an
extra branch UV Map (HR_Lightmap) -> Image Texture (the sequence) -> Emission -> Material Output, all
plain nodes, so the result plays back where the extension is not installed.
"""
import hashlib
import os
import shutil
import struct
import zlib
from contextlib import contextmanager

import bpy
import numpy as np

from ..core.output import corner_weights, locate, radiance_at
from .cache import CacheError, CacheReader
from .materials import PREVIEW

UV_NAME = "HR_Lightmap"
TEX_DIR = "textures"
FORMATS = {"EXR": ".exr", "PNG": ".png"}
MARGIN = 2        # texels of padding on each side of a packed island (islands are 2 x MARGIN apart)
RING = 1.5        # texels outside an island evaluated at the nearest point of the island
DILATE = 2        # further texels filled with the mean of their filled neighbours
PACK_VERSION = 1

N_UV, N_TEX = PREVIEW + " Lightmap UV", PREVIEW + " Lightmap"
N_EMIT, N_OUT, N_ATTR = PREVIEW + " Emission", PREVIEW + " Output", PREVIEW + " Attribute"
TAG = "hr_lightmap_of"          # on helper materials and images: the object's name


class TextureError(ValueError):
    """Texture output is not possible for an object (one-line reason)."""


# --- image files ---------------------------------------------------------------------------------

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


def _exr_unzip(data, size):
    if len(data) == size:
        return data
    p = np.frombuffer(zlib.decompress(data), np.uint8).astype(np.int64)
    t = np.empty_like(p)
    t[0] = p[0]
    t[1:] = (p[0] + np.cumsum(p[1:] - 128)) & 0xFF
    t = t.astype(np.uint8)
    h = (len(t) + 1) // 2
    out = np.empty_like(t)
    out[0::2], out[1::2] = t[:h], t[h:]
    return out.tobytes()


def encode_exr(rgb, compression="ZIP"):
    """(H, W, 3) linear RGB, row 0 at the bottom (Blender's pixel order) -> scanline OpenEXR bytes,
    channels B, G, R as 32-bit float."""
    img = np.ascontiguousarray(np.asarray(rgb, np.float32)[::-1])           # EXR stores the top row first
    H, W = img.shape[:2]
    comp, lines = (3, 16) if compression == "ZIP" else (0, 1)
    ch = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<iiii", 0, 0, W - 1, H - 1)
    header = (struct.pack("<ii", 20000630, 2) + _attr("channels", "chlist", ch)
              + _attr("compression", "compression", bytes([comp])) + _attr("dataWindow", "box2i", box)
              + _attr("displayWindow", "box2i", box) + _attr("lineOrder", "lineOrder", b"\0")
              + _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
              + _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
              + _attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0")
    planar = img[:, :, ::-1].transpose(0, 2, 1).astype("<f4")              # (H, [B, G, R], W)
    chunks = []
    for y in range(0, H, lines):
        raw = np.ascontiguousarray(planar[y:y + lines]).tobytes()
        data = _exr_zip(raw) if comp else raw
        chunks.append(struct.pack("<ii", y, len(data)) + data)
    pos = len(header) + 8 * len(chunks)
    offsets = []
    for c in chunks:
        offsets.append(pos)
        pos += len(c)
    return header + struct.pack(f"<{len(offsets)}Q", *offsets) + b"".join(chunks)


def decode_exr(data):
    """(H, W, C) float32 (row 0 at the bottom) and channel names of a scanline float EXR written by
    encode_exr (NONE, ZIPS or ZIP compression, FLOAT channels). For tests and inspection."""
    if struct.unpack_from("<i", data, 0)[0] != 20000630:
        raise ValueError("not an OpenEXR file")
    pos, attrs = 8, {}
    while data[pos] != 0:
        e = data.index(b"\0", pos)
        name = data[pos:e].decode()
        e2 = data.index(b"\0", e + 1)
        size = struct.unpack_from("<i", data, e2 + 1)[0]
        attrs[name] = data[e2 + 5:e2 + 5 + size]
        pos = e2 + 5 + size
    pos += 1
    chans, cl = [], attrs["channels"]
    i = 0
    while cl[i] != 0:
        e = cl.index(b"\0", i)
        if struct.unpack_from("<i", cl, e + 1)[0] != 2:
            raise ValueError("only 32-bit float channels are supported")
        chans.append(cl[i:e].decode())
        i = e + 17
    x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
    W, H = x1 - x0 + 1, y1 - y0 + 1
    comp = attrs["compression"][0]
    lines = {0: 1, 2: 1, 3: 16}[comp]
    n = -(-H // lines)
    offsets = struct.unpack_from(f"<{n}Q", data, pos)
    out = np.empty((H, len(chans), W), np.float32)
    for off in offsets:
        y, size = struct.unpack_from("<ii", data, off)
        m = min(lines, H - (y - y0))
        raw = data[off + 8:off + 8 + size]
        raw = _exr_unzip(raw, m * len(chans) * W * 4) if comp else raw
        out[y - y0:y - y0 + m] = np.frombuffer(raw, "<f4").reshape(m, len(chans), W)
    return out.transpose(0, 2, 1)[::-1].copy(), chans


def linear_to_srgb(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_to_linear(x):
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _png_chunk(tag, data):
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def encode_png16(rgb):
    """(H, W, 3) linear RGB, row 0 at the bottom -> 16-bit sRGB-encoded PNG bytes (clipped to [0, 1])."""
    img = np.asarray(rgb, np.float64)[::-1]
    H, W = img.shape[:2]
    q = np.round(linear_to_srgb(img) * 65535).astype(">u2").reshape(H, W * 3).view(np.uint8)
    raw = np.concatenate([np.zeros((H, 1), np.uint8), q], 1).tobytes()     # filter type 0 per row
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 16, 2, 0, 0, 0))
            + _png_chunk(b"sRGB", b"\0") + _png_chunk(b"IDAT", zlib.compress(raw, 6)) + _png_chunk(b"IEND", b""))


def decode_png16(data):
    """(H, W, 3) linear float (row 0 at the bottom) of a PNG written by encode_png16."""
    pos, idat, W = 8, b"", None
    while pos < len(data):
        n = struct.unpack_from(">I", data, pos)[0]
        tag = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        if tag == b"IHDR":
            W, H = struct.unpack_from(">II", body)
        elif tag == b"IDAT":
            idat += body
        pos += 12 + n
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(H, 1 + W * 6)
    if rows[:, 0].any():
        raise ValueError("only unfiltered PNG rows are supported")
    v = rows[:, 1:].copy().view(">u2").reshape(H, W, 3).astype(np.float64) / 65535
    return srgb_to_linear(v)[::-1].astype(np.float32)


def read_image(path):
    """(H, W, 3) float32 of a texture file of a bake (row 0 at the bottom)."""
    data = open(path, "rb").read()
    if str(path).lower().endswith(".png"):
        return decode_png16(data)
    img, chans = decode_exr(data)
    return img[..., [chans.index(c) for c in "RGB"]]


def image_file_problem(path, res=None):
    """'' if the texture file at `path` is a complete EXR (offset table and chunks within the file)
    or PNG (ends with IEND) of size res x res, else what is wrong ('missing', 'truncated', ...)."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    try:
        if str(path).lower().endswith(".png"):
            if data[:8] != b"\x89PNG\r\n\x1a\n":
                return "not a PNG file"
            if len(data) < 45 or data[-12:] != _png_chunk(b"IEND", b""):
                return "truncated"
            W, H = struct.unpack_from(">II", data, 16)
        else:
            if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != 20000630:
                return "not an OpenEXR file"
            pos, attrs = 8, {}
            while data[pos] != 0:
                e = data.index(b"\0", pos)
                e2 = data.index(b"\0", e + 1)
                size = struct.unpack_from("<i", data, e2 + 1)[0]
                attrs[data[pos:e].decode()] = data[e2 + 5:e2 + 5 + size]
                pos = e2 + 5 + size
            pos += 1
            x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
            W, H = x1 - x0 + 1, y1 - y0 + 1
            lines = {0: 1, 2: 1, 3: 16}.get(attrs["compression"][0], 1)
            n = -(-H // lines)
            for off in struct.unpack_from(f"<{n}Q", data, pos):
                _, size = struct.unpack_from("<ii", data, off)
                if off + 8 + size > len(data):
                    return "truncated"
    except (struct.error, ValueError, KeyError, IndexError, UnicodeDecodeError):
        return "truncated or not an image of a bake"
    if res is not None and (W, H) != (res, res):
        return f"is {W} x {H} texels, not {res} x {res}"
    return ""


def _atomic_write(path, data):
    path = str(path)
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _link(src, dst):
    """Hard link src as dst (a copy where links are not supported)."""
    if os.path.lexists(dst):
        os.unlink(dst)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


# --- lightmap UV packing -------------------------------------------------------------------------

def _loop_tables(loop_start, loop_total):
    P = len(loop_start)
    lp = np.repeat(np.arange(P), loop_total)
    nxt = np.arange(len(lp)) + 1
    nxt[loop_start + loop_total - 1] = loop_start
    return lp, nxt


def _components(P, pi, pj):
    """Connected component label (smallest member) of P items joined by pairs (pi, pj)."""
    lab = np.arange(P)
    while len(pi):
        m = np.minimum(lab[pi], lab[pj])
        new = lab.copy()
        np.minimum.at(new, pi, m)
        np.minimum.at(new, pj, m)
        new = new[new]
        if np.array_equal(new, lab):
            break
        lab = new
    return lab


NEAR_ANGLE = 2.0      # degrees between neighbouring polygons of a nearly planar chart
CHART_ANGLE = 10.0    # degrees between any polygon of such a chart and its mean plane
CHART_FLAT = 0.005    # its thickness off the mean plane, fraction of its size


def _charts(co, loop_start, loop_total, loop_verts):
    """Chart id per polygon and chart normals (C, 3).

    Polygons sharing an edge (of two faces) join when they lie in one plane, or when their normals
    differ by less than NEAR_ANGLE and the resulting chart stays nearly flat (within CHART_ANGLE of
    its mean plane and CHART_FLAT of its size off it: e.g. a slightly twisted wall). Flat charts project
    onto their plane without overlaps; curved surfaces give one chart per polygon."""
    P = len(loop_start)
    lp, nxt = _loop_tables(loop_start, loop_total)
    p = co[loop_verts]
    q = p[nxt]
    nl = np.stack([(p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2]), (p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0]),
                   (p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])], 1)
    n = np.stack([np.bincount(lp, nl[:, k], P) for k in range(3)], 1)
    ln = np.linalg.norm(n, axis=1)
    nu = n / np.maximum(ln, 1e-300)[:, None]
    cen = np.stack([np.bincount(lp, p[:, k], P) for k in range(3)], 1) / np.maximum(loop_total, 1)[:, None]
    scale = float(np.linalg.norm(co.max(0) - co.min(0))) if len(co) else 1.0
    tol = 1e-5 * max(scale, 1e-30)
    dev = np.zeros(P)
    np.maximum.at(dev, lp, np.abs(np.einsum("ij,ij->i", p - cen[lp], nu[lp])))
    planar = (dev <= tol) & (ln > 0)
    off = np.einsum("ij,ij->i", nu, cen)
    a, b = loop_verts, loop_verts[nxt]
    key = np.minimum(a, b) * (len(co) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    first = np.r_[True, ks[1:] != ks[:-1]]
    run = np.diff(np.r_[np.flatnonzero(first), len(ks)])
    two = np.flatnonzero(first)[run == 2]
    pi, pj = lp[order[two]], lp[order[two + 1]]
    dot = np.einsum("ij,ij->i", nu[pi], nu[pj])
    base = (pi != pj) & (ln[pi] > 0) & (ln[pj] > 0)
    strict = base & planar[pi] & planar[pj] & (dot >= 1 - 1e-8) & (np.abs(off[pi] - off[pj]) <= tol)
    near = base & (dot >= np.cos(np.radians(NEAR_ANGLE)))
    lab_s = _components(P, pi[strict], pj[strict])
    lab = _components(P, pi[near], pj[near])
    # Keep a near-planar chart only if it is flat as a whole.
    uniq, ch = np.unique(lab, return_inverse=True)
    ch = ch.ravel()
    C = len(uniq)
    cn = np.stack([np.bincount(ch, n[:, k], C) for k in range(3)], 1)
    cn /= np.maximum(np.linalg.norm(cn, axis=1), 1e-300)[:, None]
    w = 0.5 * ln
    cc = np.stack([np.bincount(ch, w * cen[:, k], C) for k in range(3)], 1) / np.maximum(np.bincount(ch, w, C), 1e-300)[:, None]
    lch = ch[lp]
    thick = np.zeros(C)
    np.maximum.at(thick, lch, np.abs(np.einsum("ij,ij->i", p - cc[lch], cn[lch])))
    lo = np.full((C, 3), np.inf)
    hi = -lo
    np.minimum.at(lo, lch, p)
    np.maximum.at(hi, lch, p)
    size = np.linalg.norm(hi - lo, axis=1)
    cos_min = np.ones(C)
    np.minimum.at(cos_min, ch, np.einsum("ij,ij->i", nu, cn[ch]))
    flat = (thick <= CHART_FLAT * size) & (cos_min >= np.cos(np.radians(CHART_ANGLE)))
    final = np.where(flat[ch], lab, lab_s + P)
    uniq, chart = np.unique(final, return_inverse=True)
    chart = chart.ravel()
    cn = np.stack([np.bincount(chart, n[:, k], len(uniq)) for k in range(3)], 1)
    cl = np.linalg.norm(cn, axis=1)
    cn = np.where(cl[:, None] > 0, cn / np.maximum(cl, 1e-300)[:, None], [0.0, 0.0, 1.0])
    return chart, cn


def _shelf_pack(fw, fh, res):
    """Next-fit shelf packing of integer rectangles (sorted by height, tallest first) into res x res.
    Returns (x, y) or None."""
    C = np.cumsum(fw)
    x = np.empty(len(fw), np.int64)
    y = np.empty(len(fw), np.int64)
    i, top = 0, 0
    while i < len(fw):
        if fw[i] > res or top + fh[i] > res:
            return None
        base = C[i - 1] if i else 0
        j = int(np.searchsorted(C, base + res, "right"))
        x[i:j] = C[i:j] - fw[i:j] - base
        y[i:j] = top
        top += fh[i]
        i = j
    return x, y


def pack_lightmap(co, loop_start, loop_total, loop_verts, res, margin=MARGIN):
    """(L, 2) lightmap UVs in [0, 1]: planar charts (edge-connected coplanar polygons, other polygons
    alone) projected isometrically onto their plane, turned to their smallest bounding rectangle and
    shelf-packed at one common texel density with `margin` texels around every chart."""
    co = np.asarray(co, np.float64)
    loop_start, loop_total = np.asarray(loop_start, np.int64), np.asarray(loop_total, np.int64)
    loop_verts = np.asarray(loop_verts, np.int64)
    lp, nxt = _loop_tables(loop_start, loop_total)
    chart, cn = _charts(co, loop_start, loop_total, loop_verts)
    C = len(cn)
    axis = np.where(np.abs(cn[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(cn, axis)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(cn, u)
    lc = chart[lp]
    p = co[loop_verts]
    x, y = np.einsum("ij,ij->i", p, u[lc]), np.einsum("ij,ij->i", p, v[lc])
    # Candidate orientations: the 4 edge directions (mod 90 degrees) carrying most edge length.
    ex, ey = x[nxt] - x, y[nxt] - y
    elen = np.hypot(ex, ey)
    qa = np.round(np.mod(np.arctan2(ey, ex), np.pi / 2) * 1000).astype(np.int64) % 1571
    pair, inv = np.unique(lc * 2000 + qa, return_inverse=True)
    w = np.bincount(inv.ravel(), elen, len(pair))
    pc, pq = pair // 2000, pair % 2000
    o = np.lexsort((-w, pc))
    pc, pq = pc[o], pq[o]
    rank = np.arange(len(pc)) - np.searchsorted(pc, pc, "left")
    keep = rank < 4
    cc, ang = pc[keep], pq[keep] / 1000.0
    # Bounding box of every (chart, angle) candidate.
    lorder = np.argsort(lc, kind="stable")
    cnt = np.bincount(lc, minlength=C)
    cstart = np.r_[0, np.cumsum(cnt)[:-1]]
    reps = cnt[cc]
    seg = np.r_[0, np.cumsum(reps)[:-1]]
    idx = lorder[np.repeat(cstart[cc], reps) + np.arange(reps.sum()) - np.repeat(seg, reps)]
    ca, sa = np.repeat(np.cos(ang), reps), np.repeat(np.sin(ang), reps)
    rx, ry = x[idx] * ca + y[idx] * sa, -x[idx] * sa + y[idx] * ca
    area = (np.maximum.reduceat(rx, seg) - np.minimum.reduceat(rx, seg)) \
        * (np.maximum.reduceat(ry, seg) - np.minimum.reduceat(ry, seg))
    o = np.lexsort((area, cc))
    best = np.full(C, 0.0)
    firsts = o[np.r_[True, cc[o][1:] != cc[o][:-1]]]
    best[cc[firsts]] = ang[firsts]
    ca, sa = np.cos(best[lc]), np.sin(best[lc])
    x, y = x * ca + y * sa, -x * sa + y * ca

    def extent(x, y):
        lo = np.stack([np.full(C, np.inf), np.full(C, np.inf)], 1)
        hi = -lo
        np.minimum.at(lo, lc, np.stack([x, y], 1))
        np.maximum.at(hi, lc, np.stack([x, y], 1))
        return lo, hi - lo

    lo, size = extent(x, y)
    tall = size[:, 1] > size[:, 0]                 # turn by 90 degrees so that width >= height
    t = tall[lc]
    x, y = np.where(t, y, x), np.where(t, -x, y)
    lo, size = extent(x, y)
    W, H = size[:, 0], size[:, 1]
    order = np.lexsort((-W, -H))
    Wo, Ho = W[order], H[order]

    def attempt(s, m):
        fw = np.maximum(np.ceil(Wo * s - 1e-9), 1).astype(np.int64) + 2 * m
        fh = np.maximum(np.ceil(Ho * s - 1e-9), 1).astype(np.int64) + 2 * m
        return _shelf_pack(fw, fh, res)

    for m in (margin, 1, 0):
        if attempt(0.0, m) is not None:
            break
    else:
        raise TextureError(f"{C} UV islands do not fit in a {res}x{res} lightmap")
    total = float(np.sum(W * H))
    hi_s = min((res - 2 * m) / max(float(W.max()), 1e-300), res / np.sqrt(max(total, 1e-300)))
    lo_s = 0.0
    if attempt(hi_s, m) is not None:
        lo_s = hi_s
    else:
        for _ in range(40):
            mid = 0.5 * (lo_s + hi_s)
            if attempt(mid, m) is not None:
                lo_s = mid
            else:
                hi_s = mid
            if hi_s - lo_s <= 1e-4 * hi_s:
                break
    s = lo_s
    px, py = attempt(s, m)
    ox, oy = np.empty(C), np.empty(C)
    ox[order], oy[order] = px + m, py + m
    uv = np.stack([ox[lc] + (x - lo[lc, 0]) * s, oy[lc] + (y - lo[lc, 1]) * s], 1) / res
    return np.clip(uv, 0.0, 1.0)


def _mesh_arrays(me):
    V, P, L = len(me.vertices), len(me.polygons), len(me.loops)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    ls, lt, lv = np.empty(P, np.int32), np.empty(P, np.int32), np.empty(L, np.int32)
    me.polygons.foreach_get("loop_start", ls)
    me.polygons.foreach_get("loop_total", lt)
    me.loops.foreach_get("vertex_index", lv)
    return co.reshape(-1, 3), ls.astype(np.int64), lt.astype(np.int64), lv.astype(np.int64)


def read_uv(me, name=UV_NAME):
    layer = me.uv_layers.get(name)
    if layer is None:
        return None
    uv = np.empty(len(me.loops) * 2, np.float32)
    layer.uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)


def _uv_signature(co, ls, lt, lv, scale, res):
    h = hashlib.sha1(f"{PACK_VERSION} {res} {MARGIN}".encode())
    for a in (co.astype(np.float32), ls, lt, lv, np.round(np.asarray(scale, float), 5)):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def resolution_for(obj, default):
    r = int(getattr(obj.hr, "lightmap_resolution", 0) or 0)
    return r if r > 0 else int(default)


def ensure_lightmap(obj, res):
    """Make sure obj's mesh has the UV map HR_Lightmap. Returns a warning or None.

    A map made by the user is kept; one made here is re-packed when the mesh or the resolution
    changed. The active UV map and the active render UV map stay what they were."""
    me = obj.data
    layer = me.uv_layers.get(UV_NAME)
    if layer is not None and "hr_lightmap" not in me:
        return None                                  # the user's own lightmap UVs
    if len(me.polygons) == 0:
        return None
    co, ls, lt, lv = _mesh_arrays(me)
    scale = np.array(obj.matrix_world.to_scale(), float)
    sig = _uv_signature(co, ls, lt, lv, scale, res)
    if layer is not None and me.get("hr_lightmap") == sig:
        return None
    if obj.mode == "EDIT":
        raise TextureError(f"Object '{obj.name}' is in Edit Mode: leave it to make its {UV_NAME} UV map.")
    if me.library is not None or not me.is_editable:
        raise TextureError(f"Mesh '{me.name}' of object '{obj.name}' is not editable (linked): "
                           f"give it a UV map named {UV_NAME} in its library file.")
    uv = pack_lightmap(co * scale, ls, lt, lv, res)
    active = me.uv_layers.active_index
    render = [lay.active_render for lay in me.uv_layers]
    if layer is None:
        layer = me.uv_layers.new(name=UV_NAME, do_init=False)
        if layer is None:
            raise TextureError(f"Mesh '{me.name}' cannot take another UV map (the limit is 8).")
    layer.uv.foreach_set("vector", np.ascontiguousarray(uv, np.float32).ravel())
    if render:                                       # restore the user's active / render UV maps
        me.uv_layers.active_index = active
        for lay, r in zip(list(me.uv_layers)[:len(render)], render):
            if r:
                lay.active_render = True
    me["hr_lightmap"] = sig
    me.update()
    return None


def ensure_lightmaps(objects, default_res):
    warnings, done = [], set()
    for obj in objects:
        if obj.data.name_full in done:
            continue
        done.add(obj.data.name_full)
        w = ensure_lightmap(obj, resolution_for(obj, default_res))
        if w:
            warnings.append(w)
    return warnings


# --- rasterisation -------------------------------------------------------------------------------

def rasterise(tri_uv, res, ring=RING, budget=400_000):
    """Texels of a res x res image covered by UV triangles tri_uv (T, 3, 2).

    Returns texel (N,) flat index y * res + x (row 0 at v = 0), tri (N,), bary (N, 3), inside (N,):
    texels whose centre lies in a triangle (barycentric coordinates of the centre) or within `ring`
    texels of one (coordinates of the nearest triangle point), each texel once."""
    Pt = np.asarray(tri_uv, np.float64) * res - 0.5               # texel (i, j) has its centre at (i, j)
    a, b, c = Pt[:, 0], Pt[:, 1], Pt[:, 2]
    v0, v1 = b - a, c - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    ok = np.abs(den) > 1e-12
    lo = np.clip(np.floor(Pt.min(1) - ring), 0, res - 1).astype(np.int64)
    hi = np.clip(np.ceil(Pt.max(1) + ring), 0, res - 1).astype(np.int64)
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    counts = np.where(ok, nx * ny, 0)
    out = []
    cum = np.cumsum(counts)
    t0 = 0
    while t0 < len(counts):
        base = cum[t0 - 1] if t0 else 0
        t1 = max(int(np.searchsorted(cum, base + budget, "right")), t0 + 1)
        ids = np.arange(t0, t1)
        cn = counts[ids]
        t0 = t1
        if cn.sum() == 0:
            continue
        t = np.repeat(ids, cn)
        k = np.arange(cn.sum()) - np.repeat(np.cumsum(cn) - cn, cn)
        x = lo[t, 0] + k % nx[t]
        y = lo[t, 1] + k // nx[t]
        q = np.stack([x, y], 1).astype(np.float64)
        w = q - a[t]
        l1 = (w[:, 0] * v1[t, 1] - v1[t, 0] * w[:, 1]) / den[t]
        l2 = (v0[t, 0] * w[:, 1] - w[:, 0] * v0[t, 1]) / den[t]
        bary = np.stack([1 - l1 - l2, l1, l2], 1)
        inside = (bary >= -1e-9).all(1)
        dist = np.zeros(len(t))
        out_i = np.flatnonzero(~inside)
        if len(out_i):
            tt, qq = t[out_i], q[out_i]
            best_d = np.full(len(out_i), np.inf)
            best_b = np.zeros((len(out_i), 3))
            for i, j in ((0, 1), (1, 2), (2, 0)):
                pa, pb = Pt[tt, i], Pt[tt, j]
                e = pb - pa
                s = np.clip(np.einsum("ij,ij->i", qq - pa, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
                d = np.linalg.norm(qq - pa - s[:, None] * e, axis=1)
                better = d < best_d
                best_d = np.where(better, d, best_d)
                nb = np.zeros((len(out_i), 3))
                nb[:, i], nb[:, j] = 1 - s, s
                best_b[better] = nb[better]
            dist[out_i] = best_d
            bary[out_i] = best_b
        keep = inside | (dist <= ring)
        out.append((y[keep] * res + x[keep], t[keep], bary[keep], dist[keep], inside[keep]))
    if not out:
        z = np.zeros(0, np.int64)
        return z, z, np.zeros((0, 3)), np.zeros(0, bool)
    texel, tri, bary, dist, inside = (np.concatenate(z) for z in zip(*out))
    o = np.lexsort((tri, dist, texel))
    firsts = o[np.r_[True, texel[o][1:] != texel[o][:-1]]]
    return texel[firsts], tri[firsts], bary[firsts], inside[firsts]


def dilation_steps(covered, res, steps=DILATE):
    """[(dst, inv, src, weight)] per step: empty texels next to filled ones take the mean of their
    filled 8-neighbours (apply in order)."""
    filled = np.zeros(res * res, bool)
    filled[covered] = True
    filled = filled.reshape(res, res)
    out = []
    offs = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    for _ in range(steps):
        pad = np.pad(filled, 1)
        cnt = sum(pad[1 + dy:1 + dy + res, 1 + dx:1 + dx + res].astype(np.int64) for dy, dx in offs)
        new = ~filled & (cnt > 0)
        ys, xs = np.nonzero(new)
        if not len(ys):
            break
        d, s = [], []
        for dy, dx in offs:
            yy, xx = ys + dy, xs + dx
            m = (yy >= 0) & (yy < res) & (xx >= 0) & (xx < res)
            m[m] = filled[yy[m], xx[m]]
            d.append(ys[m] * res + xs[m])
            s.append(yy[m] * res + xx[m])
        d, s = np.concatenate(d), np.concatenate(s)
        dst, inv = np.unique(d, return_inverse=True)
        wgt = 1.0 / np.bincount(inv.ravel())[inv.ravel()]
        out.append((dst, inv.ravel(), s, wgt))
        filled = filled | new
    return out


# --- texel plans and the per-frame writer --------------------------------------------------------

class ObjectTexels:
    """Where one object's texels are: flat texel indices, their patches and surface points."""

    def __init__(self, name, res, stem, texel, inside, lo, hi, steps, uv_digest):
        self.name, self.res, self.stem = name, res, stem
        self.texel, self.inside = texel, inside
        self.lo, self.hi = lo, hi                   # slice of the concatenated points
        self.steps = steps
        self.uv_digest = uv_digest

    def image(self, values):
        img = np.zeros((self.res * self.res, 3), np.float32)
        img[self.texel] = values
        for dst, inv, src, w in self.steps:
            for ch in range(3):
                img[dst, ch] = np.bincount(inv, w * img[src, ch], len(dst))
        return img.reshape(self.res, self.res, 3)


def _stems(names):
    out, used = {}, set()
    for n in names:
        base = bpy.path.clean_name(n) or "object"
        s, k = base, 1
        while s.lower() in used:
            s = f"{base}_{k}"
            k += 1
        used.add(s.lower())
        out[n] = s
    return out


def frame_file(stem, frame, ext):
    return f"{stem}_{frame:06d}{ext}"


class TextureBaker:
    """Texel plans of every target object (geometry is static during a bake) and the files."""

    def __init__(self, scene_in, patches, view_layer, depsgraph, default_res, fmt="EXR"):
        fmt = fmt.upper()
        if fmt not in FORMATS:
            raise TextureError(f"Unknown texture format '{fmt}' (EXR or PNG).")
        self.fmt, self.ext = fmt, FORMATS[fmt]
        self.objects = []
        self.warnings = []
        self.tmp = None
        self.files = {}                          # frame -> True once written / linked
        mesh = scene_in.mesh
        stems = _stems([t.name for t in scene_in.targets])
        pts_all, patch_all, reps_all = [], [], []
        n = 0
        for oid, t in enumerate(scene_in.targets):
            obj = view_layer.objects.get(t.name) or bpy.data.objects[t.name]
            res = resolution_for(obj, default_res)
            p0 = int(np.searchsorted(mesh.loop_start, t.loops[0]))
            p1 = int(np.searchsorted(mesh.loop_start, t.loops[1])) if t.loops[1] < len(mesh.loop_verts) \
                else len(mesh.loop_start)
            ob = obj.evaluated_get(depsgraph)
            me = ob.to_mesh()
            try:
                uv = read_uv(me)
                _, ls, lt, lv = _mesh_arrays(me)
            finally:
                ob.to_mesh_clear()
            if uv is None:
                self.warnings.append(f"Object '{t.name}': its evaluated mesh has no {UV_NAME} UV map "
                                     "(a modifier removed it); no texture.")
                continue
            if len(ls) != p1 - p0 or len(lv) != t.loops[1] - t.loops[0]:
                self.warnings.append(f"Object '{t.name}': mesh changed while reading; no texture.")
                continue
            if t.vert_map is not None:
                self.warnings.append(f"Object '{t.name}': modifiers change the topology; its "
                                     f"{UV_NAME} islands may overlap (apply the modifiers).")
            # UV of each (polygon, vertex) of the evaluated mesh.
            V = t.verts[1] - t.verts[0]
            lpoly = np.repeat(np.arange(len(ls)), lt)
            key = lpoly * (V + 1) + lv
            ko = np.argsort(key, kind="stable")
            sel = np.flatnonzero(patches.object_id == oid)
            nv = patches.nv[sel]
            vi = patches.vert_index[sel]
            tri_rows = np.concatenate([np.repeat(sel, 1), sel[nv == 4]])
            tri_c = np.concatenate([np.tile([0, 1, 2], (len(sel), 1)),
                                    np.tile([0, 2, 3], (int((nv == 4).sum()), 1))])
            rows = np.concatenate([np.arange(len(sel)), np.flatnonzero(nv == 4)])
            corners3 = patches.corners[tri_rows[:, None], tri_c]                   # (T, 3, 3)
            cv = vi[rows[:, None], tri_c] - t.verts[0]
            cp = (patches.poly[tri_rows] - p0)[:, None]
            ck = cp * (V + 1) + cv
            pos = np.clip(np.searchsorted(key[ko], ck), 0, len(ko) - 1)
            found = key[ko][pos] == ck
            tri_uv = uv[ko[pos]].astype(np.float64)
            good = found.all(1)
            if not good.all():
                self.warnings.append(f"Object '{t.name}': {int((~good).sum())} triangle(s) without UVs skipped.")
            tri_uv, corners3, tri_rows = tri_uv[good], corners3[good], tri_rows[good]
            texel, tri, bary, inside = rasterise(tri_uv, res)
            pts = np.einsum("nk,nkj->nj", bary, corners3[tri])
            pts_all.append(pts)
            patch_all.append(tri_rows[tri])
            steps = dilation_steps(texel, res)
            # representative texel: the one at the corner of its 4 x 4 block, if in the same patch
            dense = np.full(res * res, -1, np.int64)
            dense[texel] = np.arange(len(texel))
            x, y = texel % res, texel // res
            r = dense[(y - y % 4) * res + (x - x % 4)]
            own = tri_rows[tri]
            r = np.where((r >= 0) & (own[np.maximum(r, 0)] == own), r, np.arange(len(texel)))
            reps_all.append(r + n)
            dig = hashlib.sha1(np.ascontiguousarray(uv).tobytes()).hexdigest()
            self.objects.append(ObjectTexels(t.name, res, stems[t.name], texel, inside, n, n + len(texel),
                                             steps, dig))
            n += len(texel)
        self.points = np.concatenate(pts_all) if pts_all else np.zeros((0, 3))
        self.patch = np.concatenate(patch_all).astype(np.int64) if patch_all else np.zeros(0, np.int64)
        self.locator = TexelLocator(self.patch, self.points,
                                    np.concatenate(reps_all) if reps_all else None)

    def radiance(self, dyn, system):
        """(N, 3) radiance of the current solution at the texel points of all objects."""
        return solution_radiance(dyn, system, self.patch, self.points, self.locator)

    # cache manifest entries
    def objects_info(self, targets):
        mesh_of = {t.name: t.mesh_name for t in targets}
        return {o.name: {"mesh": mesh_of[o.name], "count": 0, "resolution": o.res, "format": self.fmt,
                         "texture": f"{TEX_DIR}/{o.stem}_%06d{self.ext}"} for o in self.objects}

    def signature(self, base):
        h = hashlib.sha1(base.encode())
        for o in self.objects:
            h.update(f"{o.name}|{o.res}|{self.fmt}|{o.uv_digest}".encode())
        return h.hexdigest()

    def bind(self, tmp_dir):
        self.tmp = os.path.join(str(tmp_dir), TEX_DIR)
        os.makedirs(self.tmp, exist_ok=True)

    def _path(self, o, frame, root=None):
        return os.path.join(root or self.tmp, frame_file(o.stem, frame, self.ext))

    def write(self, frame, values):
        """values (N, 3) at self.points (all objects); files encoded in parallel (zlib frees the GIL)."""
        from concurrent.futures import ThreadPoolExecutor

        def one(o):
            img = o.image(values[o.lo:o.hi])
            data = encode_exr(img) if self.fmt == "EXR" else encode_png16(img)
            _atomic_write(self._path(o, frame), data)

        workers = max(1, min(len(self.objects), os.cpu_count() or 1, 8))
        if workers == 1:
            for o in self.objects:
                one(o)
        else:
            with ThreadPoolExecutor(workers) as pool:
                for fut in [pool.submit(one, o) for o in self.objects]:
                    fut.result()
        self.files[int(frame)] = True

    def reuse(self, frame, prev_frame):
        for o in self.objects:
            _link(self._path(o, prev_frame), self._path(o, frame))
        self.files[int(frame)] = True

    def damaged_frames(self, final_dir, frames):
        """{frame: problem} of `frames` of the previous bake in final_dir whose texture files are
        missing or damaged (checked as image_file_problem does: structure, not pixels)."""
        src_dir = os.path.join(str(final_dir), TEX_DIR)
        out = {}
        for f in sorted(frames):
            for o in self.objects:
                why = image_file_problem(self._path(o, f, src_dir), o.res)
                if why:
                    out[f] = f"{os.path.basename(self._path(o, f, src_dir))} {why}"
                    break
        return out

    def finish(self, writer):
        """Before writer.commit(): bring over the texture files of the previous bake's frames that the
        commit keeps, and fill every frame number of the sequence (gaps hold the frame before; the
        number before the first frame, which Blender asks for before the start, holds the first)."""
        frames = set(self.files)
        try:
            old = CacheReader(writer.final)
            m = old.manifest
            same = (m.get("signature") == writer.signature and m.get("domain") == writer.domain
                    and m.get("objects") == writer.objects)
        except CacheError:
            same = False
        if same:
            src_dir = os.path.join(str(writer.final), TEX_DIR)
            for f in sorted(old.frames):
                if f in frames:
                    continue
                srcs = [self._path(o, f, src_dir) for o in self.objects]
                if all(os.path.isfile(s) for s in srcs):
                    for o, s in zip(self.objects, srcs):
                        _link(s, self._path(o, f))
                    frames.add(f)
        if not frames:
            return
        first, last = min(frames), max(frames)
        prev = first
        for f in range(first, last + 1):
            if f in frames:
                prev = f
                continue
            for o in self.objects:
                _link(self._path(o, prev), self._path(o, f))
        if first >= 1:
            for o in self.objects:
                _link(self._path(o, first), self._path(o, first - 1))


_NUDGE = 0.05


def radiance_per_leaf(h, B, patch, points, leaf=None, locator=None, chunk=200_000):
    """The values of core.output.radiance_at(h, B, patch, points, smooth=True), computed per leaf.

    radiance_at interpolates four values per leaf (one per corner) linearly on the leaf's triangles:
    it is called at one point just inside each corner of every leaf holding points, the corner
    values are solved for, and applied to the points. Same result; the costly corner probes run
    once per leaf instead of once per point. leaf: the points' leaves if known; locator: the
    TexelLocator that found them (keeps the interpolation weights of unchanged leaves)."""
    patch = np.asarray(patch, np.int64)
    pts = np.asarray(points, float)
    if len(pts) == 0:
        return np.zeros((0, 3))
    if locator is not None and locator.h is h:
        U, inv = locator.leaf_u, locator.inv
    else:
        if leaf is None:
            leaf = np.concatenate([locate(h, patch[a:a + chunk], pts[a:a + chunk]) for a in range(0, len(pts), chunk)])
        U, inv = np.unique(leaf, return_inverse=True)
        inv = inv.ravel()
        locator = None
    c = h.corners[U]                                                      # (u, 4, 3)
    nv = h.nv[U].astype(np.int64)
    nrm = h.normal[U]
    g = np.where((nv == 4)[:, None], c.mean(1), c[:, :3].mean(1))
    q = c + _NUDGE * (g[:, None] - c)                                     # just inside each corner
    quad = nv == 4
    rows = np.concatenate([np.repeat(np.arange(len(U)), 3), np.flatnonzero(quad)])
    ks = np.concatenate([np.tile([0, 1, 2], len(U)), np.full(int(quad.sum()), 3)])
    sp = q[rows, ks]
    roots = h.patch[U][rows].astype(np.int64)
    s = np.concatenate([radiance_at(h, B, roots[a:a + chunk], sp[a:a + chunk], smooth=True)
                        for a in range(0, len(sp), chunk)])
    M = np.zeros((len(U), 4, 4))
    rhs = np.zeros((len(U), 4, 3))
    M[rows, ks] = corner_weights(c[rows], nv[rows], nrm[rows], sp)
    rhs[rows, ks] = s
    tri = ~quad                                   # triangles: corner 3 repeats corner 2
    M[tri, 3] = [0.0, 0.0, -1.0, 1.0]
    try:
        val = np.linalg.solve(M, rhs)                                     # (u, 4, 3) corner values
    except np.linalg.LinAlgError:                 # a degenerate leaf: evaluate every point instead
        if locator is not None:
            locator.valid[:] = False
        return np.concatenate([radiance_at(h, B, patch[a:a + chunk], pts[a:a + chunk], smooth=True)
                               for a in range(0, len(pts), chunk)])
    if locator is not None:
        w = locator.weights
        todo = np.flatnonzero(~locator.valid)
    else:
        w = np.empty((len(pts), 4))
        todo = np.arange(len(pts))
    for a in range(0, len(todo), chunk):
        i = todo[a:a + chunk]
        w[i] = corner_weights(c[inv[i]], nv[inv[i]], nrm[inv[i]], pts[i])
    if locator is not None:
        locator.valid[:] = True
    out = np.empty((len(pts), 3))
    for a in range(0, len(pts), chunk):
        out[a:a + chunk] = np.einsum("mk,mkc->mc", w[a:a + chunk], val[inv[a:a + chunk]])
    return out


class TexelLocator:
    """Leaves of fixed points (texel centres) in a hierarchy that changes a little every frame.

    Remembers the points' leaves and a few of their ancestors with their corners; next frame the
    descent starts from the deepest remembered node that still has the same corners in the same
    patch (then it is the same cell of the same quadtree, so descending from it reaches the leaf a
    descent from the patch reaches), else from the patch. Per point it keeps 4-byte indices only."""
    DEPTH = 4

    def __init__(self, patch, points, rep=None):
        """rep: for each point, a nearby point of the same patch (itself for some): the first descent
        locates only those, and the others start from the deepest ancestor of their
        representative's leaf that holds them strictly inside (the descent from the patch passes
        through it), which is exact and much cheaper for dense texels."""
        self.patch = np.asarray(patch, np.int64)
        self.points = np.asarray(points, float)
        self.rep = None if rep is None else np.asarray(rep, np.int64)
        self.h = None
        self.leaf_u = None                        # unique leaves of the last call
        self.inv = None                           # (N,) int32: each point's entry in leaf_u
        self.anc = self.anc_corners = self.anc_patch = None
        self.weights = np.zeros((len(self.patch), 4), np.float32)   # see radiance_per_leaf
        self.valid = np.zeros(len(self.patch), bool)     # weights computed for the current leaf

    def leaves(self, h, chunk=200_000):
        start = self.patch.copy()
        prev = None
        if self.h is h and self.leaf_u is not None:
            best = np.full(len(self.leaf_u), -1, np.int64)
            for d in range(self.DEPTH):
                nodes = self.anc[:, d]
                i = np.flatnonzero((best < 0) & (nodes >= 0) & (nodes < h.n))
                good = (h.corners[nodes[i]] == self.anc_corners[i, d]).all((1, 2)) \
                    & (h.patch[nodes[i]] == self.anc_patch[i])
                best[i[good]] = nodes[i[good]]
            sel = best[self.inv]
            start = np.where(sel >= 0, sel, start)
            prev = self.leaf_u[self.inv]
        elif self.rep is not None and len(start):
            start = self._from_representatives(h, chunk)
        leaf = np.concatenate([locate(h, start[a:a + chunk], self.points[a:a + chunk])
                               for a in range(0, len(start), chunk)]) if len(start) else start
        same = (start == leaf) & (leaf == prev) if prev is not None else np.zeros(len(leaf), bool)
        self.valid &= same
        U, inv = np.unique(leaf, return_inverse=True)
        anc = np.empty((len(U), self.DEPTH), np.int64)
        node = U.astype(np.int64)
        for d in range(self.DEPTH):
            anc[:, d] = node
            node = np.where(node >= 0, h.parent[np.maximum(node, 0)], -1).astype(np.int64)
        self.h, self.leaf_u, self.inv = h, U, inv.ravel().astype(np.int32)
        self.anc, self.anc_corners, self.anc_patch = anc, h.corners[np.maximum(anc, 0)].copy(), h.patch[U].copy()
        return leaf

    def _from_representatives(self, h, chunk):
        start = self.patch.copy()
        samp = np.flatnonzero(self.rep == np.arange(len(self.rep)))
        start[samp] = np.concatenate([locate(h, self.patch[samp[a:a + chunk]], self.points[samp[a:a + chunk]])
                                      for a in range(0, len(samp), chunk)])
        others = np.flatnonzero(self.rep != np.arange(len(self.rep)))
        for a in range(0, len(others), chunk):
            o = others[a:a + chunk]
            cand = start[self.rep[o]]
            todo = np.ones(len(o), bool)
            for _ in range(64):
                i = np.flatnonzero(todo & (cand >= 0))
                if len(i) == 0:
                    break
                i = i[h.patch[cand[i]] == self.patch[o[i]]]
                ins = i[_strictly_inside(h, cand[i], self.points[o[i]])]
                start[o[ins]] = cand[ins]
                todo[ins] = False
                cand = np.where(cand >= 0, h.parent[np.maximum(cand, 0)], -1).astype(np.int64)
        return start


def _strictly_inside(h, nodes, pts, rel=1e-7):
    """Points inside the cells of nodes by more than rel x the cell size."""
    c = h.corners[nodes]
    e = np.roll(c, -1, axis=1) - c
    el = np.linalg.norm(e, axis=-1)
    d = np.einsum("mvj,mj->mv", np.cross(e, pts[:, None] - c), h.normal[nodes]) / np.maximum(el, 1e-300)
    d = np.where(el > 0, d, np.inf)
    return d.min(1) > rel * np.sqrt(h.area[nodes])


def solution_radiance(dyn, system, patch, points, locator=None):
    """Radiance (N, 3) of the current solution at surface points of the given input patches
    (locator: a TexelLocator of these points, to find their leaves faster)."""
    naive = getattr(dyn, "_naive", None) if dyn is not None else None
    if naive is not None:
        h, B = naive.system.h, naive.system.B
        patch, points = naive.remap(points, patch)
        locator = None
    elif dyn is not None:
        h, B = dyn.h, dyn.B
        if B.shape[1] < h.n and hasattr(dyn, "_sync"):
            dyn._sync()
            h, B = dyn.h, dyn.B
    else:
        if system.B is None:
            system.solve()
        h, B = system.h, system.B
    leaf = locator.leaves(h) if locator is not None else None
    return radiance_per_leaf(h, B, patch, points, leaf=leaf, locator=locator).astype(np.float32)


# --- material helper -----------------------------------------------------------------------------

def _manifest(scene):
    from . import playback
    directory = playback.bake_dir_abs(scene)
    if not directory:
        raise CacheError("No radiosity bake: bake first.")
    reader = CacheReader(directory)
    if reader.manifest.get("output") != "TEXTURE":
        raise CacheError("The radiosity bake holds vertex colours, not textures (Output: Baked Textures, then bake).")
    return directory, reader


def is_texture_bake(scene):
    try:
        _manifest(scene)
        return True
    except CacheError:
        return False


def _sequence_image(obj, path, fmt):
    img = next((i for i in bpy.data.images if i.get(TAG) == obj.name), None)
    if img is None:
        img = bpy.data.images.new(f"HR Lightmap {obj.name}", 4, 4, float_buffer=True)
        img[TAG] = obj.name
    fp = path
    if bpy.data.filepath:
        try:
            fp = bpy.path.relpath(path)
        except ValueError:
            pass
    img.source = "FILE"
    img.filepath = fp
    img.source = "SEQUENCE"
    for name in (("sRGB",) if fmt == "PNG" else ("Linear Rec.709", "Linear")):
        try:
            img.colorspace_settings.name = name       # PNG files are sRGB-encoded, EXR linear
            break
        except TypeError:                             # colour space not in this configuration
            pass
    img.reload()
    return img


def _node(tree, name, kind, location):
    n = tree.nodes.get(name)
    if n is not None and n.bl_idname != kind:
        tree.nodes.remove(n)
        n = None
    if n is None:
        n = tree.nodes.new(kind)
        n.name = n.label = name
        n.location = location
    return n


def _wire(mat, img, first, last):
    """Add (or update) UV Map -> Image Texture -> Emission -> Material Output, the active output."""
    if mat.node_tree is None or (bpy.app.version < (5, 0, 0) and not mat.use_nodes):
        mat.use_nodes = True
    tree = mat.node_tree
    if N_ATTR in tree.nodes:                       # a vertex-colour preview copied from the material
        tree.nodes.remove(tree.nodes[N_ATTR])
    x = max((n.location.x for n in tree.nodes if not n.name.startswith(PREVIEW)), default=0) + 300
    uvn = _node(tree, N_UV, "ShaderNodeUVMap", (x, -400))
    uvn.uv_map = UV_NAME
    tex = _node(tree, N_TEX, "ShaderNodeTexImage", (x + 200, -400))
    tex.image = img
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    iu = tex.image_user
    iu.frame_duration = last - first + 1
    iu.frame_start = first
    iu.frame_offset = first - 1
    iu.use_cyclic = False
    iu.use_auto_refresh = True
    emit = _node(tree, N_EMIT, "ShaderNodeEmission", (x + 500, -400))
    emit.inputs["Strength"].default_value = 1.0
    out = _node(tree, N_OUT, "ShaderNodeOutputMaterial", (x + 700, -400))
    out.target = "ALL"
    tree.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], emit.inputs["Color"])
    tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    out.is_active_output = True


def _helper(slot):
    m = slot.material
    return m if slot.link == "OBJECT" and m is not None and m.get(TAG) is not None else None


def add_material(scene, objects=None):
    """Show the scene's texture bake: every object of the bake gets, per material slot, an
    object-level copy of its material whose active output is UV Map (HR_Lightmap) -> Image Texture
    (the image sequence) -> Emission. The mesh's materials are untouched. Returns the number of
    objects wired; raises CacheError without a texture bake."""
    directory, reader = _manifest(scene)
    first, last = reader.frame_range
    names = None if objects is None else {o.name for o in objects}
    n = 0
    for name, info in reader.objects.items():
        if names is not None and name not in names:
            continue
        obj = scene.objects.get(name)
        if obj is None or obj.type != "MESH":
            continue
        tex = info.get("texture")
        if not tex:
            continue
        path = os.path.join(directory, *(tex % first).split("/"))
        img = _sequence_image(obj, path, info.get("format", "EXR"))
        if not obj.material_slots:
            obj.data.materials.append(None)
            obj["hr_lightmap_slot"] = len(obj.material_slots) - 1
        for slot in obj.material_slots:
            mat = _helper(slot)
            if mat is None:
                src, link = slot.material, slot.link
                if src is not None:
                    mat = src.copy()
                    mat.name = f"{src.name} (HR {obj.name})"
                else:
                    mat = bpy.data.materials.new(f"HR Lightmap {obj.name}")
                    mat["hr_preview"] = True        # read as "no material" by the bake
                mat[TAG] = obj.name
                mat["hr_lightmap_link"] = link
                if link == "OBJECT" and src is not None:
                    mat["hr_lightmap_source"] = src
                slot.link = "OBJECT"
                slot.material = mat
            _wire(mat, img, first, last)
        n += 1
    return n


def remove_material(objects=None):
    """Undo add_material: the slots show the mesh's (or the object's own) materials again."""
    n = 0
    for obj in list(bpy.data.objects if objects is None else objects):
        if obj.type != "MESH":
            continue
        hit = False
        for slot in obj.material_slots:
            m = _helper(slot)
            if m is None:
                continue
            hit = True
            if m.get("hr_lightmap_link", "DATA") == "OBJECT":
                slot.material = m.get("hr_lightmap_source")
            else:
                slot.material = None
                slot.link = "DATA"
            if m.users == 0:
                bpy.data.materials.remove(m)
        k = obj.get("hr_lightmap_slot")
        if k is not None:
            if 0 <= k < len(obj.data.materials) and obj.data.materials[k] is None:
                obj.data.materials.pop(index=k)
            del obj["hr_lightmap_slot"]
        n += hit
    for m in [m for m in bpy.data.materials if m.get(TAG) is not None and m.users == 0]:
        bpy.data.materials.remove(m)
    for img in [i for i in bpy.data.images if i.get(TAG) is not None and i.users == 0]:
        bpy.data.images.remove(img)
    return n


@contextmanager
def source_materials(objects):
    """While reading the scene, slots show the materials the helper copies stand in for."""
    saved = []
    for obj in objects:
        for slot in obj.material_slots:
            m = _helper(slot)
            if m is None:
                continue
            saved.append((slot, m))
            if m.get("hr_lightmap_link", "DATA") == "OBJECT":
                slot.material = m.get("hr_lightmap_source")
            else:
                slot.link = "DATA"
    try:
        yield
    finally:
        for slot, m in saved:
            slot.link = "OBJECT"
            slot.material = m


def after_bake(scene, directory):
    """Reload the images of the cache and re-wire existing helper materials (new frame range)."""
    d = os.path.normcase(os.path.abspath(directory))
    for img in bpy.data.images:
        if img.get(TAG) is not None and img.filepath:
            p = os.path.normcase(os.path.abspath(bpy.path.abspath(img.filepath)))
            if p.startswith(d):
                img.reload()
    wired = [o for o in scene.objects if o.type == "MESH" and any(_helper(s) for s in o.material_slots)]
    if wired:
        try:
            add_material(scene, wired)
        except CacheError:
            pass
