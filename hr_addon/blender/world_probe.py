"""A World node setup the bake cannot read (a Sky Texture, a rotated or mixed environment, a
gradient...) rendered once with Cycles into the lat-long table a diffuse solution needs
(core.sky), and each Sky Texture's sun disc measured as a sun: a disc of half a degree is a few
pixels of the table, which camera rays and the bake's cosine-weighted sky rays both sample poorly,
while a SUN light gets exact shadow rays.

The render sees the World as the camera does: a Light Path trick that lights the scene otherwise
is named in a warning. Results are cached by a digest of the node tree, so an unchanged World is
rendered once per process, and the output Background's strength is left out of it (a keyframed
strength stays a scale of the cached parts, as for the worlds read directly)."""

import hashlib
import math
import os
import shutil
import tempfile

import numpy as np

from ..core.sky import TABLE_COLS, TABLE_ROWS, reduce_table, split_sun

OVERSAMPLE = 4  # the table's render is 4x its size, reduced by solid-angle weighted block means
DISC_SAMPLES = 64  # per pixel of the plane lit by a disc: within 0.3% of 1024 (measured)
SUN_TYPES = {"NISHITA", "SINGLE_SCATTERING", "MULTIPLE_SCATTERING"}  # sky types with a sun disc
_cache = {}  # digest -> (table (H, W, 3), [(direction to the sun, irradiance (3,), angle)])


def _plain(v):
    if isinstance(v, (bool, int, float, str)):
        return v
    try:
        return tuple(round(float(x), 9) for x in v)
    except TypeError:
        return getattr(v, "name_full", None) or repr(type(v))


def _props(block, skip=()):
    out = []
    for p in block.bl_rna.properties:
        if p.is_readonly or p.identifier in skip or p.type in {"POINTER", "COLLECTION"}:
            continue
        out.append((p.identifier, _plain(getattr(block, p.identifier))))
    img = getattr(block, "image", None)
    if img is not None:
        out.append(("image", img.name_full, img.filepath, tuple(img.size), img.is_dirty))
    return out


_UI = {"location", "location_absolute", "width", "height", "select", "show_options", "show_preview"}
_UI |= {"hide", "show_texture", "color", "use_custom_color", "label", "warning_propagation"}


def digest(world, skip_socket=None):
    """sha1 of what a World's render depends on: its colour, every node's settings and unlinked
    inputs, and the links (skip_socket: an input left out, the output Background's Strength)."""
    h = hashlib.sha1(repr(tuple(world.color)).encode())
    tree = world.node_tree
    for n in sorted(tree.nodes, key=lambda n: n.name) if tree is not None else ():
        h.update(repr((n.bl_idname, n.name, _props(n, _UI))).encode())
        for s in n.inputs:
            if s != skip_socket and not s.is_linked and hasattr(s, "default_value"):
                h.update(repr((s.identifier, _plain(s.default_value))).encode())
    for lk in tree.links if tree is not None else ():
        ends = (lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier)
        h.update(repr((ends, lk.is_muted)).encode())
    return h.hexdigest()


def _track(d, axis):
    from mathutils import Vector

    return Vector(d).to_track_quat(axis, "Y" if abs(d[2]) < 0.99 else "X").to_euler()


def _camera_toward(scene, d, ortho=None):
    """A camera in `scene` looking along the unit direction d: a lat-long panorama, or
    orthographic over `ortho` units."""
    import bpy

    cam = bpy.data.cameras.new("hr_world_probe")
    if ortho is not None:
        cam.type, cam.ortho_scale = "ORTHO", ortho
    else:
        cam.type, cam.panorama_type = "PANO", "EQUIRECTANGULAR"
    ob = bpy.data.objects.new("hr_world_probe", cam)
    scene.collection.objects.link(ob)
    ob.rotation_euler = _track(d, "-Z")
    scene.camera = ob
    return ob


def _render(scene, folder, name, width, height, samples=16):
    """Render `scene` to a float EXR and return its pixels (height, width, 3), row 0 at the bottom."""
    import bpy

    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.cycles.samples = samples
    scene.render.filepath = os.path.join(folder, name + ".exr")
    bpy.ops.render.render(write_still=True, scene=scene.name)
    img = bpy.data.images.load(scene.render.filepath)
    try:
        px = np.empty(len(img.pixels), np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(height, width, 4)[..., :3].astype(np.float64)
    finally:
        bpy.data.images.remove(img)


def _disc_irradiance(scene, folder, node, d):
    """Irradiance (3,) at normal incidence of one sky node's sun disc, as Cycles lights a diffuse
    surface with it: a white diffuse plane facing the sun rendered with the disc and without (its
    radiance is E / pi), the difference. (Integrating the disc's pixels seen by a camera gives 2-3%
    more than Cycles' light sampling of the same disc delivers: measured, cause not known.)"""
    import bpy

    me = bpy.data.meshes.new("hr_world_probe")
    me.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    mat = bpy.data.materials.new("hr_world_probe")
    if mat.node_tree is None:  # (Blender < 5)
        mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    diffuse, out = nodes.new("ShaderNodeBsdfDiffuse"), nodes.new("ShaderNodeOutputMaterial")
    diffuse.inputs["Color"].default_value = (1, 1, 1, 1)
    mat.node_tree.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
    me.materials.append(mat)
    plane = bpy.data.objects.new("hr_world_probe", me)
    scene.collection.objects.link(plane)
    plane.rotation_euler = _track(d, "Z")
    cam = _camera_toward(scene, -np.asarray(d), ortho=0.5)
    cam.location = 2 * np.asarray(d)
    views = []
    for on in (True, False):
        node.sun_disc = on
        views.append(_render(scene, folder, f"disc{int(on)}", 4, 4, DISC_SAMPLES).mean((0, 1)))
    node.sun_disc = False
    return math.pi * np.clip(views[0] - views[1], 0, None)


def sun_direction(node):
    """Unit direction toward a Sky Texture's sun (its elevation above the horizon, its rotation
    clockwise from +Y about +Z), as Cycles renders it."""
    el, rot = node.sun_elevation, node.sun_rotation
    return np.array([math.cos(el) * math.sin(rot), math.cos(el) * math.cos(rot), math.sin(el)])


def probe(world, strength_socket=None):
    """(table (TABLE_ROWS, TABLE_COLS, 3) of the World's radiance without sun discs, suns
    [(unit direction toward the sun, irradiance (3,) at normal incidence, angular diameter)]), or
    raises RuntimeError. strength_socket: an input set to 1 for the render (the caller scales)."""
    key = digest(world, strength_socket)
    if key in _cache:
        return _cache[key]
    import bpy

    scene = bpy.data.scenes.new("hr_world_probe")
    copy = world.copy()  # the user's World is not touched; its animation is evaluated already
    folder = tempfile.mkdtemp(prefix="hr_world_")
    try:
        for block in (copy, copy.node_tree):
            if block is not None and block.animation_data is not None:
                block.animation_data_clear()
        if strength_socket is not None:
            node = copy.node_tree.nodes[strength_socket.node.name]
            node.inputs[strength_socket.identifier].default_value = 1.0
        scene.world = copy
        scene.render.engine = "CYCLES"
        scene.cycles.use_denoising, scene.cycles.device = False, "CPU"
        scene.cycles.filter_width = 0.01  # no pixel filter: a cell holds its own directions only
        scene.render.resolution_percentage = 100
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        skies = [
            n
            for n in (copy.node_tree.nodes if copy.node_tree is not None else ())
            if n.type == "TEX_SKY" and not n.mute and n.sky_type in SUN_TYPES and n.sun_disc
        ]
        for node in skies:
            node.sun_disc = False
        _camera_toward(scene, (1.0, 0.0, 0.0))  # the panorama's centre is +X, as an Environment Texture's
        px = _render(scene, folder, "sky", TABLE_COLS * OVERSAMPLE, TABLE_ROWS * OVERSAMPLE)
        rest, sun = split_sun(px)  # a sun in an image the setup turns or mixes (16 spp: a noisy one)
        suns = [sun] if sun is not None else []
        for node in skies:  # (after the sky: the plane lit by a disc is not in the panorama)
            d = sun_direction(node)
            irr = _disc_irradiance(scene, folder, node, d)
            if irr.max() > 0:
                suns.append((d, irr, float(node.sun_size)))
        got = (reduce_table(rest), suns)
    finally:
        for ob in list(scene.objects):
            data, store = ob.data, bpy.data.cameras if ob.type == "CAMERA" else bpy.data.meshes
            bpy.data.objects.remove(ob)
            for mat in getattr(data, "materials", ()):
                bpy.data.materials.remove(mat)
            store.remove(data)
        bpy.data.scenes.remove(scene)
        bpy.data.worlds.remove(copy)
        shutil.rmtree(folder, ignore_errors=True)
    if len(_cache) > 8:
        _cache.clear()
    _cache[key] = got
    return got
