"""Blender (bpy) set-up shared by the bpy tests and the Cycles comparisons: the add-on registered
once per process, and the sample scenes opened from a copy (a test never writes sample_blends/)."""

import shutil
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
SAMPLES = REPO_ROOT / "sample_blends"


def load_bpy():
    import bpy

    import hr_addon

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    return bpy


def open_sample(name, directory, sub="") -> Path:
    """Copy sample_blends/<name>.blend into directory[/sub] and open it; returns the copy's path."""
    bpy = load_bpy()
    d = Path(directory) / sub if sub else Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    dst = d / f"{name}.blend"
    shutil.copy(SAMPLES / f"{name}.blend", dst)
    bpy.ops.wm.open_mainfile(filepath=str(dst), load_ui=False)
    return dst


def isolated_env(directory):
    """The environment of a Blender subprocess that touches neither ~/.config/blender nor this
    process's add-ons: a throw-away HOME and user-resource folder in `directory`, no inherited
    PYTHONPATH. Returns (env, the user-resource folder)."""
    import os

    home, resources = Path(directory) / "home", Path(directory) / "blender_user"
    home.mkdir()
    resources.mkdir()
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("BLENDER_USER_") and k not in ("PYTHONPATH", "PYTHONHOME")
    }
    env.update(
        HOME=str(home),
        BLENDER_USER_RESOURCES=str(resources),
        XDG_CONFIG_HOME=str(home / ".config"),
        PYTHONDONTWRITEBYTECODE="1",
    )
    return env, resources


def look_from(scene, name, location, target, lens):
    """A new camera object `name` at `location` looking at `target` (its Y up), `lens` mm, made the
    scene's camera; returns it."""
    import bpy
    from mathutils import Vector

    data = bpy.data.cameras.new(name)
    data.lens = lens
    ob = bpy.data.objects.new(name, data)
    scene.collection.objects.link(ob)
    ob.location = location
    ob.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    scene.camera = ob
    return ob


def mesh_scene(mesh):
    """A new empty Blender scene holding `mesh` (a MeshInput), one mesh object per object: a
    Diffuse BSDF of its reflectance, an Emission shader where it emits (as scripts/make_samples.py
    builds the furnished sample). Returns the scene. Used by the Cycles comparisons of built rooms."""
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    load_bpy()
    scene = bpy.context.scene
    mats = {}
    starts = np.r_[mesh.loop_start, len(mesh.loop_verts)]
    for k, name in enumerate(mesh.object_names):
        polys = np.flatnonzero(mesh.object_id == k)
        loops = [mesh.loop_verts[starts[i] : starts[i + 1]] for i in polys]
        used, inv = np.unique(np.concatenate(loops), return_inverse=True)
        ends = np.cumsum([len(lp) for lp in loops])
        me = bpy.data.meshes.new(name)
        me.from_pydata(mesh.verts[used].tolist(), [], [p.tolist() for p in np.split(inv, ends[:-1])])
        rho = tuple(np.round(mesh.reflectance[polys[0]], 6))
        em = tuple(np.round(mesh.emission[polys[0]], 6))
        if (rho, em) not in mats:
            m = bpy.data.materials.new(f"Material {len(mats)}")
            if bpy.app.version < (5, 0, 0):
                m.use_nodes = True
            t = m.node_tree
            for n in [n for n in t.nodes if n.type != "OUTPUT_MATERIAL"]:
                t.nodes.remove(n)
            out = next(n for n in t.nodes if n.type == "OUTPUT_MATERIAL")
            if max(em) > 0:
                d = t.nodes.new("ShaderNodeEmission")
                d.inputs["Color"].default_value = (*(np.array(em) / max(em)), 1)
                d.inputs["Strength"].default_value = max(em)
            else:
                d = t.nodes.new("ShaderNodeBsdfDiffuse")
                d.inputs["Color"].default_value = (*rho, 1)
            t.links.new(d.outputs[0], out.inputs["Surface"])
            mats[rho, em] = m
        me.materials.append(mats[rho, em])
        scene.collection.objects.link(bpy.data.objects.new(name, me))
    bpy.context.view_layer.update()
    return scene
