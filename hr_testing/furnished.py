"""Furnished rooms of about 2k, 10k, 20k, 100k and 1M triangles, built from numbers (numpy only).

    from hr_testing.furnished import furnished_room
    mesh, info = furnished_room("20k")        # MeshInput (z up, metres) and a dict of facts

A 6 x 5 x 2.8 m room (walls, floor and ceiling as grids, a ceiling light panel) with tables on
legs, chairs, bookcases whose boards carry rows of books, a sofa, subdivided spheres and
cylinders (vases, cups) standing on the tables and boards, and boxes on the floor: many small
objects resting on other surfaces, the case clustering and contact handling must deal with.
The size preset scales the counts and the tessellation; the layout is deterministic (seeded), and
nothing interpenetrates (placements that would overlap are retried, then skipped).
Counts are triangles as Blender's loop_triangles would give (a quad is two).

    mesh, info = daylight_room("20k")         # no ceiling panel, a window through the south wall

daylight_room is the same room lit by daylight (issue 20): a window opening without glass through
the south wall, for a sun (SUN) shining through it onto the floor and a uniform World sky (SKY);
hr_testing/cycles_lights.py builds it in Blender with both.
"""

import numpy as np

from hr_addon.core.geometry import MeshInput

from .scenes import icosphere as _icosphere

W, D, H = 6.0, 5.0, 2.8
WOOD, WALL, FLOOR, FABRIC, CERAMIC = (
    (0.45, 0.3, 0.18),
    (0.75, 0.73, 0.7),
    (0.5, 0.42, 0.35),
    (0.3, 0.35, 0.5),
    (0.8, 0.8, 0.75),
)

# size -> (wall grid, bookcases, books per row, table count, chairs, cylinder segments, sphere subdiv,
#          objects on tables, floor boxes)
PRESETS = {
    "2k": dict(grid=8, cases=1, books=12, tables=1, chairs=2, seg=12, balls=1, sphere=2, clutter=4, boxes=6),
    "10k": dict(
        grid=18, cases=2, books=30, tables=2, chairs=4, seg=20, balls=2, sphere=3, clutter=14, boxes=20
    ),
    "20k": dict(
        grid=26, cases=4, books=44, tables=2, chairs=6, seg=24, balls=2, sphere=3, clutter=28, boxes=40
    ),
    "100k": dict(
        grid=64, cases=12, books=80, tables=4, chairs=14, seg=48, balls=3, sphere=4, clutter=80, boxes=120
    ),
    "1M": dict(
        grid=300,
        cases=24,
        books=200,
        tables=10,
        chairs=40,
        seg=160,
        balls=8,
        sphere=5,
        clutter=300,
        boxes=300,
    ),
}


class Builder:
    """Objects as arrays: vertices and faces (triangles or quads, CCW seen from outside)."""

    def __init__(self):
        self.verts, self.faces, self.rho, self.em, self.oid, self.names = [], [], [], [], [], []
        self.nv = 0

    def add(self, name, verts, faces, rho, emission=(0.0, 0.0, 0.0)):
        faces = [np.asarray(f, np.int64) for f in faces]
        oid = len(self.names)
        self.names.append(name)
        self.verts.append(np.asarray(verts, float))
        for f in faces:
            if len(f):
                self.faces.append(f + self.nv)
                self.rho.append(np.broadcast_to(np.asarray(rho, float), (len(f), 3)))
                self.em.append(np.broadcast_to(np.asarray(emission, float), (len(f), 3)))
                self.oid.append(np.full(len(f), oid))
        self.nv += len(verts)

    def build(self):
        verts = np.concatenate(self.verts)
        sizes = np.concatenate([np.full(len(f), f.shape[1]) for f in self.faces])
        loops = np.concatenate([f.ravel() for f in self.faces])
        starts = np.r_[0, np.cumsum(sizes)[:-1]]
        return MeshInput(
            verts,
            starts,
            sizes,
            loops,
            np.concatenate(self.rho),
            np.concatenate(self.em),
            np.concatenate(self.oid),
            list(self.names),
        )


def grid_quad(o, u, v, nu, nv):
    """Quad grid over the parallelogram o + s u + t v (normal u x v)."""
    s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    verts = o + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return verts, q


def box(lo, hi, n=1):
    """Closed box, outward normals, each face an n x n grid."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    e = hi - lo
    X, Y, Z = np.diag(e)
    faces = [(lo, Y, X), (lo + Z, X, Y), (lo, X, Z), (lo + Y, Z, X), (lo, Z, Y), (lo + X, Y, Z)]
    vs, qs, off = [], [], 0
    for o, u, v in faces:
        vv, q = grid_quad(o, u, v, n, n)
        vs.append(vv)
        qs.append(q + off)
        off += len(vv)
    return np.concatenate(vs), [np.concatenate(qs)]


def cylinder(base, radius, height, seg, caps=True):
    """Closed cylinder standing on `base` (z up)."""
    t = np.linspace(0, 2 * np.pi, seg, endpoint=False)
    ring = np.column_stack([radius * np.cos(t), radius * np.sin(t), np.zeros(seg)])
    verts = np.concatenate([ring, ring + [0, 0, height]]) + base
    i = np.arange(seg)
    j = (i + 1) % seg
    faces = [np.column_stack([i, j, seg + j, seg + i])]
    if caps:
        c0, c1 = len(verts), len(verts) + 1
        verts = np.concatenate([verts, [base, np.asarray(base) + [0, 0, height]]])
        faces += [
            np.column_stack([np.full(seg, c0), j, i]),
            np.column_stack([np.full(seg, c1), seg + i, seg + j]),
        ]
    return verts, faces


def icosphere(centre, radius, subdiv):
    v, f = _icosphere(subdiv, radius, inward=False)
    return v + centre, [np.array(f)]


class Footprints:
    """Occupied rectangles on one surface: objects are placed where they overlap nothing (real
    rooms have no interpenetrating furniture; rejected placements are retried, then skipped)."""

    def __init__(self, rng, lo, hi, gap=0.01):
        self.rng, self.lo, self.hi, self.gap, self.rects = (
            rng,
            np.asarray(lo, float),
            np.asarray(hi, float),
            gap,
            [],
        )

    def place(self, w, d, tries=60):
        for _ in range(tries):
            x = self.rng.uniform(self.lo[0], self.hi[0] - w) if self.hi[0] - w > self.lo[0] else None
            y = self.rng.uniform(self.lo[1], self.hi[1] - d) if self.hi[1] - d > self.lo[1] else None
            if x is None or y is None:
                return None
            if self.free(x, y, w, d):
                self.rects.append((x, y, x + w, y + d))
                return x, y
        return None

    def free(self, x, y, w, d):
        g = self.gap
        return all(
            x + w + g <= r[0] or r[2] + g <= x or y + d + g <= r[1] or r[3] + g <= y for r in self.rects
        )

    def take(self, x, y, w, d):
        self.rects.append((x, y, x + w, y + d))


# daylight_room: a window opening through the south wall (y = 0), as the box of the wall cells it
# takes out; the sun shines through it from the south-south-west, 35 degrees up, onto the floor
# and what stands there; a blue-white uniform sky. Sun and sky bring in about as much light each
# (the sun 4 W/m^2 x 2.3 m^2 x cos 40 degrees, the sky pi x radiance x 2.3 m^2).
SOUTH_WINDOW = ((0.9, -0.01, 0.9), (2.6, 0.01, 2.3))
_ELEV, _AZIM = np.radians(35.0), np.radians(20.0)
SUN = dict(
    direction=(np.sin(_AZIM) * np.cos(_ELEV), np.cos(_AZIM) * np.cos(_ELEV), -np.sin(_ELEV)),
    strength=4.0,
    color=(1.0, 0.9, 0.75),
    angle=0.0,
)
SKY = dict(color=(0.5, 0.65, 1.0), strength=1.0)


def daylight_room(size="20k", seed=1):
    """furnished_room without its ceiling panel and with SOUTH_WINDOW cut through the south wall;
    info["window"]: (lo, hi) corners of the opening (the cut cells' box)."""
    return furnished_room(size, seed, openings=(SOUTH_WINDOW,), panel=False)


def furnished_room(size="20k", seed=1, openings=(), panel=True):
    """openings: boxes (lo, hi) through the room's walls, floor or ceiling: their grid cells whose
    centre lies inside are left out (the opening follows the grid lines); panel: the ceiling light
    panel. The defaults give the furnished sample's room."""
    if size not in PRESETS:
        raise ValueError(f"unknown size {size!r} (choose from {', '.join(PRESETS)})")
    P = PRESETS[size]
    rng = np.random.default_rng(seed)
    b = Builder()
    floor = Footprints(rng, (0.05, 0.05), (W - 0.05, D - 0.05))
    g = P["grid"]
    nz = max(2, int(g * H / W))
    cut = []  # the cells left out for the openings

    def room(vq):
        v, q = vq
        if not openings:
            return v, [q]
        c = v[q].mean(1)
        out = np.zeros(len(q), bool)
        for lo, hi in openings:
            out |= np.all((c > lo) & (c < hi), 1)
        cut.append(v[q[out]].reshape(-1, 3))
        return v, [q[~out]]

    # room, normals inward
    b.add("floor", *room(grid_quad(np.zeros(3), [W, 0, 0], [0, D, 0], g, int(g * D / W))), FLOOR)
    b.add("ceiling", *room(grid_quad([0, 0, H], [0, D, 0], [W, 0, 0], int(g * D / W), g)), WALL)
    b.add("wall_south", *room(grid_quad(np.zeros(3), [0, 0, H], [W, 0, 0], nz, g)), WALL)
    b.add("wall_north", *room(grid_quad([0, D, 0], [W, 0, 0], [0, 0, H], g, nz)), WALL)
    b.add("wall_west", *room(grid_quad(np.zeros(3), [0, D, 0], [0, 0, H], int(g * D / W), nz)), WALL)
    b.add("wall_east", *room(grid_quad([W, 0, 0], [0, 0, H], [0, D, 0], nz, int(g * D / W))), WALL)
    if panel:
        b.add(
            "ceiling_light",
            *_q(grid_quad([2.4, 2.0, H - 0.005], [0, 1.0, 0], [1.2, 0, 0], 1, 1)),
            (0.8,) * 3,
            (6.0, 5.6, 5.0),
        )
    tops = []  # (x0, y0, x1, y1, z) surfaces small things can stand on
    # tables on legs
    # bookcases first: they stand along the north wall
    cw, cd = 0.9, 0.32
    cases = []
    for k in range(P["cases"]):
        x0 = 0.15 + (k % 6) * (cw + 0.05)
        y0 = D - cd - 0.02 - (k // 6) * 0.6
        floor.take(x0, y0, cw, cd)
        cases.append((x0, y0))
    sx, sy = W - 2.4, 0.3
    floor.take(sx, sy, 2.0, 0.9)
    for k in range(P["tables"]):
        tw, td, th = 1.0, 0.7, 0.74
        spot = floor.place(tw, td)
        if spot is None:
            continue
        x0, y0 = spot
        b.add(f"table{k}_top", *box([x0, y0, th - 0.04], [x0 + tw, y0 + td, th], 1), WOOD)
        for i, (lx, ly) in enumerate(
            [
                (x0 + 0.06, y0 + 0.06),
                (x0 + tw - 0.06, y0 + 0.06),
                (x0 + 0.06, y0 + td - 0.06),
                (x0 + tw - 0.06, y0 + td - 0.06),
            ]
        ):
            b.add(f"table{k}_leg{i}", *cylinder([lx, ly, 0], 0.025, th - 0.04, P["seg"] // 2), WOOD)
        tops.append((x0 + 0.1, y0 + 0.1, x0 + tw - 0.1, y0 + td - 0.1, th))
    # chairs: seat, four legs, backrest
    for k in range(P["chairs"]):
        s = 0.42
        spot = floor.place(s, s)
        if spot is None:
            continue
        x0, y0 = spot
        b.add(f"chair{k}_seat", *box([x0, y0, 0.42], [x0 + s, y0 + s, 0.46], 1), FABRIC)
        for i, (lx, ly) in enumerate(
            [
                (x0 + 0.03, y0 + 0.03),
                (x0 + s - 0.03, y0 + 0.03),
                (x0 + 0.03, y0 + s - 0.03),
                (x0 + s - 0.03, y0 + s - 0.03),
            ]
        ):
            b.add(f"chair{k}_leg{i}", *cylinder([lx, ly, 0], 0.018, 0.42, max(6, P["seg"] // 3)), WOOD)
        b.add(f"chair{k}_back", *box([x0, y0 + s - 0.04, 0.46], [x0 + s, y0 + s, 0.9], 1), FABRIC)
    # bookcases along the north wall, boards carrying rows of books
    for k, (x0, y0) in enumerate(cases):
        boards = 5
        b.add(f"case{k}_side0", *box([x0, y0, 0], [x0 + 0.02, y0 + cd, 2.0], 1), WOOD)
        b.add(f"case{k}_side1", *box([x0 + cw - 0.02, y0, 0], [x0 + cw, y0 + cd, 2.0], 1), WOOD)
        for j in range(boards):
            z = 0.05 + j * 0.4
            b.add(f"case{k}_board{j}", *box([x0 + 0.02, y0, z], [x0 + cw - 0.02, y0 + cd, z + 0.02], 1), WOOD)
            x = x0 + 0.03
            nb = 0
            while nb < P["books"] and x < x0 + cw - 0.05:
                bw = rng.uniform(0.015, 0.04) * min(1.0, 24 / P["books"] * 1.5)
                bh = rng.uniform(0.18, 0.33)
                bd = rng.uniform(0.15, 0.28)
                col = rng.uniform(0.1, 0.8, 3)
                b.add(
                    f"case{k}_book{j}_{nb}",
                    *box([x, y0 + 0.01, z + 0.02], [x + bw, y0 + 0.01 + bd, z + 0.02 + bh], 1),
                    col,
                )
                x += bw + 0.002
                nb += 1
    # sofa
    b.add("sofa_base", *box([sx, sy, 0.0], [sx + 2.0, sy + 0.9, 0.45], 2), FABRIC)
    b.add("sofa_back", *box([sx, sy, 0.45], [sx + 2.0, sy + 0.2, 0.9], 2), FABRIC)
    for i in range(3):
        b.add(
            f"sofa_cushion{i}",
            *box([sx + 0.05 + i * 0.64, sy + 0.25, 0.45], [sx + 0.64 + i * 0.64, sy + 0.85, 0.58], 2),
            FABRIC,
        )
    # clutter on the tables: spheres, vases, cups
    on_top = [Footprints(rng, t[:2], t[2:4]) for t in tops]
    for k in range(P["clutter"]):
        if not tops:
            break
        z = tops[k % len(tops)][4]
        kind = 0 if k < P["balls"] else 1 + k % 3
        r = (
            rng.uniform(0.07, 0.1)
            if kind == 0
            else rng.uniform(0.04, 0.07)
            if kind == 1
            else 0.035
            if kind == 2
            else 0.06
        )
        spot = on_top[k % len(tops)].place(2 * r, 2 * r)
        if spot is None:
            continue
        x, y = spot[0] + r, spot[1] + r
        if kind == 0:
            b.add(f"ball{k}", *icosphere([x, y, z + r], r, P["sphere"]), CERAMIC)
        elif kind == 1:
            b.add(f"vase{k}", *cylinder([x, y, z], r, rng.uniform(0.15, 0.3), P["seg"]), CERAMIC)
        elif kind == 2:
            b.add(f"cup{k}", *cylinder([x, y, z], r, 0.09, P["seg"]), CERAMIC)
        else:  # a stack of books lying flat
            zz = z
            for j in range(int(rng.integers(2, 6))):
                t = rng.uniform(0.02, 0.04)
                b.add(
                    f"stack{k}_{j}",
                    *box([x - r, y - 0.8 * r, zz], [x + r, y + 0.8 * r, zz + t], 1),
                    rng.uniform(0.1, 0.8, 3),
                )
                zz += t
    # boxes on the floor and a few stacked
    for k in range(P["boxes"]):
        s = rng.uniform(0.1, 0.35)
        spot = floor.place(s, s)
        if spot is None:
            continue
        x, y = spot
        z = 0.0
        b.add(f"box{k}", *box([x, y, z], [x + s, y + s, z + s * 0.8], 1), rng.uniform(0.2, 0.8, 3))
        if k % 4 == 0:
            t = s * 0.6
            b.add(
                f"box{k}_top",
                *box([x + 0.1 * s, y + 0.1 * s, s * 0.8], [x + 0.1 * s + t, y + 0.1 * s + t, s * 0.8 + t]),
                rng.uniform(0.2, 0.8, 3),
            )
    mesh = b.build()
    tris = int(np.sum(mesh.loop_total - 2))
    holes = np.concatenate(cut) if cut else np.zeros((0, 3))
    return mesh, {
        "window": (holes.min(0), holes.max(0)) if len(holes) else None,
        "size": size,
        "polygons": len(mesh.loop_total),
        "triangles": tris,
        "objects": len(mesh.object_names),
        "light_wall": (
            "wall_west",
            (np.array([0.0, 0.8, 0.9]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])),
        ),
    }


def _q(vq):
    v, q = vq
    return v, [q]


if __name__ == "__main__":
    import sys

    for s in sys.argv[1:] or list(PRESETS):
        m, info = furnished_room(s)
        print(info)
