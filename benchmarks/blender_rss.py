"""Blender's own memory before a bake builds anything (session 33, branch mem2g; docs/scale.md):
RSS and glibc's heap after `import bpy`, after the .blend is opened, after its depsgraph is
evaluated, and (--snapshot) after the bake's scene read (own values' helpers, near_clutter, the
evaluated meshes' arrays: snapshot.read_snapshot at the scene's settings) and after that Snapshot
is dropped again (what is left is Blender's: helpers, modifiers' evaluated meshes):

    /work/main/.venv/bin/python benchmarks/blender_rss.py COPY.blend [--snapshot] [--trace]

Use a copy of the .blend: --snapshot gives its objects helpers (in memory only; never saved)."""

import gc
import resource
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from heapinfo import mallinfo, rss_gb  # noqa: E402

BLEND = sys.argv[1]
if "--trace" in sys.argv:
    tracemalloc.start()


def mark(what):
    rss, mi = rss_gb(), mallinfo()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    traced = f" traced={tracemalloc.get_traced_memory()[0] / 1e9:.3f}" if tracemalloc.is_tracing() else ""
    print(
        f"{what:<28} rss={rss:.3f} peak={peak:.3f} heap_used={mi.uordblks / 1e9:.3f} "
        f"heap_free={mi.fordblks / 1e9:.3f} mmap={mi.hblkhd / 1e9:.3f}{traced} cpu={time.process_time():.1f}",
        flush=True,
    )


mark("python")
import bpy  # noqa: E402

mark("import bpy")
bpy.ops.wm.open_mainfile(filepath=str(Path(BLEND).resolve()), load_ui=False)
mark("file opened")
bpy.context.view_layer.update()
mark("depsgraph evaluated")
if "--snapshot" in sys.argv:
    from hr_addon import register
    from hr_addon.blender.settings import BakeConfig
    from hr_addon.blender.snapshot import read_snapshot
    from hr_addon.core.parallel import release_free_memory

    register()
    mark("add-on registered")
    scene = bpy.context.scene
    cfg = BakeConfig.resolve(scene.hr)
    snap = read_snapshot(scene, bpy.context.view_layer, cfg, lambda w: None, log=print)
    m, t = snap.mesh, snap.transport
    held = sum(a.nbytes for x in (m, t) for a in vars(x).values() if hasattr(a, "nbytes"))
    tg = sum(a.nbytes for tt in snap.scene_in.targets for a in vars(tt).values() if hasattr(a, "nbytes"))
    print(
        f"snapshot: output mesh {len(m.loop_verts):,} loops, transport {len(t.loop_verts):,}; "
        f"MeshInputs' arrays {held / 1e6:.1f} MB, targets' {tg / 1e6:.1f} MB"
    )
    mark("snapshot read")
    release_free_memory()
    mark("  trimmed")
    del snap, m, t
    gc.collect()
    release_free_memory()
    mark("snapshot dropped, trimmed")
