"""Issue 22: the scene precompute on the furnished room. Build (RadiositySystem + the final
gather's rays, the base solution and the static emitters' direct light: what a cold bake builds
before its first frame) vs capture + write vs load + restore + DynamicRadiosity on the loaded
system (what a re-bake after a light edit pays before its first frame), the file's size per input
triangle, and the restored system's gathered output after an FE event against the cold one's.
Wall and CPU seconds (process time: the machine is shared) and the load average.

    python benchmarks/bench_precompute.py [20k] [draft|medium] [gather|nogather]
"""

import json
import os
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


class Clock:
    """lap() -> [wall s, CPU s] since the last lap (CPU: this process's, all threads)."""

    def __init__(self):
        self.t = (time.perf_counter(), time.process_time())

    def lap(self):
        now = (time.perf_counter(), time.process_time())
        out = [round(now[0] - self.t[0], 3), round(now[1] - self.t[1], 3)]
        self.t = now
        return out


def main(size="20k", quality="draft", mode="gather"):
    mesh, info = furnished_room(size)
    tris = int((np.asarray(mesh.loop_total) - 2).sum())
    use_gather = mode == "gather"
    params = RefineParams.for_gather(quality) if use_gather else RefineParams.preset(quality)
    opts = DynamicRadiosity.gather_options(quality) if use_gather else {}
    settings = GATHER[quality] if use_gather else None
    clock = Clock()
    system = RadiositySystem(mesh, params)
    t_system = clock.lap()
    dyn = DynamicRadiosity(system, method="FE", **opts)
    t_base = clock.lap()
    gather = LoopGather(dyn, **settings) if use_gather else None
    pc.prepare(gather)
    t_gather = clock.lap()
    want = pc.expected(mesh, params, gather=settings, quality=quality)
    with tempfile.TemporaryDirectory() as d:
        t2 = time.perf_counter()
        arrays, graph = pc.capture(system, gather)
        t_capture = time.perf_counter() - t2
        path = pc.write(d, arrays, graph, want)
        t_write = time.perf_counter() - t2
        size_b = path.stat().st_size
        clock.lap()
        system2, gather2, why = pc.load(d, want)
        t_load = clock.lap()
        DynamicRadiosity(system2, method="FE", **opts)  # as a re-bake: no events yet
        t_dyn = clock.lap()
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
        # (wall s, CPU s) each
        t_system=t_system,
        t_base_solve=t_base,
        t_gather=t_gather,
        t_build=[a + b + c for a, b, c in zip(t_system, t_base, t_gather)],
        t_capture=round(t_capture, 3),
        t_capture_write=round(t_write, 2),
        t_load_restore=t_load,
        t_dynamic_on_loaded=t_dyn,
        load_share=round(t_load[0] / (t_system[0] + t_base[0] + t_gather[0]), 4),
        rebake_share=round((t_load[0] + t_dyn[0]) / (t_system[0] + t_base[0] + t_gather[0]), 4),
        rebake_share_cpu=round((t_load[1] + t_dyn[1]) / (t_system[1] + t_base[1] + t_gather[1]), 4),
        file_bytes=size_b,
        bytes_per_triangle=round(size_b / tris),
        arrays=len(arrays),
        array_bytes=sum(a.nbytes for a in arrays.values()),
        system_array_bytes=system_bytes,
        bytes_by_dtype=by_kind,
        bitwise_equal_fe_event=bool(np.array_equal(outs[0], outs[1])),
        created=time.strftime("%Y-%m-%d %H:%M"),
        load_average=os.getloadavg(),
    )
    print(json.dumps(res))
    out = Path(__file__).resolve().parent / "out" / f"precompute_{size}_{quality}_{mode}.json"
    out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:])
