"""Operators: bake (modal with progress, ESC cancels), light shapes, preview, cache."""
import bpy
from bpy.props import BoolProperty

from ..core.geometry import InputError
from . import playback, texture
from .bake import bake_frames, run_bake
from .cache import CacheError
from .preview import add_preview, remove_preview
from .scene_in import geometry_objects


class BakeJob:
    """Steps a bake generator and keeps the progress numbers (used by the modal operator)."""

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
        return 0.0 if p is None or not p.total else p.done / p.total

    def cancel(self):
        self.gen.close()   # the generator's finally block discards the partial bake


class HR_OT_bake(bpy.types.Operator):
    """Bake dynamic hierarchical radiosity over the frame range into HR_Radiance (ESC cancels)"""
    bl_idname = "hr.bake"
    bl_label = "Bake Radiosity"
    bl_options = {"REGISTER"}

    _job = None
    _timer = None
    running = False

    def execute(self, context):
        """Blocking bake (scripts, bpy.ops.hr.bake())."""
        try:
            res = run_bake(context.scene, view_layer=context.view_layer)
        except (InputError, OSError, RuntimeError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for w in res.warnings:
            self.report({"WARNING"}, w)
        self.report({"INFO"}, f"Baked {res.frames[0]}-{res.frames[1]}: {res.solved} solved, {res.reused} unchanged")
        return {"FINISHED"}

    def invoke(self, context, event):
        if HR_OT_bake.running:
            self.report({"WARNING"}, "A radiosity bake is already running")
            return {"CANCELLED"}
        self._job = BakeJob(bake_frames(context.scene, view_layer=context.view_layer))
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.01, window=context.window)
        wm.modal_handler_add(self)
        HR_OT_bake.running = True
        self._status(context, "HR Radiosity: reading the scene... (ESC to cancel)")
        return {"RUNNING_MODAL"}

    def _status(self, context, text):
        if context.workspace is not None:
            context.workspace.status_text_set(text)

    def _finish(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        self._status(context, None)
        HR_OT_bake.running = False

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC":
            job.cancel()
            self._finish(context)
            self.report({"WARNING"}, "Radiosity bake cancelled; the previous bake is kept")
            return {"CANCELLED"}
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"RUNNING_MODAL"} if event.type not in {"WINDOW_DEACTIVATE", "TIMER"} else {"PASS_THROUGH"}
        if job.step():
            context.window_manager.progress_update(int(100 * job.fraction()))
            self._status(context, f"HR Radiosity: {job.progress.message} (ESC to cancel)")
            return {"RUNNING_MODAL"}
        self._finish(context)
        for w in job.warnings:
            self.report({"WARNING"}, w)
        if job.error is not None:
            self.report({"ERROR"}, job.error)
            return {"CANCELLED"}
        r = job.result
        self.report({"INFO"}, f"Baked frames {r.frames[0]}-{r.frames[1]}: {r.solved} solved, "
                              f"{r.reused} unchanged ({r.seconds:.1f} s)")
        return {"FINISHED"}


class HR_OT_mark_light_shape(bpy.types.Operator):
    """Mark the selected meshes as light shapes: emissive patches lying on scene surfaces.
    They are not geometry, and are hidden from render rays (the bake carries their light)"""
    bl_idname = "hr.mark_light_shape"
    bl_label = "Mark as Light Shape"
    bl_options = {"REGISTER", "UNDO"}

    clear: BoolProperty(name="Clear", default=False, description="Turn the selected light shapes back into geometry")

    @classmethod
    def poll(cls, context):
        return any(o.type == "MESH" for o in context.selected_objects)

    def execute(self, context):
        n = 0
        for o in context.selected_objects:
            if o.type != "MESH":
                continue
            o.hr.is_light_shape = not self.clear
            for attr in ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                         "visible_volume_scatter", "visible_shadow"):
                setattr(o, attr, self.clear)
            o.show_in_front = not self.clear
            n += 1
        self.report({"INFO"}, f"{n} object(s) {'unmarked' if self.clear else 'marked as light shapes'}")
        return {"FINISHED"}


class HR_OT_add_preview(bpy.types.Operator):
    """Show the bake in the viewport and renders through an Emission shader: HR_Radiance, or for
    baked textures the image sequences on object-level material copies (restored by Remove Preview)"""
    bl_idname = "hr.add_preview"
    bl_label = "Preview Bake"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        objs = geometry_objects(context.view_layer)
        if texture.is_texture_bake(context.scene):
            try:
                n = texture.add_material(context.scene, objs)
            except (CacheError, RuntimeError) as exc:
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
            self.report({"INFO"}, f"Baked textures shown on {n} object(s)")
            return {"FINISHED"}
        texture.remove_material(objs)
        n = add_preview(objs)
        context.scene.render.use_lock_interface = True
        self.report({"INFO"}, f"Preview on {len(objs)} object(s), {n} material(s)")
        return {"FINISHED"}


class HR_OT_remove_preview(bpy.types.Operator):
    """Remove the preview nodes and give the materials their own shaders back"""
    bl_idname = "hr.remove_preview"
    bl_label = "Remove Preview"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        texture.remove_material()
        n = remove_preview()
        self.report({"INFO"}, f"Preview removed from {n} material(s)")
        return {"FINISHED"}


class HR_OT_load_frame(bpy.types.Operator):
    """Reload the current frame from the radiosity cache"""
    bl_idname = "hr.load_frame"
    bl_label = "Reload Cache"

    def execute(self, context):
        playback.forget_readers()
        if playback.load_frame(context.scene):
            return {"FINISHED"}
        self.report({"ERROR"}, playback.status(context.scene) or "No radiosity bake to load")
        return {"CANCELLED"}


class HR_OT_clear_bake(bpy.types.Operator):
    """Forget the bake (the cache files stay on disk) and remove HR_Radiance from the meshes"""
    bl_idname = "hr.clear_bake"
    bl_label = "Clear Bake"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        scene.hr.bake_dir = ""
        scene.hr.playback = False
        texture.remove_material([o for o in scene.objects if o.type == "MESH"])
        for o in scene.objects:
            if o.type == "MESH" and playback.ATTRIBUTE in o.data.color_attributes:
                o.data.color_attributes.remove(o.data.color_attributes[playback.ATTRIBUTE])
        return {"FINISHED"}


classes = (HR_OT_bake, HR_OT_mark_light_shape, HR_OT_add_preview, HR_OT_remove_preview,
           HR_OT_load_frame, HR_OT_clear_bake)
