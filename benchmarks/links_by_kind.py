"""Where a scene's links are (session 35, branch leaves): the draft gather transport built on a
scene's MeshInput as a bake reads it, its links by kind (patch-patch, cluster-cluster,
cluster-patch) and by the objects their ends join (leaf objects: names containing --leaf), with
--diag the two oracles' reasons for splitting (link_clusters' _classify: facing, size, variation,
Feps, partial visibility; the patch refinement's: Feps, partial visibility, contact), and the
build's CPU by stage (build_stages.py's wrappers, without --diag). One thread.

    python benchmarks/links_by_kind.py --dump LOFT.blend MESH.npz      # bpy: the MeshInput at frame 1
    python benchmarks/links_by_kind.py MESH.npz [--no-leaves] [--diag] [--params 'dict()'] [--json OUT]

End labels: a patch node 'l' (of a leaf object) or 'r'; a cluster 'L1' (leaves of one object),
'L' (leaves of several), 'R' (no leaf), 'M' (mixed).
"""

import argparse
import dataclasses
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

FIELDS = ("verts", "loop_start", "loop_total", "loop_verts", "reflectance", "emission", "object_id")
OPTIONAL = ("tri_loops", "face_group", "flat")


def dump(blend, out):
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
    bpy.context.scene.frame_set(1)
    from hr_addon.blender.scene_in import collect_geometry

    m = collect_geometry(bpy.context.view_layer, bpy.context.evaluated_depsgraph_get()).mesh
    d = {k: getattr(m, k) for k in FIELDS + OPTIONAL if getattr(m, k) is not None}
    np.savez(out, names=np.array(m.object_names), **d)
    print(len(m.loop_start), "polygons", len(m.object_names), "objects")


def load(path, no_leaves, leaf_word):
    from hr_addon.core.geometry import MeshInput

    z = np.load(path)
    names = [str(x) for x in z["names"]]
    m = MeshInput(object_names=names, **{k: z[k] for k in z.files if k != "names"})
    leaf = np.array([leaf_word in n for n in names])
    if not no_leaves:
        return m, leaf
    keep = ~leaf[m.object_id]
    lt = m.loop_total[keep]
    loops = np.concatenate([np.arange(s, s + t) for s, t in zip(m.loop_start[keep], lt)])
    remap = np.full(len(m.loop_verts), -1, np.int64)
    remap[loops] = np.arange(len(loops))
    tri = None
    if m.tri_loops is not None:
        tri = remap[m.tri_loops[(remap[m.tri_loops] >= 0).all(1)]]
    fg = None if m.face_group is None else np.searchsorted(np.flatnonzero(keep), m.face_group[keep])
    m = MeshInput(
        m.verts,
        np.r_[0, np.cumsum(lt)[:-1]],
        lt,
        m.loop_verts[loops],
        m.reflectance[keep],
        m.emission[keep],
        m.object_id[keep],
        names,
        tri,
        fg,
        None if m.flat is None else m.flat[keep],
    )
    return m, leaf


class Labels:
    """End labels (module docstring) of link ends in the shared id space."""

    def __init__(self, tree, h, leaf):
        from hr_addon.core import cluster

        self.h, self.leaf, self.decode = h, leaf, cluster.decode
        o = h.patches.object_id[tree.perm]
        cs = np.r_[0, np.cumsum(leaf[o])]
        nl, n = cs[tree.end] - cs[tree.start], tree.end - tree.start
        run = np.r_[0, np.cumsum(o[1:] != o[:-1])]
        one = run[tree.end - 1] == run[tree.start]
        self.cl = np.where(nl == n, np.where(one, "L1", "L"), np.where(nl == 0, "R", "M"))

    def __call__(self, ids):
        node = np.where(self.leaf[self.h.patches.object_id[self.h.patch[np.maximum(ids, 0)]]], "l", "r")
        return np.where(ids < 0, self.cl[self.decode(np.minimum(ids, -1))], node)


def counts(keys):
    u, c = np.unique(keys, return_counts=True)
    return {str(k): int(v) for k, v in sorted(zip(u, c), key=lambda x: -x[1])}


def diagnose(tally, leaf):
    """Wrap the oracles to tally their reasons for splitting (a second evaluation of their tests)."""
    from hr_addon.core import cluster, farlinks, refine
    from hr_addon.core import formfactor as ff

    def add(key, n):
        tally[key] = tally.get(key, 0) + int(n)

    labels = {}
    orig_cls = farlinks._classify

    def classify(refiner, tree, a, b, table=None, lit=None):
        out = orig_cls(refiner, tree, a, b, table, lit)
        drop, ok, take, split_a, split_b, vis = out[:6]
        h, prm = refiner.h, refiner.params
        ea, eb = cluster.Ends(tree, h, a, table), cluster.Ends(tree, h, b, table)
        fa, ba, dmax = cluster.faces(ea, eb)
        fb, bb, _ = cluster.faces(eb, ea, dmax)
        f_ab, f_ba, dist = cluster.estimate(ea, eb, both=True)
        pa, pb = ~fa & ~ba & ea.cl, ~fb & ~bb & eb.cl
        facing = (fa | pa) & (fb | pb) & ~(pa & pb)
        rho = lambda e: (
            np.where(e.cl, np.where(e.theta < cluster.GRAD_CONE, 1.0, cluster.CURVED), 0.5) * e.radius
        )
        lit_ab = lit.ends(a) | lit.ends(b) if lit is not None else np.ones(len(a), bool)
        ratio = np.where(lit_ab, prm.cluster_ratio, prm.dark_ratio or prm.cluster_ratio)
        small = (rho(ea) + rho(eb)) / np.maximum(dist, 1e-300) < ratio
        fmax = np.maximum(f_ab, f_ba)
        feps = fmax < np.where(pa | pb, prm.partial_feps * prm.feps, prm.feps)
        partial = (vis > 0) & (vis < 1)
        why = np.where(
            ~facing,
            "facing",
            np.where(~small, "size", np.where(~feps, "feps", np.where(partial, "partial vis", "variation"))),
        )
        if id(tree) not in labels:
            labels[id(tree)] = Labels(tree, h, leaf)
        lab = labels[id(tree)]
        pair = np.char.add(np.char.add(lab(a), "|"), lab(b))
        split = split_a | split_b
        add("clusters: drop", drop.sum())
        add("clusters: far link", (ok | take).sum())
        for k, v in counts(np.char.add(np.char.add(why[split], ": "), pair[split])).items():
            add(f"clusters: split by {k}", v)
        return out

    farlinks._classify = classify
    orig_or = refine.Refiner._oracle

    def oracle(self, p, q, kv, good_enough, aeps, tol):
        out = orig_or(self, p, q, kv, good_enough, aeps, tol)
        p2, q2, vis, link, sp, sq = out
        h = self.h
        cp, cq = self.centres(p2), self.centres(q2)
        fm = np.maximum(
            ff.estimate(cp, h.normal[p2], h.area[p2], h.corners[q2], cq, h.normal[q2], h.area[q2]),
            ff.estimate(cq, h.normal[q2], h.area[q2], h.corners[p2], cp, h.normal[p2], h.area[p2]),
        )
        o = h.patches.object_id[h.patch[: h.n]]
        lf = leaf[o]
        pair = np.where(
            lf[p2] & lf[q2],
            np.where(o[p2] == o[q2], "leaf-leaf same", "leaf-leaf other"),
            np.where(lf[p2] | lf[q2], "leaf-room", "room-room"),
        )
        why = np.where(
            fm >= self.params.feps, "feps", np.where((vis > 0) & (vis < 1), "partial vis", "contact")
        )
        split = sp | sq
        add("patches: pairs in", len(p))
        add("patches: link", link.sum())
        add("patches: link at Aeps with F >= Feps", (link & (fm >= self.params.feps)).sum())
        for k, v in counts(np.char.add(np.char.add(why[split], ": "), pair[split])).items():
            add(f"patches: split by {k}", v)
        return out

    refine.Refiner._oracle = oracle


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mesh", nargs="?")
    ap.add_argument("--dump", nargs=2, metavar=("BLEND", "OUT"))
    ap.add_argument("--no-leaves", action="store_true", help="the scene without its leaf objects")
    ap.add_argument("--leaf", default="leaves", help="leaf objects: names containing this")
    ap.add_argument("--diag", action="store_true")
    ap.add_argument("--quality", default="DRAFT")
    ap.add_argument("--params", default="dict()", help="RefineParams overrides (a dict)")
    ap.add_argument("--json")
    a = ap.parse_args()
    if a.dump:
        return dump(*a.dump)
    import build_stages
    from hr_addon.blender import settings
    from hr_addon.core.radiosity import RadiositySystem

    m, leaf = load(a.mesh, a.no_leaves, a.leaf)
    params, _, _ = settings.solver_setup(m, settings.refine_params(a.quality, final_gather=True))
    params = dataclasses.replace(params, **eval(a.params))
    tally, acc = {}, {}
    if a.diag:
        diagnose(tally, leaf)
    else:
        build_stages.install(acc)
    c0 = time.process_time()
    s = RadiositySystem(m, params, threads=1)
    cpu = time.process_time() - c0
    L, h = s.links, s.h
    o = h.patches.object_id[h.patch[: h.n]]
    lf = leaf[o]
    res = dict(
        params=a.params,
        no_leaves=a.no_leaves,
        patches=int(len(h.patches.nv)),
        leaf_patches=int(leaf[h.patches.object_id].sum()),
        nodes=int(h.n),
        links=len(L),
        patch_links=int(len(L.a)),
        far_links=L.n_far,
        build_cpu_s=round(cpu, 2),
        peak_gb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
    )
    kind = np.where(
        lf[L.a] & lf[L.b],
        np.where(o[L.a] == o[L.b], "leaf-leaf, one object", "leaf-leaf, two objects"),
        np.where(lf[L.a] | lf[L.b], "leaf-room", "room-room"),
    )
    res["patch_links_by"] = counts(kind)
    if L.far is not None:
        lab = Labels(L.far.tree, h, leaf)
        ends = lambda x: np.where(x < 0, "C", "P")
        key = np.char.add(np.char.add(np.char.add(ends(L.far.a), ends(L.far.b)), " "), lab(L.far.a))
        res["far_links_by"] = counts(np.char.add(np.char.add(key, "|"), lab(L.far.b)))
    res["stats"] = {k: (v if isinstance(v, int) else round(float(v), 2)) for k, v in s.refiner.stats.items()}
    res["stages"] = {k: round(v[0], 2) for k, v in acc.items()}
    res["tally"] = dict(sorted(tally.items(), key=lambda x: -x[1]))
    print(json.dumps(res, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
