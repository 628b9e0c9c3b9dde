"""Issue 22, render farms: four local processes bake disjoint frame ranges of the furnished room
into one cache folder, sharing one precompute (load_or_build: one builds, the others wait and load
it); then one process bakes all frames from a cold build, and the merged cache is compared with it
frame by frame. The light: a window shape sliding along the light wall (FE), one position per
frame. Numpy only (the engine and io.cache as the bake drives them; docs/farm.md).

    python benchmarks/bench_farm.py [20k] [draft] [frames=8] [nodes=4] [FE|AUTO|AR] [cold|warm]

cold (the bake's setting): every frame's responses are solved from their emission alone
(DynamicRadiosity warm_moves=False); warm: a moved shape's from the previous frame's response. The
one-process bake is run with both on the same build, to measure what cold moves cost.
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hr_testing import shapes as S  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, LightShape  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402
from hr_addon.io.cache import CacheReader, CacheWriter, lock_path, temp_dirs  # noqa: E402


def scene(size, quality):
    mesh, info = furnished_room(size)
    return mesh, info, RefineParams.preset(quality)


def shape_at(info, f):
    _, frame = info["light_wall"]
    outline = S.on_plane(S.rect(0.9, 0.7, centre=(0.5 + 0.08 * f, 0.6), angle=0.2), frame)
    return LightShape(outline, np.full(3, 20.0), "w")


def bake(cache, mesh, info, system, frames, method, moves):
    """The frames into the cache folder as a bake does: one event per frame, then commit. Returns
    [(solver iterations, seconds)] of the frames' events."""
    dyn = DynamicRadiosity(system, method=method, warm_moves=moves == "warm")
    w = CacheWriter(cache, {"room": {"mesh": "room", "count": len(mesh.loop_verts)}}, "CORNER", "sig", {})
    cost = []
    for f in frames:
        fr = dyn.apply({"w": shape_at(info, f)})
        cost.append((fr.iterations, round(fr.seconds, 3)))
        w.write(f, {"room": dyn.loop_radiance()})
    w.commit()
    return cost


def node(cache, size, quality, a, b, out, method, moves):
    t0 = time.perf_counter()
    mesh, info, params = scene(size, quality)
    log = []

    def build():  # as the bake: the system and its base solution (stored with it)
        log.append("build")
        system = RadiositySystem(mesh, params)
        DynamicRadiosity(system, method=method)
        return system, None

    system, _, how = pc.load_or_build(cache, pc.expected(mesh, params, quality=quality), build, log.append)
    t1 = time.perf_counter()
    bake(cache, mesh, info, system, range(a, b + 1), method, moves)
    t2 = time.perf_counter()
    cpu = time.process_time()
    Path(out).write_text(
        json.dumps(dict(how=how, log=log, precompute_s=t1 - t0, frames_s=t2 - t1, cpu_s=cpu))
    )


def main(size="20k", quality="draft", frames="8", nodes="4", method="FE", moves="cold"):
    n_frames, n_nodes = int(frames), int(nodes)
    per = n_frames // n_nodes
    ranges = [(1 + i * per, (i + 1) * per if i < n_nodes - 1 else n_frames) for i in range(n_nodes)]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        (d / "farm").mkdir()
        cache = d / "farm" / "cache"
        t0 = time.perf_counter()
        procs = [
            subprocess.Popen(
                [
                    sys.executable,
                    __file__,
                    "--node",
                    str(cache),
                    size,
                    quality,
                    str(a),
                    str(b),
                    str(d / f"n{i}"),
                    method,
                    moves,
                ]
            )
            for i, (a, b) in enumerate(ranges)
        ]
        assert all(p.wait() == 0 for p in procs)
        wall_farm = time.perf_counter() - t0
        res = [json.loads((d / f"n{i}").read_text()) for i in range(n_nodes)]
        debris = [p.name for p in (d / "farm").iterdir() if p.name != "cache"]
        debris += [str(p) for p, *_ in temp_dirs(cache)] + (
            [lock_path(cache).name] if lock_path(cache).exists() else []
        )
        listed = set(CacheReader(cache).manifest["files"])
        extra = sorted({p.name for p in cache.iterdir()} - listed - {".hr_radiosity", pc.FILENAME})
        # one process, cold build, all frames in order
        mesh, info, params = scene(size, quality)
        t1 = time.perf_counter()
        system = RadiositySystem(mesh, params)
        build_s = time.perf_counter() - t1
        cost = {}
        for other in {"cold", "warm"} - {moves}:  # the other setting's cost, on a copy of the build
            cost[other] = bake(d / other, mesh, info, system.copy(), range(1, n_frames + 1), method, other)
        t2 = time.perf_counter()
        cost[moves] = bake(d / "one", mesh, info, system, range(1, n_frames + 1), method, moves)
        wall_one = build_s + time.perf_counter() - t2
        merged, one = CacheReader(cache), CacheReader(d / "one")
        per_frame = {}
        for f in range(1, n_frames + 1):
            x, y = (
                merged.load(f)["room"][:, :3].astype(np.float64),
                one.load(f)["room"][:, :3].astype(np.float64),
            )
            rel = np.abs(x - y) / np.maximum(np.abs(y), 1e-30)
            per_frame[f] = dict(bitwise=bool(np.array_equal(x, y)), max_rel=float(rel.max()))
    tris = int((np.asarray(mesh.loop_total) - 2).sum())
    out = dict(
        date=time.strftime("%Y-%m-%d %H:%M"),
        size=size,
        quality=quality,
        method=method,
        moves=moves,
        triangles=tris,
        ranges=ranges,
        nodes=res,
        builds=sum(r["log"].count("build") for r in res),
        farm_wall_s=wall_farm,
        one_process_build_s=build_s,
        one_process_wall_s=wall_one,
        debris=debris,
        extra_files=extra,
        frames=per_frame,
        frame_cost={
            k: dict(iterations=[i for i, _ in v], seconds=[s for _, s in v]) for k, v in cost.items()
        },
        load=os.getloadavg(),
    )
    print(json.dumps(out, indent=1))
    path = ROOT / "benchmarks" / "out" / f"farm_{size}_{quality}_{method}_{moves}.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    if sys.argv[1:2] == ["--node"]:
        c, sz, q, a, b, o, m, mv = sys.argv[2:10]
        node(c, sz, q, int(a), int(b), o, m, mv)
    else:
        main(*sys.argv[1:])
