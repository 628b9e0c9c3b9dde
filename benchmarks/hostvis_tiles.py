"""core/gather/hostvis.py (the tiled host visibility) on the 100k furnished room's FE window:
its precompute (tiles traced for the window at add 0.7, then at move 1.2 m: the second position
traces only the tiles the first did not) and its per-event CPU and error against many shadow rays,
per gather level, per tile size; main's shadow rays alongside (docs/events.md, session 28 hvp).

    .venv/bin/python benchmarks/hostvis_tiles.py STORE [--level top|second] [--tiles 4,8]
        [--points 64] [--ref-rays 256] [--json out.json]

STORE: a `bench_gather_events.py --transport gather --cache DIR` build of the furnished room (the
hv34 store: /work/cache/hvstore100k).
"""

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store")
    ap.add_argument("--level", default="top", choices=("top", "second"))
    ap.add_argument("--tiles", default="4,8")
    ap.add_argument("--points", type=int, default=None, help="stored points per shape (top 64, second 16)")
    ap.add_argument("--ref-rays", type=int, default=None, help="the reference's rays (top 256, second 64)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--size", default="100k")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    from bench_gather_events import load_store
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.events.direct import clear_shafts
    from hr_addon.core.gather.hostvis import HostVisibility
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    cpu = time.process_time
    top = args.level == "top"
    points = args.points or (64 if top else 16)
    ref_rays = args.ref_rays or (256 if top else 64)
    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    s.links.extended(s.h)
    lv = g if top else g.second
    _, info = furnished_room(args.size)
    frame = tuple(np.asarray(f, float) for f in info["light_wall"][1])

    def window(cx):
        return LightShape(
            S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
        )

    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    base = dict(rays=lv.shadow_rays, far=getattr(lv, "FAR_RAYS", 0))

    def level_light(rec, rays=None, far=None):
        lv.shadow_rays = rays or base["rays"]
        if not top:
            lv.FAR_RAYS = base["far"] if far is None else far
        lv._shape_cache.pop(rec.geom_key, None)
        c0 = cpu()
        D = lv._shape(dyn, rec)[0]
        t = cpu() - c0
        lv._shape_cache.pop(rec.geom_key, None)
        lv.shadow_rays = base["rays"]
        if not top:
            lv.FAR_RAYS = base["far"]
        return D.astype(np.float64), t

    res = dict(
        store=args.store, level=args.level, points=points, ref_rays=ref_rays, samples=int(lv.n), events={}
    )
    stores = {}
    for step, cx in (("add", 0.7), ("move", 1.2)):
        if step == "add":
            dyn.add("w", window(cx))
        else:
            dyn.apply({"w": window(cx)})
        rec = dyn.shapes["w"]
        em = lv._shape_emitter(dyn, rec)[0]
        R, tr = level_light(rec, ref_rays, 0)
        M, tm = level_light(rec)
        lit = R > 0
        rms = lambda X: float(np.sqrt(np.mean((X - R)[lit] ** 2)) / R[lit].mean())  # noqa: E731
        row = dict(
            ref_cpu_s=round(tr, 3),
            main=dict(cpu_s=round(tm, 3), sum_vs_ref=float(M.sum() / R.sum() - 1), rms=rms(M)),
        )
        print(
            f"{step}: reference {tr:.2f} s; main {tm:.3f} s, sum {row['main']['sum_vs_ref']:+.5f}, rms "
            f"{row['main']['rms']:.4f}",
            flush=True,
        )
        for T in (int(t) for t in args.tiles.split(",")):
            if T not in stores:
                sh = clear_shafts(s, em.point, em.normal)
                stores[T] = HostVisibility(lv, em.normal, em.point, points=points, shafts=sh, tile=T)
            H = stores[T]
            r0, n0, c0 = H.rays, len(H.tiles), cpu()
            D = H.light(em).astype(np.float64)  # traces the tiles it needs first
            tfirst = cpu() - c0
            ts = []
            for _ in range(args.repeat):
                c0 = cpu()
                D2 = H.light(em)
                ts.append(cpu() - c0)
            assert np.array_equal(D2, D.astype(np.float32))
            L = H.layout(em.rings)[1]
            row[f"tile{T}"] = r = dict(
                level=L,
                cell_m=H.cell(L),
                new_tiles=len(H.tiles) - n0,
                new_rays=int(H.rays - r0),
                first_cpu_s=round(tfirst, 3),
                event_cpu_s=round(float(np.median(ts)), 4),
                tiles=len(H.tiles),
                rays=int(H.rays),
                bytes=int(H.nbytes),
                sum_vs_ref=float(D.sum() / R.sum() - 1),
                rms=rms(D),
            )
            print(
                f"   tile {T}: L {L} (h {100 * H.cell(L):.2f} cm), +{r['new_tiles']} tiles, "
                f"+{r['new_rays']:,} rays, "
                f"first call {tfirst:.2f} s, event {r['event_cpu_s']:.3f} s, store {r['tiles']} tiles "
                f"{r['bytes'] / 1e6:.2f} MB; sum {r['sum_vs_ref']:+.5f}, rms {r['rms']:.4f}",
                flush=True,
            )
        res["events"][step] = row
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
