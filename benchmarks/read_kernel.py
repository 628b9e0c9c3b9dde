"""Threads (issue 23, session 21): what limits the gather's read on two threads. The read kernel
of final._csr_matvec (per row block: the columns' values taken, times the weights, summed per row
by reduceat) on 1 and on 2 threads over the same batches, for variants of its arrays: the 100k
room's second level (stored precompute) or the same entries over a leaf-value array that fits in
a core's cache; random (as stored) or sorted columns within rows; float32 or float64 values; the
three channels apart (main) or interleaved (n, 3); int32 columns; row blocks read in smaller
sub-blocks. Two references: `compute` (np.sin over an array within L1: no memory traffic) and
`stream` (adding arrays far larger than the caches: memory bandwidth alone).

A shared machine runs other jobs, so two threads seldom run at the same time for a whole batch:
every numpy operation of a batch is timed (CPU: time.thread_time in its thread, and wall), and an
operation of the 2-thread run counts when it ran on a core all along (CPU / wall >= BUSY) while
the other thread's operations on a core covered BUSY of it (`together`); its CPU is compared with
the same operation's on 1 thread (on a core all along there too). No wall speed-up is read.

    taskset -c 0-1 nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/read_kernel.py
        --store /work/cache/s20main [--level 1] [--repeat 6] [--json out.json] [--variants a,b]
"""

import argparse
import json
import os
import resource
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from hr_addon.core.parallel import batch_map  # noqa: E402

BUSY = 0.9


class Ops:
    """Per-operation records (key, thread, wall start, wall end, CPU s, system CPU s) of one map."""

    def __init__(self):
        self.recs, self.lock = [], threading.Lock()

    def __call__(self, key, fn, *a, **kw):
        s0 = resource.getrusage(resource.RUSAGE_THREAD).ru_stime
        t0, w0 = time.thread_time(), time.perf_counter()
        out = fn(*a, **kw)
        w1, t1 = time.perf_counter(), time.thread_time()
        s1 = resource.getrusage(resource.RUSAGE_THREAD).ru_stime
        with self.lock:
            self.recs.append((key, threading.get_ident(), w0, w1, t1 - t0, s1 - s0))
        return out


def read(ops, indptr, cols, w, VT, interleaved=False, sub=1 << 20, reuse=False):
    """The read's batch function over rows r0..r1 (in sub-blocks of about `sub` entries; reuse:
    the products taken into a buffer each thread keeps) and its output (n, 3)."""
    out = np.zeros((len(indptr) - 1, 3))
    V3 = np.ascontiguousarray(VT.T) if interleaved else None
    own = threading.local()

    def block(r0, r1):
        q0 = r0
        while q0 < r1:
            q1 = min(max(int(np.searchsorted(indptr, indptr[q0] + sub, "right")) - 1, q0 + 1), r1)
            a, b = indptr[q0], indptr[q1]
            c = cols[a:b]
            starts = indptr[q0:q1] - a
            nonempty = np.flatnonzero(indptr[q0 + 1 : q1 + 1] > indptr[q0:q1])
            rows, starts = q0 + nonempty, starts[nonempty]
            if interleaved:
                prod = ops((q0, "take"), np.take, V3, c, 0, mode="clip")
                ops((q0, "mul"), np.multiply, prod, w[a:b, None], out=prod)
                out[rows] = ops((q0, "sum"), np.add.reduceat, prod, starts, 0)
            else:
                for k in range(3):
                    buf = None
                    if reuse:
                        buf = own.__dict__.get("buf")
                        if buf is None or len(buf) < b - a:
                            buf = own.buf = np.empty(max(b - a, sub), VT.dtype)
                        buf = buf[: b - a]
                    prod = ops((q0, k, "take"), np.take, VT[k], c, mode="clip", out=buf)
                    ops((q0, k, "mul"), np.multiply, prod, w[a:b], out=prod)
                    out[rows, k] = ops((q0, k, "sum"), np.add.reduceat, prod, starts)
            q0 = q1

    return block, out


def blocks(indptr, chunk=1 << 20):
    n = len(indptr) - 1
    got, r0 = [], 0
    while r0 < n:
        r1 = min(max(int(np.searchsorted(indptr, indptr[r0] + chunk, "right")) - 1, r0 + 1), n)
        got.append((r0, r1))
        r0 = r1
    return got


def sorted_within_rows(indptr, cols, w):
    row = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    order = np.lexsort((cols, row))
    return cols[order], w[order]


def compacted(cols, V, order="count"):
    """(cols renumbered, V's rows in that numbering): the used values only, the most read first
    ("count") or in their first read's order ("first") or in V's order ("index"): the same products
    summed in the same order."""
    cnt = np.bincount(cols, minlength=V.shape[1])
    used = np.flatnonzero(cnt)
    if order == "count":
        used = used[np.argsort(-cnt[used], kind="stable")]
    elif order == "first":
        u, first = np.unique(cols, return_index=True)
        used = u[np.argsort(first, kind="stable")]
    rank = np.zeros(V.shape[1], np.intp)
    rank[used] = np.arange(len(used))
    return rank[cols], np.ascontiguousarray(V[:, used])


def compute_ref(ops, nb, calls=30, n=4096):
    """nb batches of 20 operations, each np.sin over 4k float64 (32 KB, within L1) `calls` times."""
    x = np.linspace(0, 1, n)
    own = threading.local()  # each thread's own output

    def sins(out):
        for _ in range(calls):
            np.sin(x, out=out)

    def block(k):
        out = own.__dict__.setdefault("out", np.empty(n))
        for j in range(20):
            ops((k, j), sins, out)

    return block, [(k,) for k in range(nb)], None


def stream_ref(ops, nb, n=1 << 22):
    """nb batches of 4 operations each adding two float32 arrays of 16 MB into a third."""
    a = [np.ones(n, np.float32) for _ in range(3)]
    b = [np.ones(n, np.float32) for _ in range(3)]
    own = threading.local()

    def block(k):
        out = own.__dict__.setdefault("out", np.empty(n, np.float32))
        for j in range(4):
            ops((k, j), np.add, a[(k + j) % 3], b[(k + j) % 3], out=out)

    return block, [(k,) for k in range(nb)], None


def rays_ref(ops, backend, a, b, per=1 << 13):
    """Batches of `per` occlusion rays (the 100k room's Embree scene: segments between samples),
    each batch one operation."""

    def block(i, j):
        ops((i,), backend.occluded, a[i:j], b[i:j])

    return block, [(i, min(i + per, len(a))) for i in range(0, len(a), per)], None


def idle_cores(dt=0.3):
    """Idle cores over the next dt seconds (/proc/stat)."""

    def snap():
        f = [int(v) for v in open("/proc/stat").readline().split()[1:]]
        return f[3] + f[4], sum(f)

    i0, t0 = snap()
    time.sleep(dt)
    i1, t1 = snap()
    return os.cpu_count() * (i1 - i0) / max(t1 - t0, 1)


def machine_busy():
    """(CPU s all cores were busy since boot, this process's CPU s)."""
    f = [int(v) for v in open("/proc/stat").readline().split()[1:]]
    return (sum(f) - f[3] - f[4]) / os.sysconf("SC_CLK_TCK"), time.process_time()


def quiet(makers, seconds, passes=3, idle=1.8):
    """Bursts taken when the machine's other jobs leave both cores idle (idle_cores >= idle): per
    variant in turn, `passes` passes on 1 thread, then on 2; per run its CPU s (this process),
    wall s and `foreign`, the CPU s the machine spent on other processes meanwhile (/proc/stat,
    10 ms ticks). A burst counts where foreign stayed under 5% of the wall in both runs."""
    out, end, k = {}, time.time() + seconds, 0
    names = list(makers)
    while time.time() < end:
        free = idle_cores()
        if free < idle:
            time.sleep(0.5)
            continue
        name = names[k % len(names)]
        k += 1
        rec = {"idle": free}
        for t in (1, 2):
            (b0, c0), w0 = machine_busy(), time.perf_counter()
            for _ in range(passes):
                fn, batches, _ = makers[name](lambda key, f, *a, **kw: f(*a, **kw))
                batch_map(fn, batches, t)
            (b1, c1), w1 = machine_busy(), time.perf_counter()
            rec[t] = dict(cpu=c1 - c0, wall=w1 - w0, foreign=(b1 - b0) - (c1 - c0))
        ok = all(rec[t]["foreign"] < 0.05 * rec[t]["wall"] for t in (1, 2))
        rec["quiet"] = ok
        out.setdefault(name, []).append(rec)
        print(
            f"{time.strftime('%H:%M:%S')} {name:8s} idle {free:.2f}:"
            f" CPU {rec[1]['cpu']:.3f} -> {rec[2]['cpu']:.3f} s"
            f" ({rec[2]['cpu'] / rec[1]['cpu']:.2f}x), wall {rec[1]['wall']:.3f} -> {rec[2]['wall']:.3f} s,"
            f" foreign {rec[1]['foreign']:.2f} / {rec[2]['foreign']:.2f} s{' QUIET' if ok else ''}",
            flush=True,
        )
    return out


def sweep(makers, seconds):
    """Passes without waiting, the variants and 1 / 2 threads in turn, each with its CPU s, wall s and
    `foreign` (the CPU s the machine spent on other processes meanwhile, /proc/stat): on a loaded
    machine, a pass's CPU against how busy the other core was with other jobs tells whether a job
    on the other core slows this one (memory, caches, the host's scheduling of the two vCPUs)."""
    out, end, k = {}, time.time() + seconds, 0
    names = list(makers)
    noop = lambda key, f, *a, **kw: f(*a, **kw)  # noqa: E731
    while time.time() < end:
        name, t = names[(k // 2) % len(names)], 1 + k % 2
        k += 1
        (b0, c0), w0 = machine_busy(), time.perf_counter()
        fn, batches, _ = makers[name](noop)
        batch_map(fn, batches, t)
        (b1, c1), w1 = machine_busy(), time.perf_counter()
        out.setdefault(f"{name} {t}", []).append((c1 - c0, w1 - w0, (b1 - b0) - (c1 - c0)))
    for key, recs in out.items():  # CPU a pass by the other jobs' share of the pass's wall time
        r = np.array(recs)
        f = r[:, 2] / r[:, 1]
        bins = [
            (lo, hi, r[(f >= lo) & (f < hi), 0]) for lo, hi in ((-9, 0.1), (0.1, 0.5), (0.5, 0.9), (0.9, 9))
        ]
        print(
            f"{key:14s}",
            "  ".join(
                f"foreign {lo:.1f}-{hi:.1f}: {len(c):3d} x {np.median(c) * 1e3 if len(c) else 0:6.1f} ms"
                for lo, hi, c in bins
            ),
            flush=True,
        )
    return out


def together(one, two):
    """(CPU on 2 threads, CPU on 1, count) of the operations that ran on a core all along while the
    other thread's operations on a core covered BUSY of them, against the same operations on 1
    thread (on a core all along there too), and the same sums over every operation on a core
    all along in both runs (`alone` or not)."""
    ref = {}
    for r in one:
        for key, _, w0, w1, c, _ in r:
            if c >= BUSY * (w1 - w0):
                ref.setdefault(key, []).append(c)
    ref = {k: float(np.median(v)) for k, v in ref.items()}
    tog, every = [0.0, 0.0, 0], [0.0, 0.0, 0]
    for r in two:
        busy = sorted((w0, w1, t) for _, t, w0, w1, c, _ in r if c >= BUSY * (w1 - w0))
        for key, tid, w0, w1, c, _ in r:
            if key not in ref or c < BUSY * (w1 - w0):
                continue
            every[0], every[1], every[2] = every[0] + c, every[1] + ref[key], every[2] + 1
            cover = sum(
                max(0.0, min(w1, v1) - max(w0, v0)) for v0, v1, t in busy if t != tid and v1 > w0 and v0 < w1
            )
            if cover >= BUSY * (w1 - w0):
                tog[0], tog[1], tog[2] = tog[0] + c, tog[1] + ref[key], tog[2] + 1
    return tog, every


def measure(make, repeat):
    """{threads: per repeat the operations' records}; the 1- and 2-thread outputs equal (asserted)."""
    got, outs = {}, {}
    for t in (1, 2):
        got[t] = []
        for _ in range(repeat):
            ops = Ops()
            fn, batches, out = make(ops)
            batch_map(fn, batches, t)
            got[t].append(ops.recs)
        outs[t] = out
    if outs[1] is not None:
        assert np.array_equal(outs[1], outs[2])
    return got


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", default="/work/cache/s20main")
    ap.add_argument("--level", type=int, default=1, help="0 the top level, 1 the second")
    ap.add_argument("--repeat", type=int, default=6)
    ap.add_argument("--variants", default=None, help="comma-separated names to run (default all)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quiet", type=float, default=0, help="seconds of quiet() bursts instead")
    ap.add_argument("--sweep", type=float, default=0, help="seconds of sweep() passes instead")
    args = ap.parse_args(argv)
    sys.path.insert(1, str(ROOT / "benchmarks"))
    from bench_gather_events import load_store
    from hr_addon.io import precompute as pc

    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    rng = np.random.default_rng(2)
    i, j = rng.integers(0, g.n, 1 << 18), rng.integers(0, g.n, 1 << 18)
    ra, rb = g.points[i] + 1e-3 * g.normals[i], g.points[j] + 1e-3 * g.normals[j]
    backend = s.system.backend if hasattr(s, "system") else s.backend
    for _ in range(args.level):
        g = g.second
    indptr, cols32, w = g.indptr, g.leaf_columns(), g.w
    m = int(cols32.max()) + 1
    del g
    V = np.random.default_rng(1).random((3, m), dtype=np.float32)
    cols = cols32.astype(np.intp)
    small = 1 << 14  # 16k leaf values: 64 KB a channel in float32, within a core's L2
    cols_small = cols % small
    scols, sw = sorted_within_rows(indptr, cols, w)
    nb = len(blocks(indptr))
    variants = {  # name: the read's arguments
        "main": (cols, w, V),
        "cache": (cols_small, w, V[:, :small].copy()),
        "sorted": (scols, sw, V),
        "f64": (cols, w, V.astype(np.float64)),
        "interleaved": (cols, w, V, True),
        "sub64k": (cols, w, V, False, 1 << 16),
        "cache_sub64k": (cols_small, w, V[:, :small].copy(), False, 1 << 16),
        "cols32": (cols32, w, V),
        "reuse": (cols, w, V, False, 1 << 20, True),
        "reuse_sub64k": (cols, w, V, False, 1 << 16, True),
        "reuse_sub256k": (cols, w, V, False, 1 << 18, True),
        "compact_count": (*compacted(cols, V, "count")[:1], w, compacted(cols, V, "count")[1]),
        "compact_first": (*compacted(cols, V, "first")[:1], w, compacted(cols, V, "first")[1]),
        "compact_index": (*compacted(cols, V, "index")[:1], w, compacted(cols, V, "index")[1]),
    }

    def maker(name):
        if name == "compute":
            return lambda ops: compute_ref(ops, nb)
        if name == "stream":
            return lambda ops: stream_ref(ops, nb)
        if name == "rays":
            return lambda ops: rays_ref(ops, backend, ra, rb)
        return lambda ops: (lambda f, o: (f, blocks(indptr), o))(*read(ops, indptr, *variants[name]))

    names = args.variants.split(",") if args.variants else ["compute", "stream", "rays", *variants]
    if args.quiet or args.sweep:
        makers = {n: maker(n) for n in names}
        got = quiet(makers, args.quiet) if args.quiet else sweep(makers, args.sweep)
        if args.json:
            Path(args.json).write_text(json.dumps(got))
        return
    res = {"entries": len(cols), "rows": len(indptr) - 1, "values": m, "batches": nb}
    print(f"{len(cols)} entries, {len(indptr) - 1} rows, {m} values, {nb} batches", flush=True)
    for name in names:
        load = os.getloadavg()[0]
        got = measure(maker(name), args.repeat)
        c1, c2 = (float(np.median([sum(r[4] for r in recs) for recs in got[t]])) for t in (1, 2))
        s1, s2 = (float(np.median([sum(r[5] for r in recs) for recs in got[t]])) for t in (1, 2))
        tog, every = together(got[1], got[2])
        kinds = {}  # 1 thread: CPU ms a pass per kind of operation (take, mul, sum)
        for recs in got[1]:
            for key, *_, c, _ in recs:
                kinds[key[-1]] = kinds.get(key[-1], 0.0) + c * 1e3 / len(got[1])
        kinds = {k: round(v, 1) for k, v in kinds.items() if isinstance(k, str)}
        res[name] = dict(
            load=load, cpu1=c1, cpu2=c2, sys1=s1, sys2=s2, together=tog, on_core=every, kinds=kinds
        )
        print(
            f"{name:13s} load {load:.2f}: ops' CPU a pass 1 thr {c1 * 1e3:6.1f} ms, 2 thr {c2 * 1e3:6.1f} ms"
            f" ({c2 / c1:.2f}x), sys {s1 * 1e3:.1f} / {s2 * 1e3:.1f} ms;"
            f" on a core {every[2]:4d} ops {every[0] / max(every[1], 1e-9):.2f}x;"
            f" together {tog[2]:4d} ops {tog[0] / max(tog[1], 1e-9):.2f}x {kinds or ''}",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(res))


if __name__ == "__main__":
    main()
