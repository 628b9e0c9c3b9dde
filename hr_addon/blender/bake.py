"""The bake: one hierarchy, then per frame light shapes -> apply -> solve -> cache.

`bake_frames()` is a generator shared by the headless loop (`run_bake()`, also what the
background worker of the interactive bake runs, see background.py) and tests; closing it early
discards the partial bake and keeps the previous cache. The hierarchy build reports its progress
through the `progress` callback (core.progress), frames through the yielded BakeProgress.
"""

import dataclasses
import hashlib
import inspect
import os
import re
import time
from collections import OrderedDict
from contextlib import nullcontext
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.events import DynamicRadiosity, LightShape
from ..core.geometry import InputError, isolated_objects
from ..core.lights import Light
from ..core.progress import Cancelled, FrameEta
from ..core.radiosity import RadiositySystem
from ..core.refine import RefineParams
from ..core.texels import loop_incident
from ..io.cache import CacheError, CacheWriter, check_writable, frame_ranges
from ..lightmap import TextureError
from ..lightmap.plan import FORMATS as TEXTURE_FORMATS
from .state import STATE
from . import paths, playback, signatures, texture
from .props import custom_range
from .scene_in import (
    SceneError,
    collect_geometry,
    collect_light_shapes,
    collect_lights,
    lights_signature,
    frozen_emitters,
    geometry_objects,
    light_check,
    light_shape_objects,
    shapes_signature,
)

METHODS = ("AUTO", "AR", "FE", "NAIVE")
QUALITIES = ("DRAFT", "MEDIUM", "HIGH", "CUSTOM")
DOMAINS = ("CORNER", "POINT")
OUTPUTS = ("VERTEX", "TEXTURE")
RADIANCE_MODES = ("RADIANCE", "IRRADIANCE")


@dataclass
class BakeProgress:
    stage: str  # "build", "frame"
    frame: int = 0
    done: int = 0  # frames finished
    total: int = 0
    message: str = ""
    reused: bool = False
    warnings: list = field(default_factory=list)
    fraction: float = 0.0  # of the whole bake (estimate: the build counts as BUILD_SHARE)
    eta: float = float("nan")  # seconds left of the current stage (nan: unknown yet)


BUILD_SHARE = 0.5  # share of the progress bar given to the hierarchy build


def ray_backend_name(system):
    """ "embree", "numpy", ... of the ray backend a RadiositySystem was built with."""
    name = getattr(getattr(system, "backend", None), "name", "")
    if not name:  # BuildReport.backend holds the class name, e.g. "EmbreeBackend"
        cls = str(getattr(getattr(system, "build", None), "backend", "") or "unknown")
        name = cls[: -len("Backend")].lower() if cls.endswith("Backend") else cls.lower()
    return name


def ray_backend_note(name):
    """'' for Embree, else why the bake traces rays with `name` (shown in the summary line)."""
    if name == "embree":
        return ""
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except ImportError as exc:
        return f"embreex not available on this platform/Python ({exc}); numpy tracer, slower"
    return "numpy tracer"


class Warnings:
    """The bake's warnings, each shown once: repeats (the same shape on every frame, numbers
    aside) are counted, with the frames they came from."""

    def __init__(self):
        self.items = OrderedDict()  # key -> [first text, count, frames]

    @staticmethod
    def key(text):
        return re.sub(r"\d+(?:\.\d+)?", "#", text)

    def add(self, text, frame=None):
        """Count one occurrence; True if it is the first of its kind."""
        k = self.key(text)
        item = self.items.get(k)
        if item is None:
            self.items[k] = [text, 1, [] if frame is None else [frame]]
            return True
        item[1] += 1
        if frame is not None and frame not in item[2]:
            item[2].append(frame)
        return False

    def texts(self):
        return [v[0] for v in self.items.values()]

    def lines(self):
        out = []
        for text, count, frames in self.items.values():
            if count > 1:
                where = f" on frames {frame_ranges(frames)}" if frames else ""
                text = f"{text} [{count} times{where}]"
            out.append(text)
        return out

    def __len__(self):
        return len(self.items)


class _NoInterrupts:
    """Stand-in for blender.interrupt.Interrupts when the caller does not handle signals."""

    def check(self):
        pass

    def raising(self):
        return nullcontext()


@dataclass
class BakeResult:
    cache_dir: str = ""
    frames: tuple = (0, 0)
    solved: int = 0  # frames that needed a new solution
    reused: int = 0  # frames identical to the previous one
    kept: int = 0  # frames of the previous bake kept outside the range
    rebaked: list = field(default_factory=list)  # damaged frames of the previous bake baked again
    warnings: list = field(default_factory=list)  # each warning once (first text); see warning_lines
    log: object = None  # the Warnings collector (counts and frames of repeats)
    build_seconds: float = 0.0
    gather_seconds: float = 0.0  # the final gather's precompute (0: off)
    seconds: float = 0.0
    build_report: object = None
    rays: str = ""  # ray backend of the build ("embree", "numpy", ...)
    rays_note: str = ""  # why not embree, if not

    def warning_lines(self):
        """Every warning once, repeats counted ('... [8 times on frames 6-13]')."""
        return self.log.lines() if self.log is not None else list(self.warnings)

    @property
    def rays_text(self):
        return f"rays: {self.rays}" + (f" ({self.rays_note})" if self.rays_note else "")

    def summary(self):
        again = f", {len(self.rebaked)} damaged re-baked" if self.rebaked else ""
        return (
            f"baked frames {self.frames[0]}-{self.frames[1]} into {self.cache_dir}: "
            f"{self.solved} solved, {self.reused} unchanged, {self.kept} kept from the previous bake{again} "
            f"(hierarchy {self.build_seconds:.1f} s, "
            + (f"final gather {self.gather_seconds:.1f} s, " if self.gather_seconds else "final gather off, ")
            + f"total {self.seconds:.1f} s, {self.rays_text})"
        )


# Final gather (core/gather.py, docs/gather.md) per quality: hemisphere rays per output sample,
# shadow rays per sample and emitter, levels (2: the hits gather exact direct light of their own),
# iterations (the second level's samples gather from each other: light after more bounces)
GATHER = {
    "DRAFT": dict(rays=128, shadow_rays=16, levels=2, iterations=4),
    "MEDIUM": dict(rays=128, shadow_rays=32, levels=2, iterations=4),
    "HIGH": dict(rays=256, shadow_rays=64, levels=2, iterations=8),
    "CUSTOM": dict(rays=128, shadow_rays=32, levels=2, iterations=4),
}


def gather_params(quality, final_gather=True):
    """The final gather's settings for `quality`, or None when it is off (the hierarchy's leaves
    are shown, as before the final gather)."""
    return dict(GATHER[quality.upper()]) if final_gather else None


def make_gather(solution, output_plan=None, settings=None, smooth_angle=30.0):
    """The output stage for a solution (DynamicRadiosity or RadiositySystem): a LoopGather for
    vertex output, the texture plan's texel gather for texture output, None when it is off."""
    if settings is None:
        return None
    if output_plan is not None:
        return output_plan.final_gather(solution, **settings)
    from ..core.gather import LoopGather

    return LoopGather(solution, smooth_angle=smooth_angle, **settings)


def refine_params(quality, feps=None, aeps=None, contacts=True, final_gather=False):
    # orient: faces facing the wrong way are turned around, as Cycles (two-sided) shows them.
    # final_gather: the output gathers its own light, the hierarchy only carries what the gather
    # reads: the quality's transport preset for that (RefineParams.for_gather, coarser links;
    # docs/gather.md, Transport). Custom feps / aeps stay the user's.
    p = _preset(quality, feps, aeps)
    if final_gather and quality.upper() != "CUSTOM":
        p = RefineParams.for_gather(quality.lower())
    return dataclasses.replace(p, contacts=bool(contacts), orient=True)


def solve_options(quality, final_gather=False):
    """DynamicRadiosity's solver options: with the final gather, tolerances matched to the output
    (DynamicRadiosity.gather_options); off, the defaults (1e-7)."""
    if not final_gather:
        return {}
    q = quality.upper()
    return DynamicRadiosity.gather_options("medium" if q == "CUSTOM" else q.lower())


def _preset(quality, feps, aeps):
    quality = quality.upper()
    if quality not in QUALITIES:
        raise SceneError(
            f"Unknown quality '{quality}' (choose from {', '.join(q.lower() for q in QUALITIES)})."
        )
    if quality == "CUSTOM":
        return dataclasses.replace(RefineParams.preset("medium"), feps=float(feps), aeps=float(aeps))
    return RefineParams.preset(quality.lower())


def cache_dir_for(scene):
    """Absolute cache directory for scene's settings and the current .blend file."""
    d = paths.default_cache_dir(scene)
    if d is None:
        raise SceneError("Save the .blend file first: the cache folder is relative to it.")
    return d


def frame_range_for(scene, frames=None):
    if frames is None:
        frames = custom_range(scene) if scene.hr.use_frame_range else (scene.frame_start, scene.frame_end)
    a, b = int(frames[0]), int(frames[1])
    if b < a:
        raise SceneError(f"Bad frame range {a}-{b}: the end frame is before the start frame.")
    return a, b


def _signature(mesh, params, domain, targets, radiance_mode="RADIANCE", gather=None):
    h = hashlib.sha1()
    for arr in (
        mesh.verts,
        mesh.loop_start,
        mesh.loop_total,
        mesh.loop_verts,
        mesh.reflectance,
        mesh.emission,
    ):
        h.update(np.ascontiguousarray(arr, np.float64).tobytes())
    h.update(repr(dataclasses.astuple(params)).encode())
    h.update(domain.encode())
    if radiance_mode != "RADIANCE":  # (radiance bakes keep the signature they had before the mode)
        h.update(radiance_mode.encode())
    h.update(repr([(t.name, t.n_corner, t.n_point) for t in targets]).encode())
    if gather is not None:  # (bakes without the final gather keep the signature they had)
        h.update(repr(sorted(gather.items())).encode())
    return h.hexdigest()


def bake_frames(
    scene,
    view_layer=None,
    frames=None,
    method=None,
    quality=None,
    domain=None,
    feps=None,
    aeps=None,
    output=None,
    resolution=None,
    texture_format=None,
    radiance_mode=None,
    contacts=None,
    final_gather=None,
    cache_dir=None,
    progress=None,
    interrupts=None,
    warnings=None,
):
    """Generator: yields BakeProgress, returns (StopIteration.value) a BakeResult.

    progress: callable(BakeProgress) called during the hierarchy build (between batches); it may
    raise core.progress.Cancelled (or anything) to stop the bake, which keeps the previous cache.
    interrupts: a blender.interrupt.Interrupts (Ctrl-C / SIGTERM): checked between batches of the
    build and of every frame, and raising at once inside the core's computations (pure numpy).
    warnings: a Warnings collector to fill (the caller keeps it when the bake fails).
    cache_dir: absolute cache directory (default: from the scene's settings and the .blend path;
    the background bake passes the real one because it bakes a copy of the file elsewhere).

    Static geometry is read at the scene's start frame (the same for every partial bake, so
    split bakes agree); light shapes are evaluated from scratch at every frame.
    output VERTEX: colour attribute HR_Radiance; TEXTURE: per-object image sequences (texture.py)
    at `resolution` (objects may override it) in `texture_format` EXR or PNG.
    radiance_mode RADIANCE: outgoing radiance (textured materials modulate texture output per
    texel); IRRADIANCE: irradiance / pi without emission (the material's colour multiplies it).
    final_gather (default Scene.hr.final_gather): every output sample gathers its own light from
    the solution (core/gather.py); off, the output reads the hierarchy's leaves.
    """
    hr = scene.hr
    view_layer = view_layer or (
        bpy.context.view_layer if bpy.context.scene == scene else scene.view_layers[0]
    )
    method = (method or hr.method).upper()
    if method not in METHODS:
        raise SceneError(f"Unknown method '{method}' (choose from {', '.join(m.lower() for m in METHODS)}).")
    domain = (domain or hr.domain).upper()
    if domain not in DOMAINS:
        raise SceneError(f"Unknown domain '{domain}' (CORNER or POINT).")
    quality = (quality or hr.quality).upper()
    gather = gather_params(quality, hr.final_gather if final_gather is None else final_gather)
    params = refine_params(
        quality,
        hr.feps if feps is None else feps,
        hr.aeps if aeps is None else aeps,
        hr.contacts if contacts is None else contacts,
        final_gather=gather is not None,
    )
    output = (output or hr.output).upper()
    if output not in OUTPUTS:
        raise SceneError(f"Unknown output '{output}' (VERTEX or TEXTURE).")
    texture_format = (texture_format or hr.texture_format).upper()
    if texture_format not in TEXTURE_FORMATS:
        raise SceneError(f"Unknown texture format '{texture_format}' (EXR or PNG).")
    radiance_mode = (radiance_mode or hr.radiance_mode).upper()
    if radiance_mode not in RADIANCE_MODES:
        raise SceneError(f"Unknown radiance mode '{radiance_mode}' (RADIANCE or IRRADIANCE).")
    resolution = int(resolution or hr.texture_resolution)
    if not 8 <= resolution <= 16384:
        raise SceneError(f"Bad texture resolution {resolution} (8 to 16384).")
    start, end = frame_range_for(scene, frames)
    # frames outside the scene's range are baked as asked, but said (a typo, another scene's range)
    s0, s1 = scene.frame_start, scene.frame_end
    outside = [
        f"{a}-{b}" if a < b else str(a)
        for a, b in ((start, min(end, s0 - 1)), (max(start, s1 + 1), end))
        if a <= b
    ]
    if output == "TEXTURE" and start < 0:
        raise SceneError("Texture output needs frame numbers >= 0 (image sequence file names).")
    final_dir = os.path.abspath(cache_dir) if cache_dir else cache_dir_for(scene)
    intr = interrupts or _NoInterrupts()
    log = warnings if warnings is not None else Warnings()
    try:
        check_writable(final_dir)  # before the (long) build, not after it
    except CacheError as exc:
        raise SceneError(str(exc)) from None
    t_start = time.perf_counter()
    result = BakeResult(cache_dir=final_dir, frames=(start, end), log=log)
    original_frame = scene.frame_current
    writer = None
    committed = False

    def warn(items, frame=None):
        """Count warnings; returns the new ones (shown in progress reports)."""
        new = [w for w in items if log.add(w, frame)]
        result.warnings[:] = log.texts()
        return new

    if outside:
        warn(
            [
                f"Frames {' and '.join(outside)} lie outside the scene's frame range {s0}-{s1}: baked "
                "as asked (is the frame range right?)."
            ]
        )

    STATE.bake_starts(scene)  # Live ends: the bake shows its own result when it has finished
    STATE.baking = True
    try:
        scene.frame_set(scene.frame_start)
        depsgraph = view_layer.depsgraph
        geo_objects = geometry_objects(view_layer)
        if output == "VERTEX":
            warn(playback.linked_meshes(geo_objects))
        if output == "TEXTURE":
            try:
                warn(texture.ensure_lightmaps(geo_objects, resolution))
            except TextureError as exc:
                raise SceneError(str(exc)) from None
        with texture.source_materials(geo_objects):  # texture preview copies stand for these
            scene_in = collect_geometry(view_layer, depsgraph)
        warn(scene_in.warnings)
        # never a black bake without a word: nothing emits -> refused before the build
        error, light_warnings = light_check(view_layer, scene, depsgraph, bool(scene_in.mesh.emission.any()))
        if error:
            raise SceneError(error)
        warn(light_warnings + frozen_emitters(view_layer, scene.frame_start))
        intr.check()
        geometry_sig = signatures.geometry_signatures(view_layer, depsgraph)
        shapes_id = signatures.light_shape_identity(view_layer)
        params, min_area_rel, far_warning = solver_setup(scene_in.mesh, params)
        if far_warning:
            warn([far_warning])
        has_shapes = bool(light_shape_objects(view_layer, include_hidden=True))
        # Blender lights (issue 20): read per frame like light shapes (keyframed transform, colour,
        # power, cone); hidden ones may appear on another frame
        has_lights = bool([o for o in _walk_lights(view_layer)])
        npoly = len(scene_in.mesh.loop_start)
        total = end - start + 1
        yield BakeProgress(
            "build",
            total=total,
            warnings=list(result.warnings),
            message=f"Building the hierarchy ({npoly} polygons, {quality.lower()} quality)",
        )
        intr.check()
        t0 = time.perf_counter()

        def on_build(info):
            intr.check()
            if progress is not None:
                progress(
                    BakeProgress(
                        "build",
                        total=total,
                        fraction=BUILD_SHARE * float(info.fraction),
                        eta=float(info.eta),
                        message=f"Building the hierarchy: {info.message}",
                    )
                )

        with intr.raising():
            system = RadiositySystem(scene_in.mesh, params, progress=on_build)
            dyn = None
            if has_shapes or has_lights:
                dyn = DynamicRadiosity(
                    system,
                    method=method,
                    min_area_rel=min_area_rel,
                    **solve_options(quality, gather is not None),
                )
        result.build_seconds = time.perf_counter() - t0
        result.build_report = system.build
        result.rays = ray_backend_name(system)
        result.rays_note = ray_backend_note(result.rays)
        warn(system.build.warnings)
        info = {
            "blend": os.path.basename(bpy.data.filepath),
            "scene": scene.name,
            "method": method,
            "quality": quality,
            "feps": params.feps,
            "aeps": params.aeps,
            "contacts": params.contacts,
            "final_gather": gather is not None,
            "output": output,
            "radiance_mode": radiance_mode,
            "rays": result.rays,
            "created": time.strftime("%Y-%m-%d %H:%M:%S"),
            "view_layer": view_layer.name,
            "geometry": geometry_sig,
            "light_shapes": shapes_id,
        }
        if has_lights:  # which Blender lights took part (not their animated values)
            info["lights"] = {o.name: f"{o.data.type} {o.data.name}" for o in _walk_lights(view_layer)}
        if result.rays_note:
            info["rays_note"] = result.rays_note
        baker = None
        if output == "TEXTURE":
            try:
                baker = texture.texture_plan(
                    scene_in,
                    system.patches,
                    view_layer,
                    view_layer.depsgraph,
                    resolution,
                    texture_format,
                    albedo=radiance_mode == "RADIANCE",
                )
            except TextureError as exc:
                raise SceneError(str(exc)) from None
            warn(baker.warnings)
            objects = baker.objects_info(scene_in.targets)
            writer = CacheWriter(
                final_dir,
                objects,
                "TEXTURE",
                baker.signature(
                    _signature(scene_in.mesh, params, "TEXTURE", scene_in.targets, radiance_mode, gather)
                ),
                info,
            )
            baker.bind(writer.tmp)
        else:
            objects = {
                t.name: {"mesh": t.mesh_name, "count": t.n_corner if domain == "CORNER" else t.n_point}
                for t in scene_in.targets
            }
            writer = CacheWriter(
                final_dir,
                objects,
                domain,
                _signature(scene_in.mesh, params, domain, scene_in.targets, radiance_mode, gather),
                info,
            )
        final = None
        if gather is not None:
            yield BakeProgress(
                "build",
                total=total,
                fraction=BUILD_SHARE,
                message=f"Final gather: tracing {gather['rays']} rays per output sample",
            )
            t1 = time.perf_counter()
            with intr.raising():
                final = make_gather(dyn if dyn is not None else system, baker, gather)
            result.gather_seconds = time.perf_counter() - t1
        # Frames of the previous bake that this one keeps but whose files are missing or damaged
        # are baked again (not kept, not dropped).
        in_range = set(range(start, end + 1))
        damaged = writer.damaged_frames(in_range)
        if baker is not None:
            old, why = writer.previous()
            if old is not None and not why:
                damaged.update(
                    baker.damaged_frames(writer.final, [f for f in old.frames if f not in in_range])
                )
        frames_todo = sorted(in_range | set(damaged))
        if damaged:
            result.rebaked = sorted(damaged)
            reasons = sorted(set(damaged.values()))
            warn(
                [
                    f"Frames {frame_ranges(damaged)} of the previous bake were missing or damaged "
                    f"({'; '.join(reasons[:3])}): baked them again."
                ]
            )
        total = len(frames_todo)
        prev_sig = prev_frame = None
        time_left = FrameEta(total)  # steady: an average of the frames' times, counting down
        for i, f in enumerate(frames_todo):
            t_frame = time.perf_counter()
            intr.check()
            frame_warnings = []
            lights = None
            if has_shapes or has_lights:
                scene.frame_set(f)
                shapes = (
                    collect_light_shapes(view_layer, view_layer.depsgraph, LightShape, frame_warnings)
                    if has_shapes
                    else {}
                )
                sig = shapes_signature(shapes)
                if has_lights:
                    lights = collect_lights(view_layer, view_layer.depsgraph, Light, frame_warnings)
                    sig += lights_signature(lights)
            else:
                shapes, sig = None, "static"
            intr.check()
            if sig == prev_sig:
                writer.reuse(f, prev_frame)
                if baker is not None:
                    baker.reuse(f, prev_frame)
                result.reused += 1
                reused = True
            else:
                with intr.raising():
                    if dyn is not None:
                        report = dyn.apply(shapes, lights)
                        frame_warnings += [
                            m
                            for m in (getattr(report, "messages", []) or [])
                            if "response reused from the cache" not in m
                        ]
                    else:
                        system.solve()
                    if baker is not None:
                        values = baker.radiance(dyn, system, radiance_mode, gather=final)
                    else:
                        if final is not None:
                            kind = "incident" if radiance_mode == "IRRADIANCE" else "radiance"
                            values = final.loop_radiance(dyn if dyn is not None else system, domain, kind)
                        elif radiance_mode == "IRRADIANCE":
                            values = loop_incident(dyn, system, domain)
                        elif dyn is not None:
                            values = dyn.loop_radiance(domain)
                        else:
                            values = system.loop_radiance(domain)
                        values = {t.name: t.extract(values, domain) for t in scene_in.targets}
                intr.check()
                if baker is not None:
                    baker.write(f, values)
                    writer.write(f, {})  # the frame's entry in the manifest (textures hold the values)
                else:
                    writer.write(f, values)
                result.solved += 1
                reused = False
            prev_sig, prev_frame = sig, f
            new_w = warn(frame_warnings, f)
            left = time_left.done(time.perf_counter() - t_frame)
            yield BakeProgress(
                "frame",
                frame=f,
                done=i + 1,
                total=total,
                reused=reused,
                warnings=new_w,
                fraction=BUILD_SHARE + (1 - BUILD_SHARE) * (i + 1) / total,
                eta=left,
                message=f"Frame {f} ({i + 1}/{total}): "
                + ("unchanged" if reused else f"{time.perf_counter() - t_frame:.2f} s"),
            )
        if baker is not None:
            baker.finish(writer)
        intr.check()  # the last moment a cancel keeps the previous bake
        writer.commit()
        committed = True
        result.kept = writer.kept
        warn(writer.messages)
        use_bake(scene, final_dir, output, geo_objects)
    finally:
        if writer is not None and not committed:
            writer.abort()
        STATE.baking = False
        scene.frame_set(original_frame)  # also loads this frame through the handler
    if committed and not hr.playback:
        playback.load_frame(scene)
    result.seconds = time.perf_counter() - t_start
    return result


def _walk_lights(view_layer):
    """Light objects of the view layer's rendered collections not excluded from the bake, hidden
    ones included (they may be shown on another frame)."""
    from .scene_in import light_objects

    return light_objects(view_layer, include_hidden=True)


def solver_setup(mesh, params):
    """(params, min_area_rel, warning or '') for solving `mesh` (a core MeshInput), as every bake and
    Live Relight set the solver up. Objects far from the rest exchange practically no light with
    it; the area thresholds (Aeps, AR/AUTO's smallest element) are made relative to the rest only,
    so that the rest gets the same light with or without them (the warning names them)."""
    extent = isolated_objects(mesh)
    area_ratio = extent.area_ratio
    warning = ""
    if extent.distant:
        far = extent.distant
        names = ", ".join(f"'{n}'" for n, _, _ in far[:5]) + (
            f" and {len(far) - 5} more" if len(far) > 5 else ""
        )
        near, farthest = _length(far[-1][1]), _length(far[0][1])
        dist = farthest if near == farthest else f"{near} to {farthest}"
        warning = (
            f"{len(far)} object(s) lie far from the rest of the scene ({names}, {dist} away; the rest "
            f"is {_length(extent.main_size)} across): they "
            "exchange almost no light with it and do not change its element sizes. Exclude them "
            "(Object > HR Radiosity > Exclude) if they are not meant to be there."
        )
        params = dataclasses.replace(params, aeps=params.aeps * area_ratio)
    return params, _MIN_AREA_REL * area_ratio, warning


_MIN_AREA_REL = inspect.signature(DynamicRadiosity).parameters["min_area_rel"].default


def _length(m):
    return f"{m / 1000:.3g} km" if m >= 1000 else (f"{m:.3g} m" if m >= 0.1 else f"{m * 100:.3g} cm")


class BakeJob:
    """Steps a bake_frames generator in this process and keeps the progress numbers (scripts and
    tests; the interactive bake runs in another process, see background.py)."""

    def __init__(self, gen):
        self.gen = gen
        self.progress = None
        self.result = None
        self.error = None
        self.warnings = []

    def step(self):
        """Advance one step; returns False when finished (result or error set)."""
        try:
            self.progress = next(self.gen)
            self.warnings += self.progress.warnings
            return True
        except StopIteration as stop:
            self.result = stop.value
        except (InputError, OSError, RuntimeError, ValueError) as exc:
            self.error = str(exc)
        return False

    def fraction(self):
        p = self.progress
        return 0.0 if p is None else p.fraction

    def cancel(self):
        self.gen.close()  # the generator's finally block discards the partial bake


def use_bake(scene, final_dir, output, geo_objects=None):
    """Point the scene at the bake in final_dir (after the bake, or after a background bake
    finished): Scene.hr.bake_dir, playback on, Lock Interface on, texture preview re-wired."""
    hr = scene.hr
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
    if output == "TEXTURE":
        texture.after_bake(scene, final_dir)
    else:
        from .scene_in import geometry_objects

        objs = (
            geo_objects
            if geo_objects is not None
            else geometry_objects(
                bpy.context.view_layer if bpy.context.scene == scene else scene.view_layers[0]
            )
        )
        texture.remove_material(objs)  # a texture preview would show deleted files
        from .preview import bake_mode, refresh_preview

        refresh_preview(objs, bake_mode(scene) == "IRRADIANCE")


def run_bake(scene, log=print, status=None, **kwargs):
    """Headless bake: a plain loop printing progress lines, then every warning once (repeats
    counted: 'HR Radiosity: warning: ... [8 times on frames 6-13]'); returns the BakeResult. The
    warnings are printed when the bake fails or is cancelled too (then the exception propagates).

    status: optional callable(BakeProgress) receiving every progress report (build and frames),
    e.g. the background worker's status file writer."""

    def report(p):
        log(f"HR Radiosity: {p.message}", flush=True)
        if status is not None:
            status(p)

    collected = kwargs.pop("warnings", None)
    if collected is None:
        collected = Warnings()
    gen = bake_frames(scene, progress=report, warnings=collected, **kwargs)
    try:
        while True:
            try:
                p = next(gen)
            except StopIteration as stop:
                res = stop.value
                break
            report(p)
    except BaseException:
        gen.close()
        for w in collected.lines():
            log(f"HR Radiosity: warning: {w}", flush=True)
        raise
    log(f"HR Radiosity: {res.summary()}", flush=True)
    for w in res.warning_lines():
        log(f"HR Radiosity: warning: {w}", flush=True)
    return res


__all__ = [
    "bake_frames",
    "run_bake",
    "use_bake",
    "BakeJob",
    "BakeProgress",
    "BakeResult",
    "Warnings",
    "SceneError",
    "InputError",
    "Cancelled",
    "METHODS",
    "QUALITIES",
    "DOMAINS",
    "OUTPUTS",
]
