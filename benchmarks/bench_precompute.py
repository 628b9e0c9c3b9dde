"""Issue 22: the scene precompute on the furnished room. Build (RadiositySystem + the final
gather's rays) vs capture + write vs load + restore, the file's size per input triangle, and the
restored system's gathered output after an FE event against the cold one's.

    python benchmarks/bench_precompute.py [20k] [draft|medium] [gather|nogather]
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hr_testing import shapes as S  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, LightShape  # noqa: E402
from hr_addon.core.gather import LoopGather  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

# the bake's settings per quality with the final gather on (blender/bake.py GATHER, solve_options)
GATHER = {
    "draft": dict(rays=128, shadow_rays=16, levels=2, iterations=4),
    "medium": dict(rays=128, shadow_rays=32, levels=2, iterations=4),
}


def main(size="20k", quality="draft", mode="gather"):
    mesh, info = furnished_room(size)
    tris = int((np.asarray(mesh.loop_total) - 2).sum())
    use_gather = mode == "gather"
    params = RefineParams.for_gather(quality) if use_gather else RefineParams.preset(quality)
    opts = DynamicRadiosity.gather_options(quality) if use_gather else {}
    settings = GATHER[quality] if use_gather else None
    t0 = time.perf_counter()
    system = RadiositySystem(mesh, params)
    t_system = time.perf_counter() - t0
    dyn = DynamicRadiosity(system, method="FE", **opts)
    t1 = time.perf_counter()
    gather = LoopGather(dyn, **settings) if use_gather else None
    t_gather = time.perf_counter() - t1
    want = pc.expected(mesh, params, gather=settings, quality=quality)
    with tempfile.TemporaryDirectory() as d:
        t2 = time.perf_counter()
        arrays, graph = pc.capture(system, gather)
        t_capture = time.perf_counter() - t2
        path = pc.write(d, arrays, graph, want)
        t_write = time.perf_counter() - t2
        size_b = path.stat().st_size
        t3 = time.perf_counter()
        system2, gather2, why = pc.load(d, want)
        t_load = time.perf_counter() - t3
    assert why is None, why
    system_bytes = sum(a.nbytes for a in pc.capture(system)[0].values())  # without the gather
    by_kind = {}
    for v in arrays.values():
        by_kind[str(v.dtype)] = by_kind.get(str(v.dtype), 0) + v.nbytes
    _, frame = info["light_wall"]
    shape = LightShape(
        S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame), np.full(3, 20.0), "w"
    )
    outs = []
    for s, g in ((system, gather), (system2, gather2)):
        dd = DynamicRadiosity(s.copy(), method="FE", **opts)
        dd.apply({"w": shape})
        outs.append(g.loop_radiance(dd) if g is not None else dd.loop_radiance())
    res = dict(
        size=size,
        quality=quality,
        mode=mode,
        triangles=tris,
        patches=len(system.patches.nv),
        nodes=int(system.h.n),
        links=len(system.links),
        gather_weights=int(len(gather.w) + (len(gather.second.w) if gather.second is not None else 0))
        if gather is not None
        else 0,
        t_system=round(t_system, 2),
        t_gather=round(t_gather, 2),
        t_build=round(t_system + t_gather, 2),
        t_capture=round(t_capture, 3),
        t_capture_write=round(t_write, 2),
        t_load_restore=round(t_load, 2),
        load_share=round(t_load / (t_system + t_gather), 4),
        file_bytes=size_b,
        bytes_per_triangle=round(size_b / tris),
        arrays=len(arrays),
        array_bytes=sum(a.nbytes for a in arrays.values()),
        system_array_bytes=system_bytes,
        bytes_by_dtype=by_kind,
        bitwise_equal_fe_event=bool(np.array_equal(outs[0], outs[1])),
        created=time.strftime("%Y-%m-%d %H:%M"),
    )
    print(json.dumps(res))
    out = Path(__file__).resolve().parent / "out" / f"precompute_{size}_{quality}_{mode}.json"
    out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:])
