"""The setup books_texels.py and books_sides.py share: the furnished sample against its cached
Cycles reference (frame 1), one draft FE solution, and the bake's gather setting."""

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import cycles_compare as CC  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

BASE = dict(rays=128, shadow_rays=16, levels=2, iterations=4)  # the bake's draft gather


def variants(argv):
    """{name: texel_gather keywords} from name=dict(...) arguments, "main" (BASE) first."""
    out = {"main": {}}
    out.update({k: eval(v) for k, v in (x.split("=", 1) for x in argv)})
    return out


def furnished():
    """(rs, Cycles' two seeds {name: (texels, 3)}, system, dyn, ours) of the furnished sample."""
    cfg = CC.SCENES["furnished"]
    rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
    a, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[0])
    b, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[1])
    t0 = time.process_time()
    s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
    dyn = DynamicRadiosity(s, method="FE")
    dyn.apply(C.shape_proxies(rs, 1))
    print(f"build + frame 1: {time.process_time() - t0:.0f} s CPU", flush=True)
    return rs, (a, b), s, dyn, C.Ours(rs, s, dyn)


def book_boxes(rs):
    """{book: (lo, hi)}: each book's box from its vertices."""
    mesh = rs.scene_in.mesh
    tg = {t.name: t for t in rs.scene_in.targets}
    box = {}
    for n in (n for n in rs.objects if "_book" in n):
        lo_l, hi_l = tg[n].loops
        v = mesh.verts[mesh.loop_verts[lo_l:hi_l]]
        box[n] = (v.min(0), v.max(0))
    return box


def neighbour(box, n, side):
    """The box facing book n's side -x (side 0) or +x (side 1): the next book of its row, or None
    (the case's sides, 1 cm from a row's first book, are not looked at)."""
    case, row, k = n.split("_")[0], n.split("_")[1], int(n.split("_")[2])
    return box.get(f"{case}_{row}_{k + (1 if side else -1)}")


def texel_centres(at):
    """(at.n, 3) each texel's centre sample point of a cycles_ref.Atlas (nan where it has none)."""
    cen = np.flatnonzero(at.s_centre)
    x = np.full((at.n, 3), np.nan)
    x[at.s_texel[cen]] = at.s_point[cen]
    return x


def side_above(x, lo, hi, side, nb):
    """(N,) texels (centres x, texel_centres) on the book (box lo, hi)'s side -x (side 0) or +x
    (side 1) above the facing box nb's top, within the two boxes' overlap in y."""
    fx = hi[0] if side else lo[0]
    iny = (x[:, 1] > max(lo[1], nb[0][1])) & (x[:, 1] < min(hi[1], nb[1][1]))
    return (np.abs(x[:, 0] - fx) < 1e-4) & iny & (x[:, 2] > min(hi[2], nb[1][2]))


def centre_texels(rs, ours, ref, n, grey=True):
    """Object n's texels sampled at their centre: (points, patches, axes, triangles, the Cycles
    reference ref[n] at them, grey or (k, 3))."""
    at = rs.atlases[n]
    cen = np.flatnonzero(at.s_centre)
    return (
        at.s_point[cen],
        ours.samples[n][0][cen],
        at.s_axes[cen],
        at.s_tri[cen],
        ref[n][at.s_texel[cen]].mean(1) if grey else ref[n][at.s_texel[cen]],
    )


FACE = (
    "top",
    "front",
    "back",
    "bottom",
    "side: open (no neighbour book)",
    "side in slot, receiver shorter",
    "side in slot, receiver taller",
    "side in slot, equal",
    "side above the neighbour's top",
    "side, front/back overhang",
)


def book_texels(rs, s, ours, ref, books, box, H, grey=True):
    """The books' texels sampled at their centre, where Cycles' bake has them: (points, patches,
    axes, triangles, ref at them, book index, face class (FACE), height over the overlap's top in
    gap widths H (sides facing a neighbour book; nan elsewhere))."""
    cols = {k: [] for k in ("X", "P", "AX", "TR", "REF", "OBJ", "CLS", "ZREL")}
    for k, n in enumerate(books):
        x, patch, axes, tris, r = centre_texels(rs, ours, ref, n, grey)
        nrm = s.patches.normal[patch]
        lo, hi = box[n]
        ax = np.abs(nrm).argmax(1)
        sg = np.sign(nrm[np.arange(len(nrm)), ax])
        cls = np.full(len(x), 4)
        cls[(ax == 2) & (sg > 0)] = 0
        cls[(ax == 1) & (sg < 0)] = 1
        cls[(ax == 1) & (sg > 0)] = 2
        cls[(ax == 2) & (sg < 0)] = 3
        zrel = np.full(len(x), np.nan)
        for side in (0, 1):
            sel = np.flatnonzero((ax == 0) & ((sg > 0) == bool(side)))
            nb = neighbour(box, n, side)
            if nb is None or not len(sel):
                continue
            p = x[sel]
            top = min(hi[2], nb[1][2])
            iny = (p[:, 1] > max(lo[1], nb[0][1])) & (p[:, 1] < min(hi[1], nb[1][1]))
            below = p[:, 2] < top
            dz = hi[2] - nb[1][2]
            c = np.where(dz < -1e-4, 5, np.where(dz > 1e-4, 6, 7))
            cls[sel] = np.where(iny, np.where(below, c, 8), 9)
            zrel[sel] = (p[:, 2] - top) / H
        for key, v in zip(cols, (x, patch, axes, tris, r, np.full(len(x), k), cls, zrel)):
            cols[key].append(v)
    out = [np.concatenate(v) for v in cols.values()]
    ok = np.isfinite(out[4]).reshape(len(out[4]), -1).all(1)  # texels Cycles' bake left out
    return [v[ok] for v in out]


# the top and side-above texels by their row from the book's front (texels of 55 mm)
FRONT_GROUPS = (
    (0, "top, front row", (0,)),
    (0, "top, other rows", (1, 2, 3, 4, 5)),
    (8, "side above, front column", (0,)),
    (8, "side above, other columns", (1, 2, 3, 4, 5)),
)


def front_rows(X, OBJ, texel=0.0553):
    """(n,) each texel's row from its book's front (y grows from the front): 0 the front texel."""
    front = {}
    for k in range(len(X)):
        front[OBJ[k]] = min(front.get(OBJ[k], np.inf), X[k, 1])
    return np.rint((X[:, 1] - np.array([front[o] for o in OBJ])) / texel).astype(int)


def front_groups(X, OBJ, CLS):
    """[(name, mask)]: all books, the tops' front row and rows behind, the sides above a shorter
    neighbour's front column and columns behind (rows counted as front_rows, as books_hits.py)."""
    row = np.full(len(X), -1)
    ts = np.isin(CLS, (0, 8))
    row[ts] = front_rows(X[ts], OBJ[ts])
    return [
        ("all books", np.ones(len(X), bool)),
        ("tops, front row", (CLS == 0) & (row == 0)),
        ("tops, rows behind", (CLS == 0) & (row > 0)),
        ("sides above, front column", (CLS == 8) & (row == 0)),
        ("sides above, columns behind", (CLS == 8) & (row > 0)),
    ]
