"""The 100k build on one thread from checkout argv[1]: a sampler thread reads the main thread's
minor faults and CPU (/proc/self/task/TID/stat) every ~2 ms and gives each delta to the main
thread's Python stack at that moment, outside every batch map only (the serial part). Prints the
serial faults and CPU by stage and by innermost hr_addon line (issue 23, docs/threads.md,
session 37). Linux only.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/serial_faults.py CHECKOUT [100k]
"""

import collections
import os
import resource
import sys
import threading
import time

sys.path.insert(0, sys.argv[1])
size = sys.argv[2] if len(sys.argv) > 2 else "100k"
from hr_addon.core import parallel  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402

state = {"inside": 0}
orig = parallel.batch_map


def wrapped(*a, **k):
    state["inside"] += 1
    try:
        return orig(*a, **k)
    finally:
        state["inside"] -= 1


for name, mod in list(sys.modules.items()):
    if name.startswith("hr_addon") and getattr(mod, "batch_map", None) is orig:
        mod.batch_map = wrapped
# modules imported later (lazily) get the wrapped one too
parallel.batch_map = wrapped

mesh = furnished_room(size)[0]
main_id, tid = threading.get_ident(), threading.get_native_id()
fd = os.open(f"/proc/self/task/{tid}/stat", os.O_RDONLY)


def read():
    s = os.pread(fd, 1024, 0).decode()
    f = s[s.rindex(")") + 2 :].split()
    return int(f[7]), (int(f[11]) + int(f[12]))  # minflt, utime+stime ticks


faults, cpu = collections.Counter(), collections.Counter()
stage_f, stage_c = collections.Counter(), collections.Counter()
run = [True]
tot = {"in": [0, 0], "out": [0, 0]}


def sampler():
    last = read()
    while run[0]:
        time.sleep(0.002)
        now = read()
        df, dc = now[0] - last[0], now[1] - last[1]
        last = now
        inside = state["inside"] > 0
        fr = sys._current_frames().get(main_id)
        t = tot["in" if inside else "out"]
        t[0] += df
        t[1] += dc
        if inside or fr is None or (df == 0 and dc == 0):
            continue
        chain = []
        while fr is not None:
            co = fr.f_code
            if "hr_addon" in co.co_filename:
                chain.append(f"{co.co_name} {os.path.basename(co.co_filename)}:{fr.f_lineno}")
            fr = fr.f_back
        chain.reverse()
        key = chain[-1] if chain else "?"
        faults[key] += df
        cpu[key] += dc
        st = " > ".join(c.split(":")[0] for c in chain[1:4])
        stage_f[st] += df
        stage_c[st] += dc


th = threading.Thread(target=sampler, daemon=True)
c0, r0 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
th.start()
s = RadiositySystem(mesh, RefineParams.for_gather("draft"), threads=1)
run[0] = False
th.join()
r1 = resource.getrusage(resource.RUSAGE_SELF)
tick = os.sysconf("SC_CLK_TCK")
print(
    f"build CPU {time.process_time() - c0:.2f} s, faults {r1.ru_minflt - r0.ru_minflt}; main thread: "
    f"in maps {tot['in'][0]} faults {tot['in'][1] / tick:.2f} s, "
    f"serial {tot['out'][0]} faults {tot['out'][1] / tick:.2f} s"
)
print("-- serial by stage (faults, CPU s)")
for k, v in stage_f.most_common(20):
    print(f"{v:8d} {stage_c[k] / tick:6.2f}  {k}")
print("-- serial by innermost line (faults, CPU s)")
for k, v in faults.most_common(30):
    print(f"{v:8d} {cpu[k] / tick:6.2f}  {k}")
print("-- serial by innermost line, CPU")
for k, v in cpu.most_common(25):
    print(f"{faults[k]:8d} {v / tick:6.2f}  {k}")
