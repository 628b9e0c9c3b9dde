"""Blender's re-evaluation after Live's write on the furnished 100k room (session 31, reeval): a script
for profile_live_write.py's --cmd DIR (copy it there; it runs on the room that process built).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/profile_live_write.py --cmd DIR
    cp benchmarks/reeval_room_cmd.py DIR/

Per strength and colour edit (bench_live's sequence, exact): CPU ms of the edit's own depsgraph update
(Blender's, before Live reads anything), the write, the re-evaluation after it, and how much every
object's values changed against the previous write (Rows.change: the largest RGB change relative to
the object's level); then one mesh tagged, all meshes tagged, and the floor of a shader-side factor
(one node group's value in every material of the room). docs/live.md, session 31 reeval.
"""

import time

import numpy as np


def _cpu(fn):
    c0 = time.process_time()
    fn()
    return 1000 * (time.process_time() - c0)


rows, prev = [], None
for name, edit in [e for e in seq if e[0] in ("strength", "colour")]:  # noqa: F821 (--cmd globals)
    edit()
    t_edit = _cpu(vl.update)  # noqa: F821
    live._reconcile(sess, scene, vl, check_geometry=False, fast=True)  # noqa: F821
    w.flush(refine=True)  # noqa: F821
    t_write = _cpu(lambda: live._deliver(sess, scene))  # noqa: F821
    new = sess.written  # noqa: F821
    t_eval = _cpu(vl.update)  # noqa: F821
    if prev is not None and new is not None:
        rel = new.change(prev)
        print(
            f"{name}: edit update {t_edit:.1f}, write {t_write:.1f}, re-evaluation {t_eval:.1f} ms; "
            f"objects changed by > 1e-3: {int((rel > 1e-3).sum())}, "
            f"> 1e-2: {int((rel > 1e-2).sum())} of {len(rel)}; "
            f"smallest change {rel.min():.2e}, median {np.median(rel):.2e}",
            flush=True,
        )
        rows.append((t_edit, t_write, t_eval))
    prev = new
m = np.median(rows, axis=0)
print(
    f"emission edits ({len(rows)}): CPU ms median edit update {m[0]:.1f}, write {m[1]:.1f}, "
    f"re-evaluation {m[2]:.1f}"
)

meshes = [o.data for o in scene.objects if o.type == "MESH" and o is not obj]  # noqa: F821
for label, fn in (
    ("one mesh tagged", lambda i: meshes[i].update_tag()),
    ("all meshes tagged", lambda i: [m.update_tag() for m in meshes]),
):
    ts = []
    for i in range(5):
        fn(i)
        ts.append(_cpu(vl.update))  # noqa: F821
    print(
        f"{label}: view_layer.update() CPU ms median {np.median(ts):.1f} ({np.round(ts, 1).tolist()})",
        flush=True,
    )

ng = bpy.data.node_groups.new("HR probe factor", "ShaderNodeTree")  # noqa: F821
ng.interface.new_socket("Factor", in_out="OUTPUT", socket_type="NodeSocketFloat")
val = ng.nodes.new("ShaderNodeValue")
ng.links.new(val.outputs[0], ng.nodes.new("NodeGroupOutput").inputs[0])
mats = {m for o in scene.objects for m in o.data.materials if m is not None}  # noqa: F821
for m in mats:
    m.node_tree.nodes.new("ShaderNodeGroup").node_tree = ng
vl.update()  # noqa: F821
ts = []
for i in range(5):
    val.outputs[0].default_value = 1.0 + 0.01 * i
    ts.append(_cpu(vl.update))  # noqa: F821
print(
    f"a node group's value in all {len(mats)} materials: view_layer.update() CPU ms "
    f"median {np.median(ts):.1f}"
)
