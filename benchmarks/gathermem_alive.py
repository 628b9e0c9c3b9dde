"""What is alive at the first frame's output of a Blender bake (session 38, branch mem38;
docs/scale.md): gathermem_marks.py, and at the first three calls of FinalGather._response_parts and
LoopGather._loops the bake's live objects (found by gc: Snapshot, RadiositySystem,
DynamicRadiosity, the gather, the writer) are walked for numpy arrays, each buffer counted once,
under the first path that reaches it (the roots in that order). Writes OUT.json (the marks) and
OUT.json.alive (per point: RSS, heap in use, the arrays' bytes by root and by path):

    cd WORKTREE && /usr/bin/time -v nice -n 5 env OPENBLAS_NUM_THREADS=1 \\
        /work/main/.venv/bin/python benchmarks/gathermem_alive.py OUT.json -- \\
        bake furnished_100k.blend --frames 1-1 --threads 1 --save baked.blend"""

import atexit
import collections
import gc
import json
import os
import runpy
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(HERE), HERE]
from heapinfo import mallinfo, rss_gb  # noqa: E402

ROOTS = (
    "Snapshot",
    "RadiositySystem",
    "DynamicRadiosity",
    "LoopGather",
    "CacheWriter",
    "_Bake",
    "FlatExtract",
)
SKIP = (str, bytes, int, float, bool, type(None), type)
maps = []


def _children(path, o):
    if isinstance(o, dict):
        return [(f"{path}[{str(k)[:20]}]", v) for k, v in o.items()]
    if isinstance(o, (list, tuple, set, frozenset)):
        return [(f"{path}[]", v) for v in o]
    kids = [(f"{path}.{k}", v) for k, v in (getattr(o, "__dict__", None) or {}).items()]
    kids += [(f"{path}.{s}", getattr(o, s)) for s in getattr(type(o), "__slots__", ()) if hasattr(o, s)]
    if hasattr(o, "__func__"):
        kids.append((f"{path}.__self__", getattr(o, "__self__", None)))
    for c in getattr(o, "__closure__", None) or ():
        kids.append((f"{path}.<cell>", c.cell_contents))
    return kids


def walk(label):
    """The arrays reachable from the bake's roots, by root and by path (4 levels deep)."""
    roots = sorted(
        ((type(o).__name__, o) for o in gc.get_objects() if type(o).__name__ in ROOTS),
        key=lambda r: ROOTS.index(r[0]),
    )
    seen, bufs, by, top = set(), set(), collections.Counter(), collections.Counter()
    stack = [(t, o, 0) for t, o in reversed(roots)]
    while stack:
        path, o, depth = stack.pop()
        if id(o) in seen or depth > 12 or isinstance(o, SKIP):
            continue
        seen.add(id(o))
        if isinstance(o, np.ndarray):
            b = o
            while isinstance(b.base, np.ndarray):
                b = b.base
            if id(b) not in bufs:
                bufs.add(id(b))
                nb = b.nbytes if b.base is None else o.nbytes
                by[".".join(path.split(".")[:4])] += nb
                top[path.split(".")[0]] += nb
            continue
        if type(o).__module__.startswith(("bpy", "numpy")):
            continue
        stack += [(p, v, depth + 1) for p, v in reversed(_children(path, o))]
    mi = mallinfo()
    maps.append(
        dict(
            at=label,
            rss_gb=rss_gb(),
            heap_used_gb=mi.uordblks / 1e9 if mi else None,
            mmap_gb=mi.hblkhd / 1e9 if mi else None,
            arrays_gb=sum(by.values()) / 1e9,
            roots={k: round(v / 1e6, 1) for k, v in top.most_common()},
            paths={k: round(v / 1e6, 2) for k, v in by.most_common(120)},
        )
    )
    print("ALIVE", label, maps[-1]["arrays_gb"], maps[-1]["roots"], flush=True)


def hook(owner, name, calls=collections.Counter()):
    fn = getattr(owner, name)

    def w(*a, **k):
        calls[name] += 1
        if calls[name] <= 3:
            walk(f"{name}#{calls[name]} <")
        return fn(*a, **k)

    setattr(owner, name, w)


from hr_addon.core.gather import final, layouts  # noqa: E402

hook(final.FinalGather, "_response_parts")
hook(layouts.LoopGather, "_loops")
atexit.register(lambda: open(sys.argv[1] + ".alive", "w").write(json.dumps(maps, indent=1)))
sys.argv = [os.path.join(HERE, "gathermem_marks.py")] + sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
