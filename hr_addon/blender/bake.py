"""The bake: one hierarchy, then per frame light shapes -> apply -> solve -> cache.

`bake_frames()` is a generator shared by the modal operator (one step per timer tick) and the
headless loop (`run_bake()`); closing it early (ESC) discards the partial bake and keeps the
previous cache.
"""
import dataclasses
import hashlib
import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.geometry import InputError
from ..core.radiosity import RadiositySystem
from ..core.refine import RefineParams
from . import playback, texture
from .cache import CacheWriter
from .scene_in import (SceneError, collect_geometry, collect_light_shapes, geometry_objects,
                       light_shape_objects, shapes_signature)

try:  # the dynamic (light-event) solver
    from ..core.events import DynamicRadiosity, LightShape
except ImportError:  # pragma: no cover - older core
    DynamicRadiosity = LightShape = None

METHODS = ("AUTO", "AR", "FE", "NAIVE")
QUALITIES = ("DRAFT", "MEDIUM", "HIGH", "CUSTOM")
DOMAINS = ("CORNER", "POINT")
OUTPUTS = ("VERTEX", "TEXTURE")


@dataclass
class BakeProgress:
    stage: str            # "build", "frame"
    frame: int = 0
    done: int = 0         # frames finished
    total: int = 0
    message: str = ""
    reused: bool = False
    warnings: list = field(default_factory=list)


@dataclass
class BakeResult:
    cache_dir: str = ""
    frames: tuple = (0, 0)
    solved: int = 0       # frames that needed a new solution
    reused: int = 0       # frames identical to the previous one
    kept: int = 0         # frames of the previous bake kept outside the range
    warnings: list = field(default_factory=list)
    build_seconds: float = 0.0
    seconds: float = 0.0
    build_report: object = None


def refine_params(quality, feps=None, aeps=None):
    quality = quality.upper()
    if quality not in QUALITIES:
        raise SceneError(f"Unknown quality '{quality}' (choose from {', '.join(q.lower() for q in QUALITIES)}).")
    if quality == "CUSTOM":
        return dataclasses.replace(RefineParams.preset("medium"), feps=float(feps), aeps=float(aeps))
    return RefineParams.preset(quality.lower())


def cache_dir_for(scene):
    """Absolute cache directory for scene's settings and the current .blend file."""
    d = playback.default_cache_dir(scene)
    if d is None:
        raise SceneError("Save the .blend file first: the cache folder is relative to it.")
    return d


def frame_range_for(scene, frames=None):
    if frames is None:
        hr = scene.hr
        frames = (hr.frame_start, hr.frame_end) if hr.use_frame_range else (scene.frame_start, scene.frame_end)
    a, b = int(frames[0]), int(frames[1])
    if b < a:
        raise SceneError(f"Bad frame range {a}-{b}: the end frame is before the start frame.")
    return a, b


def _signature(mesh, params, domain, targets):
    h = hashlib.sha1()
    for arr in (mesh.verts, mesh.loop_start, mesh.loop_total, mesh.loop_verts, mesh.reflectance, mesh.emission):
        h.update(np.ascontiguousarray(arr, np.float64).tobytes())
    h.update(repr(dataclasses.astuple(params)).encode())
    h.update(domain.encode())
    h.update(repr([(t.name, t.n_corner, t.n_point) for t in targets]).encode())
    return h.hexdigest()


def bake_frames(scene, view_layer=None, frames=None, method=None, quality=None, domain=None,
                feps=None, aeps=None, output=None, resolution=None, texture_format=None):
    """Generator: yields BakeProgress, returns (StopIteration.value) a BakeResult.

    Static geometry is read at the scene's start frame (the same for every partial bake, so
    split bakes agree); light shapes are evaluated from scratch at every frame.
    output VERTEX: colour attribute HR_Radiance; TEXTURE: per-object image sequences (texture.py)
    at `resolution` (objects may override it) in `texture_format` EXR or PNG.
    """
    hr = scene.hr
    view_layer = view_layer or (bpy.context.view_layer if bpy.context.scene == scene else scene.view_layers[0])
    method = (method or hr.method).upper()
    if method not in METHODS:
        raise SceneError(f"Unknown method '{method}' (choose from {', '.join(m.lower() for m in METHODS)}).")
    domain = (domain or hr.domain).upper()
    if domain not in DOMAINS:
        raise SceneError(f"Unknown domain '{domain}' (CORNER or POINT).")
    quality = (quality or hr.quality).upper()
    params = refine_params(quality, hr.feps if feps is None else feps, hr.aeps if aeps is None else aeps)
    output = (output or hr.output).upper()
    if output not in OUTPUTS:
        raise SceneError(f"Unknown output '{output}' (VERTEX or TEXTURE).")
    texture_format = (texture_format or hr.texture_format).upper()
    if texture_format not in texture.FORMATS:
        raise SceneError(f"Unknown texture format '{texture_format}' (EXR or PNG).")
    resolution = int(resolution or hr.texture_resolution)
    if not 8 <= resolution <= 16384:
        raise SceneError(f"Bad texture resolution {resolution} (8 to 16384).")
    start, end = frame_range_for(scene, frames)
    if output == "TEXTURE" and start < 0:
        raise SceneError("Texture output needs frame numbers >= 0 (image sequence file names).")
    final_dir = cache_dir_for(scene)
    t_start = time.perf_counter()
    result = BakeResult(cache_dir=final_dir, frames=(start, end))
    original_frame = scene.frame_current
    writer = None
    committed = False
    playback.state["baking"] = True
    try:
        scene.frame_set(scene.frame_start)
        depsgraph = view_layer.depsgraph
        geo_objects = geometry_objects(view_layer)
        if output == "TEXTURE":
            try:
                result.warnings += texture.ensure_lightmaps(geo_objects, resolution)
            except texture.TextureError as exc:
                raise SceneError(str(exc)) from None
        with texture.source_materials(geo_objects):    # texture preview copies stand for these
            scene_in = collect_geometry(view_layer, depsgraph)
        result.warnings += scene_in.warnings
        has_shapes = bool(light_shape_objects(view_layer, include_hidden=True))
        if has_shapes and DynamicRadiosity is None:
            raise SceneError("Light shapes need the dynamic solver (hr_addon.core.events), "
                             "which this version does not have.")
        npoly = len(scene_in.mesh.loop_start)
        yield BakeProgress("build", total=end - start + 1, warnings=list(result.warnings),
                           message=f"Building the hierarchy ({npoly} polygons, {quality.lower()} quality)")
        t0 = time.perf_counter()
        system = RadiositySystem(scene_in.mesh, params)
        dyn = DynamicRadiosity(system, method=method) if has_shapes else None
        result.build_seconds = time.perf_counter() - t0
        result.build_report = system.build
        result.warnings += [w for w in system.build.warnings if w not in result.warnings]
        info = {"blend": os.path.basename(bpy.data.filepath), "scene": scene.name, "method": method,
                "quality": quality, "feps": params.feps, "aeps": params.aeps, "output": output,
                "created": time.strftime("%Y-%m-%d %H:%M:%S")}
        baker = None
        if output == "TEXTURE":
            try:
                baker = texture.TextureBaker(scene_in, system.patches, view_layer, view_layer.depsgraph,
                                             resolution, texture_format)
            except texture.TextureError as exc:
                raise SceneError(str(exc)) from None
            result.warnings += [w for w in baker.warnings if w not in result.warnings]
            objects = baker.objects_info(scene_in.targets)
            writer = CacheWriter(final_dir, objects, "TEXTURE",
                                 baker.signature(_signature(scene_in.mesh, params, "TEXTURE", scene_in.targets)), info)
            baker.bind(writer.tmp)
        else:
            objects = {t.name: {"mesh": t.mesh_name, "count": t.n_corner if domain == "CORNER" else t.n_point}
                       for t in scene_in.targets}
            writer = CacheWriter(final_dir, objects, domain, _signature(scene_in.mesh, params, domain, scene_in.targets), info)
        prev_sig = prev_frame = None
        total = end - start + 1
        for i, f in enumerate(range(start, end + 1)):
            frame_warnings = []
            if has_shapes:
                scene.frame_set(f)
                shapes = collect_light_shapes(view_layer, view_layer.depsgraph, LightShape, frame_warnings)
                sig = shapes_signature(shapes)
            else:
                shapes, sig = None, "static"
            if sig == prev_sig:
                writer.reuse(f, prev_frame)
                if baker is not None:
                    baker.reuse(f, prev_frame)
                result.reused += 1
                reused = True
            else:
                if dyn is not None:
                    report = dyn.apply(shapes)
                    frame_warnings += list(getattr(report, "messages", []) or [])
                else:
                    system.solve()
                if baker is not None:
                    baker.write(f, baker.radiance(dyn, system))
                    writer.write(f, {})      # the frame's entry in the manifest (textures hold the values)
                else:
                    values = dyn.loop_radiance(domain) if dyn is not None else system.loop_radiance(domain)
                    writer.write(f, {t.name: t.extract(values, domain) for t in scene_in.targets})
                result.solved += 1
                reused = False
            prev_sig, prev_frame = sig, f
            new_w = [w for w in frame_warnings if w not in result.warnings]
            result.warnings += new_w
            yield BakeProgress("frame", frame=f, done=i + 1, total=total, reused=reused, warnings=new_w,
                               message=f"Frame {f} ({i + 1}/{total}){' unchanged' if reused else ''}")
        if baker is not None:
            baker.finish(writer)
        writer.commit()
        committed = True
        result.kept = writer.kept
        result.warnings += writer.messages
        bpy_dir = final_dir
        if bpy.data.filepath:
            try:
                bpy_dir = bpy.path.relpath(final_dir)
            except ValueError:  # other drive (Windows)
                pass
        hr.bake_dir = bpy_dir.rstrip("/\\") + "/"
        hr.playback = True
        scene.render.use_lock_interface = True  # renders read HR_Radiance in frame_change_pre
        playback.forget_readers()
        if baker is not None:
            texture.after_bake(scene, final_dir)
        else:
            texture.remove_material(geo_objects)    # a texture preview would show deleted files
    finally:
        if writer is not None and not committed:
            writer.abort()
        playback.state["baking"] = False
        scene.frame_set(original_frame)   # also loads this frame through the handler
    if committed and not hr.playback:
        playback.load_frame(scene)
    result.seconds = time.perf_counter() - t_start
    return result


def run_bake(scene, log=print, **kwargs):
    """Headless bake: a plain loop printing progress lines; returns the BakeResult."""
    gen = bake_frames(scene, **kwargs)
    while True:
        try:
            p = next(gen)
        except StopIteration as stop:
            res = stop.value
            break
        for w in p.warnings:
            log(f"HR Radiosity: warning: {w}", flush=True)
        log(f"HR Radiosity: {p.message}", flush=True)
    log(f"HR Radiosity: baked frames {res.frames[0]}-{res.frames[1]} into {res.cache_dir}: "
        f"{res.solved} solved, {res.reused} unchanged, {res.kept} kept from the previous bake "
        f"(hierarchy {res.build_seconds:.1f} s, total {res.seconds:.1f} s)", flush=True)
    return res


__all__ = ["bake_frames", "run_bake", "BakeProgress", "BakeResult", "SceneError", "InputError",
           "METHODS", "QUALITIES", "DOMAINS", "OUTPUTS"]
