"""Fit the constants of Blender's light units against Cycles itself (issue 20).

The simplest scene: a diffuse plane (base colour rho) at z = 0, an orthographic camera looking
straight down, one light; Standard view transform, no bounces matter (nothing else in the scene).
A pixel's radiance is L = rho E / pi, so the irradiance E = pi L / rho is compared with the
light's closed form. Run: .venv/bin/python scripts/measure_light_units.py [samples]
Prints one JSON line per measurement (written into docs/lights.md by hand)."""

import json
import math
import os
import sys
import tempfile

import bpy
import numpy as np

RHO = 0.5
RES = 64


def scene(ortho=0.2, samples=64):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_denoising = False
    sc.cycles.use_adaptive_sampling = False
    sc.cycles.max_bounces = 0
    sc.cycles.seed = 1
    sc.render.resolution_x = sc.render.resolution_y = RES
    sc.render.resolution_percentage = 100
    sc.render.filter_size = 0.01
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0
    sc.view_settings.gamma = 1
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.world = None
    me = bpy.data.meshes.new("plane")
    s = 50.0
    me.from_pydata([(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new("plane", me)
    sc.collection.objects.link(ob)
    mat = bpy.data.materials.new("m")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    d = nt.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (RHO, RHO, RHO, 1)
    o = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(d.outputs[0], o.inputs[0])
    me.materials.append(mat)
    cam = bpy.data.cameras.new("cam")
    cam.type = "ORTHO"
    cam.ortho_scale = ortho
    co = bpy.data.objects.new("cam", cam)
    co.location = (0, 0, 10)
    sc.collection.objects.link(co)
    sc.camera = co
    return sc


def light(sc, kind, loc=(0, 0, 2), rot=(0, 0, 0), **props):
    ld = bpy.data.lights.new(kind, kind)
    for k, v in props.items():
        setattr(ld, k, v)
    ob = bpy.data.objects.new(kind, ld)
    ob.location = loc
    ob.rotation_euler = rot
    ob.visible_camera = False
    sc.collection.objects.link(ob)
    return ob


def render(sc):
    path = os.path.join(tempfile.mkdtemp(), "r.exr")
    sc.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    px = np.array(img.pixels[:], dtype=np.float64).reshape(RES, RES, 4)[..., 0]
    bpy.data.images.remove(img)
    return px  # row 0 = bottom (y = -ortho/2)


def centre(px, k=8):
    c = RES // 2
    v = px[c - k : c + k, c - k : c + k]
    return float(v.mean()), float(v.std() / math.sqrt(v.size))


def rect_factor(a, b, h):
    """Form factor from a point on the axis of a parallel a x b rectangle at distance h."""
    x, y = a / 2 / h, b / 2 / h
    f = lambda x, y: (
        (x / math.sqrt(1 + x * x)) * math.atan(y / math.sqrt(1 + x * x))
        + (y / math.sqrt(1 + y * y)) * math.atan(x / math.sqrt(1 + y * y))
    )
    return 4 * f(x, y) / (2 * math.pi)


def main(samples):
    out = []
    h, P = 2.0, 100.0
    # point light, radius 0: E = K P / h^2; radius 0.5 (a sphere light): the same K this far away?
    for label, radius in (("POINT", 0.0), ("POINT r=0.5", 0.5)):
        sc = scene(samples=samples)
        light(sc, "POINT", energy=P, shadow_soft_size=radius)
        L, se = centre(render(sc))
        E = math.pi * L / RHO
        K = E * h * h / P
        out.append(dict(light=label, P=P, h=h, L=L, se=L and se / L, K=K, K_x_4pi=K * 4 * math.pi))
    # sun: E = K S cos
    for tilt in (0.0, 60.0):
        sc = scene(samples=samples)
        light(sc, "SUN", rot=(math.radians(tilt), 0, 0), energy=3.0, angle=0.0)
        L, se = centre(render(sc))
        E = math.pi * L / RHO
        out.append(
            dict(light=f"SUN tilt {tilt}", S=3.0, L=L, se=se / L, K=E / 3.0 / math.cos(math.radians(tilt)))
        )
    # area square 1 m at h: E = pi L_e F, L_e = K P / A
    for shape, sx, sy in (("SQUARE", 1.0, 1.0), ("RECTANGLE", 1.0, 0.5)):
        sc = scene(samples=samples)
        props = dict(energy=P, shape=shape, size=sx)
        if shape == "RECTANGLE":
            props["size_y"] = sy
        light(sc, "AREA", **props)
        L, se = centre(render(sc))
        E = math.pi * L / RHO
        F = rect_factor(sx, sy, h)
        Le = E / (math.pi * F)
        out.append(
            dict(
                light=f"AREA {shape}",
                P=P,
                A=sx * sy,
                L=L,
                se=se / L,
                F=F,
                K=Le * sx * sy / P,
                K_x_pi=Le * sx * sy / P * math.pi,
            )
        )
    # spot: profile across the cone edge (ortho 3 m wide at h = 2)
    ortho = 4.0
    sc = scene(ortho=ortho, samples=samples)
    size, blend = math.radians(60.0), 0.5
    light(sc, "SPOT", energy=P, spot_size=size, spot_blend=blend, shadow_soft_size=0.0)
    px = render(sc)
    row = px[RES // 2 - 2 : RES // 2 + 2].mean(0)
    x = (np.arange(RES) + 0.5) / RES * ortho - ortho / 2
    r2 = x * x + h * h
    cos = h / np.sqrt(r2)
    K = out[0]["K"]
    att = (math.pi * row / RHO) / (K * P * cos / r2)
    # Cycles 4.x+: smoothstep((cos_angle - cos_half) / ((1 - cos_half) * blend))? fit candidates
    ch = math.cos(size / 2)
    t = np.clip((cos - ch) / ((1 - ch) * blend), 0, 1)
    cand_a = t * t * (3 - 2 * t)
    out.append(
        dict(
            light="SPOT",
            size_deg=60,
            blend=blend,
            x=x.round(4).tolist(),
            att=att.round(4).tolist(),
            cand_smoothstep=cand_a.round(4).tolist(),
            max_abs_diff=float(np.abs(att - cand_a).max()),
        )
    )
    for o in out:
        print("MEASURE " + json.dumps(o))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 64)
