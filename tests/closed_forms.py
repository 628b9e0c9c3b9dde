"""Closed-form view factors, computed (the tests' analytic oracles; no numbers typed in elsewhere).

The formulas are those of J. R. Howell's "A Catalog of Radiation Heat Transfer Configuration
Factors" (http://www.thermalradiation.net/indexCat.html): differential area to a parallel
rectangle with the normal through a corner (section B), directly opposed parallel rectangles
(C-11), perpendicular rectangles with a common edge (C-14), differential area on the axis of a
parallel disc; a tilted differential area under an infinite plane sees (1 + cos theta) / 2.
Superposition gives any point under a parallel rectangle (point_to_parallel_rect).
tests/test_formfactor.py checks them against the catalog's tabulated values and each other.
"""

from math import atan, log, pi, sqrt

import numpy as np


def point_to_rect_corner(a, b, c):
    """Element at distance c below the corner of an a x b rectangle, both parallel."""
    x, y = a / c, b / c
    sx, sy = sqrt(1 + x * x), sqrt(1 + y * y)
    return (x / sx * atan(y / sx) + y / sy * atan(x / sy)) / (2 * pi)


def point_to_parallel_rect(px, py, x0, x1, y0, y1, c):
    """Element at (px, py), distance c below the rectangle [x0, x1] x [y0, y1] (parallel, facing it):
    the four corner rectangles meeting at the foot point, signed (superposition)."""

    def corner(x, y):
        s = (1 if x >= 0 else -1) * (1 if y >= 0 else -1)
        return s * point_to_rect_corner(abs(x), abs(y), c) if x and y else 0.0

    return (
        corner(x1 - px, y1 - py)
        - corner(x0 - px, y1 - py)
        - corner(x1 - px, y0 - py)
        + corner(x0 - px, y0 - py)
    )


def opposed_rects(a, b, c):
    """C-11: a x b rectangle to the same rectangle directly opposite at distance c."""
    x, y = a / c, b / c
    x1, y1 = 1 + x * x, 1 + y * y
    return (
        2
        / (pi * x * y)
        * (
            log(sqrt(x1 * y1 / (x1 + y1 - 1)))
            + x * sqrt(y1) * atan(x / sqrt(y1))
            + y * sqrt(x1) * atan(y / sqrt(x1))
            - x * atan(x)
            - y * atan(y)
        )
    )


def perpendicular_rects(edge, w, h):
    """C-14: rectangle edge x w to the rectangle edge x h at right angles to it, sharing the edge."""
    W, H = w / edge, h / edge
    W2, H2, S = W * W, H * H, W * W + H * H
    t = log(
        (1 + W2)
        * (1 + H2)
        / (1 + S)
        * (W2 * (1 + S) / ((1 + W2) * S)) ** W2
        * (H2 * (1 + S) / ((1 + H2) * S)) ** H2
    )
    return (W * atan(1 / W) + H * atan(1 / H) - sqrt(S) * atan(1 / sqrt(S)) + t / 4) / (pi * W)


def point_to_coaxial_disc(r, h):
    """Element facing a disc of radius r on its axis at distance h."""
    return r * r / (r * r + h * h)


def tilted_under_plane(cos_theta):
    """Element under an infinite plane, its normal at angle theta to the plane's normal."""
    return (1 + cos_theta) / 2


# --- Blender lights in Cycles' units (issue 20) ------------------------------------------------------
# Each constant was fitted against a Cycles render of a diffuse plane under the light
# (scripts/measure_light_units.py; the measurements are in docs/lights.md). The oracles below give
# irradiance E (W/m^2) at a surface element; the tests compare E / pi with the code's "incident".


def point_light_irradiance(power, dist, cos_theta, radius=0.0):
    """Point light of `power` W (Cycles): I = P / (4 pi) W/sr (measured 0.99984 x); with a radius
    and soft falloff Cycles lights like a disc of that radius facing the element, so on its axis
    E = I / (d^2 + r^2) = pi L x point_to_coaxial_disc(r, d) with pi L r^2 = I (measured r = 0.5,
    d = 2: 0.9408 x I / d^2, the disc gives 0.9412)."""
    intensity = power / (4 * pi)
    if radius > 0:
        return intensity / (radius * radius) * point_to_coaxial_disc(radius, dist) * cos_theta
    return intensity * cos_theta / (dist * dist)


def sun_irradiance(strength, cos_theta):
    """Sun of strength S W/m^2 (Cycles): E = S cos (measured 1.0000 x at 0 and 60 degrees)."""
    return strength * max(cos_theta, 0.0)


def area_light_radiance(power, area):
    """Area light of `power` W over `area` m^2 (Cycles, normalized): L = P / (pi A) (measured 0.9996 x
    and 0.9997 x, square and rectangle)."""
    return power / (pi * area)


def spot_factor(cos_angle, spot_size, blend):
    """Cycles' spot cone: smoothstep((cos a - cos(size/2)) / ((1 - cos(size/2)) blend)) (the
    rendered profile of size 60 deg, blend 0.5 is within 0.007 of it)."""
    from math import cos

    ch = cos(spot_size / 2)
    if blend <= 0:
        return 1.0 if cos_angle > ch else 0.0
    t = min(max((cos_angle - ch) / ((1 - ch) * blend), 0.0), 1.0)
    return t * t * (3 - 2 * t)


def point_to_polygon_contour(p, n, poly):
    """Points p (K, 3) with normal n to the polygon poly (M, 3), unoccluded: Lambert's contour integral."""
    R = poly[None] - p[:, None]
    R /= np.linalg.norm(R, axis=2, keepdims=True)
    S = np.roll(R, -1, axis=1)
    g = np.cross(R, S)
    theta = np.arccos(np.clip((R * S).sum(2), -1, 1))
    g *= (theta / np.linalg.norm(g, axis=2))[..., None]
    return np.abs(g.sum(1) @ n) / (2 * np.pi)
