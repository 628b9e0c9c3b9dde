"""Threads (issue 23, session 21): the gather's run-time reads (FinalGather._read of both levels of
the stored 100k room) on 1 and 2 threads, CPU seconds per read (process time), for a before / after
pair of checkouts run in turn (--root). The values read are written to --dump (to compare bits).

    taskset -c 0-1 nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/read_cpu.py
        --store /work/cache/s20main [--root CHECKOUT] [--repeat 10] [--dump out.npz]
"""

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main_matvec(indptr, cols, w, V, chunk=1 << 20, threads=1):
    """main's final._csr_matvec at 3edcba7 (session 20), verbatim but for the imports: the paired
    reference (--paired) run in the same process as this checkout's, in turn."""
    from hr_addon.core.gather.final import _row_blocks
    from hr_addon.core.parallel import batch_map

    n = len(indptr) - 1
    out = np.zeros((n, V.shape[1]))
    if len(cols) == 0:
        return out
    VT = np.ascontiguousarray(V.T, dtype=np.float32)
    if int(cols.max()) >= len(V):
        raise IndexError(f"_csr_matvec: a column beyond V's {len(V)} rows")

    def block(r0, r1):
        a, b = indptr[r0], indptr[r1]
        if b > a:
            c = np.asarray(cols[a:b], np.intp)
            starts = indptr[r0:r1] - a
            nonempty = np.flatnonzero(indptr[r0 + 1 : r1 + 1] > indptr[r0:r1])
            rows, starts = r0 + nonempty, starts[nonempty]
            for k in range(len(VT)):
                prod = np.take(VT[k], c, mode="clip")
                prod *= w[a:b]
                out[rows, k] = np.add.reduceat(prod, starts)

    batch_map(block, _row_blocks(indptr, chunk), threads)
    return out


def paired(levels, Ys, threads, repeat):
    """Per level, main's read (main_matvec over the intp columns, as main's second level reads)
    and this checkout's (_read) in turn, `repeat` times each: CPU medians and their ratio, values
    equal (asserted). -> {level: (main's CPU s per repeat, this one's)}."""
    got = {}
    for k, (lv, Y) in enumerate(zip(levels, Ys)):
        lv.threads = threads
        ci = lv.leaf_columns().astype(np.intp)
        cpu = {"main": [], "this": []}
        for _ in range(repeat):
            for name in cpu:
                c0 = time.process_time()
                v = (
                    main_matvec(lv.indptr, ci, lv.w, Y, threads=threads)
                    if name == "main"
                    else lv._read((Y, None, None, None))
                )
                cpu[name].append(time.process_time() - c0)
                assert np.array_equal(v, lv._read((Y, None, None, None)))
        m, t = np.median(cpu["main"]), np.median(cpu["this"])
        got[f"level{k}"] = (cpu["main"], cpu["this"])
        print(
            f"level {k}, {threads} thread(s), load {os.getloadavg()[0]:.2f}: CPU a read,"
            f" main {m * 1e3:.1f} ms, this {t * 1e3:.1f} ms ({t / m:.3f}x)",
            flush=True,
        )
    return got


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", default="/work/cache/s20main")
    ap.add_argument("--root", default=str(ROOT))
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--dump", default=None)
    ap.add_argument("--json", default=None, help="--paired: the CPU seconds of every read")
    ap.add_argument("--paired", action="store_true", help="main's read and this one's in turn (paired())")
    ap.add_argument("--step", type=int, default=None, help="final.READ_STEP for this checkout's reads")
    args = ap.parse_args(argv)
    sys.path.insert(0, args.root)
    from hr_addon.io import precompute as pc  # (first: bench_gather_events puts this checkout first)

    sys.path.insert(1, str(ROOT / "benchmarks"))
    from bench_gather_events import load_store

    if args.step:
        from hr_addon.core.gather import final

        final.READ_STEP = args.step
    _, g, _ = load_store(Path(args.store) / pc.FILENAME)
    levels = [g, g.second]
    rng = np.random.default_rng(3)
    Ys = [rng.random((int(lv.leaf_columns().max()) + 1, 3)) for lv in levels]
    out = {}
    for lv, Y in zip(levels, Ys):
        lv._read((Y, None, None, None))  # (its kept columns made)
    if args.paired:
        got = {t: paired(levels, Ys, int(t), args.repeat) for t in args.threads.split(",")}
        if args.json:
            Path(args.json).write_text(json.dumps(dict(step=args.step, threads=got)))
        return
    for t in map(int, args.threads.split(",")):
        for k, (lv, Y) in enumerate(zip(levels, Ys)):
            lv.threads = t
            cpu, csw = [], []
            for _ in range(args.repeat):
                s0, c0 = resource.getrusage(resource.RUSAGE_SELF).ru_nvcsw, time.process_time()
                v = lv._read((Y, None, None, None))
                cpu.append(time.process_time() - c0)
                csw.append(resource.getrusage(resource.RUSAGE_SELF).ru_nvcsw - s0)
            out[f"level{k}"] = v
            print(
                f"{Path(pc.__file__).parents[1]}: level {k}, {t} thread(s), load {os.getloadavg()[0]:.2f}:"
                " CPU a read median"
                f" {np.median(cpu) * 1e3:.1f} ms (min {min(cpu) * 1e3:.1f}),"
                f" voluntary switches {np.median(csw):.0f}",
                flush=True,
            )
    if args.dump:
        np.savez(args.dump, **out)


if __name__ == "__main__":
    main()
