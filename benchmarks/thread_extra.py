"""Issue 23: where two threads' extra CPU in the build goes, by stage and by thread. The furnished
room's build (RadiositySystem, the bake's draft refinement) on T threads from checkout CHECKOUT, in
this process; a sampler thread reads every thread's CPU (/proc/self/task/TID/schedstat, ns) and
minor faults every ~3 ms and gives each delta to the stage the calling thread is in at that moment:
the caller of the outermost batch map running (`map:<file>.<function>`), else the calling thread's
serial code (`serial:<function>`). Threads are told apart as the calling thread, the pool's workers
(hr-batch-*) and the others (OpenBLAS's own threads, Embree's, ...: by their name). Run it once per
thread count (each in its own process) and compare the stages' CPU: a stage's 2-thread CPU over
its 1-thread CPU. The sampler's own CPU is left out (it holds the GIL a few us per read).

    OPENBLAS_NUM_THREADS=1 taskset -c 0-1 .venv/bin/python benchmarks/thread_extra.py CHECKOUT 20k 2 \
        [--json out.json]
"""

import argparse
import collections
import json
import os
import resource
import sys
import threading
import time

ap = argparse.ArgumentParser()
ap.add_argument("root")
ap.add_argument("size")
ap.add_argument("threads", type=int)
ap.add_argument("--json", default=None)
ap.add_argument(
    "--set", action="append", default=[], help="module.NAME=int in hr_addon.core (A/B of a constant)"
)
ap.add_argument("--every", type=float, default=0.003, help="the sampler's period, s (0: no sampler)")
args = ap.parse_args()
sys.path.insert(0, args.root)

from hr_addon.core import parallel  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402

for kv in args.set:
    key, val = kv.split("=")
    mod, name = key.rsplit(".", 1)
    setattr(__import__(f"hr_addon.core.{mod}", fromlist=["x"]), name, int(eval(val)))

state = {"depth": 0, "caller": None}
orig = parallel.batch_map


def wrapped(*a, **k):
    if state["depth"] == 0 and threading.get_ident() == main_id:
        f = sys._getframe(1)
        state["caller"] = f"map:{os.path.basename(f.f_code.co_filename)[:-3]}.{f.f_code.co_name}"
    state["depth"] += threading.get_ident() == main_id
    try:
        return orig(*a, **k)
    finally:
        state["depth"] -= threading.get_ident() == main_id


for name, mod in list(sys.modules.items()):
    if name.startswith("hr_addon") and getattr(mod, "batch_map", None) is orig:
        mod.batch_map = wrapped
parallel.batch_map = wrapped

mesh = furnished_room(args.size)[0]
main_id, main_tid = threading.get_ident(), threading.get_native_id()
me = [None]
fds = {}  # tid -> (fd schedstat, fd stat)


def kind(tid):
    if tid == main_tid:
        return "caller"
    for t in threading.enumerate():
        if t.native_id == tid:
            return "worker" if t.name.startswith("hr-batch") else f"py:{t.name}"
    try:
        with open(f"/proc/self/task/{tid}/comm") as f:
            return "other:" + f.read().strip()
    except OSError:
        return "other:?"


def read_all():
    out = {}
    for name in os.listdir("/proc/self/task"):
        tid = int(name)
        if tid == me[0]:
            continue
        try:
            if tid not in fds:
                fds[tid] = (
                    os.open(f"/proc/self/task/{tid}/schedstat", os.O_RDONLY),
                    os.open(f"/proc/self/task/{tid}/stat", os.O_RDONLY),
                )
            ns = int(os.pread(fds[tid][0], 128, 0).split()[0])
            s = os.pread(fds[tid][1], 1024, 0).decode()
            flt = int(s[s.rindex(")") + 2 :].split()[7])
        except (OSError, ValueError, IndexError):
            continue
        out[tid] = (ns, flt)
    return out


cpu = collections.defaultdict(float)  # (stage, thread kind) -> s
walls = collections.defaultdict(float)  # stage -> s (the sampler's periods in it)
flt = collections.Counter()
kinds = {}
run = [True]


def stage():
    if state["depth"] > 0:
        return state["caller"]
    fr = sys._current_frames().get(main_id)
    chain = []
    while fr is not None:
        if "hr_addon" in fr.f_code.co_filename:
            chain.append(fr.f_code.co_name)
        fr = fr.f_back
    chain.reverse()
    return "serial:" + (chain[1] if len(chain) > 1 else chain[0] if chain else "?")


def sampler():
    me[0] = threading.get_native_id()
    pol = os.sched_getscheduler(0)
    if pol == os.SCHED_FIFO:  # (run under chrt -f: the sampler above the build's threads, or it starves)
        os.sched_setscheduler(me[0], pol, os.sched_param(os.sched_getparam(0).sched_priority + 1))
    last, t0 = read_all(), time.perf_counter()
    while run[0]:
        time.sleep(args.every)
        now, t1 = read_all(), time.perf_counter()
        st = stage()
        walls[st] += t1 - t0
        t0 = t1
        for tid, (ns, f) in now.items():
            ns0, f0 = last.get(tid, (0, 0))
            if ns != ns0 or f != f0:
                k = kinds.get(tid) or kinds.setdefault(tid, kind(tid))
                if k.startswith("py:") or k == "other:python":
                    kinds.pop(tid)  # (a thread seen before its Thread object is listed, or after)
                cpu[st, k] += (ns - ns0) / 1e9
                flt[st, k] += f - f0
        last = now


th = threading.Thread(target=sampler, daemon=True, name="sampler")
c0, w0, r0 = time.process_time(), time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
if args.every > 0:
    th.start()
system = RadiositySystem(mesh, RefineParams.for_gather("draft"), threads=args.threads)
run[0] = False
if args.every > 0:
    th.join()
r1 = resource.getrusage(resource.RUSAGE_SELF)
total = {
    "process_cpu": time.process_time() - c0,
    "wall": time.perf_counter() - w0,
    "sys": r1.ru_stime - r0.ru_stime,
    "minflt": r1.ru_minflt - r0.ru_minflt,
    "nvcsw": r1.ru_nvcsw - r0.ru_nvcsw,
    "nivcsw": r1.ru_nivcsw - r0.ru_nivcsw,
    "sampled_cpu": sum(cpu.values()),
    "load": os.getloadavg()[0],
    "links": len(system.links) if hasattr(system.links, "__len__") else None,
    "openblas": os.environ.get("OPENBLAS_NUM_THREADS"),
    "set": args.set,
}
by_stage = collections.defaultdict(dict)
for (st, k), v in cpu.items():
    by_stage[st][k] = v
print(json.dumps(total))
print(f"{'stage':44s}{'CPU s':>7s}{'wall s':>7s}  by thread (CPU s, faults)")
for st, d in sorted(by_stage.items(), key=lambda x: -sum(x[1].values())):
    parts = ", ".join(f"{k} {v:.2f} {flt[st, k]}" for k, v in sorted(d.items(), key=lambda x: -x[1]))
    print(f"{st:44s}{sum(d.values()):7.2f}{walls[st]:7.2f}  {parts}")
if args.json:
    rows = [{"stage": st, "thread": k, "cpu": v, "minflt": flt[st, k]} for (st, k), v in cpu.items()]
    rows += [{"stage": st, "thread": "wall", "wall": v} for st, v in walls.items()]
    Path = __import__("pathlib").Path
    Path(args.json).write_text(json.dumps({"total": total, "threads": args.threads, "rows": rows}, indent=1))
