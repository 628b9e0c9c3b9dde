"""The bake: settings -> one read of the scene -> one hierarchy -> per frame light shapes -> apply
-> solve -> cache.

`bake_frames()` is a generator shared by the headless loop (`run_bake()`, also what the
background worker of the interactive bake runs, see background.py) and tests; closing it early
discards the partial bake and keeps the previous cache. The hierarchy build reports its progress
through the `progress` callback (core.progress), frames through the yielded BakeProgress.
"""

import dataclasses
import functools
import gc
import hashlib
import os
import time
from contextlib import nullcontext

import bpy
import numpy as np

from ..core.events import DynamicRadiosity, LightShape
from ..core.geometry import InputError
from ..core.lights import Light, indirect_incident
from ..core.parallel import release_free_memory
from ..core.progress import Cancelled, FrameEta
from ..core.radiosity import RadiositySystem
from ..core.texels import loop_incident
from ..io import precompute as pc
from ..io.cache import CacheError, CacheWriter, check_writable, frame_ranges
from ..lightmap import TextureError
from . import paths, playback, texture
from .preview import bake_mode, refresh_preview
from .props import custom_range
from .report import BUILD_SHARE, BakeProgress, BakeResult, Warnings, ray_backend_name, ray_backend_note
from .lights_in import collect_light_shapes, collect_lights, lights_signature, shapes_signature
from .lights_in import scene_moving_shapes
from .scene_in import FlatExtract, SceneError, back_in_depsgraph, geometry_objects, out_of_depsgraph
from .snapshot import read_snapshot
from .settings import BakeConfig, make_gather, precompute_key, solver_setup
from .state import STATE


class _NoInterrupts:
    """Stand-in for blender.interrupt.Interrupts when the caller does not handle signals."""

    def check(self):
        pass

    def raising(self):
        return nullcontext()


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


def _signature(mesh, params, domain, targets, radiance_mode="RADIANCE", gather=None, transport=None):
    h = hashlib.sha1()
    for m in (mesh,) if transport is None else (mesh, transport):  # (transport: the hierarchy's
        # mesh where it is not the output's, Vertex Spacing; bakes without one keep their signature)
        for arr in (m.verts, m.loop_start, m.loop_total, m.loop_verts, m.reflectance, m.emission):
            h.update(np.ascontiguousarray(arr, np.float64).tobytes())
    h.update(repr(dataclasses.astuple(params)).encode())
    h.update(domain.encode())
    if radiance_mode != "RADIANCE":  # (radiance bakes keep the signature they had before the mode)
        h.update(radiance_mode.encode())
    h.update(repr([(t.key, t.n_corner, t.n_point) for t in targets]).encode())
    if gather is not None:  # (bakes without the final gather keep the signature they had)
        h.update(repr(sorted(gather.items())).encode())
    return h.hexdigest()


def _let_go():
    """Free the dropped system's arrays now: DynamicRadiosity's parts hold callbacks into it (a
    reference cycle), so it would otherwise live until Python's next full collection, under
    Blender's evaluation of the geometry given back (the 100k room: 2.25 GB at the end, not 1.5)."""
    gc.collect()
    release_free_memory()


def hide_while_baking():
    """Whether a vertex bake takes its geometry out of the depsgraph while it runs (memory: the
    100k room's peak -0.12 GB): in background mode (the command line, tests), not in the UI."""
    return bpy.app.background


def bake_frames(
    scene,
    view_layer=None,
    frames=None,
    cache_dir=None,
    progress=None,
    interrupts=None,
    warnings=None,
    rebuild=False,
    **overrides,
):
    """Generator: yields BakeProgress, returns (StopIteration.value) a BakeResult.

    progress: callable(BakeProgress) called during the hierarchy build (between batches); it may
    raise core.progress.Cancelled (or anything) to stop the bake, which keeps the previous cache.
    interrupts: a blender.interrupt.Interrupts (Ctrl-C / SIGTERM): checked between batches of the
    build and of every frame, and raising at once inside the core's computations (pure numpy).
    warnings: a Warnings collector to fill (the caller keeps it when the bake fails).
    overrides: Scene.hr settings to use instead (method, quality, domain, feps, aeps, output,
    resolution, texel_density, texture_format, radiance_mode, contacts, final_gather): settings.BakeConfig.
    cache_dir: absolute cache directory (default: from the scene's settings and the .blend path;
    the background bake passes the real one because it bakes a copy of the file elsewhere).
    rebuild: build the scene precompute even if the cache folder holds a valid one.

    Static geometry is read at the scene's start frame (the same for every partial bake, so
    split bakes agree); light shapes are evaluated from scratch at every frame.
    output VERTEX: colour attribute HR_Radiance; TEXTURE: per-object image sequences (texture.py)
    at `resolution` (objects may override it) in `texture_format` EXR or PNG.
    radiance_mode RADIANCE: outgoing radiance (textured materials modulate texture output per
    texel); IRRADIANCE: irradiance / pi without emission (the material's colour multiplies it);
    INDIRECT: IRRADIANCE without the Blender lights' and the World's direct light (EEVEE's part).
    final_gather (default Scene.hr.final_gather): every output sample gathers its own light from
    the solution (core/gather.py); off, the output reads the hierarchy's leaves.
    """
    cfg = BakeConfig.resolve(scene.hr, **overrides)
    view_layer = view_layer or _view_layer(scene)
    start, end = frame_range_for(scene, frames)
    if cfg.output == "TEXTURE" and start < 0:
        raise SceneError("Texture output needs frame numbers >= 0 (image sequence file names).")
    final_dir = os.path.abspath(cache_dir) if cache_dir else cache_dir_for(scene)
    try:
        check_writable(final_dir)  # before the (long) build, not after it
    except CacheError as exc:
        raise SceneError(str(exc)) from None
    t_start = time.perf_counter()
    run = _Bake(
        scene, view_layer, cfg, interrupts, warnings, BakeResult(cache_dir=final_dir, frames=(start, end))
    )
    run.warn(_outside_scene_range(scene, start, end))
    original_frame = scene.frame_current
    writer = None
    committed = False
    hidden = []  # geometry out of the depsgraph while the bake runs (out_of_depsgraph)
    STATE.bake_starts(scene)  # Live ends: the bake shows its own result when it has finished
    STATE.baking = True
    try:
        scene.frame_set(scene.frame_start)
        snap = read_snapshot(scene, view_layer, cfg, run.warn, log=run.result.notes.append)
        total = end - start + 1
        for line in run.result.notes:  # log lines (the progress messages), not warnings
            yield BakeProgress("build", total=total, warnings=list(run.result.warnings), message=line)
        run.intr.check()
        # only without a window (a viewport emptied for a bake's minutes would alarm its user);
        # the texture plan reads the evaluated meshes again
        if cfg.output == "VERTEX" and hide_while_baking():
            hidden = out_of_depsgraph(snap.objects, view_layer)
            # their evaluated copies' freed pages (in the main heap and Blender's threads' arenas):
            # not resident under the build (the 100k room: RSS 1.23 -> 0.90 GB there; docs/scale.md,
            # session 37 mem37)
            release_free_memory()
        params, min_area_rel, far_warning = solver_setup(snap.transport, cfg.params)
        run.warn([far_warning] if far_warning else [])
        yield BakeProgress(
            "build",
            total=total,
            warnings=list(run.result.warnings),
            message=f"Building the hierarchy ({len(snap.transport.loop_start)} polygons, "
            f"{cfg.quality.lower()} quality)",
        )
        run.intr.check()
        system, dyn, final = run.build(snap, params, min_area_rel, progress, total, final_dir, rebuild)
        writer, baker = run.open_writer(snap, params, system, final_dir)
        todo = run.frames_todo(snap, writer, baker, start, end)
        yield from run.frame_loop(snap, todo, dyn, final, writer, baker)
        run.intr.check()  # the last moment a cancel keeps the previous bake
        try:  # under the cache folder's lock, with the texture files of kept frames (farms)
            writer.commit(before=baker.finish if baker is not None else None)
        except CacheError as exc:
            raise SceneError(str(exc)) from None
        committed = True
        run.result.kept = writer.kept
        run.warn(writer.messages)
        # the host visibility its events traced, for the next bake (only speed: not written on a cancel)
        pc.keep(final_dir, final, log=run.result.notes.append, warn=lambda m: run.warn([m]))
        system = dyn = final = None  # (not held while Blender evaluates the geometry again)
        _let_go()
        back_in_depsgraph(hidden)
        hidden = []
        use_bake(scene, final_dir, cfg.output, snap.objects)
    finally:
        if writer is not None and not committed:
            writer.abort()
        if hidden:  # (a failed or cancelled bake: its arrays not held while Blender evaluates)
            system = dyn = final = None
            _let_go()
            back_in_depsgraph(hidden)
        STATE.baking = False
        scene.frame_set(original_frame)  # also loads this frame through the handler
    if committed and not scene.hr.playback:
        playback.load_frame(scene)
    run.result.seconds = time.perf_counter() - t_start
    return run.result


def _view_layer(scene):
    return bpy.context.view_layer if bpy.context.scene == scene else scene.view_layers[0]


def _outside_scene_range(scene, start, end):
    """Frames outside the scene's range are baked as asked, but said (a typo, another scene's range)."""
    s0, s1 = scene.frame_start, scene.frame_end
    outside = [
        f"{a}-{b}" if a < b else str(a)
        for a, b in ((start, min(end, s0 - 1)), (max(start, s1 + 1), end))
        if a <= b
    ]
    if not outside:
        return []
    return [
        f"Frames {' and '.join(outside)} lie outside the scene's frame range {s0}-{s1}: baked "
        "as asked (is the frame range right?)."
    ]


SMALL_SHAPE = 0.25  # a light shape under this share of its largest face: vertex output may miss it


def small_shape_warnings(dyn, final=None):
    """Light shapes much smaller than the faces they lie on (a ceiling panel on a cube room's
    one-quad ceiling): vertex output holds values at the corners, gathered once per corner's quarter
    of a face, so such a shape's light shows smeared over the face or not at all (an artist's cube
    room read -33% against Cycles, benchmarks/unseen_vs_cycles.py). Named, with the remedy. final:
    the gather; with an output layout (Vertex Spacing) a face's size is its largest finer face's."""
    recs = [r for r in dyn.shapes.values() if r.roots is not None and len(r.roots) and r.area > 0]
    if not recs:  # (most frames of most scenes: no per-patch pass)
        return []
    pt = dyn.system.patches
    poly_area = np.bincount(pt.poly, pt.area)
    out_layout = getattr(final, "output", None)
    if out_layout is not None:  # the output's faces on each transport polygon: the largest
        op = out_layout.patches
        poly_area = np.bincount(pt.poly, pt.area, len(out_layout.under_start) - 1)
        finer = np.zeros(len(poly_area))
        np.maximum.at(
            finer, out_layout.poly[op.poly], np.bincount(op.poly, op.area, len(out_layout.poly))[op.poly]
        )
        poly_area = np.minimum(poly_area, np.where(finer > 0, finer, poly_area))
    out = []
    for rec in recs:
        polys = np.unique(pt.poly[rec.roots])
        big = polys[np.argmax(poly_area[polys])]
        if rec.area < SMALL_SHAPE * poly_area[big]:
            obj = pt.object_names[int(pt.object_id[np.flatnonzero(pt.poly == big)[0]])]
            out.append(
                f"Light shape '{rec.name}' covers {100 * rec.area / poly_area[big]:.0f}% of the face of "
                f"'{obj}' it lies on ({poly_area[big]:.2g} m2): vertex output keeps the light at the "
                "faces' corners, so the shape's light shows smeared over the face or not at all; "
                f"subdivide '{obj}' (faces about the shape's size) or bake textures (Output: Baked Textures)."
            )
    return out


class _Bake:
    """The steps of one bake_frames run, sharing its settings, interrupts and warnings."""

    def __init__(self, scene, view_layer, cfg, interrupts, warnings, result):
        self.scene, self.view_layer, self.cfg = scene, view_layer, cfg
        self.intr = interrupts or _NoInterrupts()
        self.log = warnings if warnings is not None else Warnings()
        self.result = result
        result.log = self.log
        self._plan = None  # the texture plan, made once per bake (build() or open_writer())
        self._extract = None  # vertex output: every object's RGBA rows of one array (open_writer())

    def warn(self, items, frame=None):
        """Count warnings; returns the new ones (shown in progress reports)."""
        new = [w for w in items if self.log.add(w, frame)]
        self.result.warnings[:] = self.log.texts()
        return new

    def build(self, snap, params, min_area_rel, progress, total, cache_dir, rebuild=False):
        """(system, dyn, final gather): the scene precompute (hierarchy and final gather,
        io/precompute.py) loaded from the cache folder when it is valid, else built and stored
        there (rebuild: built in any case); the DynamicRadiosity every frame
        is solved and read through (without light shapes or lights, the base solution).
        What happened and why goes to the progress messages and result.precompute."""
        t0 = time.perf_counter()
        cfg, r = self.cfg, self.result

        def say(message, fraction=0.0, eta=float("nan")):
            if progress is not None:
                progress(BakeProgress("build", total=total, fraction=fraction, eta=eta, message=message))

        def on_build(info):
            self.intr.check()
            say(
                f"Building the hierarchy: {info.message}", BUILD_SHARE * float(info.fraction), float(info.eta)
            )

        def engine(system):
            # without light events the solution is the system's, solved to its own tolerance as
            # it always was: the gather's looser solver options pay off on events only
            options = cfg.solve_options if snap.has_shapes or snap.has_lights else {}
            # warm_moves off: a frame's values do not depend on the frames baked before it, so
            # farm nodes' frames equal one process's (docs/farm.md)
            return DynamicRadiosity(
                system, method=cfg.method, min_area_rel=min_area_rel, warm_moves=False, **options
            )

        made = {}

        def build():
            system = RadiositySystem(snap.transport, params, progress=on_build, threads=cfg.threads)
            made["dyn"] = dyn = engine(system)
            r.build_seconds = time.perf_counter() - t0
            final = None
            if cfg.gather is not None:
                dyn.solves.release_work()  # (the base solve's work arrays: not held under the gather's)
                release_free_memory()  # the build's freed temporaries: not resident under the gather's
                say(f"Final gather: tracing {cfg.gather['rays']} rays per output sample", BUILD_SHARE)
                t1 = time.perf_counter()
                plan = self.texture_plan(snap, system)
                if plan is not None:  # before the gather takes the memory (the previous bake stays)
                    try:
                        texture.check_memory(plan, cfg.gather, cfg.texel_density)
                    except TextureError as exc:
                        raise SceneError(str(exc)) from None
                final = make_gather(dyn, plan, dict(cfg.gather, threads=cfg.threads), output=snap.output)
                release_free_memory()  # (the gather's freed temporaries: not under prepare's)
                pc.prepare(final)  # the static emitters' direct light, stored with the rest
                r.gather_seconds = time.perf_counter() - t1
            return system, final

        def log(line):
            r.precompute.append(line)
            say(line[:1].upper() + line[1:])

        texture_gather = cfg.output == "TEXTURE" and cfg.gather is not None
        texels = (
            texture.lightmap_key(snap, self.view_layer, cfg.resolution, cfg.texel_density)
            if texture_gather
            else None
        )
        want = precompute_key(snap.transport, params, cfg.gather, texels, output=snap.output)
        with self.intr.raising():
            system, final, how = pc.load_or_build(
                cache_dir, want, build, log=log, force=rebuild, warn=lambda m: self.warn([m])
            )
            release_free_memory()  # the precompute's freed temporaries: not under the first frame's
            t1 = time.perf_counter()
            pc.use_threads(system, final, cfg.threads)  # a loaded precompute has the builder's count
            dyn = made["dyn"] if "dyn" in made else engine(system)
        r.precompute_loaded = how == "loaded"
        if r.precompute_loaded:
            r.load_seconds = t1 - t0  # the key (the scene's signatures) and the file read and restored
            r.build_seconds = time.perf_counter() - t0  # + DynamicRadiosity (its stored base)
        r.build_report = system.build
        r.rays = ray_backend_name(system)
        r.rays_note = ray_backend_note(r.rays)
        self.warn(system.build.warnings)
        return system, dyn, final

    def texture_plan(self, snap, system):
        """The texture output's plan on the system's patches (None for vertex output)."""
        if self.cfg.output != "TEXTURE" or self._plan is not None:
            return self._plan
        try:
            self._plan = texture.texture_plan(
                snap.scene_in,
                system.patches,
                self.view_layer,
                self.view_layer.depsgraph,
                self.cfg.resolution,
                self.cfg.texture_format,
                albedo=self.cfg.radiance_mode == "RADIANCE",
                density=self.cfg.texel_density,
            )
        except TextureError as exc:
            raise SceneError(str(exc)) from None
        return self._plan

    def manifest_info(self, snap, params):
        cfg, r = self.cfg, self.result
        info = {
            "blend": os.path.basename(bpy.data.filepath),
            "scene": self.scene.name,
            "method": cfg.method,
            "quality": cfg.quality,
            "feps": params.feps,
            "aeps": params.aeps,
            "contacts": params.contacts,
            "final_gather": cfg.gather is not None,
            "output": cfg.output,
            "radiance_mode": cfg.radiance_mode,
            "rays": r.rays,
            "created": time.strftime("%Y-%m-%d %H:%M:%S"),
            "view_layer": self.view_layer.name,
            "geometry": snap.geometry,
            "light_shapes": snap.shapes_id,
        }
        if snap.has_lights:  # which Blender lights took part (not their animated values)
            info["lights"] = {o.name: f"{o.data.type} {o.data.name}" for o in snap.lights}
            if snap.world:
                info["lights"]["(World)"] = f"WORLD {snap.world}"
        if r.rays_note:
            info["rays_note"] = r.rays_note
        return info

    def open_writer(self, snap, params, system, final_dir):
        """(CacheWriter, texture plan or None): where the frames go."""
        cfg, targets = self.cfg, snap.scene_in.targets
        info = self.manifest_info(snap, params)
        if cfg.output != "TEXTURE":
            objects = {
                t.key: {"mesh": t.mesh_name, "count": t.n_corner if cfg.domain == "CORNER" else t.n_point}
                for t in targets
            }
            sig = _signature(
                snap.mesh, params, cfg.domain, targets, cfg.radiance_mode, cfg.gather, snap.scene_in.transport
            )
            self._extract = FlatExtract(targets, cfg.domain)
            return CacheWriter(final_dir, objects, cfg.domain, sig, info), None
        baker = self.texture_plan(snap, system)
        self.warn(baker.warnings)
        sig = baker.signature(
            _signature(snap.mesh, params, "TEXTURE", targets, cfg.radiance_mode, cfg.gather)
        )
        writer = CacheWriter(final_dir, baker.objects_info(targets), "TEXTURE", sig, info)
        baker.bind(writer.tmp)
        return writer, baker

    def frames_todo(self, snap, writer, baker, start, end):
        """The range, and frames of the previous bake that this one keeps but whose files are
        missing or damaged, or whose light changed since: baked again (not kept, not dropped)."""
        in_range = set(range(start, end + 1))
        damaged = writer.damaged_frames(in_range)
        if snap.has_shapes or snap.has_lights:
            relit = writer.relit_frames(in_range | set(damaged), lambda f: self.lights_at(snap, f, [])[2])
            if relit:
                self.warn(
                    [
                        f"Frames {frame_ranges(relit)} of the previous bake were baked with other "
                        "light (light shapes, Blender lights or the World changed there since): "
                        "baked them again."
                    ]
                )
                in_range.update(relit)
                self.result.rebaked = list(relit)
        if baker is not None:
            old, why = writer.previous()
            if old is not None and not why:
                damaged.update(
                    baker.damaged_frames(writer.final, [f for f in old.frames if f not in in_range])
                )
        if damaged:
            self.result.rebaked = sorted(set(self.result.rebaked) | set(damaged))
            reasons = sorted(set(damaged.values()))
            self.warn(
                [
                    f"Frames {frame_ranges(damaged)} of the previous bake were missing or damaged "
                    f"({'; '.join(reasons[:3])}): baked them again."
                ]
            )
        return sorted(in_range | set(damaged))

    @functools.cached_property
    def moving(self):
        """The light shapes that move (lights_in.moving_shapes), read once per bake from the scene,
        not from its frames: a frame's values do not depend on the bake's frame range."""
        return scene_moving_shapes(self.view_layer)

    def lights_at(self, snap, frame, frame_warnings):
        """(light shapes, Blender lights, signature) at frame; ({}, None, "static") without either."""
        if not (snap.has_shapes or snap.has_lights):
            return {}, None, "static"
        self.scene.frame_set(frame)
        depsgraph = self.view_layer.depsgraph
        shapes = (
            collect_light_shapes(self.view_layer, depsgraph, LightShape, frame_warnings, moving=self.moving)
            if snap.has_shapes
            else {}
        )
        sig, lights = shapes_signature(shapes), None
        if snap.has_lights:
            lights = collect_lights(self.view_layer, depsgraph, Light, frame_warnings)
            sig += lights_signature(lights)
        return shapes, lights, sig

    def frame_values(self, snap, dyn, final, baker, shapes, lights, frame_warnings):
        """Solve the frame's light and return its values for the writer (texture plan or targets)."""
        cfg = self.cfg
        frame_warnings += dyn.apply(shapes, lights).messages
        if final is not None:  # the solves' work arrays and freed temporaries: not under the output's
            dyn.solves.release_work()
            release_free_memory()
        if baker is not None:
            return baker.radiance(dyn, cfg.radiance_mode, gather=final)
        frame_warnings += small_shape_warnings(dyn, final)
        mode, fx = cfg.radiance_mode, self._extract
        if final is not None and mode == "RADIANCE" and cfg.domain == "CORNER" and fx.flat:
            # the gather writes the objects' loops straight into the RGBA rows (as Live does; a
            # strength or colour edit: one sum over the cached responses, no array of every loop)
            return fx.rgba(None, lambda rows, out: final.loop_radiance(dyn, rows=rows, out=out))
        if mode == "INDIRECT":  # (BakeConfig: with the final gather only)
            values = final.loop_values(indirect_incident(final, dyn), cfg.domain)
        elif final is not None:
            values = final.loop_radiance(dyn, cfg.domain, "incident" if mode == "IRRADIANCE" else "radiance")
        elif mode == "IRRADIANCE":
            values = loop_incident(dyn, cfg.domain)
        else:
            values = dyn.loop_radiance(cfg.domain)
        return fx.rgba(values)  # {object name: (N, 4) float32 RGBA}, the values Target.extract gives

    def frame_loop(self, snap, todo, dyn, final, writer, baker):
        """Generator over the frames: a frame whose light equals the previous one's reuses its file."""
        total, r = len(todo), self.result
        prev_sig = prev_frame = None
        time_left = FrameEta(total)  # steady: an average of the frames' times, counting down
        for i, f in enumerate(todo):
            t_frame = time.perf_counter()
            self.intr.check()
            frame_warnings = []
            shapes, lights, sig = self.lights_at(snap, f, frame_warnings)
            self.intr.check()
            reused = sig == prev_sig
            if reused:
                writer.reuse(f, prev_frame)
                if baker is not None:
                    baker.reuse(f, prev_frame)
                r.reused += 1
            else:
                with self.intr.raising():
                    values = self.frame_values(snap, dyn, final, baker, shapes, lights, frame_warnings)
                self.intr.check()
                if baker is not None:
                    baker.write(f, values)
                    writer.write(f, {}, sig)  # the frame's entry in the manifest (textures hold the values)
                else:
                    writer.write(f, values, sig)
                r.solved += 1
            prev_sig, prev_frame = sig, f
            new_w = self.warn(frame_warnings, f)
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
    hr.bake_dir = paths.blend_relative(final_dir).rstrip("/\\") + "/"
    hr.playback = True
    scene.render.use_lock_interface = True  # renders read HR_Radiance in frame_change_pre
    playback.forget_readers()
    if output == "TEXTURE":
        texture.after_bake(scene, final_dir)
    else:
        objs = geo_objects if geo_objects is not None else geometry_objects(_view_layer(scene))
        texture.remove_material(objs)  # a texture preview would show deleted files
        refresh_preview(objs, bake_mode(scene))


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
    "ray_backend_name",
]
