"""How many polygons core/orientation.find_reversed turns around on each scene, by object and
reason: the artist-made room (small and full) and the samples (sample_blends/), read through
collect_geometry as the bake reads them; the core Cornell box, the clutter room, the furnished 20k
(seeds 1, 2) and 100k rooms, the daylight room and the two rooms (docs/accuracy.md, "An artist-made
room"). Per scene also the turned polygons' indices, to compare two checkouts polygon by polygon.

    python benchmarks/orient_counts.py OUT.json [--repo DIR]   # DIR: the checkout whose hr_addon runs
"""

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path


def blender_meshes():
    """{name: MeshInput} of the scenes built or opened in Blender."""
    from hr_testing.artist_room import artist_room
    from hr_testing.blend import SAMPLES, load_bpy, open_sample

    bpy = load_bpy()
    from hr_addon.blender.scene_in import collect_geometry

    def mesh():
        return collect_geometry(bpy.context.view_layer, bpy.context.evaluated_depsgraph_get()).mesh

    out = {}
    for small in (True, False):
        artist_room(small=small)
        out["artist small" if small else "artist full"] = mesh()
    for name in sorted(p.stem for p in SAMPLES.glob("*.blend")):
        open_sample(name, tempfile.mkdtemp())
        out[f"{name} sample"] = mesh()
    return out


def core_meshes():
    from hr_testing import clutter, furnished, scenes, two_rooms

    yield "Cornell box (core)", scenes.cornell_box()
    yield "clutter", clutter.clutter_room()[0]
    yield "furnished 20k seed 1", furnished.furnished_room("20k", 1)[0]
    yield "furnished 20k seed 2", furnished.furnished_room("20k", 2)[0]
    yield "daylight 20k", furnished.daylight_room("20k")[0]
    yield "furnished 100k", furnished.furnished_room("100k", 1)[0]
    yield "two rooms", two_rooms.two_rooms()[0]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--repo", default=str(Path(__file__).resolve().parents[1]))
    a = ap.parse_args()
    sys.path.insert(0, a.repo)
    from hr_addon.core import orientation
    from hr_addon.core.geometry import prepare_patches
    from hr_addon.core.visibility import make_backend

    res = {}
    for name, mesh in [*blender_meshes().items(), *core_meshes()]:
        t = time.process_time()
        pt = prepare_patches(mesh)
        _, reasons = orientation.find_reversed(pt, make_backend(pt.triangles, "auto", 1))
        first = {int(p): int(o) for o, p in zip(pt.object_id, pt.poly)}
        by = Counter(f"{mesh.object_names[first[p]]}: {r}" for p, r in reasons.items())
        res[name] = dict(polygons=len(mesh.loop_start), turned=len(reasons), by=dict(by))
        res[name]["cpu_s"] = round(time.process_time() - t, 2)
        print(name, res[name], flush=True)
        res[name]["polys"] = sorted(int(p) for p in reasons)
    res["repo"] = a.repo
    Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
