"""Issue 19 (branch kern31, docs/gather.md): which sources' light the closed furnished room's
transport loses, bpy-free: uniform unit radiance (B = exposure) on one object's (or patch's)
leaves, one gather + push with all links (and patch / far links only), the power received over
the power sent (1 in a closed room: every unit sent arrives somewhere).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/source_probe.py \
        [--room 20k] [--patches OBJECT] [--json benchmarks/out/source_probe_20k.json]
"""

import argparse
import dataclasses
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from far_vis_check import BASE  # noqa: E402
from kernel_split import received  # noqa: E402

from hr_addon.core.links import Links  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--room", default="20k")
    ap.add_argument("--shadow-feps", type=float, default=BASE.shadow_feps)
    ap.add_argument("--patches", default=None, help="per patch of the objects whose name starts so")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    mesh, _ = furnished_room(args.room)
    s = RadiositySystem(mesh, dataclasses.replace(BASE, shadow_feps=args.shadow_feps))
    h, L = s.h, s.links
    op = s.operator()
    lf, A = op.leaves, op.area
    ex = np.ones(op.n) if op.expo is None else op.expo.astype(float)
    patch_only = Links(L.a, L.b, L.f_ab, L.f_ba, L.vis, L.corr, None)
    far_only = Links(*(np.zeros(0, dt) for dt in (np.int64, np.int64, float, float, float)), far=L.far)
    names = np.array(list(s.patches.object_names))
    oid = np.asarray(s.patches.object_id)
    lp = h.patch[lf]
    out = {}
    if args.patches:
        keys = [
            (f"{names[oid[p]]}/{p}", lp == p)
            for p in np.flatnonzero(np.char.startswith(names[oid].astype(str), args.patches))
        ]
    else:
        keys = [(n, oid[lp] == i) for i, n in enumerate(names)]
    for k, sel in keys:
        if not sel.any():
            continue
        U = np.zeros((1, op.n))
        U[0, lf[sel]] = ex[lf[sel]]
        sent = float((A[lf] * U[0, lf]).sum())
        if sent <= 0:
            continue
        r = dict(
            sent=sent,
            **{
                n: float(received(s, lk, U)[0] / sent)
                for n, lk in (("all", L), ("patch", patch_only), ("far", far_only))
            },
        )
        out[k] = r
    tot = sum(r["sent"] for r in out.values())
    lost = sorted(out.items(), key=lambda kv: -(1 - kv[1]["all"]) * kv[1]["sent"])
    for k, r in lost[:40]:
        print(
            f"{k:28s} sent {r['sent']:8.4f} ({r['sent'] / tot:.4f})  received/sent {r['all']:.4f} "
            f"(patch {r['patch']:.4f}, far {r['far']:.4f}) lost share {(1 - r['all']) * r['sent'] / tot:+.5f}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
