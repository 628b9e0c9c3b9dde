"""Check (bpy, ~2 s): the light shapes of the sample scenes face the way of the surface they lie on.

Found by the Cycles comparison (docs/accuracy.md): docs/user_guide.md says a light shape's "normal
must face the same way as the surface", but 'Back Patch' (cornell), 'Searchbeam' (searchbeam) and
'Screen 1' / 'Screen 2' (office) were wound +y, into the wall / monitor, while make_samples.py's
comments said -y. The core accepts either winding silently (events._find_surface takes coplanar
surfaces facing either way and emits on the surface's side), so the bakes were as intended, but a
one-sided Cycles emitter made from these objects lit the inside of the wall. make_samples.py now
winds them -y; this script fails (exit status 1) if a sample shape faces into its surface again.
"""

import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main():
    import bpy
    import hr_addon
    from hr_addon.blender.scene_in import collect_geometry, light_shape_objects, read_mesh

    hr_addon.register()
    bad = []
    for name in ("cornell", "moonlight", "curtain", "searchbeam", "office"):
        bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "sample_blends", f"{name}.blend"), load_ui=False)
        vl = bpy.context.view_layer
        mesh = collect_geometry(vl, vl.depsgraph).mesh
        for ob in light_shape_objects(vl, include_hidden=True):
            em = read_mesh(ob, vl.depsgraph)
            for s, k in zip(em.loop_start, em.loop_total):
                ring = em.verts[em.loop_verts[s : s + k]]
                n = np.cross(ring[1] - ring[0], ring[2] - ring[0])
                n /= np.linalg.norm(n)
                for ps, pk in zip(mesh.loop_start, mesh.loop_total):
                    q = mesh.verts[mesh.loop_verts[ps : ps + pk]]
                    qn = np.cross(q[1] - q[0], q[2] - q[0])
                    qn /= np.linalg.norm(qn)
                    if abs(qn @ n) > 0.999 and np.abs((q - ring[0]) @ qn).max() < 1e-4:
                        ok = qn @ n > 0
                        print(
                            f"{name:10s} {ob.name:12s} shape normal {np.round(n, 3)} surface normal "
                            f"{np.round(qn, 3)}: {'ok' if ok else 'FACES INTO THE SURFACE'}"
                        )
                        if not ok:
                            bad.append((name, ob.name))
                        break
                break  # first polygon of each shape is enough
    if bad:
        print(f"FAIL: {bad}")
        sys.exit(1)


if __name__ == "__main__":
    main()
