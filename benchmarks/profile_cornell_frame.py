"""One frame's work on the Cornell sample at medium, as benchmarks/cycles_compare.py times it (the
light event plus the texel gather's first evaluate), with the compare's gather settings: frames
1, 6, 13, 21 applied in order, CPU seconds (time.process_time) per frame and phase; optionally a
cProfile (process time) of one frame and a dump of every frame's gathered output (for a bitwise
check of a change).

    .venv/bin/python benchmarks/profile_cornell_frame.py [--method FE] [--profile-frame 13]
        [--profile out.txt] [--dump out.npz] [--compare other.npz]
"""

import argparse
import cProfile
import os
import pstats
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import numpy as np  # noqa: E402


def setup(method="FE", frames=(1, 6, 13, 21), rays=128, shadow_rays=32, bake_transport=False):
    """(dyn, texel gather, {frame: shapes}) of the Cornell sample at medium, as cycles_compare builds them."""
    import dataclasses

    import cycles_compare as CC
    from hr_testing import cycles_ref as C
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.gather import texel_gather
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    scene = CC.open_scene("cornell")
    rs = C.prepare(scene, texel_rel=CC.SCENES["cornell"]["texel_rel"])
    shapes = {f: C.shape_proxies(rs, f) for f in frames}
    t0 = time.process_time()
    # bake_transport: the links and solver tolerances the bake takes with the gather on
    params = RefineParams.for_gather("medium") if bake_transport else RefineParams.preset("medium")
    base = RadiositySystem(rs.scene_in.mesh, dataclasses.replace(params))
    opts = DynamicRadiosity.gather_options("medium") if bake_transport else {}
    dyn = DynamicRadiosity(base.copy(), method=method, **opts)
    ours = C.Ours(rs, dyn.system, dyn)
    names = rs.objects
    cen = {n: np.flatnonzero(rs.atlases[n].s_centre) for n in names}
    cat = np.concatenate
    g = texel_gather(
        dyn,
        cat([ours.samples[n][0][cen[n]] for n in names]),
        cat([rs.atlases[n].s_point[cen[n]] for n in names]),
        axes=cat([rs.atlases[n].s_axes[cen[n]] for n in names]),
        tris=cat([rs.atlases[n].s_tri[cen[n]] for n in names]),
        rays=rays,
        shadow_rays=shadow_rays,
        levels=2,
        iterations=4,
    )
    print(f"build + gather precompute {time.process_time() - t0:.2f} s CPU, {g.n} samples", flush=True)
    return dyn, g, shapes


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--method", default="FE")
    ap.add_argument("--frames", default="1,6,13,21")
    ap.add_argument("--profile-frame", type=int, default=13)
    ap.add_argument("--profile", default=None, help="cProfile summary of that frame's work")
    ap.add_argument("--dump", default=None, help="npz of each frame's gathered reflected radiance")
    ap.add_argument("--compare", default=None, help="an earlier --dump: bitwise check")
    ap.add_argument("--rays", type=int, default=128)
    ap.add_argument("--shadow-rays", type=int, default=32)
    ap.add_argument("--bake-transport", action="store_true", help="RefineParams.for_gather, gather_options")
    args = ap.parse_args(argv)
    frames = [int(f) for f in args.frames.split(",")]
    dyn, g, shapes = setup(args.method, frames, args.rays, args.shadow_rays, args.bake_transport)
    dump = {}
    for f in frames:
        prof = cProfile.Profile(time.process_time) if args.profile and f == args.profile_frame else None
        if prof:
            prof.enable()
        c0 = time.process_time()
        dyn.apply(shapes[f])
        c1 = time.process_time()
        refl = g.evaluate(dyn, "reflected")
        c2 = time.process_time()
        if prof:
            prof.disable()
            with open(args.profile, "w") as fh:
                st = pstats.Stats(prof, stream=fh)
                st.sort_stats("cumulative").print_stats(60)
                st.sort_stats("tottime").print_stats(40)
        dump[f"f{f}"] = refl
        print(
            f"frame {f}: event {c1 - c0:.3f} s + gather evaluate {c2 - c1:.3f} s = {c2 - c0:.3f} s CPU",
            flush=True,
        )
    if args.dump:
        np.savez(args.dump, **dump)
    if args.compare:
        z = np.load(args.compare)
        for k, v in dump.items():
            same = np.array_equal(z[k], v)
            d = np.abs(z[k] - v).max() / max(np.abs(z[k]).max(), 1e-30)
            print(f"{k}: bitwise {'equal' if same else 'DIFFERENT'}, max rel diff {d:.3g}")


if __name__ == "__main__":
    main()
