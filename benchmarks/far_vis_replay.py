"""Issue 19 (bld32, docs/scale.md): far_visibility of another checkout (--other, e.g. main) against
this one's on the same calls, in one process: the calls of this checkout's build of the furnished
room recorded (ends, weak, second, decide) and replayed at the end of link_clusters, alternating
the two versions on the same refiner, tree, end table and ray backend; CPU s per kind of call
(oracle, shadows, second trace), min over --repeats. The other checkout's hr_addon is copied to a
scratch package (hr_other) so both import side by side; its far_visibility has no `decide` (it
traces every oracle link's 16 segments). A build's CPU varies by more than such a cut under this
machine's load; here both versions run on the same inputs minutes apart at most.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/far_vis_replay.py 20k --other /work/main
"""

import argparse
import importlib
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import hr_addon.core.farlinks as FL  # noqa: E402
from hr_addon.core.params import RefineParams  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def other_farlinks(root):
    tmp = tempfile.mkdtemp(prefix="far_vis_replay_")
    shutil.copytree(os.path.join(root, "hr_addon"), os.path.join(tmp, "hr_other"))
    sys.path.insert(0, tmp)
    return importlib.import_module("hr_other.core.farlinks")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("size", default="20k")
    ap.add_argument("--other", default="/work/main")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    OL = other_farlinks(a.other)
    import inspect

    has_second = "second" in inspect.signature(OL.far_visibility).parameters
    calls, res = [], {}
    orig, orig_link = FL.far_visibility, FL.link_clusters

    def record(refiner, tree, x, y, weak=None, table=None, second=False, decide=False):
        kind = (
            "oracle"
            if decide or (weak is None and not second and FL.SECOND_TRACE and _in_classify())
            else None
        )
        kind = kind or ("second" if second else "shadows")
        calls.append(
            (kind, x.copy(), y.copy(), None if weak is None else np.array(weak), table, second, decide)
        )
        return orig(refiner, tree, x, y, weak, table, second, decide)

    def link_clusters(refiner, tree, progress=None):
        out = orig_link(refiner, tree, progress)
        FL.far_visibility = orig
        for kind in ("oracle", "shadows", "second"):
            res[kind] = dict(this=[], other=[], rays_this=0, rays_other=0)
        for rep in range(a.repeats):
            for which, fn in (
                (("this", orig), ("other", OL.far_visibility))
                if rep % 2 == 0
                else (
                    ("other", OL.far_visibility),
                    ("this", orig),
                )
            ):
                tot = {k: 0.0 for k in res}
                for kind, x, y, weak, table, second, decide in calls:
                    r0 = refiner.stats["rays"]
                    t0 = time.process_time()
                    if which == "this":
                        fn(refiner, tree, x, y, weak, table, second, decide)
                    elif has_second:
                        fn(refiner, tree, x, y, weak, table, second)
                    else:  # (session 21's: no second set of points; its one set traced again)
                        fn(refiner, tree, x, y, weak, table)
                    tot[kind] += time.process_time() - t0
                    if rep == 0:
                        res[kind]["rays_" + which] += refiner.stats["rays"] - r0
                for k in res:
                    res[k][which].append(tot[k])
        return out

    def _in_classify():
        import inspect

        return any(f.function == "_classify" for f in inspect.stack()[2:4])

    FL.far_visibility = record
    FL.link_clusters = link_clusters
    mesh, _ = furnished_room(a.size)
    RadiositySystem(mesh, RefineParams.for_gather("draft"))
    out = dict(size=a.size, other=a.other, repeats=a.repeats, load_average=os.getloadavg())
    for k, v in res.items():
        t, o = min(v["this"]), min(v["other"])
        out[k] = dict(this_s=t, other_s=o, ratio=t / o, rays_this=v["rays_this"], rays_other=v["rays_other"])
        print(
            f"{k:8s} this {t:.3f} s  other {o:.3f} s  x{t / o:.3f}  rays {v['rays_this']} / {v['rays_other']}"
        )
    t = sum(out[k]["this_s"] for k in res)
    o = sum(out[k]["other_s"] for k in res)
    out["all"] = dict(this_s=t, other_s=o, ratio=t / o)
    print(f"all      this {t:.3f} s  other {o:.3f} s  x{t / o:.3f}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
