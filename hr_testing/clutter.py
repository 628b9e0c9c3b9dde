"""A small closed room with the two failure modes issue 19 saw on an unseen furnished room (numpy
only; tests/test_cycles_clutter.py, benchmarks/clutter_vs_cycles.py):

- clutter sunk into clutter: a table (top and four legs) carrying a box, a cylinder and a lid
  that pass through each other and are sunk 2-3 cm into the table top, the lid standing partly on
  the box and the cylinder;
- a pillar of thin strips: a 64-segment cylinder 10 and 15 cm from the two walls of a corner.

    mesh, info = clutter_room()      # MeshInput (z up, metres), {"compared": [...], ...}

A 4 x 4 x 2.6 m room lit by an emissive ceiling panel (one-sided, facing down).
"""

import numpy as np

from .furnished import FLOOR, WALL, WOOD, Builder, box, cylinder, grid_quad

W, D, H = 4.0, 4.0, 2.6
TOP = 0.74  # the table top's upper face
PANEL = dict(lo=(1.4, 1.5), hi=(2.6, 2.5), emission=(6.0, 5.6, 5.0))
PILLAR = dict(centre=(W - 0.10 - 0.15, D - 0.15 - 0.15), radius=0.15, height=2.45, seg=64)
RED, BLUE, CERAMIC, GREEN = (0.7, 0.3, 0.25), (0.3, 0.4, 0.7), (0.8, 0.8, 0.75), (0.55, 0.6, 0.5)
# the objects whose per-object mean is compared with Cycles
COMPARED = ("sunk_box", "sunk_cylinder", "lid", "table_top", "pillar")


def clutter_room(grid=10, n=1):
    """The room as a MeshInput (walls, floor and ceiling grid x grid quads, normals inward) and a
    dict of facts: compared objects, triangles, the pillar's gaps to the walls. n: the table top's
    and the boxes' faces as n x n grids."""
    b = Builder()
    nz = max(2, int(grid * H / W))
    b.add("floor", *_q(grid_quad(np.zeros(3), [W, 0, 0], [0, D, 0], grid, grid)), FLOOR)
    b.add("ceiling", *_q(grid_quad([0, 0, H], [0, D, 0], [W, 0, 0], grid, grid)), WALL)
    b.add("wall_south", *_q(grid_quad(np.zeros(3), [0, 0, H], [W, 0, 0], nz, grid)), WALL)
    b.add("wall_north", *_q(grid_quad([0, D, 0], [W, 0, 0], [0, 0, H], grid, nz)), WALL)
    b.add("wall_west", *_q(grid_quad(np.zeros(3), [0, D, 0], [0, 0, H], grid, nz)), WALL)
    b.add("wall_east", *_q(grid_quad([W, 0, 0], [0, 0, H], [0, D, 0], nz, grid)), WALL)
    (x0, y0), (x1, y1) = PANEL["lo"], PANEL["hi"]
    b.add(
        "ceiling_light",
        *_q(grid_quad([x0, y0, H - 0.005], [0, y1 - y0, 0], [x1 - x0, 0, 0], 1, 1)),
        (0.0,) * 3,
        PANEL["emission"],
    )
    # table: 1.2 x 0.8 m top on four legs
    tx, ty = 1.0, 1.3
    solids = {}  # name -> ("box", lo, hi) or ("cylinder", base, radius, height): buried()

    def add_box(name, lo, hi, rho):
        b.add(name, *box(lo, hi, n), rho)
        solids[name] = ("box", np.asarray(lo, float), np.asarray(hi, float))

    def add_cylinder(name, base, r, h, seg, rho):
        b.add(name, *cylinder(base, r, h, seg), rho)
        solids[name] = ("cylinder", np.asarray(base, float), r, h)

    add_box("table_top", [tx, ty, TOP - 0.04], [tx + 1.2, ty + 0.8, TOP], WOOD)
    for i, (lx, ly) in enumerate([(0.06, 0.06), (1.14, 0.06), (0.06, 0.74), (1.14, 0.74)]):
        add_cylinder(f"table_leg{i}", [tx + lx, ty + ly, 0], 0.025, TOP - 0.04, 12, WOOD)
    # clutter sunk into the top and into each other
    add_box("sunk_box", [1.26, 1.45, TOP - 0.02], [1.60, 1.75, TOP + 0.21], RED)
    add_cylinder("sunk_cylinder", [1.62, 1.60, TOP - 0.03], 0.08, 0.24, 24, BLUE)
    add_box("lid", [1.40, 1.50, TOP + 0.19], [1.72, 1.70, TOP + 0.26], CERAMIC)
    # the pillar near the north-east corner
    (cx, cy), r = PILLAR["centre"], PILLAR["radius"]
    add_cylinder("pillar", [cx, cy, 0.0], r, PILLAR["height"], PILLAR["seg"], GREEN)
    mesh = b.build()
    return mesh, {
        "compared": list(COMPARED),
        "solids": solids,
        "polygons": len(mesh.loop_total),
        "triangles": int(np.sum(mesh.loop_total - 2)),
        "pillar_gaps": (W - cx - r, D - cy - r),
        "strip_width": 2 * r * np.sin(np.pi / PILLAR["seg"]),
    }


def buried(points, name, solids, eps=1e-6):
    """Points (N, 3) of object `name` strictly inside another of the solids (clutter_room's
    info["solids"]; the cylinders as their circles, not their polygons): the parts a render never
    shows."""
    p = np.asarray(points, float)
    out = np.zeros(len(p), bool)
    for other, s in solids.items():
        if other == name:
            continue
        if s[0] == "box":
            out |= np.all((p > s[1] + eps) & (p < s[2] - eps), 1)
        else:
            _, base, r, h = s
            d = p - base
            out |= (np.hypot(d[:, 0], d[:, 1]) < r - eps) & (d[:, 2] > eps) & (d[:, 2] < h - eps)
    return out


def visible_texels(atlas, name, solids):
    """(N,) texels of a cycles_ref.Atlas of object `name` none of whose sub-samples is buried: the
    same texels on both sides, whether a texel straddling an outline counts is no question."""
    return np.bincount(atlas.s_texel, buried(atlas.s_point, name, solids), atlas.n) == 0


def _q(vq):
    v, q = vq
    return v, [q]
