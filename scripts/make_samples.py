"""Generate the sample scenes in sample_blends/ with bpy (Blender as a Python module).

    .venv/bin/python scripts/make_samples.py [--out sample_blends] [names...]

cornell     Cornell box (hr_testing/scenes.py numbers: metres, z up), walls 8x8 quads, ceiling
            light as an emissive mesh; a window (2x2 panes) appears on the green wall at frame 6,
            a patch on the back wall at frame 13, the window disappears at frame 21.
moonlight   room; an irregular moonlight patch on the floor whose emission strength is keyframed.
curtain     room; a slit on a wall widening into a window (keyframed scale).
searchbeam  room; an ellipse sweeping the back wall (keyframed location).
office      room with a desk and two monitors whose screens switch on (frames 4 and 8).
furnished   hr_testing/furnished.py's furnished room of ~20k triangles (850 objects: tables,
            chairs, bookcases full of books, a sofa, spheres, vases, cups, boxes) lit by a ceiling
            panel; a window patch on the west wall is on from frame 3 to frame 7.
policespot  room at dusk (a deep blue World through a window opening) with a spot light turning
            once round a vertical axis in 30 frames (keyframed rotation, linear): its footprint
            sweeps every wall; a table, a cabinet and a crate cast shadows.
daylight    room with a window opening (no glass) in the south wall, a World sky and a sun whose
            rotation (and colour) is keyframed from a low morning sun through noon to a low
            evening sun: the sun patch moves across the floor and the walls.

policespot and daylight use Blender lights and the World instead of light shapes (issue 20).
Every light shape lies exactly on the plane of the surface it lights (same float32 coordinate),
has its origin on that plane and only moves / scales within it.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402

import hr_addon  # noqa: E402
from hr_testing import scenes  # noqa: E402
from hr_testing.scenes import grid  # noqa: E402

SUBDIV = 8


# --- helpers ------------------------------------------------------------------------------------


def reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    try:
        hr_addon.register()
    except ValueError:  # already registered in this process
        pass
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 16
    scene.cycles.max_bounces = 16
    scene.cycles.diffuse_bounces = 16
    scene.cycles.sample_clamp_indirect = 0.0
    scene.render.resolution_x, scene.render.resolution_y = 320, 240
    scene.view_settings.view_transform = "Standard"
    scene.render.use_lock_interface = True
    world = bpy.data.worlds.new("World")
    world.color = (0, 0, 0)
    if world.node_tree is not None:
        bg = world.node_tree.nodes.get("Background")
        if bg is not None:
            bg.inputs["Strength"].default_value = 0.0
    scene.world = world
    return scene


def _bare_material(name):
    """A new material whose node tree holds only its Material Output."""
    m = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        m.use_nodes = True
    for n in list(m.node_tree.nodes):
        if n.type != "OUTPUT_MATERIAL":
            m.node_tree.nodes.remove(n)
    return m, m.node_tree


def diffuse(name, rgb):
    m, t = _bare_material(name)
    d = t.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (*rgb, 1)
    t.links.new(d.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    m.diffuse_color = (*rgb, 1)
    return m


def principled(name, rgb, emission=(1, 1, 1), strength=0.0):
    m = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        m.use_nodes = True
    b = m.node_tree.nodes["Principled BSDF"]
    b.inputs["Base Color"].default_value = (*rgb, 1)
    b.inputs["Emission Color"].default_value = (*emission, 1)
    b.inputs["Emission Strength"].default_value = strength
    b.inputs["Roughness"].default_value = 1.0
    m.diffuse_color = (*rgb, 1)
    return m


def emission(name, rgb, strength):
    m, t = _bare_material(name)
    e = t.nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = (*rgb, 1)
    e.inputs["Strength"].default_value = strength
    t.links.new(e.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    return m


def mesh_object(name, verts, polys, material=None, location=(0, 0, 0)):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [list(map(int, p)) for p in polys])
    me.validate()
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def from_mesh_input(mi, object_ids):
    """Vertices and polygons of the given objects of a core MeshInput (vertices compacted)."""
    sel = np.flatnonzero(np.isin(mi.object_id, list(object_ids)))
    polys = [mi.loop_verts[mi.loop_start[i] : mi.loop_start[i] + mi.loop_total[i]] for i in sel]
    used = np.unique(np.concatenate(polys))
    remap = {int(v): k for k, v in enumerate(used)}
    return mi.verts[used], [[remap[int(v)] for v in p] for p in polys]


def orient(quad, towards):
    q = np.asarray(quad, float)
    n = np.cross(q[1] - q[0], q[2] - q[0])
    return q[::-1] if np.dot(n, np.asarray(towards, float) - q.mean(0)) < 0 else q


def box_quads(lo, hi, inward, skip=()):
    """Six faces of an axis-aligned box as named quads, normals in or out."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = (lo + hi) / 2
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    faces = {
        "floor": [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],
        "ceiling": [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],
        "wall_x0": [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)],
        "wall_x1": [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)],
        "wall_y0": [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],
        "wall_y1": [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],
    }
    out = {}
    for k, q in faces.items():
        if k in skip:
            continue
        q = np.array(q)
        target = c if inward else 2 * q.mean(0) - c
        out[k] = orient(q, target)
    return out


def quads_object(name, quads, material, subdiv=1):
    verts, polys = [], []
    for q in quads:
        v, p = grid(q, subdiv)
        polys += [[i + sum(len(x) for x in verts) for i in pp] for pp in p]
        verts.append(v)
    return mesh_object(name, np.concatenate(verts), polys, material)


def room(size, materials, subdiv=SUBDIV, openings=None):
    """Inward-facing room walls, one object each (subdiv x subdiv quads). openings: {wall name:
    (lo, hi)} world-space corners of a hole in that wall (wall_with_opening)."""
    objs = {}
    openings = openings or {}
    for k, q in box_quads((0, 0, 0), size, inward=True).items():
        mat = materials.get(k, materials["default"])
        if k in openings:
            objs[k] = wall_with_opening(k, q, openings[k], mat, subdiv)
        else:
            objs[k] = quads_object(k, [q], mat, subdiv)
    return objs


def wall_with_opening(name, quad, hole, material, cells=SUBDIV):
    """A rectangular wall (corners a, b, c, d, wound as it should face) as a grid whose lines
    include the edges of the opening, without the cells inside it: a window without glass whose
    edges the cells around it share (no T-junctions, no cracks for light to leak through).
    hole: (lo, hi), world-space corners of the opening on the wall."""
    a, b, _, d = np.asarray(quad, float)
    u, v = b - a, d - a
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    lo, hi = np.asarray(hole, float)

    def lines(axis, length):
        edges = sorted(float((p - a) @ axis) for p in (lo, hi))  # metres along the axis
        if not 0 < edges[0] < edges[1] < length:
            raise ValueError(f"the opening in '{name}' does not lie inside the wall")
        regular = np.linspace(0, length, cells + 1)
        keep = [t for t in regular if min(abs(t - e) for e in edges) > 0.25 * length / cells]
        return np.array(sorted(keep + edges)), edges  # regular lines too close to an edge dropped

    us, (u0, u1) = lines(u / lu, lu)
    vs, (v0, v1) = lines(v / lv, lv)
    verts = a + us[:, None, None] * (u / lu) + vs[None, :, None] * (v / lv)
    idx = np.arange(len(us) * len(vs)).reshape(len(us), len(vs))
    polys = [
        [idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]]
        for i in range(len(us) - 1)
        for j in range(len(vs) - 1)
        if not (u0 < (us[i] + us[i + 1]) / 2 < u1 and v0 < (vs[j] + vs[j + 1]) / 2 < v1)
    ]
    used = np.unique(polys)  # the vertices inside the opening belong to no cell
    remap = np.zeros(idx.size, int)
    remap[used] = np.arange(len(used))
    return mesh_object(name, verts.reshape(-1, 3)[used], [list(remap[p]) for p in polys], material)


def light_shape(name, verts, polys, material, location=(0, 0, 0)):
    ob = mesh_object(name, verts, polys, material, location)
    ob.hr.is_light_shape = True
    for attr in (
        "visible_camera",
        "visible_diffuse",
        "visible_glossy",
        "visible_transmission",
        "visible_volume_scatter",
        "visible_shadow",
    ):
        setattr(ob, attr, False)
    ob.show_in_front = True
    return ob


def key_visibility(ob, frames_on):
    """hide_render keyframes: visible exactly in the given [start, end) intervals."""
    keys = {1: True}
    for a, b in frames_on:
        keys[a] = False
        if b is not None:
            keys[b] = True
    for f, hidden in sorted(keys.items()):
        ob.hide_render = hidden
        ob.keyframe_insert("hide_render", frame=f)


def constant_interpolation(ob):
    interpolation(ob, "CONSTANT")


def interpolation(block, kind):
    """Every keyframe of an object's (or a light's) action gets interpolation `kind`."""
    ad = block.animation_data
    if ad is None or ad.action is None:
        return
    for fc in _fcurves(ad.action):
        for kp in fc.keyframe_points:
            kp.interpolation = kind


def _fcurves(action):
    if hasattr(action, "fcurves") and bpy.app.version < (5, 0, 0):
        return list(action.fcurves)
    out = []
    for layer in getattr(action, "layers", []):
        for strip in layer.strips:
            for bag in strip.channelbags:
                out += list(bag.fcurves)
    return out


def camera(location, target, lens=35):
    cam = bpy.data.cameras.new("Camera")
    cam.lens = lens
    ob = bpy.data.objects.new("Camera", cam)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = location
    ob.rotation_euler = pointing(np.asarray(target, float) - np.asarray(location, float))
    bpy.context.scene.camera = ob
    return ob


def pointing(direction, compat=None):
    """The Euler rotation that turns an object's -Z (a camera's view, a light's beam) along
    `direction`, its Y up; compat: the previous key's rotation (no 360-degree jumps between keys)."""
    from mathutils import Vector

    q = Vector(tuple(map(float, direction))).to_track_quat("-Z", "Y")
    return q.to_euler("XYZ", compat) if compat is not None else q.to_euler()


def light(name, kind, location=(0, 0, 0), **settings):
    """A Blender light object of `kind` with the light data's `settings` (energy, color, ...)."""
    ld = bpy.data.lights.new(name, kind)
    for k, v in settings.items():
        setattr(ld, k, v)
    ob = bpy.data.objects.new(name, ld)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def sky(rgb, strength):
    """The scene's World as a uniform sky: its Background node's colour and strength."""
    world = bpy.context.scene.world
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*rgb, 1)
    bg.inputs["Strength"].default_value = strength
    world.color = rgb  # the viewport's World colour
    return world


def finish(scene, path, frames, quality="DRAFT"):
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    scene.hr.quality = quality
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()  # no .blend1 backup next to the committed file
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True, check_existing=False)
    print(f"wrote {path} ({path.stat().st_size // 1024} KB)", flush=True)


# --- scenes -------------------------------------------------------------------------------------

# Window on the green wall (plane x = 0, normal +x): 2x2 panes, centre (y, z) = (0.28, 0.30).
WINDOW_CENTRE = (0.28, 0.30)
WINDOW_PANE, WINDOW_BAR = 0.09, 0.02
WINDOW_EMISSION = ((1.0, 0.95, 0.85), 8.0)
# Patch on the back wall (plane y = 0.5592, normal -y).
BACK_Y = 0.5592
PATCH_RECT = (0.20, 0.36, 0.26, 0.38)  # x0, x1, z0, z1
PATCH_EMISSION = ((0.6, 0.7, 1.0), 6.0)
CORNELL_FRAMES = (1, 24)
WINDOW_ON = (6, 21)
PATCH_ON = 13


def window_polys():
    cy, cz = WINDOW_CENTRE
    p, b = WINDOW_PANE, WINDOW_BAR
    verts, polys = [], []
    for dy in (-(b / 2 + p), b / 2):
        for dz in (-(b / 2 + p), b / 2):
            y0, z0 = cy + dy, cz + dz
            k = len(verts)
            verts += [(0.0, y0, z0), (0.0, y0 + p, z0), (0.0, y0 + p, z0 + p), (0.0, y0, z0 + p)]
            polys.append([k, k + 1, k + 2, k + 3])  # normal +x
    return verts, polys


def patch_polys():
    x0, x1, z0, z1 = PATCH_RECT
    return [(x0, BACK_Y, z0), (x1, BACK_Y, z0), (x1, BACK_Y, z1), (x0, BACK_Y, z1)], [
        [0, 1, 2, 3]
    ]  # normal -y


def make_cornell(path):
    scene = reset()
    mi = scenes.cornell_box(subdiv=SUBDIV, light=True)
    names = list(mi.object_names)
    white = diffuse("White", scenes.WHITE)
    mats = {"red": diffuse("Red", scenes.RED), "green": diffuse("Green", scenes.GREEN), "white": white}
    block = principled("Block White", scenes.WHITE)
    light_rgb = np.array(scenes.CORNELL_LIGHT) / max(scenes.CORNELL_LIGHT)
    light_mat = principled("Ceiling Light", (0.78, 0.78, 0.78), tuple(light_rgb), max(scenes.CORNELL_LIGHT))
    for i, n in enumerate(names):
        if n.startswith(("short_block", "tall_block")):
            continue
        mat = (
            mats["red"]
            if "red" in n
            else mats["green"]
            if "green" in n
            else light_mat
            if n == "light"
            else white
        )
        v, p = from_mesh_input(mi, [i])
        mesh_object(n, v, p, mat)
    for blk in ("short_block", "tall_block"):
        ids = [i for i, n in enumerate(names) if n.startswith(blk)]
        v, p = from_mesh_input(mi, ids)
        mesh_object(blk, v, p, block)
    wv, wp = window_polys()
    win = light_shape("Window", wv, wp, principled("Window Light", (0, 0, 0), *WINDOW_EMISSION))
    key_visibility(win, [WINDOW_ON])
    pv, pp = patch_polys()
    patch = light_shape("Back Patch", pv, pp, emission("Patch Light", *PATCH_EMISSION))
    key_visibility(patch, [(PATCH_ON, None)])
    camera((0.278, -0.80, 0.273), (0.278, 0.28, 0.273), lens=35)
    finish(scene, path, CORNELL_FRAMES)


ROOM = (4.0, 3.0, 2.5)


def room_materials():
    return {
        "default": diffuse("Wall", (0.7, 0.7, 0.68)),
        "floor": diffuse("Floor", (0.45, 0.35, 0.25)),
        "ceiling": diffuse("Ceiling", (0.8, 0.8, 0.8)),
    }


def checker_image(name="Checker", n=8, px=64, light=(0.8, 0.62, 0.4), dark=(0.08, 0.09, 0.12)):
    """A float (linear) n x n checker image of px x px pixels, made with numpy."""
    img = bpy.data.images.new(name, px, px, float_buffer=True)
    i = np.arange(px) * n // px
    on = (i[:, None] + i[None, :]) % 2 == 0
    rgba = np.ones((px, px, 4), np.float32)
    rgba[..., :3] = np.where(on[..., None], light, dark)
    img.pixels.foreach_set(rgba.ravel())
    img.pack()
    return img


def textured_room(size=(3.0, 3.0, 2.4), light=0.8, strength=12.0, checker=8):
    """A room lit by a square ceiling emitter whose floor is a checker Image Texture (Principled
    Base Color, default UV map "UVMap" spanning the floor): the textured-surfaces test scene."""
    mats = {
        "default": diffuse("Wall", (0.7, 0.7, 0.68)),
        "wall_x0": diffuse("Red", (0.7, 0.2, 0.15)),
        "ceiling": diffuse("Ceiling", (0.8, 0.8, 0.8)),
    }
    floor_mat = principled("Checker Floor", (0.5, 0.5, 0.5))
    t = floor_mat.node_tree
    tex = t.nodes.new("ShaderNodeTexImage")
    tex.image = checker_image(n=checker)
    t.links.new(tex.outputs["Color"], t.nodes["Principled BSDF"].inputs["Base Color"])
    mats["floor"] = floor_mat
    objs = room(size, mats, subdiv=1)
    me = objs["floor"].data
    uv = me.uv_layers.new(name="UVMap")
    co = np.array([me.vertices[lp.vertex_index].co[:2] for lp in me.loops]) / np.array(size[:2])
    uv.uv.foreach_set("vector", co.astype(np.float32).ravel())
    cx, cy, z = size[0] / 2, size[1] / 2, size[2] - 0.002
    h = light / 2
    quad = [(cx - h, cy - h, z), (cx - h, cy + h, z), (cx + h, cy + h, z), (cx + h, cy - h, z)]  # faces -z
    objs["light"] = mesh_object("light", quad, [[0, 1, 2, 3]], emission("Lamp", (1.0, 0.95, 0.85), strength))
    return objs


def make_moonlight(path):
    scene = reset()
    room(ROOM, room_materials())
    quads_object(
        "Bed",
        list(box_quads((2.4, 0.3, 0.0), (3.6, 1.3, 0.45), inward=False, skip=("floor",)).values()),
        diffuse("Blanket", (0.3, 0.35, 0.6)),
        2,
    )
    # Irregular (concave) moonlight patch on the floor (plane z = 0, normal +z), an n-gon.
    pts = [(0.6, 0.9), (1.5, 0.7), (2.1, 1.2), (1.8, 1.5), (2.3, 2.2), (1.2, 2.4), (0.9, 1.7)]
    verts = [(x, y, 0.0) for x, y in pts]
    mat = emission("Moonlight", (0.55, 0.65, 1.0), 1.0)
    light_shape("Moonlight", verts, [list(range(len(verts)))], mat)
    s = mat.node_tree.nodes["Emission"].inputs["Strength"]
    for f, v in ((1, 0.5), (6, 4.0), (9, 4.0), (12, 1.5)):
        s.default_value = v
        s.keyframe_insert("default_value", frame=f)
    camera((0.2, 0.15, 2.3), (2.0, 1.8, 0.2), lens=20)
    finish(scene, path, (1, 12))


def make_curtain(path):
    scene = reset()
    room(ROOM, room_materials())
    quads_object(
        "Table",
        list(box_quads((1.2, 1.0, 0.0), (2.0, 1.8, 0.7), inward=False, skip=("floor",)).values()),
        diffuse("Wood", (0.5, 0.3, 0.15)),
        2,
    )
    # A slit on the wall x = 0 (normal +x) centred at (y, z) = (1.5, 1.4); it widens along y.
    verts = [(0.0, -0.05, -0.6), (0.0, 0.05, -0.6), (0.0, 0.05, 0.6), (0.0, -0.05, 0.6)]
    ob = light_shape(
        "Curtain Gap",
        verts,
        [[0, 1, 2, 3]],
        principled("Daylight", (0, 0, 0), (1.0, 0.97, 0.9), 6.0),
        location=(0.0, 1.5, 1.4),
    )
    for f, s in ((1, 1.0), (12, 12.0)):
        ob.scale = (1.0, s, 1.0)
        ob.keyframe_insert("scale", frame=f)
    camera((3.8, 0.2, 1.8), (0.5, 1.6, 1.0))
    finish(scene, path, (1, 12))


def make_searchbeam(path):
    scene = reset()
    room(ROOM, room_materials())
    # Ellipse (32-gon) on the back wall y = 3 (normal -y), origin on the wall, moving along x.
    t = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    verts = [(0.4 * np.cos(a), 0.0, 0.25 * np.sin(a)) for a in t]  # counter-clockwise seen from -y: normal -y
    ob = light_shape(
        "Searchbeam",
        verts,
        [list(range(32))],
        emission("Beam", (1.0, 1.0, 0.9), 20.0),
        location=(0.8, ROOM[1], 1.6),
    )
    for f, x in ((1, 0.8), (12, 3.2)):
        ob.location.x = x
        ob.keyframe_insert("location", index=0, frame=f)
    camera((2.0, 0.1, 1.4), (2.0, 3.0, 1.4), lens=20)
    finish(scene, path, (1, 12))


def make_office(path):
    scene = reset()
    room((5.0, 4.0, 2.7), room_materials())
    mesh_ceiling = quads_object(
        "Ceiling Panel",
        [
            orient(
                [(2.2, 1.7, 2.699), (2.8, 1.7, 2.699), (2.8, 2.3, 2.699), (2.2, 2.3, 2.699)], (2.5, 2.0, 0.0)
            )
        ],
        principled("Panel", (0.8, 0.8, 0.8), (1, 1, 1), 1.5),
        2,
    )
    mesh_ceiling.name = "Ceiling Panel"
    quads_object(
        "Desk",
        list(box_quads((1.5, 2.6, 0.0), (3.5, 3.4, 0.75), inward=False, skip=("floor",)).values()),
        diffuse("Desk", (0.55, 0.4, 0.25)),
        2,
    )
    screen_mats = []
    for i, x0 in enumerate((1.75, 2.65)):
        x1 = x0 + 0.6
        y0, y1, z0, z1 = 2.9, 2.95, 0.85, 1.2  # the screen is the y = 2.9 face, normal -y
        quads_object(
            f"Monitor {i + 1}",
            list(box_quads((x0, y0, z0), (x1, y1, z1), inward=False).values()),
            principled(f"Monitor Case {i + 1}", (0.05, 0.05, 0.05)),
            1,
        )
        d = 0.02
        verts = [
            (x0 + d, y0, z0 + d),
            (x1 - d, y0, z0 + d),
            (x1 - d, y0, z1 - d),
            (x0 + d, y0, z1 - d),
        ]  # normal -y
        mat = emission(f"Screen {i + 1}", (0.8, 0.9, 1.0), 5.0)
        screen_mats.append(mat)
        ob = light_shape(f"Screen {i + 1}", verts, [[0, 1, 2, 3]], mat)
        key_visibility(ob, [((4, 8)[i], None)])
    camera((2.5, 0.3, 1.6), (2.5, 3.0, 0.9), lens=24)
    finish(scene, path, (1, 10))


def make_furnished(path):
    from hr_testing.furnished import furnished_room

    scene = reset()
    mi, info = furnished_room("20k")
    mats = {}

    def material(rho, em):
        key = (tuple(np.round(rho, 2)), tuple(np.round(em, 3)))
        if key not in mats:
            if max(em) > 0:
                strength = float(max(em))
                mats[key] = emission(f"Light {len(mats)}", tuple(float(e) / strength for e in em), strength)
            else:
                mats[key] = diffuse(f"Diffuse {len(mats)}", tuple(float(x) for x in key[0]))
        return mats[key]

    first = np.searchsorted(mi.object_id, np.arange(len(mi.object_names)))  # polygons are grouped by object
    for k, name in enumerate(mi.object_names):
        verts, polys = from_mesh_input(mi, [k])
        mesh_object(name, verts, polys, material(mi.reflectance[first[k]], mi.emission[first[k]]))
    _, (o, u, v) = info["light_wall"]
    corners = [
        o + a * u + b * v for a, b in ((0.25, 0.25), (1.15, 0.25), (1.15, 0.95), (0.25, 0.95))
    ]  # faces +x
    ob = light_shape("Window", corners, [[0, 1, 2, 3]], emission("Window", (1.0, 0.95, 0.85), 12.0))
    key_visibility(ob, [(3, 8)])
    camera((5.6, 0.4, 1.7), (1.5, 3.5, 0.7), lens=20)
    finish(scene, path, (1, 10))


# policespot and daylight: Blender lights and the World, no light shapes (issue 20).
DUSK_ROOM = (5.0, 4.0, 2.6)
DUSK_WINDOW = ((0.0, 1.3, 0.9), (0.0, 2.7, 2.0))  # opening in the wall x = 0 (lo, hi corners)
DUSK_SKY = ((0.1, 0.16, 0.45), 1.0)  # deep blue, colour and strength
SPOT = dict(
    location=(2.5, 2.0, 1.7),
    tilt=np.radians(12),  # below the horizontal
    energy=500.0,
    color=(1.0, 0.92, 0.8),
    spot_size=np.radians(30),
    spot_blend=0.3,
)
SPOT_TURN = 30  # frames per revolution; the sample is frames 1-30
FURNITURE_SUBDIV = 2


def furniture(items, subdiv=FURNITURE_SUBDIV):
    """Closed boxes standing on the floor: {name: (lo, hi, material)} (no bottom face)."""
    return {
        name: quads_object(name, list(box_quads(lo, hi, inward=False, skip=("floor",)).values()), mat, subdiv)
        for name, (lo, hi, mat) in items.items()
    }


def make_policespot(path):
    scene = reset()
    room(DUSK_ROOM, room_materials(), subdiv=16, openings={"wall_x0": DUSK_WINDOW})
    wood = diffuse("Wood", (0.5, 0.3, 0.15))
    furniture(
        {
            "Table": ((3.2, 2.6, 0.0), (4.2, 3.4, 0.75), wood),
            "Cabinet": ((1.0, 3.0, 0.0), (1.5, 3.5, 1.8), diffuse("Cabinet", (0.6, 0.6, 0.55))),
            "Crate": ((3.6, 0.6, 0.0), (4.2, 1.2, 0.6), wood),
            "Post": ((2.45, 1.95, 0.0), (2.55, 2.05, 1.6), diffuse("Post", (0.2, 0.2, 0.2))),
        }
    )
    sky(*DUSK_SKY)
    s = SPOT
    ob = light(
        "Police Spot",
        "SPOT",
        s["location"],
        energy=s["energy"],
        color=s["color"],
        spot_size=s["spot_size"],
        spot_blend=s["spot_blend"],
        shadow_soft_size=0.0,  # a point source: sharp shadows
    )
    for f, yaw in ((1, 0.0), (1 + SPOT_TURN, 2 * np.pi)):  # -Z tilted from straight down, turned
        ob.rotation_euler = (np.pi / 2 - s["tilt"], 0.0, yaw)
        ob.keyframe_insert("rotation_euler", frame=f)
    interpolation(ob, "LINEAR")  # a steady turn; frame 31 would equal frame 1
    camera((4.8, 0.3, 2.3), (0.8, 3.4, 0.9), lens=16)
    finish(scene, path, (1, SPOT_TURN))


DAY_ROOM = (5.0, 4.0, 2.6)
DAY_WINDOW = ((1.8, 0.0, 0.8), (3.2, 0.0, 2.0))  # opening in the south wall y = 0 (x east, y north)
DAY_SKY = ((0.35, 0.55, 1.0), 0.8)
SUN_STRENGTH = 5.0
SUN_ANGLE = np.radians(0.5)
# frame: (azimuth from south towards east, altitude) in degrees, and the sun's colour
SUN_PATH = {
    1: ((65, 12), (1.0, 0.7, 0.45)),
    7: ((35, 35), (1.0, 0.9, 0.75)),
    13: ((0, 50), (1.0, 0.97, 0.92)),
    19: ((-35, 35), (1.0, 0.9, 0.75)),
    25: ((-65, 12), (1.0, 0.7, 0.45)),
}


def sun_direction(azimuth, altitude):
    """Unit vector from the room towards the sun (degrees; azimuth from south (-y) towards east (+x))."""
    az, alt = np.radians(azimuth), np.radians(altitude)
    return np.array([np.sin(az) * np.cos(alt), -np.cos(az) * np.cos(alt), np.sin(alt)])


def make_daylight(path):
    scene = reset()
    room(DAY_ROOM, room_materials(), subdiv=16, openings={"wall_y0": DAY_WINDOW})
    furniture(
        {
            "Table": ((1.0, 2.2, 0.0), (2.0, 3.0, 0.75), diffuse("Wood", (0.5, 0.3, 0.15))),
            "Sofa": ((4.2, 1.0, 0.0), (4.9, 2.8, 0.45), diffuse("Sofa", (0.25, 0.4, 0.3))),
            "Shelf": ((0.1, 2.6, 0.0), (0.5, 3.8, 1.6), diffuse("Shelf", (0.6, 0.6, 0.55))),
        }
    )
    sky(*DAY_SKY)
    ob = light("Sun", "SUN", (2.5, -2.0, 4.0), energy=SUN_STRENGTH, angle=SUN_ANGLE)
    rot = None
    for f, ((az, alt), rgb) in SUN_PATH.items():
        rot = pointing(-sun_direction(az, alt), rot)  # the sun shines along its -Z
        ob.rotation_euler = rot
        ob.keyframe_insert("rotation_euler", frame=f)
        ob.data.color = rgb
        ob.data.keyframe_insert("color", frame=f)
    interpolation(ob, "LINEAR")
    interpolation(ob.data, "LINEAR")
    camera((2.5, 3.85, 2.0), (2.5, 0.5, 0.7), lens=16)
    finish(scene, path, (min(SUN_PATH), max(SUN_PATH)))


MAKERS = {
    "cornell": make_cornell,
    "moonlight": make_moonlight,
    "curtain": make_curtain,
    "searchbeam": make_searchbeam,
    "office": make_office,
    "furnished": make_furnished,
    "policespot": make_policespot,
    "daylight": make_daylight,
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", choices=[[]] + list(MAKERS), default=[])
    ap.add_argument("--out", default=str(ROOT / "sample_blends"))
    args = ap.parse_args(argv)
    for name in args.names or list(MAKERS):
        MAKERS[name](Path(args.out) / f"{name}.blend")


if __name__ == "__main__":
    main()
