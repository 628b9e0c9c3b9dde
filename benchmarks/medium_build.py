"""One build on one checkout, for bisecting build time (docs/scale.md, session 28, bis34): the
Cornell box (bench_core's mesh) or a furnished room, process CPU seconds (min of --runs), links,
nodes, push corrections, rays and a hash of the built links (equal hashes: the same links and
values bit for bit). Prints one JSON line.

  python benchmarks/medium_build.py [--root CHECKOUT] [--quality medium|draft|high|gather:medium]
      [--scene cornell|20k|...] [--runs 3] [--no-leaf-visibility]

--root: the checkout whose hr_addon is imported (default: this one), so one copy of this script
measures any commit (older ones keep the scenes in benchmarks/scenes.py). --no-leaf-visibility:
the push corrections without each leaf's own visibility (push_corrections(visibility=None), as
before 18616d9) on a checkout that has it.
"""

import argparse
import hashlib
import json
import os
import sys
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", default=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    ap.add_argument("--quality", default="medium")
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--no-leaf-visibility", action="store_true")
    args = ap.parse_args()
    root = os.path.abspath(args.root)
    sys.path.insert(0, root)
    import hr_addon
    from hr_addon.core import radiosity
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    assert hr_addon.__file__.startswith(root), hr_addon.__file__
    if args.scene == "cornell":
        try:
            from hr_testing import scenes
        except ImportError:  # before hr_testing
            from benchmarks import scenes
        mesh = scenes.cornell_box(subdiv=8)
    else:
        from hr_testing.furnished import furnished_room

        mesh = furnished_room(args.scene)[0]
    q = args.quality
    prm = RefineParams.for_gather(q.split(":")[1]) if q.startswith("gather:") else RefineParams.preset(q)
    if args.no_leaf_visibility:
        pc = radiosity.push_corrections
        radiosity.push_corrections = lambda *a, **k: pc(*a[:6], visibility=None)
    ts = []
    for _ in range(args.runs):
        t0 = time.process_time()
        s = RadiositySystem(mesh, prm)
        ts.append(time.process_time() - t0)
    L = s.links
    h = hashlib.sha1()
    arrays = [getattr(L, k) for k in ("a", "b", "f_ab", "f_ba", "vis")]
    if L.far is not None:
        arrays += [v for _, v in sorted(vars(L.far).items()) if isinstance(v, np.ndarray)]
    if L.corr is not None:
        arrays += list(L.corr)
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    st = s.build.refine
    out = dict(
        quality=q,
        scene=args.scene,
        leaf_visibility=not args.no_leaf_visibility,
        cpu_min=round(min(ts), 3),
        cpu=[round(t, 3) for t in ts],
        links=len(L),
        nodes=s.h.n,
        corrections=L.n_corrections,
        rays=st.get("rays", 0),
        link_hash=h.hexdigest()[:12],
    )
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
