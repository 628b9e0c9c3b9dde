"""Threads (issue 23): where two threads' extra CPU goes. CPU seconds, not wall time, so that a
shared machine can measure it: each thread count in its own process, the FE and the AUTO event
on the 100k room (its system loaded from bench_threads.py's --system folder; a new window, then
its removal, repeated) or the room's build (--build). Per event: the process's user and system
CPU, page faults and context switches (getrusage), and per outermost batch map its batches'
count, their CPU seconds (time.thread_time in the thread that ran each) and the map's whole
process CPU. The CPU a map spends beyond its batches is the threads' handing out (starting,
waking, joining); batches that take more CPU on 2 threads than on 1 show contention (memory,
caches, the GIL), measured apart for the batches that ran at the same time as another thread's
(`contention`: on a loaded machine only some do).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/thread_cpu.py --system /work/cache/t19sys
        [--threads 1,2] [--repeat 4] [--json out.json] [--cpus 0-1] [--root CHECKOUT] [--build]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/thread_cpu.py --store /work/cache/s20main
    taskset -c 0-1 .venv/bin/python benchmarks/thread_cpu.py --dispatch [--root CHECKOUT]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/thread_cpu.py --build [--size 100k] [--gil]

--root runs another checkout's hr_addon (main's, for a before / after pair).

Per batch also (session 33) the thread's time waiting for a core (Linux's schedstat: the machine's
other jobs) and blocked (off a core without waiting for one: the GIL held by the other thread);
--build and --store print them by the maps' callers (the build's stages; the outputs) with each
map's idle thread-seconds (the tail, the hand-out) and the model of each caller's maps on 2 and 16
cores (their 1-thread batches' makespans). --gil (1-thread runs): each batch's GIL-held CPU, read
by benchmarks/gil_sampler.c (compiled with cc; CPython 3.11) on the second core of the affinity.
Per batch also (session 36) the thread's minor page faults and system CPU (RUSAGE_THREAD): the
`minflt` and `sys` columns by caller (numpy's temporaries that malloc hands back to the kernel and
gets again as fresh pages; they do not depend on the machine's load).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

_tl = threading.local()
_gil = []  # gil_sampler(): (the sampler's library, its counters' buffer) once started


def gil_sampler():
    """Start benchmarks/gil_sampler.c's thread (compiled with cc into a temporary folder) on
    CPython 3.11's GIL flag, found in _PyRuntime by its neighbours (the switch interval in us, the
    holder's thread state, locked = 1 while this thread holds it), pinned to the second core of the
    affinity and this thread to the first. gil_counts() then reads
    (this thread's CPU ns, those with the GIL held). The sampler spins on a core: for 1-thread runs
    only (it measures the thread that started it)."""
    import ctypes
    import struct
    import tempfile

    rt = ctypes.addressof(ctypes.c_char.in_dll(ctypes.pythonapi, "_PyRuntime"))
    ctypes.pythonapi.PyThreadState_Get.restype = ctypes.c_void_p
    me, iv = ctypes.pythonapi.PyThreadState_Get(), round(sys.getswitchinterval() * 1e6)
    buf = ctypes.string_at(rt, 1 << 18)
    at = [o + 16 for o in range(0, len(buf) - 24, 8) if struct.unpack_from("QQi", buf, o) == (iv, me, 1)]
    if len(at) != 1 or sys.version_info[:2] != (3, 11):
        raise RuntimeError(f"the GIL's flag not found ({len(at)} candidates, Python {sys.version})")
    so = Path(tempfile.mkdtemp()) / "gil_sampler.so"
    cmd = ["cc", "-O2", "-shared", "-fPIC", "-o", so, ROOT / "benchmarks/gil_sampler.c", "-lpthread"]
    subprocess.run(cmd, check=True)
    lib = ctypes.CDLL(str(so))
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        raise RuntimeError("the GIL sampler needs a second core")
    os.sched_setaffinity(0, cores[:1])  # (this thread only: its batches and serial code run there)
    if lib.gs_start(ctypes.c_void_p(rt + at[0]), cores[1]):
        raise RuntimeError("the GIL sampler did not start")
    _gil.append((lib, (ctypes.c_ulonglong * 2)()))


def gil_counts():
    """(CPU ns, CPU ns with the GIL held) of the thread gil_sampler measures so far; (0, 0) without it."""
    if not _gil:
        return (0, 0)
    lib, out = _gil[0]
    lib.gs_read(out)
    return (out[0], out[1])


def instrument(maps):
    """Every module's batch_map wrapped: each outermost call appends (batches, batch CPU s, map
    process CPU s, map wall s, its caller's name, batches run off the calling thread, and per batch
    (index, thread id, wall start, wall end, CPU s)) to `maps`."""
    from hr_addon.core import parallel

    orig = parallel.batch_map

    def wrapped(fn, batches, threads=1, progress=None, poll=0.1):
        if getattr(_tl, "inside", False) or parallel.in_worker():
            return orig(fn, batches, threads, progress, poll)
        secs, off, each = [], [], []
        lock = threading.Lock()
        caller = threading.current_thread()

        def timed(k, *a):
            _tl.inside = True
            fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY) if SCHEDSTAT else None
            s0, g0, r0 = schedstat(fd), gil_counts(), thread_usage()
            t0, w0 = time.thread_time(), time.perf_counter()
            try:
                return fn(*a)
            finally:
                dt, w1 = time.thread_time() - t0, time.perf_counter()
                s1, g1, r1 = schedstat(fd), gil_counts(), thread_usage()
                if fd is not None:
                    os.close(fd)
                _tl.inside = False
                rq = s1[1] - s0[1]  # waiting for a core (other processes' load)
                with lock:
                    secs.append(dt)
                    off.append(threading.current_thread() is not caller)
                    # blocked: off a core and not waiting for one (the GIL, a lock)
                    blocked = max(w1 - w0 - (s1[0] - s0[0]) - rq, 0.0)
                    # held: the batch's CPU times the GIL-held share of its samples (gil_sampler)
                    held = dt * (g1[1] - g0[1]) / max(g1[0] - g0[0], 1)
                    # this thread's minor faults and system CPU in the batch (RUSAGE_THREAD)
                    flt, sy = r1[0] - r0[0], r1[1] - r0[1]
                    each.append((k, threading.get_ident(), w0, w1, dt, rq, blocked, held, flt, sy))

        f = sys._getframe(1)
        where = f"{Path(f.f_code.co_filename).stem}.{f.f_code.co_name}"
        c0, w0 = time.process_time(), time.perf_counter()
        out = orig(timed, [(k, *b) for k, b in enumerate(batches)], threads, progress, poll)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        each.sort()
        used = 1 if parallel.in_worker() else parallel.resolve_threads(threads)
        busy = sum(b[3] - b[2] for b in each)
        extra = dict(
            rq=sum(b[5] for b in each),
            blocked=sum(b[6] for b in each),
            held=sum(b[7] for b in each),
            minflt=sum(b[8] for b in each),
            sys=sum(b[9] for b in each),
            # the map's thread-seconds outside its batches: the tail (a thread with no batch left),
            # the hand-out, the worker's start
            idle=max(min(used, len(each)) * wall - busy, 0.0),
            # the map modelled on 2 and 16 cores from its batches' CPU (parallel.makespan)
            mk2=parallel.makespan([x[4] for x in each], 2),
            mk16=parallel.makespan([x[4] for x in each], 16),
            threads=min(used, len(each)),
        )
        maps.append((len(secs), sum(secs), cpu, wall, where, sum(off), each, extra))
        return out

    for name, mod in list(sys.modules.items()):
        if name.startswith("hr_addon") and getattr(mod, "batch_map", None) is orig:
            mod.batch_map = wrapped


SCHEDSTAT = Path("/proc/thread-self/schedstat").exists()
RUSAGE_THREAD = getattr(resource, "RUSAGE_THREAD", None)  # (Linux)


def thread_usage():
    """(minor faults, system CPU s) of the calling thread so far; zeros where unknown."""
    if RUSAGE_THREAD is None:
        return (0, 0.0)
    r = resource.getrusage(RUSAGE_THREAD)
    return (r.ru_minflt, r.ru_stime)


def schedstat(fd):
    """(seconds on a core, seconds waiting for one) of the calling thread (Linux's schedstat:
    the wall time beyond both is time blocked, e.g. waiting for the GIL); zeros elsewhere."""
    if fd is None:
        return (0.0, 0.0)
    run, wait = os.pread(fd, 64, 0).split()[:2]
    return int(run) * 1e-9, int(wait) * 1e-9


def task_cpu():
    """{thread id: (name, CPU s)} of every thread of this process, from /proc (threads that no
    Python code started, e.g. a BLAS or Embree pool's, show up here only)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for t in Path("/proc/self/task").iterdir():
        try:
            stat = (t / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        f = stat[stat.rindex(")") + 2 :].split()
        out[t.name] = (name + " (main)" * (t.name == str(os.getpid())), (int(f[11]) + int(f[12])) / tick)
    return out


VMSTAT = ("compact_stall", "thp_fault_alloc", "thp_fault_fallback")  # machine-wide counters
IRQS = ("TLB", "CAL")  # machine-wide too (/proc/interrupts, all cores): TLB shootdowns, function calls


def usage():
    r = resource.getrusage(resource.RUSAGE_SELF)
    vm = dict(line.split() for line in Path("/proc/vmstat").read_text().splitlines())
    vm = [int(vm.get(k, 0)) for k in VMSTAT]
    irq = {}
    for line in Path("/proc/interrupts").read_text().splitlines()[1:]:
        f = line.split()
        if f and f[0].rstrip(":") in IRQS:
            irq[f[0].rstrip(":")] = sum(int(v) for v in f[1:] if v.isdigit())
    irq = [irq.get(k, 0) for k in IRQS]
    f = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    busy = (sum(f) - f[3] - f[4]) / os.sysconf("SC_CLK_TCK")  # every core's busy CPU s (all processes)
    return np.array([r.ru_utime, r.ru_stime, r.ru_minflt, r.ru_nvcsw, r.ru_nivcsw, *vm, *irq, busy])


def dispatch(reps=300):
    """CPU ms per map of `batch_map` over 1, 10 and 40 batches of about 10 us of numpy each, on 1
    and 2 threads: the cost of handing batches out, apart from any real work."""
    from hr_addon.core import parallel

    a = np.ones(1 << 14)
    out = {}
    for nb in (1, 10, 40):
        for th in (1, 2):
            c0 = time.process_time()
            for _ in range(reps):
                parallel.batch_map(lambda i: float((a * 2.0).sum()), [(i,) for i in range(nb)], th)
            out[f"{nb} batches, {th} thread(s)"] = (time.process_time() - c0) / reps * 1e3
    return out


def build(threads, size="100k", quality="draft"):
    """The room's build (RadiositySystem) once: its CPU, faults, switches and maps (instrument)."""
    from hr_testing.furnished import furnished_room
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    import hr_addon.core.boxes, hr_addon.core.contacts, hr_addon.core.farlinks  # noqa: F401, E401

    mesh = furnished_room(size)[0]
    maps = []
    instrument(maps)
    got = []
    rec = measured(
        maps, lambda: got.append(RadiositySystem(mesh, RefineParams.for_gather(quality), threads=threads))
    )
    here = str(Path(sys.modules["hr_addon"].__file__).parent)
    return {"hr_addon": here, "build": [rec], "links": len(got[0].links), "tasks": task_cpu()}


def measured(maps, fn):
    """fn() with its CPU (user, system), wall, faults, switches, the machine's VMSTAT counters and
    the outermost maps it ran (instrument's records)."""
    m0, u0, c0, w0, t0 = len(maps), usage(), time.process_time(), time.perf_counter(), time.thread_time()
    fn()
    u = usage() - u0
    rec = dict(cpu=time.process_time() - c0, wall=time.perf_counter() - w0, user=u[0], sys=u[1])
    rec["thread_cpu"] = time.thread_time() - t0  # the calling thread's (--gil: without the sampler's)
    rec.update(minflt=int(u[2]), nvcsw=int(u[3]), nivcsw=int(u[4]), maps=maps[m0:])
    rec.update({k: int(v) for k, v in zip(VMSTAT + IRQS, u[5:-1])})
    # the CPU other processes took meanwhile (/proc/stat, 10 ms ticks): 0 on an idle machine
    rec["foreign"] = float(u[-1] - rec["user"] - rec["sys"])
    return rec


def stored(store, threads, quality="draft"):
    """bench_gather_events.py's steps on a stored 100k precompute (--store DIR): per method the
    output of the base parts, then a new window and the window moved, each event and its gathered
    output measured apart. The first event builds the solver's operator (the base solution is
    stored), so its maps run in the event here, not in a base solve as in child()."""
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.io import precompute as pc

    sys.path.insert(1, str(ROOT / "benchmarks"))  # (after hr_addon: the --root checkout's)
    from bench_gather_events import load_store

    _, frame = furnished_room("100k")[1]["light_wall"]
    s, g, _ = load_store(Path(store) / pc.FILENAME)
    pc.use_threads(s, g, threads)
    s.links.extended(s.h)
    maps = []
    instrument(maps)
    out = {"hr_addon": str(Path(sys.modules["hr_addon"].__file__).parent)}

    def window(cx):
        return LightShape(
            S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
        )

    for method in ("FE", "AUTO"):
        dyn = DynamicRadiosity(s.copy(), method=method, **DynamicRadiosity.gather_options(quality))
        lv = g
        while lv is not None:  # the shape's direct light is each method's event cost
            lv._shape_cache.clear()
            lv = lv.second
        # the base parts' output (the first of a loaded store: it makes the gather's kept arrays)
        out[f"{method} first output"] = [measured(maps, lambda: g.loop_radiance(dyn))]
        for what, fn in (
            ("add", lambda: dyn.add("w", window(0.7))),
            ("move", lambda: dyn.apply({"w": window(1.2)})),
        ):
            out[f"{method} {what}"] = [measured(maps, fn)]
            out[f"{method} {what} output"] = [measured(maps, lambda: g.loop_radiance(dyn))]
            print(
                f"{method} {what}: {out[f'{method} {what}'][0]['cpu']:.3f} s CPU", file=sys.stderr, flush=True
            )
        out[f"{method} B"] = float(np.abs(dyn.B).sum())
    out["tasks"] = task_cpu()
    return out


def child(system, threads, repeat, size="100k", quality="draft"):
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    from hr_addon.core.events import DynamicRadiosity, LightShape
    import hr_addon.core.events.direct  # noqa: F401 (instrumented below)
    import hr_addon.core.gather  # noqa: F401

    sys.path.insert(1, str(ROOT / "benchmarks"))  # (after hr_addon: the --root checkout's)
    from bench_threads import _system

    mesh, info = furnished_room(size)
    _, frame = info["light_wall"]

    def window(k):  # a new shape each repeat (a shape seen before has its response cached)
        rect = S.rect(0.9, 0.7, centre=(0.7 + 0.05 * k, 0.6), angle=0.2)
        return LightShape(S.on_plane(rect, frame), np.full(3, 20.0), "window")

    s, _ = _system(mesh, size, quality, threads, system)
    dkw = DynamicRadiosity.gather_options(quality)
    maps = []
    instrument(maps)
    out = {"hr_addon": str(Path(sys.modules["hr_addon"].__file__).parent)}
    for method in ("FE", "AUTO"):
        dyn = DynamicRadiosity(s.copy(), method=method, **dkw)
        for k in range(repeat):
            for what, fn in (("add", lambda: dyn.add("w", window(k))), ("remove", lambda: dyn.remove("w"))):
                rec = measured(maps, fn)
                out.setdefault(f"{method} {what}", []).append(rec)
                print(f"{method} {what} {k}: {rec['cpu']:.3f} s CPU", file=sys.stderr, flush=True)
        out[f"{method} B"] = float(np.abs(dyn.B).sum())  # (a check that both counts agree)
    out["tasks"] = task_cpu()
    return out


def summary(runs):
    """Per event: the first one's CPU, and the median over the repeats after it of CPU, user,
    sys, faults, switches, the maps' batch CPU, their overhead (map CPU - batch CPU) and the
    serial CPU (event CPU - map CPU)."""
    rows = {}
    for t, r in runs.items():
        for ev, recs in r.items():
            if not isinstance(recs, list):
                continue
            first, recs = recs[0], recs[1:] or recs
            med = lambda f: float(np.median([f(x) for x in recs]))  # noqa: E731
            rows.setdefault(ev, {})[t] = dict(
                cpu=med(lambda x: x["cpu"]),
                wall=med(lambda x: x["wall"]),
                sys=med(lambda x: x["sys"]),
                minflt=med(lambda x: x["minflt"]),
                csw=med(lambda x: x["nvcsw"] + x["nivcsw"]),
                compact=med(lambda x: x.get("compact_stall", 0)),
                tlb=med(lambda x: x.get("TLB", 0)),
                foreign=med(lambda x: x.get("foreign", 0.0)),
                maps=med(lambda x: len(x["maps"])),
                batches=med(lambda x: sum(m[0] for m in x["maps"])),
                off_caller=med(lambda x: sum(m[5] for m in x["maps"])),
                batch_cpu=med(lambda x: sum(m[1] for m in x["maps"])),
                overhead=med(lambda x: sum(m[2] - m[1] for m in x["maps"])),
                serial=med(lambda x: x["cpu"] - sum(m[2] for m in x["maps"])),
                first_cpu=first["cpu"],
            )
    return rows


def contention(runs, busy=0.8):
    """The batches' CPU on 2 threads against the same batches on 1 (same event, repeat, map and
    batch), split by whether a batch ran together with another thread's: "together" when batches
    of another thread cover at least `busy` of its wall interval and it and they were on a core
    for at least `busy` of their wall time (CPU / wall), "alone" when none covers more than 1 -
    busy of it and it was on a core. On a loaded machine only some batches run together; the
    ratio of those is the contention (memory, caches, the GIL) of truly parallel batches."""
    one, two = runs["1"], runs[max(runs, key=int)]
    sums = {"together": [0.0, 0.0, 0], "alone": [0.0, 0.0, 0]}
    for ev, recs in two.items():
        if not isinstance(recs, list):
            continue
        for r2, r1 in zip(recs, one[ev]):
            for m2, m1 in zip(r2["maps"], r1["maps"]):
                if len(m2) < 7 or len(m1) < 7 or m2[0] != m1[0]:
                    continue
                cpu1 = {b[0]: b[4] for b in m1[6]}
                for k, tid, w0, w1, c, *_ in m2[6]:
                    wall = max(w1 - w0, 1e-9)
                    if c / wall < busy:
                        continue
                    cover = 0.0
                    for _, t2, v0, v1, c2, *_ in m2[6]:
                        if t2 != tid and c2 / max(v1 - v0, 1e-9) >= busy:
                            cover += max(0.0, min(w1, v1) - max(w0, v0))
                    cls = (
                        "together"
                        if cover >= busy * wall
                        else "alone"
                        if cover <= (1 - busy) * wall
                        else None
                    )
                    if cls:
                        sums[cls][0] += c
                        sums[cls][1] += cpu1[k]
                        sums[cls][2] += 1
    return {
        k: dict(cpu2=v[0], cpu1=v[1], batches=v[2], ratio=v[0] / v[1] if v[1] else None)
        for k, v in sums.items()
    }


def by_caller(runs, steps=("build",)):
    """Per caller of the outermost maps of `steps` (the build's stages; --store: the outputs), per
    thread count: maps, batches, the batches' CPU, and on N threads where the N cores' time in the
    maps went besides the batches' CPU: waiting for a core (rq: the machine's other jobs), blocked
    inside a batch (the GIL: another thread's batch running Python), idle (a thread with no batch
    left: the tail, the hand-out); --gil: the batches' GIL-held CPU; the maps modelled on 2 and 16
    cores (makespans of their 1-thread batches). Also the steps' wall, CPU, serial wall (outside
    the maps) and, on 1 thread, serial CPU and the model of the whole (serial + makespans)."""
    rows, whole = {}, {}
    for t, r in runs.items():
        recs = [rec for step in steps for rec in r[step]]
        maps = [m for rec in recs for m in rec["maps"]]
        w = {k: sum(rec.get(k, rec["cpu"]) for rec in recs) for k in ("wall", "cpu", "thread_cpu")}
        w.update(maps_wall=sum(m[3] for m in maps), serial_wall=w["wall"] - sum(m[3] for m in maps))
        if t == "1":  # the serial CPU and the model on 2 and 16 cores (serial + the maps' makespans)
            w["serial_cpu"] = w["thread_cpu"] - sum(m[1] for m in maps)
            for c in (2, 16):
                mk = sum(m[-1].get(f"mk{c}", 0.0) for m in maps if isinstance(m[-1], dict))
                w[f"model{c}"] = w["thread_cpu"] / (w["serial_cpu"] + mk)
        whole[t] = w
        for m in maps:
            x = m[-1] if isinstance(m[-1], dict) else {}
            row = rows.setdefault(m[4], {}).setdefault(t, dict.fromkeys(CALLER_COLS, 0.0))
            keys = ("rq", "blocked", "idle", "held", "mk2", "mk16", "minflt", "sys")
            for c, v in zip(CALLER_COLS, (1, m[0], m[1], m[3], *(x.get(k, 0.0) for k in keys))):
                row[c] += v
    return rows, whole


CALLER_COLS = (
    "maps",
    "batches",
    "batch_cpu",
    "wall",
    "rq",
    "blocked",
    "idle",
    "gil_held",
    "mk2",
    "mk16",
    "minflt",  # the batches' minor page faults (fresh pages of numpy's temporaries, session 36)
    "sys",  # the batches' system CPU s (the faults' zeroing, unmapping)
)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--system", default=None, help="bench_threads.py's --system folder (events)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--cpus", default="0-1", help="taskset -c of every run")
    ap.add_argument("--repeat", type=int, default=4)
    ap.add_argument("--json", default=None)
    ap.add_argument("--root", default=str(ROOT), help="the checkout whose hr_addon runs")
    ap.add_argument("--build", action="store_true", help="the build instead of the events")
    ap.add_argument("--size", default="100k", help="the room of --build")
    ap.add_argument(
        "--gil", action="store_true", help="1-thread runs: the batches' GIL-held CPU (gil_sampler)"
    )
    ap.add_argument("--store", default=None, help="a stored 100k precompute's folder (stored())")
    ap.add_argument("--dispatch", action="store_true", help="batch_map's own CPU per map (dispatch())")
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.dispatch:
        sys.path.insert(0, args.root)
        print(f"{args.root}, load {os.getloadavg()[0]:.2f}: CPU ms per map", json.dumps(dispatch()))
        return
    if args.child is not None:
        sys.path.insert(0, args.root)
        if args.gil and args.child == 1:
            gil_sampler()
        if args.store:
            print(json.dumps(stored(args.store, args.child)))
        else:
            print(
                json.dumps(
                    build(args.child, args.size)
                    if args.build
                    else child(args.system, args.child, args.repeat)
                )
            )
        return
    runs = {}
    for t in args.threads.split(","):
        cmd = ["taskset", "-c", args.cpus, sys.executable, __file__]
        cmd += ["--repeat", str(args.repeat), "--root", args.root, "--child", t]
        cmd += ["--build", "--size", args.size] * args.build + ["--gil"] * args.gil
        cmd += ["--system", args.system] if args.system else []
        cmd += ["--store", args.store] if args.store else []
        print(f"{t} thread(s), load {os.getloadavg()[0]:.2f}", flush=True)
        r = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, check=True)
        runs[t] = json.loads(r.stdout.strip().splitlines()[-1])
    rows = summary(runs)
    ks = list(runs)
    cont = contention(runs) if len(ks) > 1 else None
    if args.json:  # without the per-batch records (their use: contention)
        for r in runs.values():
            for recs in r.values():
                for rec in recs if isinstance(recs, list) else ():
                    rec["maps"] = [[*m[:6], *m[7:]] for m in rec["maps"]]
        Path(args.json).write_text(json.dumps(dict(runs=runs, summary=rows, contention=cont)))
    cols = (
        "first_cpu",
        "cpu",
        "sys",
        "minflt",
        "csw",
        "compact",
        "tlb",
        "foreign",
        "maps",
        "batches",
        "off_caller",
        "batch_cpu",
        "overhead",
        "serial",
    )
    print(f"{'event':12s}{'thr':>4s}" + "".join(f"{c:>10s}" for c in cols))
    for ev, by in rows.items():
        for t in ks:
            print(f"{ev:12s}{t:>4s}" + "".join(f"{by[t][c]:10.3f}" for c in cols))
        print(
            f"{'':12s}{'2/1':>4s}" + "".join(f"{by[ks[-1]][c] / max(by[ks[0]][c], 1e-9):10.2f}" for c in cols)
        )
    print("B sums:", {t: {k: v for k, v in r.items() if k not in ("tasks", *rows)} for t, r in runs.items()})
    for t, r in runs.items():  # the threads alive at the end, besides the main one
        print(f"threads at the end, {t} thread(s): {len(r['tasks'])}; CPU s of the others:", end=" ")
        print(sorted((round(c, 2), n) for n, c in r["tasks"].values() if not n.endswith("(main)")))
    if cont:
        print("batches' CPU, 2 threads / 1:", cont)
    if args.build or args.store:
        steps = ("build",) if args.build else [k for k in runs[ks[0]] if k.endswith("output")]
        rows, whole = by_caller(runs, steps)
        print(f"the maps of {', '.join(steps)} by caller, per thread count (s):")
        print(f"{'caller':34s}{'thr':>4s}" + "".join(f"{c:>10s}" for c in CALLER_COLS))
        for where, by in sorted(rows.items(), key=lambda kv: -kv[1][ks[0]]["batch_cpu"]):
            for t in ks:
                print(f"{where[:34]:34s}{t:>4s}" + "".join(f"{by[t][c]:10.3f}" for c in CALLER_COLS))
        for t in ks:
            print(f"all of them, {t} thread(s):", {k: round(v, 3) for k, v in whole[t].items()})
        if args.json:
            data = json.loads(Path(args.json).read_text())
            data.update(by_caller=rows, whole=whole)
            Path(args.json).write_text(json.dumps(data))


if __name__ == "__main__":
    main()
