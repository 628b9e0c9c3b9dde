"""Blender's memory before the build as the command-line vertex bake has it (session 37, branch
mem37; docs/scale.md): the .blend opened and evaluated, `read_snapshot`, `out_of_depsgraph`, then the
heap trimmed, then the Snapshot dropped; RSS by mapping (/proc/self/smaps: the main heap, other
threads' malloc arenas (64 MB aligned), file-backed pages, other anonymous) and glibc's heap:

    cd WORKTREE && nice -n 5 /work/main/.venv/bin/python benchmarks/blender_before_build.py COPY.blend

Use a copy of the .blend: the scene read gives its objects helpers (in memory only; never saved)."""

import collections
import gc
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from heapinfo import mallinfo  # noqa: E402


def by_mapping():
    cat, name, a, b = collections.Counter(), None, 0, 0
    for line in open("/proc/self/smaps"):
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            parts = line.split()
            name = parts[5] if len(parts) > 5 else "[anon]"
            a, b = (int(x, 16) for x in parts[0].split("-"))
        elif line.startswith("Rss:"):
            key = name if name.startswith("[") else ("file" if "/" in name else name)
            if key == "[anon]" and a % (64 << 20) == 0 and b - a <= 64 << 20:
                key = "arenas"
            cat[key] += int(line.split()[1]) / 1e6
    return cat


def mark(what):
    c, mi = by_mapping(), mallinfo()
    print(
        f"{what:<34} rss={sum(c.values()):.3f} heap={c['[heap]']:.3f} arenas={c['arenas']:.3f} "
        f"file={c['file']:.3f} anon={c['[anon]']:.3f} | in_use={mi.uordblks / 1e9:.3f} "
        f"free={mi.fordblks / 1e9:.3f} mmapped={mi.hblkhd / 1e9:.3f} cpu={time.process_time():.1f}",
        flush=True,
    )


mark("python")
import bpy  # noqa: E402

mark("import bpy")
bpy.ops.wm.open_mainfile(filepath=str(Path(sys.argv[1]).resolve()), load_ui=False)
bpy.context.view_layer.update()
mark("file opened, evaluated")
from hr_addon import register  # noqa: E402
from hr_addon.blender.scene_in import out_of_depsgraph  # noqa: E402
from hr_addon.blender.settings import BakeConfig  # noqa: E402
from hr_addon.blender.snapshot import read_snapshot  # noqa: E402
from hr_addon.core.parallel import release_free_memory  # noqa: E402

register()
scene, vl = bpy.context.scene, bpy.context.view_layer
snap = read_snapshot(scene, vl, BakeConfig.resolve(scene.hr), lambda w: None, log=lambda s: None)
mark("read_snapshot")
hidden = out_of_depsgraph(snap.objects, vl)
mark(f"out_of_depsgraph ({len(hidden)} hidden)")
release_free_memory()
mark("  trimmed")
del snap
gc.collect()
release_free_memory()
mark("Snapshot dropped, trimmed")
d = bpy.data
print(f"objects {len(d.objects)} meshes {len(d.meshes)} materials {len(d.materials)} images {len(d.images)}")
