"""What the orientation check turns around in the artist room (hr_testing/artist_room.py) with a
Vertex Spacing, judged per user's face (MeshInput.face_group, the bake's) and per subdivided polygon
(as before branch orient21), against the bake without a spacing: polygons per object. Only the
check runs (the bake's scene input, patches and ray backend; no hierarchy).

    python benchmarks/orient_spacing.py --spacing 0.25 --out benchmarks/out/orient21_artist_room.json
"""

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def turned(mesh):
    from hr_addon.core.geometry import prepare_patches
    from hr_addon.core.orientation import _voters, find_reversed
    from hr_addon.core.visibility import make_backend

    pt = prepare_patches(mesh)
    t0 = time.process_time()
    _, reasons = find_reversed(pt, make_backend(pt.triangles, "auto", 1))
    cpu = time.process_time() - t0
    voters = _voters(pt)
    per = {}
    for p, why in reasons.items():
        name = pt.object_names[int(pt.object_id[np.flatnonzero(voters == p)[0]])]
        per[f"{name} ({why})"] = per.get(f"{name} ({why})", 0) + 1
    return {"polygons": len(mesh.loop_start), "turned": per, "check_cpu_s": round(cpu, 2)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spacing", type=float, default=0.25)
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--out")
    args = ap.parse_args()
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    from hr_addon.blender.own_values import ensure_own_values
    from hr_addon.blender.scene_in import collect_geometry, geometry_objects
    from hr_testing.artist_room import artist_room

    scene, _ = artist_room(small=args.small)
    out = {}
    for spacing in (0.0, args.spacing):
        vl = bpy.context.view_layer
        ensure_own_values(geometry_objects(vl), scene.hr.domain, vl.depsgraph, spacing)
        mesh = collect_geometry(vl, vl.depsgraph).mesh
        out[f"spacing {spacing:g}, by face"] = turned(mesh)
        if mesh.face_group is not None:
            mesh.face_group = None
            out[f"spacing {spacing:g}, by polygon"] = turned(mesh)
    print(json.dumps(out, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
