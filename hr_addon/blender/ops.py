"""Operators: bake (a background process with progress; Cancel keeps the previous bake), light
shapes, preview, cache (reload, clear, delete), Live Relight (toggle, synchronous update)."""

import os

import bpy
from bpy.props import BoolProperty

from ..core.geometry import InputError
from ..io import precompute as pc
from ..io.cache import MANIFEST, MARKER, TEX_DIR, CacheError, CacheReader, owned_files
from ..io.cache_folder import CARRIED
from .state import STATE
from . import background, live, names, paths, playback, texture
from .bake import run_bake
from .props import custom_range
from .preview import (
    add_preview,
    add_preview_steps,
    bake_mode,
    has_preview,
    remove_preview,
    remove_preview_steps,
)
from .lights_in import light_shape_problem
from .own_values import remove_own_values
from .scene_in import geometry_objects
from .steps import advance


def _report_bake_state(op, context):
    """Compare the scene with its bake (playback.check_scene) and report it; the message or ''."""
    try:
        dg = context.evaluated_depsgraph_get()
    except (RuntimeError, AttributeError):
        dg = None
    msg = playback.check_scene(context.scene, dg, force=True)
    if msg:
        op.report({"WARNING"}, msg)
    problem = STATE.messages.get(context.scene.name_full, "")
    if problem and problem != msg:
        op.report({"WARNING"}, problem)
    return msg


def _has_bake(scene):
    return bool(paths.bake_dir_abs(scene))


def _bake_ended(scene, warnings, error=""):
    """Keep what the panel shows after a bake: its warnings, and why it failed ('' if it did not)."""
    STATE.notes[scene.name_full] = list(warnings)
    STATE.errors[scene.name_full] = error


def _redraw(context):
    wm = context.window_manager
    for win in wm.windows:
        for area in win.screen.areas:
            if area.type in {"PROPERTIES", "VIEW_3D"}:
                area.tag_redraw()


def _status_text(context, text):
    for win in context.window_manager.windows:
        if win.workspace is not None:
            win.workspace.status_text_set(text)


FINISH_TICK = 0.02  # seconds between the bake timer's ticks while the result loads (background.poll)
PREVIEW_TICK, PREVIEW_SLICE = 0.01, 0.04  # the Preview button's timer; seconds of wiring per tick


class HR_OT_bake(bpy.types.Operator):
    """Bake dynamic hierarchical radiosity over the frame range, in a background process
    (Blender stays usable; Cancel keeps the previous bake)"""

    bl_idname = "hr.bake"
    bl_label = "Bake Radiosity"
    bl_options = {"REGISTER"}

    _timer = None
    _job = None
    _fast = False

    @classmethod
    def poll(cls, context):
        if context.scene is None or not hasattr(context.scene, "hr"):
            return False
        if background.running():
            cls.poll_message_set("A radiosity bake is running")
            return False
        if paths.default_cache_dir(context.scene) is None:
            cls.poll_message_set("Save the .blend file first: the cache folder is relative to it")
            return False
        return True

    def execute(self, context):
        """Blocking bake in this process (scripts, bpy.ops.hr.bake(), background mode)."""
        try:
            res = run_bake(context.scene, view_layer=context.view_layer)
        except (InputError, OSError, RuntimeError, ValueError) as exc:
            _bake_ended(context.scene, [], str(exc))
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for w in res.warning_lines():
            self.report({"WARNING"}, w)
        _bake_ended(context.scene, res.warning_lines())
        self.report(
            {"INFO"},
            f"Baked {res.frames[0]}-{res.frames[1]}: {res.solved} solved, "
            f"{res.reused} unchanged ({res.rays_text})",
        )
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background:  # no event loop: bake here
            return self.execute(context)
        job = background.BackgroundBake(context.scene, context.view_layer)
        try:
            job.start()
        except (InputError, OSError, RuntimeError, ValueError) as exc:
            _bake_ended(context.scene, job.warnings, str(exc))
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        STATE.errors.pop(context.scene.name_full, None)
        self._job = job
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.modal_handler_add(self)
        _status_text(context, f"HR Radiosity: {job.text()}")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        # Every event passes through: the viewport, timeline and editors stay fully usable.
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"PASS_THROUGH"}
        job = self._job
        if job.poll():
            if job.finishing and not self._fast:  # the result loads a short step per tick: faster ticks
                wm = context.window_manager
                wm.event_timer_remove(self._timer)
                self._timer, self._fast = wm.event_timer_add(FINISH_TICK, window=context.window), True
            _status_text(context, f"HR Radiosity: {job.text()}")
            _redraw(context)
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        self._timer = None
        _status_text(context, None)
        _redraw(context)
        for w in job.warnings:
            self.report({"WARNING"}, w)
        scene = bpy.data.scenes.get(getattr(job, "scene_name", "") or "")
        if job.state == "done":
            if scene is not None:
                _bake_ended(scene, job.warnings)
            self.report({"INFO"}, f"HR Radiosity: {job.summary}")
            return {"FINISHED"}
        if job.state == "cancelled":
            self.report({"WARNING"}, "Radiosity bake cancelled; the previous bake is kept")
        else:
            if scene is not None:
                _bake_ended(scene, job.warnings, job.error)
            self.report({"ERROR"}, f"Radiosity bake failed: {job.error}")
        return {"CANCELLED"}


class HR_OT_cancel_bake(bpy.types.Operator):
    """Stop the running radiosity bake; the previous bake is kept"""

    bl_idname = "hr.cancel_bake"
    bl_label = "Cancel Bake"

    @classmethod
    def poll(cls, context):
        job = background.active()
        return background.running() and not job.cancelling and not job.finishing

    def execute(self, context):
        job = background.active()
        if job is not None:
            # the signal only: the bake's timer (HR_OT_bake.modal) ends it once the worker has gone,
            # the UI does not wait for it (a worker still loading the file takes seconds to stop)
            job.cancel(wait=bpy.app.background)
        return {"FINISHED"}


class HR_OT_mark_light_shape(bpy.types.Operator):
    """Mark the selected meshes as light shapes: emissive patches lying on scene surfaces.
    They are not geometry, and are hidden from render rays (the bake carries their light)"""

    bl_idname = "hr.mark_light_shape"
    bl_label = "Mark as Light Shape"
    bl_options = {"REGISTER", "UNDO"}

    clear: BoolProperty(
        name="Clear", default=False, description="Turn the selected light shapes back into geometry"
    )

    @classmethod
    def poll(cls, context):
        return any(o.type == "MESH" for o in context.selected_objects)

    def execute(self, context):
        n = 0
        for o in context.selected_objects:
            if o.type != "MESH":
                continue
            o.hr.is_light_shape = not self.clear
            for attr in (
                "visible_camera",
                "visible_diffuse",
                "visible_glossy",
                "visible_transmission",
                "visible_volume_scatter",
                "visible_shadow",
            ):
                setattr(o, attr, self.clear)
            o.show_in_front = not self.clear
            n += 1
        problems = []
        if not self.clear:  # said now, not first at bake time (and again then)
            dg = context.evaluated_depsgraph_get()
            for o in context.selected_objects:
                why = o.type == "MESH" and light_shape_problem(o, dg)[1]
                if why:
                    problems.append(f"Light shape '{o.name}': {why}.")
        for p in problems:
            self.report({"WARNING"}, p)
        more = f"; {len(problems)} with a problem (see the warnings)" if problems else ""
        self.report({"INFO"}, f"{n} object(s) {'unmarked' if self.clear else 'marked as light shapes'}{more}")
        return {"FINISHED"}


class HR_OT_custom_frame_range(bpy.types.Operator):
    """Bake a custom frame range instead of the scene's (turned on, it starts from the scene's
    range until Start and End are set)"""

    bl_idname = "hr.custom_frame_range"
    bl_label = "Custom Frame Range"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        hr = context.scene.hr
        if not hr.use_frame_range:
            # an operator, not an update callback on use_frame_range (see props.py)
            hr.frame_start, hr.frame_end = custom_range(context.scene)
        hr.use_frame_range = not hr.use_frame_range
        return {"FINISHED"}


class _SlicedModal:
    """A button's work as a generator of steps (preview.add_preview_steps ...), a slice of them per
    timer tick (PREVIEW_SLICE s) so the UI stays usable. Subclasses give STOPPED (the error when
    the data went away meanwhile), progress(done) -> status text and finished(context, n)."""

    _timer = None
    _steps = None

    def _start(self, context, steps, total=None):
        self._steps, self._done, self._total = steps, 0, total
        wm = context.window_manager
        self._timer = wm.event_timer_add(PREVIEW_TICK, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"PASS_THROUGH"}
        try:  # a step at least, then until the slice is used
            taken, finished, n = advance(self._steps, PREVIEW_SLICE)
        except ReferenceError:  # objects or materials removed meanwhile
            self._end(context)
            self.report({"ERROR"}, self.STOPPED)
            return {"CANCELLED"}
        self._done += taken
        if not finished:
            _status_text(context, self.progress(self._done))
            return {"PASS_THROUGH"}
        self._end(context)
        self.finished(context, n)
        _redraw(context)
        return {"FINISHED"}

    def _end(self, context):
        context.window_manager.event_timer_remove(self._timer)
        self._timer, self._steps = None, None
        _status_text(context, None)


class HR_OT_add_preview(_SlicedModal, bpy.types.Operator):
    """Show the bake in the viewport and renders through an Emission shader: HR_Radiance, or for
    baked textures the image sequences on object-level material copies (restored by Remove Preview)"""

    bl_idname = "hr.add_preview"
    bl_label = "Preview Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.scene is None or not _has_bake(context.scene):
            cls.poll_message_set("Nothing to preview: bake first")
            return False
        return True

    def execute(self, context):
        if not _has_bake(context.scene):
            self.report({"ERROR"}, "Nothing to preview: there is no radiosity bake (Bake Radiosity first)")
            return {"CANCELLED"}
        objs = geometry_objects(context.view_layer)
        if texture.is_texture_bake(context.scene):
            warnings = []
            try:
                n = texture.add_material(context.scene, objs, warnings)
            except (CacheError, RuntimeError) as exc:
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
            for w in warnings:
                self.report({"WARNING"}, w)
            self.report({"INFO"}, f"Baked textures shown on {n} object(s)")
            _report_bake_state(self, context)
            return {"FINISHED"}
        texture.remove_material(objs)
        n = add_preview(objs, bake_mode(context.scene))
        context.scene.render.use_lock_interface = True
        self.report({"INFO"}, f"Preview on {len(objs)} object(s), {n} material(s)")
        _report_bake_state(self, context)
        return {"FINISHED"}

    def invoke(self, context, event):
        """The button: the vertex preview wired a slice of materials per timer tick (PREVIEW_SLICE
        s), the UI usable meanwhile; the stale check then runs on playback's timer. Scripts and
        background mode (execute) wire every material in one call."""
        if not playback.SPREAD or not _has_bake(context.scene) or texture.is_texture_bake(context.scene):
            return self.execute(context)  # (SPREAD: False in background mode, no timers there)
        objs = geometry_objects(context.view_layer)
        texture.remove_material(objs)
        self._n_objects = len(objs)
        n_materials = len({s.material for o in objs for s in o.material_slots if s.material})
        # the Attribute nodes named in one last step: naming one costs Blender a relations update
        # (~0.6 s at 100k) at its next evaluation, so per slice the UI would pay it every tick
        return self._start(context, add_preview_steps(objs, bake_mode(context.scene), last=True), n_materials)

    STOPPED = "Preview stopped: objects were removed meanwhile (press Preview again)"

    def progress(self, done):
        return f"HR Radiosity: preview, {done} of ~{self._total} material(s)"

    def finished(self, context, n):
        context.scene.render.use_lock_interface = True
        self.report({"INFO"}, f"Preview on {self._n_objects} object(s), {n} material(s)")
        problem = STATE.messages.get(context.scene.name_full, "")
        if problem:
            self.report({"WARNING"}, problem)
        STATE.dirty.add(context.scene.name_full)  # compared on playback's timer, a slice per tick
        playback._schedule_check(0.0)


class HR_OT_remove_preview(_SlicedModal, bpy.types.Operator):
    """Remove the preview nodes and give the materials their own shaders back"""

    bl_idname = "hr.remove_preview"
    bl_label = "Remove Preview"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return has_preview()

    def execute(self, context):
        texture.remove_material()
        n = remove_preview()
        self.report({"INFO"}, f"Preview removed from {n} material(s)")
        return {"FINISHED"}

    def invoke(self, context, event):
        """The button: a slice of materials per timer tick, as Preview Bake's (execute: in one call)."""
        if not playback.SPREAD:
            return self.execute(context)
        texture.remove_material()
        return self._start(context, remove_preview_steps())

    STOPPED = "Remove Preview stopped: materials were removed meanwhile (press it again)"

    def progress(self, done):
        return f"HR Radiosity: removing the preview, {done} material(s)"

    def finished(self, context, n):
        self.report({"INFO"}, f"Preview removed from {n} material(s)")


class HR_OT_load_frame(bpy.types.Operator):
    """Reload the current frame from the radiosity cache"""

    bl_idname = "hr.load_frame"
    bl_label = "Reload Cache"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and _has_bake(context.scene)

    def execute(self, context):
        playback.forget_readers()
        ok = playback.load_frame(context.scene)
        stale = _report_bake_state(self, context)
        if ok:
            return {"FINISHED"}
        msg = STATE.messages.get(context.scene.name_full, "")
        if msg or not stale:
            self.report({"ERROR"}, msg or "No radiosity bake to load")
        return {"CANCELLED"}


class HR_OT_clear_bake(bpy.types.Operator):
    """Forget the bake (the cache files stay on disk) and remove HR_Radiance from the meshes"""

    bl_idname = "hr.clear_bake"
    bl_label = "Clear Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.scene is None or background.running():
            return False
        if not _has_bake(context.scene):
            cls.poll_message_set("There is no radiosity bake to clear")
            return False
        return True

    def execute(self, context):
        _forget_bake(context.scene)
        return {"FINISHED"}


def _forget_bake(scene):
    scene.hr.bake_dir = ""
    scene.hr.playback = False
    STATE.stale.pop(scene.name_full, None)
    STATE.messages.pop(scene.name_full, None)
    STATE.notes.pop(scene.name_full, None)
    STATE.errors.pop(scene.name_full, None)
    texture.remove_material([o for o in scene.objects if o.type == "MESH"])
    remove_own_values([o for o in scene.objects if o.type == "MESH"])
    for o in scene.objects:
        if o.type == "MESH" and names.ATTRIBUTE in o.data.color_attributes:
            o.data.color_attributes.remove(o.data.color_attributes[names.ATTRIBUTE])
    playback.forget_readers()


def delete_cache_files(directory, keep_precompute=True):
    """Remove the files a bake wrote in `directory` (io.cache.owned_files: the ones its manifest
    lists, its marker and manifest), then its textures folder and the folder itself if nothing else
    is left in them. Returns the number of files removed. Nothing is removed from a folder that is
    not a radiosity cache (CacheError), nor any file a bake did not write.
    keep_precompute: the scene precompute (io/precompute.py) stays, and with it the folder's
    marker that makes it ours; else it goes too."""
    CacheReader(directory)  # raises CacheError unless it is a radiosity cache
    kept = keep_precompute and os.path.isfile(os.path.join(directory, pc.FILENAME))
    removed = 0 if kept else int(pc.remove(directory))
    # the manifest and the marker last: an interrupted delete leaves a cache folder that says so
    own = sorted(owned_files(directory), key=lambda r: (r == MARKER, r == MANIFEST, r))
    if kept:  # the precompute and its lock outlive bakes (io.cache_folder.CARRIED), the marker with them
        own = [r for r in own if r != MARKER and r not in CARRIED]
    for r in own:
        os.remove(os.path.join(directory, r))
    for d in (os.path.join(directory, TEX_DIR), directory):
        try:
            os.rmdir(d)
        except OSError:
            pass  # absent, or other files in it: not ours, left alone
    return len(own) + removed


class HR_OT_delete_bake(bpy.types.Operator):
    """Delete the baked files from disk and remove HR_Radiance (asks for confirmation)"""

    bl_idname = "hr.delete_bake"
    bl_label = "Delete Bake"
    bl_options = {"REGISTER"}

    keep_precompute: BoolProperty(
        name="Keep the Scene Precompute",
        description="Keep the precompute (hierarchy, links, final gather) in the cache folder, so that "
        "the next bake of the unchanged scene skips the build",
        default=True,
    )

    @classmethod
    def poll(cls, context):
        if context.scene is None or background.running():
            return False
        if not _has_bake(context.scene):
            cls.poll_message_set("There is no radiosity bake to delete")
            return False
        return True

    def invoke(self, context, event):
        wm = context.window_manager
        if bpy.app.version >= (4, 1, 0):
            return wm.invoke_props_dialog(self, title="Delete Bake", confirm_text="Delete")
        return wm.invoke_props_dialog(self)

    def draw(self, context):
        self.layout.label(
            text=f"Delete the files of the radiosity bake in {paths.bake_dir_abs(context.scene)}?"
        )
        if os.path.isfile(os.path.join(paths.bake_dir_abs(context.scene), pc.FILENAME)):
            self.layout.prop(self, "keep_precompute")

    def execute(self, context):
        scene = context.scene
        directory = paths.bake_dir_abs(scene)
        try:
            n = delete_cache_files(directory, self.keep_precompute)
        except (CacheError, OSError) as exc:
            self.report({"ERROR"}, f"Cannot delete the bake in '{directory}': {exc}")
            return {"CANCELLED"}
        _forget_bake(scene)
        self.report({"INFO"}, f"Deleted the radiosity bake ({n} file(s)) in {directory}")
        return {"FINISHED"}


class HR_OT_rebuild_precompute(bpy.types.Operator):
    """Discard the scene precompute, so that the next bake (or Live Relight) builds the hierarchy
    and the final gather again (the command line: --rebuild)"""

    bl_idname = "hr.rebuild_precompute"
    bl_label = "Rebuild Precompute"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if context.scene is None or STATE.bake_running():
            return False
        d = paths.default_cache_dir(context.scene)
        if not d or not os.path.isfile(os.path.join(d, pc.FILENAME)):
            cls.poll_message_set("There is no scene precompute")
            return False
        return True

    def execute(self, context):
        d = paths.default_cache_dir(context.scene)
        try:
            gone = pc.remove(d)
        except OSError as exc:
            self.report({"ERROR"}, f"Cannot delete the scene precompute in '{d}': {exc}")
            return {"CANCELLED"}
        if not gone:
            self.report({"WARNING"}, f"'{pc.FILENAME}' in '{d}' is not a file a bake wrote: left alone")
            return {"CANCELLED"}
        self.report({"INFO"}, "Scene precompute discarded: the next bake builds it again")
        return {"FINISHED"}


class HR_OT_live_toggle(bpy.types.Operator):
    """Live Relight: keep the hierarchy in memory and update HR_Radiance whenever a light shape is
    moved, reshaped, recoloured, hidden or shown (press again: the baked playback comes back)"""

    bl_idname = "hr.live_toggle"
    bl_label = "Live Relight"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if context.scene is None or not hasattr(context.scene, "hr"):
            return False
        if STATE.bake_running() and not live.is_live(context.scene):
            cls.poll_message_set(live.BAKE_RUNNING)
            return False
        return True

    def execute(self, context):
        scene = context.scene
        if live.is_live(scene) or scene.hr.live:
            what = live.stop(scene)
            self.report({"INFO"}, f"Live Relight off: {what or 'it was not running'}")
            _redraw(context)
            return {"FINISHED"}
        try:
            if bpy.app.background:  # no event loop: build and compute here
                scene.hr.live = True
                live.update(scene, context.view_layer)
                self.report({"INFO"}, "Live Relight on: HR_Radiance is current")
            else:
                live.start(scene, context.view_layer)
                self.report({"INFO"}, "Live Relight on: building the hierarchy in the background")
        except (InputError, RuntimeError, ValueError) as exc:
            self.report({"ERROR"}, f"Live Relight: {exc}")
            return {"CANCELLED"}
        _redraw(context)
        return {"FINISHED"}


class HR_OT_live_update(bpy.types.Operator):
    """Make HR_Radiance current for Live Relight now: read every light shape (hide_render: on or
    off) and the geometry, apply what changed since the last update and write HR_Radiance. It
    starts Live when Scene.hr.live is on, and ends it (the baked playback again) when it is off.
    Synchronous: what scripts and Blender in background mode use"""

    bl_idname = "hr.live_update"
    bl_label = "Update Live Relight"
    bl_options = {"REGISTER"}

    check_geometry: BoolProperty(
        name="Check Geometry",
        default=True,
        description="Compare every participating object with the geometry the hierarchy was built "
        "from (off: only which objects take part and what the depsgraph reported as "
        "changed; faster on big scenes)",
    )

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "hr")

    def execute(self, context):
        scene = context.scene
        try:
            sess, what = live.update(scene, context.view_layer, check_geometry=self.check_geometry)
        except (InputError, RuntimeError, ValueError) as exc:
            self.report({"ERROR"}, f"Live Relight: {exc}")
            return {"CANCELLED"}
        if sess is None:
            self.report(
                {"INFO"} if scene.hr.live or what.startswith("Live Relight off") else {"WARNING"}, what
            )
            return {"FINISHED"} if what.startswith("Live Relight off") else {"CANCELLED"}
        return {"FINISHED"}


classes = (
    HR_OT_bake,
    HR_OT_cancel_bake,
    HR_OT_mark_light_shape,
    HR_OT_custom_frame_range,
    HR_OT_add_preview,
    HR_OT_remove_preview,
    HR_OT_load_frame,
    HR_OT_clear_bake,
    HR_OT_delete_bake,
    HR_OT_rebuild_precompute,
    HR_OT_live_toggle,
    HR_OT_live_update,
)
