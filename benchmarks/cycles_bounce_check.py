"""What Cycles' Diffuse bake counts as a bounce (hr_testing.cycles_ref.bake(bounces=...)), on a
tiny scene: a floor lit by an emitter (a light shape's proxy: Transparent + one-sided Emission,
or an opaque one-sided emitter) beside a wall. Its floor (H / pi = bake / rho) at bounces 0 must
equal the DIRECT pass at 64 bounces, and the INDIRECT pass at bounces 0 must be 0; the floor sees
no other floor, so its indirect at bounces 1 is the wall's first reflection alone and must not
change with the floor's reflectance (at 2 and more it does: floor -> wall -> floor).

    .venv/bin/python benchmarks/cycles_bounce_check.py [spp=1024]
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from hr_testing import cycles_ref as C  # noqa: E402
from hr_testing.blend import load_bpy  # noqa: E402

spp = int(sys.argv[1].split("=")[1]) if len(sys.argv) > 1 else 1024
bpy = load_bpy()


def quad(name, v, rho, emission=(0, 0, 0), transparent=False):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(p) for p in v], [], [[0, 1, 2, 3]])
    me.materials.append(C.one_sided_material(name, rho, emission, transparent))
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def run(rho_floor, transparent):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    floor = quad("floor", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], (rho_floor,) * 3)
    quad("wall", [(1, 0, 0), (1, 0, 1), (1, 1, 1), (1, 1, 0)], (0.8,) * 3)  # faces -x
    em = quad(
        "emitter",
        [(0.1, 0.3, 0.8), (0.1, 0.7, 0.8), (0.4, 0.7, 0.8), (0.4, 0.3, 0.8)],
        (0, 0, 0),
        (10, 10, 10),
        transparent,
    )  # faces -z
    em.hide_select = False
    at = C.Atlas.build(floor, 0.05)
    img = bpy.data.images.new("floor_img", at.width, at.height, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    tex = floor.data.materials[0].node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    floor.data.materials[0].node_tree.nodes.active = tex
    for ob in (o for o in sc.objects if o is not floor):  # only the floor is baked (needs a UV map too)
        ob.data.uv_layers.new(name=C.UV_NAME)
    rs = C.RefScene(sc, bpy.context.view_layer, ["floor"], {"floor": at}, {"floor": img}, None, {})
    out = {}
    for key, bounces, passes in (
        ("full_b0", 0, ("DIRECT", "INDIRECT")),
        ("direct_b64", 64, ("DIRECT",)),
        ("indirect_b0", 0, ("INDIRECT",)),
        ("full_b1", 1, ("DIRECT", "INDIRECT")),
        ("full_b2", 2, ("DIRECT", "INDIRECT")),
        ("full_b64", 64, ("DIRECT", "INDIRECT")),
    ):
        v, _, mask = C.bake(rs, spp, seed=1, passes=passes, bounces=bounces)
        out[key] = float(v["floor"][mask["floor"]].mean() / rho_floor)  # H / pi, grey
    return out


for transparent in (True, False):
    r = {rho: run(rho, transparent) for rho in (0.5, 0.25)}
    print(f"emitter {'transparent proxy' if transparent else 'opaque'}: floor H/pi (spp {spp})")
    for rho, o in r.items():
        print(f"  rho_floor {rho}: " + ", ".join(f"{k} {v:.5f}" for k, v in o.items()))
    for rho, o in r.items():
        print(
            f"  rho_floor {rho}: bounce 1 adds {o['full_b1'] - o['full_b0']:.5f}, 2 adds "
            f"{o['full_b2'] - o['full_b1']:.5f}, the rest {o['full_b64'] - o['full_b2']:.5f}"
        )
