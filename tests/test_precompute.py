"""The scene precompute (hr_addon/io/precompute.py, docs/precompute.md): a restored system and
gather give the cold build's values bit for bit; every change of what the build read invalidates
it with a reason naming the cause; damaged files are never used; processes sharing a cache folder
build once under the lock."""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from hr_testing import scenes
from hr_testing import shapes as S
from hr_addon.core.events import DynamicRadiosity, LightShape
from hr_addon.core.gather import LoopGather, texel_gather
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_addon.io import precompute as pc
from hr_addon.io.cache import MARKER

ROOT = Path(__file__).resolve().parents[1]
DRAFT = RefineParams.preset("draft")
GATHER = dict(rays=16, shadow_rays=4, levels=2, iterations=2)


def cornell():
    mesh = scenes.cornell_box()
    shape = LightShape(
        S.on_plane(S.rect(0.2, 0.15, centre=(0.25, 0.3)), S.CORNELL_BACK_WALL), np.full(3, 5.0), "r"
    )
    return mesh, shape


def furnished():
    from hr_testing.furnished import furnished_room

    mesh, info = furnished_room("2k")
    _, frame = info["light_wall"]
    shape = LightShape(
        S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame), np.full(3, 20.0), "w"
    )
    return mesh, shape


def build(mesh, params=DRAFT):
    system = RadiositySystem(mesh, params)
    gather = LoopGather(DynamicRadiosity(system, method="FE"), **GATHER)
    return system, gather


def outputs(system, gather, shape):
    """Static solve, an FE and an AUTO event (each on its own copy), the final gather's output."""
    out = {"static": system.copy().solve().copy()}
    for method in ("FE", "AUTO"):
        dyn = DynamicRadiosity(system.copy(), method=method)
        dyn.apply({"s": shape})
        out[method] = dyn.loop_radiance()
        out[f"{method} gather"] = gather.loop_radiance(dyn)
    return out


@pytest.mark.parametrize("scene", [cornell, furnished])
def test_restored_system_and_gather_equal_the_cold_build_bitwise(scene, tmp_path):
    """Everything the light does not change is restored as stored (same arrays, same float
    operations afterwards), and the ray backend is rebuilt from the same triangles: bit for bit."""
    mesh, shape = scene()
    system, gather = build(mesh)
    want = pc.expected(mesh, DRAFT, gather=GATHER)
    pc.write(tmp_path, *pc.capture(system, gather), want)
    cold = outputs(system, gather, shape)
    system2, gather2, why = pc.load(tmp_path, want)
    assert why is None and system2 is not system and gather2.system is system2
    assert system2.h.n == system.h.n and len(system2.links) == len(system.links) > 0
    warm = outputs(system2, gather2, shape)
    for key in cold:
        assert cold[key].shape == warm[key].shape and np.array_equal(cold[key], warm[key]), key
    assert cold["FE gather"].max() > 0


def test_far_link_terms_are_stored_equal_to_a_fresh_computation(tmp_path):
    """The solver's far-link terms (Links.extended, made by the build's base solution) come back
    from the file, so a re-bake's first light event does not make them again, and equal bit for
    bit those the restored geometry gives."""
    mesh, _ = furnished()
    system, gather = build(mesh)
    assert system.links.n_far > 0 and system.links._ext is not None
    want = pc.expected(mesh, DRAFT, gather=GATHER)
    pc.write(tmp_path, *pc.capture(system, gather), want)
    restored = pc.load(tmp_path, want)[0]
    stored = restored.links._ext
    assert stored is not None
    restored.links._ext = None
    fresh = restored.links.extended(restored.h)
    pairs = [(x, y) for s, f in zip(stored, fresh) for x, y in zip(s, f)]
    assert len(pairs) == 7 and len(pairs[0][0]) > 0
    for x, y in pairs:
        assert x.dtype == y.dtype and np.array_equal(x, y)


def test_texel_gather_restores_bitwise(tmp_path):
    """The texture output's gather (FinalGather at texel points) goes through the same graph."""
    mesh, shape = cornell()
    system = RadiositySystem(mesh, DRAFT)
    pt = system.patches
    rng = np.random.default_rng(3)
    patch = rng.integers(0, len(pt.nv), 300)
    w = rng.dirichlet(np.ones(3), 300)  # points inside each patch's first triangle
    points = np.einsum("nk,nkj->nj", w, pt.corners[patch][:, :3])
    gather = texel_gather(DynamicRadiosity(system, method="FE"), patch, points, **GATHER)
    want = pc.expected(mesh, DRAFT, gather=GATHER, output="TEXTURE")
    pc.write(tmp_path, *pc.capture(system, gather), want)
    system2, gather2, why = pc.load(tmp_path, want)
    assert why is None

    def frame(s, g):
        dyn = DynamicRadiosity(s.copy(), method="AUTO")
        dyn.apply({"s": shape})
        return g.evaluate(dyn, "radiance")

    cold, warm = frame(system, gather), frame(system2, gather2)
    assert np.array_equal(cold, warm) and cold.max() > 0


def test_the_base_solution_and_static_direct_light_are_stored_and_used(tmp_path, monkeypatch):
    """DynamicRadiosity's base solve (the static emitters' solution) and the gather's static direct
    light are in the file: a DynamicRadiosity on the restored system starts without solving, with
    the cold one's base bit for bit, and the gather does not trace the static emitters again."""
    from hr_addon.core.events.solves import Solves

    mesh, shape = cornell()
    system, gather = build(mesh)
    pc.prepare(gather)
    assert len(system.bases) == 1 and all(g._D_static is not None for g in pc.levels(gather))
    cold = DynamicRadiosity(system.copy(), method="FE", tol=1e-5)  # another tolerance: solved, kept
    assert len(system.bases) == 2
    want = pc.expected(mesh, DRAFT, gather=GATHER)
    pc.write(tmp_path, *pc.capture(system, gather), want)
    system2, gather2, _ = pc.load(tmp_path, want)
    assert system2.bases.keys() == system.bases.keys()
    for g, g2 in zip(pc.levels(gather), pc.levels(gather2)):
        assert np.array_equal(g._D_static, g2._D_static)

    def no_solve(*a, **k):
        raise AssertionError("the base was solved again")

    with monkeypatch.context() as mp:
        mp.setattr(Solves, "solve", no_solve)
        mp.setattr(type(gather2), "direct_light", no_solve)
        warm = DynamicRadiosity(system2.copy(), method="FE", tol=1e-5)
        gather2.direct_static()
    assert np.array_equal(warm._Bbase, cold._Bbase) and warm.base_iterations == cold.base_iterations > 0
    for d in (cold, warm):
        d.apply({"s": shape})
    assert np.array_equal(gather.loop_radiance(cold), gather2.loop_radiance(warm))


def test_a_changed_static_emitter_is_solved_again_never_stale():
    """The base is kept per emission (and tolerance), and only while the hierarchy is the build's:
    a brighter static emitter is solved anew (equal to a cold build's base), and so is a system
    whose hierarchy light events have changed. In the file, the objects' emission is part of the
    key (test_every_change_invalidates_and_names_its_cause: "object 'light' changed emission")."""
    mesh, shape = cornell()
    system = RadiositySystem(mesh, DRAFT)
    base = DynamicRadiosity(system)._Bbase
    bright = RadiositySystem(brighter_light(mesh), DRAFT)
    assert system.h.n == bright.h.n  # the same hierarchy: only the emission differs
    system.patches.emission = bright.patches.emission.copy()  # as if the lamp were turned up in place
    again = DynamicRadiosity(system)._Bbase
    assert len(system.bases) == 2 and np.array_equal(again, DynamicRadiosity(bright)._Bbase)
    assert again.max() > 1.5 * base.max()
    dyn = DynamicRadiosity(system, method="AUTO")
    dyn.apply({"s": shape})  # splits below the build's leaves
    assert system.h.version != system.build_version
    fresh = DynamicRadiosity(system)._Bbase
    assert fresh.shape[1] == system.h.n > bright.h.n and len(system.bases) == 2


def test_code_key_follows_only_the_code_that_makes_what_is_stored(tmp_path):
    """The key's code digest covers the build, the gather and the base solve with every module
    they import, not the rest of the package: an edit of the light events' coverage, the cache or
    the Blender glue keeps precomputes valid; an edit of the refinement or the base's rule does
    not."""
    import shutil

    root = tmp_path / "hr_addon"
    shutil.copytree(ROOT / "hr_addon", root, ignore=shutil.ignore_patterns("__pycache__"))
    names = {p.relative_to(root).as_posix() for p in pc.code_files(root)}
    assert {"core/refine.py", "core/solver.py", "core/gather/final.py", "core/visibility.py"} <= names
    assert not names & {"core/events/coverage.py", "io/cache.py", "blender/bake.py", "core/texels.py"}
    d0 = pc.code_digest(root)
    assert d0 == pc.code_digest()  # the copy is the package

    def edited(rel):
        with open(root / rel, "a") as fh:
            fh.write("\n# an edit\n")
        return pc.code_digest(root)

    for rel in ("core/events/coverage.py", "io/cache.py", "blender/bake.py", "core/texels.py"):
        assert edited(rel) == d0, rel
    assert edited("core/refine.py") != d0
    d1 = pc.code_digest(root)
    assert edited("core/events/dynamic.py") != d1


def test_capture_refuses_a_hierarchy_changed_by_light_events():
    mesh, shape = cornell()
    system, gather = build(mesh)
    DynamicRadiosity(system, method="AUTO").apply({"s": shape})
    with pytest.raises(ValueError, match="before light events"):
        pc.capture(system, gather)


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    mesh, _ = cornell()
    system, gather = build(mesh)
    d = tmp_path_factory.mktemp("pc")
    pc.write(d, *pc.capture(system, gather), pc.expected(mesh, DRAFT, gather=GATHER))
    return mesh, d


def moved_wall(mesh):
    m = dataclasses.replace(mesh, verts=mesh.verts.copy())
    wall = mesh.object_names.index("back")
    loops = np.concatenate(
        [
            np.arange(s, s + n)
            for s, n, o in zip(mesh.loop_start, mesh.loop_total, mesh.object_id)
            if o == wall
        ]
    )
    m.verts[np.unique(mesh.loop_verts[loops]), 1] += 0.05
    return m


def new_reflectance(mesh):
    m = dataclasses.replace(mesh, reflectance=mesh.reflectance.copy())
    m.reflectance[np.asarray(mesh.object_id) == mesh.object_names.index("left_red")] = (0.5, 0.1, 0.1)
    return m


def brighter_light(mesh):
    m = dataclasses.replace(mesh, emission=mesh.emission.copy())
    m.emission[np.asarray(mesh.object_id) == mesh.object_names.index("light")] *= 2
    return m


@pytest.mark.parametrize(
    "change, reason",
    [
        (lambda m, p, w: (brighter_light(m), p, w), "object 'light' changed emission"),
        (lambda m, p, w: (moved_wall(m), p, w), "object 'back' moved or changed shape"),
        (lambda m, p, w: (new_reflectance(m), p, w), "object 'left_red' changed reflectance"),
        (lambda m, p, w: (m, dataclasses.replace(p, feps=0.02), w), "feps 0.05 -> 0.02"),
        (
            lambda m, p, w: (m, p, {**w, "format_version": pc.FORMAT_VERSION + 1}),
            f"format version {pc.FORMAT_VERSION} -> {pc.FORMAT_VERSION + 1}",
        ),
        (lambda m, p, w: (m, p, {**w, "extension": "9.9.9"}), "extension version"),
    ],
)
def test_every_change_invalidates_and_names_its_cause(stored, change, reason):
    mesh, d = stored
    want = pc.expected(mesh, DRAFT, gather=GATHER)
    assert pc.validate(pc.read_header(d / pc.FILENAME), want) is None
    m, p, extra = change(mesh, DRAFT, {})
    want = {**pc.expected(m, p, gather=GATHER), **extra}
    why = pc.validate(pc.read_header(d / pc.FILENAME), want)
    assert why is not None and reason in why, why
    system, gather, why2 = pc.load(d, want)
    assert system is None and reason in why2


def test_a_file_of_other_code_is_refused_not_followed(tmp_path):
    """A class the file names that this code does not have (moved or renamed in a refactor)."""
    mesh, _ = cornell()
    arrays, graph = pc.capture(RadiositySystem(mesh, DRAFT))
    graph["system"]["state"]["links"]["cls"] = "core.refine:OldLinks"
    want = pc.expected(mesh, DRAFT)
    pc.write(tmp_path, arrays, graph, want)
    system, _, why = pc.load(tmp_path, want)
    assert system is None and "written by other code (class core.refine:OldLinks not found)" in why


def test_stale_precompute_is_rebuilt_saying_why(stored, tmp_path):
    mesh, d = stored
    m = moved_wall(mesh)
    (tmp_path / "c").mkdir()
    for f in (pc.FILENAME, MARKER):
        (tmp_path / "c" / f).write_bytes((d / f).read_bytes())
    (tmp_path / "c" / f".{pc.FILENAME}.99999.tmp").write_bytes(b"half written by a killed builder")
    log = []
    system, gather, how = pc.load_or_build(
        tmp_path / "c", pc.expected(m, DRAFT, gather=GATHER), lambda: build(m), log.append
    )
    assert how == "built" and any("object 'back' moved" in line for line in log), log
    assert pc.load(tmp_path / "c", pc.expected(m, DRAFT, gather=GATHER))[2] is None
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == sorted([MARKER, pc.FILENAME])


@pytest.mark.parametrize("damage", ["truncate", "flip", "header"])
def test_damaged_file_is_named_rebuilt_and_never_used(stored, tmp_path, damage):
    mesh, d = stored
    want = pc.expected(mesh, DRAFT, gather=GATHER)
    c = tmp_path / "c"
    c.mkdir()
    (c / MARKER).write_bytes((d / MARKER).read_bytes())
    data = bytearray((d / pc.FILENAME).read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":  # one byte inside the largest array, zip structure intact
        with zipfile.ZipFile(d / pc.FILENAME) as z:
            big = max(z.infolist(), key=lambda i: i.file_size)
        data[big.header_offset + 30 + len(big.filename) + big.file_size // 2] ^= 0xFF
    else:
        with zipfile.ZipFile(d / pc.FILENAME) as z:
            h = z.getinfo("header.json")
        data[h.header_offset + 30 + len(h.filename)] = ord("#")
    (c / pc.FILENAME).write_bytes(bytes(data))
    system, _, why = pc.load(c, want)
    assert system is None and pc.FILENAME in why and ("damaged" in why or "checksum" in why), why
    log = []
    _, _, how = pc.load_or_build(c, want, lambda: build(mesh), log.append)
    assert how == "built" and any(pc.FILENAME in line for line in log), log
    assert pc.load(c, want)[2] is None


def test_the_file_is_written_and_read_without_a_second_copy_in_memory(tmp_path):
    """Each array is streamed into and out of its zip member: the write holds no serialised copy
    of the arrays (a 100k texture bake at resolution 16 ran out of memory on one) and the read
    never holds a member's bytes beside its array."""
    import tracemalloc

    rng = np.random.default_rng(1)
    arrays = {"big": rng.random(4_000_000), "ids": np.arange(1_000_000, dtype=np.int64), "none": np.zeros(0)}
    arrays["slice"] = arrays["big"][::2]  # not contiguous
    total = sum(a.nbytes for a in arrays.values())
    tracemalloc.start()
    try:
        pc.write(tmp_path, arrays, {}, {})
        write_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        back, header = pc.read(tmp_path / pc.FILENAME)
        read_peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # at most numpy's writer's chunk (16 MiB) beside the arrays, whatever their total (56 MB here)
    assert write_peak < 20e6 < total, (write_peak, total)
    assert read_peak < total + arrays["big"].nbytes / 4, (read_peak, total)  # the arrays themselves
    assert header["arrays"]["big"]["crc32"] == zipfile.ZipFile(tmp_path / pc.FILENAME).getinfo("big.npy").CRC
    for k, a in arrays.items():
        assert back[k].dtype == a.dtype and np.array_equal(back[k], a), k


def test_foreign_folder_and_file_are_never_written(tmp_path):
    mesh, _ = cornell()
    want = pc.expected(mesh, DRAFT)
    (tmp_path / "notes.txt").write_text("mine")
    arrays, graph = pc.capture(RadiositySystem(mesh, DRAFT))
    with pytest.raises(pc.PrecomputeError, match="no radiosity bake wrote"):
        pc.write(tmp_path, arrays, graph, want)
    (tmp_path / pc.FILENAME).write_text("someone else's file")
    log = []
    system, _, how = pc.load_or_build(
        tmp_path, want, lambda: (RadiositySystem(mesh, DRAFT), None), log.append
    )
    assert how == "built" and system is not None and any("not stored" in line for line in log)
    assert (tmp_path / pc.FILENAME).read_text() == "someone else's file"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["notes.txt", pc.FILENAME])


def test_describe_and_remove_for_the_panel(stored, tmp_path):
    mesh, d = stored
    c = tmp_path / "c"
    c.mkdir()
    assert pc.describe(c) is None and not pc.remove(c)
    (c / pc.FILENAME).write_bytes((d / pc.FILENAME).read_bytes())
    assert not pc.remove(c)  # not a cache folder: not ours to delete
    (c / MARKER).write_bytes((d / MARKER).read_bytes())
    info = pc.describe(c, pc.expected(mesh, DRAFT, gather=GATHER))
    assert info["problem"] == "" and info["bytes"] == (d / pc.FILENAME).stat().st_size
    assert time.time() - 3600 < info["created"] <= time.time()
    assert (
        "feps 0.05 -> 0.02"
        in pc.describe(c, pc.expected(mesh, dataclasses.replace(DRAFT, feps=0.02), gather=GATHER))["problem"]
    )
    assert pc.remove(c) and sorted(p.name for p in c.iterdir()) == [MARKER]


# -- several processes on one cache folder -----------------------------------------------------------

WORKER = textwrap.dedent(
    """
    import json, sys, time
    sys.path.insert(0, {root!r})
    from hr_testing import scenes
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    from hr_addon.io import precompute as pc

    cache, feps, delay, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
    mesh = scenes.closed_box(subdiv=2)
    params = RefineParams(feps=feps, contacts=False)
    log = []

    def build():
        log.append("build")
        time.sleep(delay)  # keeps the lock held long enough for the others to meet it
        return RadiositySystem(mesh, params), None

    system, _, how = pc.load_or_build(cache, pc.expected(mesh, params), build, log.append, stale=20, beat=0.2)
    B = system.solve()
    json.dump(dict(how=how, log=log, B=B.sum(0).tolist()), open(out, "w"))
    """
).format(root=str(ROOT))


def run_workers(tmp_path, n, feps=0.05, delay=1.5, tag="w"):
    script = tmp_path / "worker.py"
    script.write_text(WORKER)
    outs = [tmp_path / f"{tag}{i}.json" for i in range(n)]
    procs = [
        subprocess.Popen(
            [sys.executable, str(script), str(tmp_path / "cache"), str(feps), str(delay), str(o)]
        )
        for o in outs
    ]
    return procs, outs


def test_racing_processes_build_once_and_leave_no_debris(tmp_path):
    procs, outs = run_workers(tmp_path, 3)
    assert all(p.wait(timeout=300) == 0 for p in procs)
    res = [json.loads(o.read_text()) for o in outs]
    assert sorted(r["how"] for r in res) == ["built", "loaded", "loaded"], [r["log"] for r in res]
    assert sum(r["log"].count("build") for r in res) == 1
    assert all(np.array_equal(r["B"], res[0]["B"]) for r in res)
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == sorted([MARKER, pc.FILENAME])


def test_killed_builder_keeps_the_previous_precompute_and_its_lock_is_taken_over(tmp_path):
    procs, outs = run_workers(tmp_path, 1, feps=0.05, delay=0, tag="first")
    assert procs[0].wait(timeout=300) == 0
    before = (tmp_path / "cache" / pc.FILENAME).read_bytes()
    # a new setting: the builder rebuilds and is killed while it holds the lock
    procs, _ = run_workers(tmp_path, 1, feps=0.04, delay=60, tag="killed")
    lock = tmp_path / "cache" / pc.LOCKNAME
    t0 = time.time()
    while pc.holder(lock) is None and time.time() - t0 < 120:
        time.sleep(0.05)
    assert pc.holder(lock)["pid"] == procs[0].pid
    os.kill(procs[0].pid, signal.SIGKILL)
    procs[0].wait()
    assert (tmp_path / "cache" / pc.FILENAME).read_bytes() == before and lock.exists()
    procs, outs = run_workers(tmp_path, 1, feps=0.04, delay=0, tag="next")
    assert procs[0].wait(timeout=300) == 0
    r = json.loads(outs[0].read_text())
    assert r["how"] == "built" and any("taken over" in line and "is gone" in line for line in r["log"]), r
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == sorted([MARKER, pc.FILENAME])


def test_a_silent_holder_on_another_host_is_taken_over_after_the_timeout(tmp_path):
    d = tmp_path
    lock = d / pc.LOCKNAME
    lock.write_text(json.dumps({"pid": 1, "host": "elsewhere", "started": 0, "token": "x"}))
    past = time.time() - 100
    os.utime(lock, (past, past))
    other = pc.Lock(d)
    assert "no heartbeat from elsewhere" in other.take_over(stale=30)
    assert other.try_acquire() and pc.holder(lock)["token"] == other.token
    # a fresh holder elsewhere (just written: its heartbeat is new) is left alone
    lock.write_text(json.dumps({"pid": 1, "host": "elsewhere", "started": 0, "token": "y"}))
    assert pc.Lock(d).take_over(stale=30) == ""
    other.release()
    assert lock.exists()  # not ours any more: release leaves it
