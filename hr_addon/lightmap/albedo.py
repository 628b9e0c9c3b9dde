"""Texture colour at the texels of a lightmap (no bpy): the material's own UVs interpolated at each
texel's surface point, the image sampled there as Cycles' Image Texture node samples it.

The radiosity exchange uses one reflectance per material (the texture's average); the outgoing
radiance a textured surface shows is that light times the texture's colour at the point, so the
texture output multiplies each texel's reflected radiance by albedo(texel) / average (plan.py).
"""

import numpy as np


def texel_uv(uv, loops, bary):
    """(N, 2) UVs of points given by barycentric coordinates bary (N, 3) on triangles whose corners
    are the loops (N, 3) of a UV layer uv (L, 2)."""
    return np.einsum("nk,nkj->nj", np.asarray(bary, np.float64), np.asarray(uv, np.float64)[loops])


def sample_image(pixels, uv, interpolation="Linear", extension="REPEAT"):
    """(N, C) values of an image (H, W, C) (row 0 at v = 0, as Blender stores pixels) at uv (N, 2).

    Pixel (i, j) has its centre at ((i + 0.5) / W, (j + 0.5) / H). interpolation "Closest" takes the
    nearest pixel, anything else is bilinear (Cubic and Smart are approximated so); extension
    REPEAT wraps, EXTEND clamps, CLIP gives 0 outside [0, 1], MIRROR reflects."""
    px = np.asarray(pixels)
    H, W = px.shape[:2]
    uv = np.asarray(uv, np.float64)
    x, y = uv[:, 0] * W - 0.5, uv[:, 1] * H - 0.5

    def index(i, n):
        if extension == "EXTEND" or extension == "CLIP":
            return np.clip(i, 0, n - 1)
        if extension == "MIRROR":
            m = np.mod(i, 2 * n)
            return np.where(m < n, m, 2 * n - 1 - m)
        return np.mod(i, n)

    if interpolation == "Closest":
        out = px[index(np.floor(y + 0.5).astype(np.int64), H), index(np.floor(x + 0.5).astype(np.int64), W)]
        out = out.astype(np.float64)
    else:
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        xa, xb, ya, yb = index(x0, W), index(x0 + 1, W), index(y0, H), index(y0 + 1, H)
        out = (1 - fy) * ((1 - fx) * px[ya, xa] + fx * px[ya, xb]) + fy * (
            (1 - fx) * px[yb, xa] + fx * px[yb, xb]
        )
    if extension == "CLIP":
        outside = (uv < 0).any(1) | (uv > 1).any(1)
        out[outside] = 0.0
    return out


def mix_colour(tex, mix):
    """The colour a single Mix node makes of the texture colour tex (N, 3): mix None (the texture
    itself) or (blend "MIX" | "MULTIPLY", factor, other colour (3,), texture is input A)."""
    if mix is None:
        return tex
    blend, fac, other, tex_is_a = mix
    other = np.broadcast_to(np.asarray(other, np.float64), tex.shape)
    a, b = (tex, other) if tex_is_a else (other, tex)
    if blend == "MULTIPLY":
        return (1 - fac) * a + fac * a * b
    return (1 - fac) * a + fac * b


def albedo_factor(albedo, average):
    """(N, 3) float32 albedo / average per channel (1 where the average is 0: nothing to modulate)."""
    avg = np.asarray(average, np.float64)
    f = np.where(avg > 0, np.clip(albedo, 0.0, None) / np.where(avg > 0, avg, 1.0), 1.0)
    return f.astype(np.float32)
