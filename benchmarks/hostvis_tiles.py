"""core/gather/hostvis.py (the tiled host visibility) on the 100k furnished room's FE window:
its precompute (tiles traced for the window at add 0.7, then at move 1.2 m: the second position
traces only the tiles the first did not) and its per-event CPU and error against many shadow rays,
per gather level, per tile size; main's shadow rays alongside (docs/events.md, session 28 hvp).

    .venv/bin/python benchmarks/hostvis_tiles.py STORE [--level top|second] [--tiles 4,8]
        [--points 64] [--ref-rays 256] [--json out.json]
    .venv/bin/python benchmarks/hostvis_tiles.py --end-to-end STORE [--rounds 2] [--json out.json]
    .venv/bin/python benchmarks/hostvis_tiles.py --end-to-end STORE --sweep 24 --policies lazy
        [--keep DIR [--from-kept]]

--end-to-end: the FE window event's gathered output (loop_radiance) with hostvis.ENABLED off
(main) and on (every level's shape light from the stores, the tiles traced before, untimed),
alternating, and per object against 256 rays at the top and 64 (no far rays) at the second level
(as host_visibility.py --end-to-end).

--sweep N: the window swept in N steps (sweep()); a policy `lazy:4` trims the stores to 4 MB a
level (hostvis.MEMORY); every host mode's outputs are compared with the first's; --no-main: main's
shadow rays not swept. --keep DIR: after the sweep, its stores written with io/precompute.keep
into DIR (a cache folder whose precompute.hrpc is a link to STORE's: the segments are bound to
that file), timed, with the file's size; --from-kept: no main, the stores
loaded from DIR (precompute.load_kept, timed) before the first policy's sweep, then that policy
again from empty stores, the two sweeps' outputs compared bit for bit (a re-bake from the kept
segments against a bake without them; docs/events.md, session 30 hvkeep). Peak RSS printed.

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
    ap.add_argument(
        "--policy", default="always", help="hostvis POLICY: always (tiles stored), never (the one-shot path)"
    )
    ap.add_argument("--size", default="100k")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    from bench_gather_events import load_store
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.events.direct import clear_shafts
    from hr_addon.core.gather import hostvis
    from hr_addon.core.gather.hostvis import HostVisibility
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    hostvis.ENABLED = False  # main's shadow rays in level_light; the stores made here
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

    counted = count_rays(lv.system.backend)  # (main's shadow rays, counted)

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
        n0 = counted[0]
        M, tm = level_light(rec)
        main_rays = counted[0] - n0
        lit = R > 0
        rms = lambda X: float(np.sqrt(np.mean((X - R)[lit] ** 2)) / R[lit].mean())  # noqa: E731
        row = dict(
            ref_cpu_s=round(tr, 3),
            main=dict(
                cpu_s=round(tm, 3), rays=main_rays, sum_vs_ref=float(M.sum() / R.sum() - 1), rms=rms(M)
            ),
        )
        print(
            f"{step}: reference {tr:.2f} s; main {tm:.3f} s, {main_rays:,} rays, "
            f"sum {row['main']['sum_vs_ref']:+.5f}, rms {row['main']['rms']:.4f}",
            flush=True,
        )
        for T in (int(t) for t in args.tiles.split(",")):
            if T not in stores:
                sh = clear_shafts(s, em.point, em.normal)
                stores[T] = HostVisibility(
                    lv, em.normal, em.point, points=points, shafts=sh, tile=T, policy=args.policy
                )
            H = stores[T]
            r0, n0, q0, c0 = H.rays, len(H.tiles), H.event_rays, cpu()
            D = H.light(em).astype(np.float64)  # traces the tiles it needs first
            tfirst, q1 = cpu() - c0, H.event_rays
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
                event_rays=int(q1 - q0),  # (the first call's: the repeats trace as many with --policy never)
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
                f"+{r['new_rays']:,} rays, one-shot {r['event_rays']:,} rays, "
                f"first call {tfirst:.2f} s, event {r['event_cpu_s']:.3f} s, store {r['tiles']} tiles "
                f"{r['bytes'] / 1e6:.2f} MB; sum {r['sum_vs_ref']:+.5f}, rms {r['rms']:.4f}",
                flush=True,
            )
        res["events"][step] = row
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


def count_rays(backend):
    """A counter of the rays backend traces from now on (its occluded / occluded_cm wrapped)."""
    counted = [0]
    occ, occ_cm = backend.occluded, backend.occluded_cm

    def _occ(a, b, *k, **kw):
        counted[0] += len(a)
        return occ(a, b, *k, **kw)

    def _occ_cm(a, d, *k, **kw):
        counted[0] += d.shape[1]
        return occ_cm(a, d, *k, **kw)

    backend.occluded, backend.occluded_cm = _occ, _occ_cm
    return counted


def end_to_end(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("store")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--fresh", action="store_true", help="no precompute: every host round from empty stores")
    ap.add_argument("--sweep", type=int, default=0, help="the window swept in N steps instead (sweep())")
    ap.add_argument("--policies", default="lazy,second", help="--sweep: the host's POLICY values")
    ap.add_argument("--points", type=int, default=None, help="hostvis.POINTS (the top level's)")
    ap.add_argument("--points-second", type=int, default=None, help="hostvis.POINTS_SECOND")
    ap.add_argument("--size", default="100k", help="the store's furnished room")
    ap.add_argument("--keep", default=None, help="--sweep: write the stores into this cache folder")
    ap.add_argument("--from-kept", action="store_true", help="--sweep: start from --keep's stores")
    ap.add_argument("--no-main", action="store_true", help="--sweep: without main's shadow rays")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    from bench_gather_events import load_store
    from compare_gather_dumps import difference, per_object
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.gather import hostvis
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    cpu = time.process_time
    hostvis.POINTS = args.points or hostvis.POINTS
    hostvis.POINTS_SECOND = args.points_second or hostvis.POINTS_SECOND
    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    s.links.extended(s.h)
    g.iterations = 4
    g2 = g.second
    _, info = furnished_room(args.size)
    frame = tuple(np.asarray(f, float) for f in info["light_wall"][1])
    obj = np.asarray(s.mesh.object_id)[np.repeat(np.arange(len(s.mesh.loop_start)), s.mesh.loop_total)]

    def window(cx):
        return LightShape(
            S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
        )

    pos = {"add": 0.7, "move": 1.2}
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    g.loop_radiance(dyn)  # the base parts

    def levels():
        return (g, g2) + ((g._slot["f"],) if getattr(g, "_slot", None) is not None else ())

    def clear():  # every level's shape light and the shape's gathered parts
        for lv in levels():
            lv._shape_cache.clear()
        for k in [k for k in g._responses if k[0] == "shape"]:
            del g._responses[k]

    counted = count_rays(s.backend)
    if args.sweep:
        return sweep(args, dyn, g, levels, clear, window, counted)
    # the precompute (untimed): the tiles of both positions at every level (--fresh: none)
    t0 = cpu()
    hostvis.ENABLED, policy = True, hostvis.POLICY
    hostvis.POLICY = "always"
    for step, cx in () if args.fresh else pos.items():
        dyn.apply({"w": window(cx)})
        for lv in levels():
            lv._shape(dyn, dyn.shapes["w"])
        clear()
    hostvis.ENABLED, hostvis.POLICY = False, policy
    if "w" in dyn.shapes:
        dyn.remove("w")
    stores = [H for lv in levels() for H in getattr(lv, "_host_stores", {}).values()]
    res = dict(
        store=args.store,
        precompute_cpu_s=round(cpu() - t0, 3),
        precompute_rays=int(sum(H.rays for H in stores)),
        store_bytes=int(sum(H.nbytes for H in stores)),
        events={},
    )
    print(
        f"precompute {res['precompute_cpu_s']} s, {res['precompute_rays']:,} rays, "
        f"{res['store_bytes'] / 1e6:.1f} MB"
    )
    out, times, refs = {}, {}, {}
    for rnd in range(args.rounds):
        for name in ("main", "host"):
            hostvis.ENABLED = name == "host"
            if "w" in dyn.shapes:
                clear()
                dyn.remove("w")
            if args.fresh:  # the product's first events: no tile stored
                for lv in levels():
                    lv.__dict__.pop("_host_stores", None)
            for step, cx in pos.items():
                clear()
                c0 = cpu()
                if step == "add":
                    dyn.add("w", window(cx))
                else:
                    dyn.apply({"w": window(cx)})
                c1, n1 = cpu(), counted[0]
                v = np.array(g.loop_radiance(dyn), np.float32)
                c2 = cpu()
                times.setdefault((step, name), []).append((c1 - c0, c2 - c1, counted[0] - n1))
                out[(step, name)] = v
                print(
                    f"{step} round {rnd} {name}: event {c1 - c0:.3f} s, output {c2 - c1:.3f} s, "
                    f"{counted[0] - n1:,} rays",
                    flush=True,
                )
                if rnd == 0 and name == "host":  # the reference: 256 rays at the top, 64 at the second
                    hostvis.ENABLED = False
                    clear()
                    g.shadow_rays, g2.shadow_rays, far = 256, 64, g2.FAR_RAYS
                    g2.FAR_RAYS = 0
                    refs[step] = per_object(np.array(g.loop_radiance(dyn), np.float32), obj)
                    g.shadow_rays, g2.shadow_rays, g2.FAR_RAYS = 16, 8, far
                    clear()
                    hostvis.ENABLED = True
    hostvis.ENABLED = False
    for step in pos:
        row = {}
        for name in ("main", "host"):
            d = difference(refs[step], per_object(out[(step, name)], obj))
            ev = [t[0] for t in times[(step, name)]]
            op = [t[1] for t in times[(step, name)]]
            rays = [t[2] for t in times[(step, name)]]
            row[name] = dict(
                event_cpu_s=float(np.median(ev)), output_cpu_s=float(np.median(op)), output_rays=rays, **d
            )
            print(
                f"{step} {name}: event {np.median(ev):.3f} + output {np.median(op):.3f} s; vs reference "
                f"median {100 * d['median']:.3f}%, p95 {100 * d['p95']:.2f}%, worst {100 * d['worst']:.1f}%, "
                f"bias {100 * d['bias']:+.3f}%",
                flush=True,
            )
        res["events"][step] = row
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


def sweep(args, dyn, g, levels, clear, window, counted):
    """The window swept across the wall in args.sweep steps (0.7 to 1.2 m, FE; a bake's frames or a
    Live drag): per step the event and its gathered output's CPU and rays, main (hostvis off) and
    the host visibility under each policy from empty stores; at the end the tiles stored and their
    bytes. No error (end_to_end measures it at the two ends)."""
    from hr_addon.core.gather import hostvis

    cpu = time.process_time
    from hr_addon.io import precompute as pc

    xs = np.linspace(0.7, 1.2, args.sweep)
    res = dict(store=args.store, steps=[float(x) for x in xs], modes={})
    modes = args.policies.split(",")
    if args.from_kept:  # (a re-bake from the kept segments, then the same from empty stores)
        modes = [modes[0] + "+kept", modes[0]]
    elif not (args.keep or args.no_main) and "main" not in modes:  # (--keep: main only if asked)
        modes = ["main"] + modes
    outs, memory = {}, hostvis.MEMORY
    for mode in modes:
        hostvis.ENABLED = mode != "main"
        pol, _, cap = mode.split("+")[0].partition(":")  # lazy:4: the stores trimmed to 4 MB a level
        hostvis.POLICY = pol if mode != "main" else hostvis.POLICY
        hostvis.MEMORY = int(float(cap) * (1 << 20)) if cap else memory
        if "w" in dyn.shapes:
            dyn.remove("w")
        clear()
        for lv in levels():
            lv.__dict__.pop("_host_stores", None)
        if mode.endswith("+kept"):
            g._precompute_id = pc.header_id(Path(args.keep) / pc.FILENAME)
            c0, w0 = cpu(), time.perf_counter()
            line = pc.load_kept(args.keep, g)
            res["load_cpu_s"], res["load_wall_s"] = cpu() - c0, time.perf_counter() - w0
            print(f"{line}: {res['load_cpu_s']:.3f} s CPU, {res['load_wall_s']:.3f} s wall", flush=True)
        rows = []
        for k, cx in enumerate(xs):
            c0, n0 = cpu(), counted[0]
            if k == 0:
                dyn.add("w", window(cx))
            else:
                dyn.apply({"w": window(cx)})
            c1 = cpu()
            v = g.loop_radiance(dyn)
            rows.append((c1 - c0, cpu() - c1, counted[0] - n0))
            outs.setdefault(mode, []).append(np.array(v, np.float32))
        stores = [H for lv in levels() for H in getattr(lv, "_host_stores", {}).values()]
        r = res["modes"][mode] = dict(
            event_cpu_s=[round(t[0], 3) for t in rows],
            output_cpu_s=[round(t[1], 3) for t in rows],
            rays=[int(t[2]) for t in rows],
            tiles=sum(len(H.tiles) for H in stores),
            stored_rays=int(sum(H.rays for H in stores)),
            event_rays=int(sum(H.event_rays for H in stores)),
            store_bytes=int(sum(H.nbytes for H in stores)),
        )
        print(
            f"{mode}: {len(xs)} steps, event {sum(r['event_cpu_s']):.1f} s + output "
            f"{sum(r['output_cpu_s']):.1f} s CPU, {sum(r['rays']):,} rays (first step "
            f"{r['output_cpu_s'][0]:.2f} s, {r['rays'][0]:,}; median "
            f"step {np.median(r['output_cpu_s']):.2f} s); tiles {r['tiles']} ({r['stored_rays']:,} rays), "
            f"events' own {r['event_rays']:,} rays, {r['store_bytes'] / 1e6:.1f} MB",
            flush=True,
        )
        if args.keep and not args.from_kept and mode == modes[-1]:
            keep(args, g, res)
    hostvis.MEMORY = memory
    host = [m for m in outs if m != "main"]
    for m in host[1:]:  # (values never depend on what is stored)
        same = all(np.array_equal(a, b) for a, b in zip(outs[host[0]], outs[m]))
        res.setdefault("bitwise_equal_to_" + host[0], {})[m] = bool(same)
        print(f"{m} equal to {host[0]}, every step bit for bit: {same}")
    import resource

    res["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS {res['peak_rss_mb']:.0f} MB")
    hostvis.ENABLED = False
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


def keep(args, g, res):
    """The gather's stores written with io/precompute.keep into args.keep (its precompute a link to
    the store's file), timed."""
    from hr_addon.io import precompute as pc

    d = Path(args.keep)
    d.mkdir(parents=True, exist_ok=True)
    link = d / pc.FILENAME
    if not link.exists():
        link.symlink_to((Path(args.store) / pc.FILENAME).resolve())
    g._precompute_id = pc.header_id(link)
    c0, w0 = time.process_time(), time.perf_counter()
    path = pc.keep(d, g)
    res["keep_cpu_s"], res["keep_wall_s"] = time.process_time() - c0, time.perf_counter() - w0
    res["keep_bytes"] = path.stat().st_size
    print(
        f"kept: {res['keep_bytes'] / 1e6:.1f} MB written in {res['keep_cpu_s']:.3f} s CPU, "
        f"{res['keep_wall_s']:.3f} s wall",
        flush=True,
    )


if __name__ == "__main__":
    if "--end-to-end" in sys.argv:
        sys.argv.remove("--end-to-end")
        end_to_end()
    else:
        main()
