"""hostvis' trace CPU at two batch sizes, in one process, alternating (session 37, branch mem37;
docs/scale.md): test_hostvis' room (hr_testing.contact_furnace, its two light shapes on a wall and
the moved window) at SAMPLES gather samples per m^2; each round a fresh lazy store per batch size
(`hostvis.TRACE_CHUNK` 2^20, main's, and 2^16), every shape's light traced, their order alternating
round by round; process time of each, the values compared bit for bit:

    cd WORKTREE && nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python \\
        benchmarks/hostvis_chunk_ab.py SAMPLES ROUNDS [OUT.json]"""

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hr_addon.core.gather import hostvis as hv  # noqa: E402
from tests.test_hostvis import build, store  # noqa: E402

S, R = float(sys.argv[1]), int(sys.argv[2])
t0 = time.process_time()
dyn, g, ems = build(samples=S)
print(f"samples {g.n}, built in {time.process_time() - t0:.1f} s CPU", flush=True)
cpu, rays, ref = {20: [], 16: []}, {}, {}
for r in range(R):
    for c in (20, 16) if r % 2 == 0 else (16, 20):
        hv.TRACE_CHUNK = 1 << c
        H = [store(dyn, g, e, policy="lazy") for e in ems.values()]
        t = time.process_time()
        out = [h.light(e) for h, e in zip(H, ems.values())]
        cpu[c].append(time.process_time() - t)
        rays[c] = sum(h.event_rays for h in H)
        if c in ref:
            assert all(np.array_equal(a, b) for a, b in zip(out, ref[c]))
        ref[c] = out
    print(r, {c: round(v[-1], 3) for c, v in cpu.items()}, flush=True)
same = all(np.array_equal(a, b) for a, b in zip(ref[20], ref[16]))
res = dict(samples=g.n, rays=rays, cpu=cpu, ratio_16_over_20=sum(cpu[16]) / sum(cpu[20]), equal=same)
print(json.dumps(res), flush=True)
if len(sys.argv) > 3:
    Path(sys.argv[3]).write_text(json.dumps(res, indent=1))
