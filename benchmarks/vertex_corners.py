"""The corners Vertex Spacing makes of a scene, counted without baking (own_values.face_edges and the
group's level rule), and what the corner budget (own_values.corner_budget) does to it
(docs/accuracy.md, session 23, branch vx26).

    .venv/bin/python benchmarks/vertex_corners.py sample_blends/furnished.blend --spacings 0.35,0.25,0.2,0.15
    .venv/bin/python benchmarks/vertex_corners.py --artist --spacings 0.25       # hr_testing.artist_room
    .venv/bin/python benchmarks/vertex_corners.py --furnished 100k --spacings 0.25  # furnished_room's room
    .venv/bin/python benchmarks/vertex_corners.py --terrain 1000,100 --spacings 0.25  # a plane of n x n quads

Per spacing: the objects that get the subdividing group (has_coarse_edges), the scene's corners
(the evaluated meshes' loops, the finer objects' at the group's levels), the budget and, when the
scene exceeds it, the raised spacings (one common spacing since session 31; near_clutter's finer
objects counted too, as ensure_own_values counts them). --json writes the figures.
The file is not changed (nothing is baked, no modifier is made).
"""

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(ROOT, "scripts"))


def terrain(ms, size, n):
    """A size x size m plane of n x n quads (a terrain) and a lamp above it."""
    step = size / n
    verts = [(i * step, j * step, 0.0) for j in range(n + 1) for i in range(n + 1)]
    faces = [
        [j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i]
        for j in range(n)
        for i in range(n)
    ]
    ms.mesh_object("Terrain", verts, faces, ms.diffuse("Ground", (0.5,) * 3))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("blend", nargs="?")
    p.add_argument("--artist", action="store_true", help="hr_testing.artist_room.artist_room()")
    p.add_argument("--furnished", metavar="SIZE", help="bench_live.make_furnished's room (20k, 100k)")
    p.add_argument("--terrain", metavar="SIZE,N", help="a SIZE m plane of N x N quads")
    p.add_argument("--spacings", default="0.35,0.25,0.2,0.15")
    p.add_argument("--json")
    a = p.parse_args()
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    if a.blend:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(a.blend), load_ui=False)
        name = os.path.basename(a.blend)
    elif a.artist:
        from hr_testing.artist_room import artist_room

        artist_room()
        name = "artist_room"
    elif a.furnished:
        import tempfile

        from bench_live import make_furnished

        make_furnished(tempfile.mkdtemp(), a.furnished)
        name = f"furnished_{a.furnished}"
    else:
        import make_samples as ms

        size, n = a.terrain.split(",")
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        terrain(ms, float(size), int(n))
        name = f"terrain_{size}_{n}"
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.lights_in import light_edges
    from hr_addon.blender.scene_in import geometry_objects

    scene = bpy.context.scene
    vl = scene.view_layers[0]
    dg = vl.depsgraph
    dg.update()
    objects = geometry_objects(vl)
    own = [o for o in objects if o.data.library is None and o.library is None]
    t_edges = time.process_time()
    edges = light_edges(scene, vl)  # (the light shapes' outlines, spot lights' cones over the frames)
    t_edges = time.process_time() - t_edges
    out = {"scene": name, "objects": len(objects), "spacings": {}}
    for s in (float(x) for x in a.spacings.split(",")):
        t0 = time.process_time()
        t1 = time.process_time()
        # (ensure_own_values leaves shared meshes out too)
        clutter = ov._cluttered(objects, own, s, dg, *edges)
        t_clutter = time.process_time() - t1
        finer = [o for o in own if ov.has_coarse_edges(o, s, dg) or o.name in clutter]
        # (as ensure_own_values)
        changed, counts, fine = ov.corner_budget(objects, finer, s, dg, clutter=clutter)
        raised = {n: v for n, v in changed.items() if v is None or v > s}
        dt = time.process_time() - t0
        own_c, want, got = (
            counts if counts else (sum(len(o.evaluated_get(dg).data.loops) for o in objects),) * 3
        )
        finer = [o for o in finer if ov.has_coarse_edges(o, s, dg) or o.name in fine]  # (ensure_own_values')
        r = dict(
            subdivided=len(finer),
            own_corners=own_c,
            corners=want,
            budget=ov.budget(own_c),
            with_budget=got,
            raised={n: v for n, v in sorted(raised.items())},
            clutter_faces={n: int((v > 0).sum()) for n, v in sorted(fine.items())},
            clutter_area={n: round(float(clutter[n][1][v > 0].sum()), 4) for n, v in sorted(fine.items())},
            clutter_candidates=len(clutter),
            near_clutter_cpu_s=round(t_clutter, 3),
            light_edges_cpu_s=round(t_edges, 3),
            count_cpu_s=round(dt, 3),
        )
        out["spacings"][f"{s:g}"] = r
        print(
            f"{name} at {s:g} m: {len(finer)} of {len(objects)} objects subdivided, own corners {own_c:,}, "
            f"at the spacing {want:,} (x{want / own_c:.2f}), budget {ov.budget(own_c):,}, with it {got:,}; "
            f"raised {len(raised)}"
            + (": " + ov.budget_line(raised, s, counts) if raised else "")
            + (f"; {ov.clutter_line(fine, clutter, s)}" if fine else "")
            + f" ({dt:.2f} s CPU)",
            flush=True,
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
