"""Panels: Properties > Render > HR Radiosity, Properties > Object > HR Radiosity, and the
3D View sidebar tab "HR"."""

import os
import time

import bpy

from ..io import precompute as pc
from .state import STATE
from . import background, live, paths, playback


def _draw_bake(layout, context):
    scene = context.scene
    hr = scene.hr
    col = layout.column()
    job = background.active()
    if job is not None and job.state == "running":
        row = col.row(align=True)
        row.progress(factor=job.fraction, type="BAR", text=job.text())
        row.operator("hr.cancel_bake", text="", icon="CANCEL")
    else:
        row = col.row()
        row.scale_y = 1.4
        row.operator("hr.bake", icon="RENDER_ANIMATION")
    _draw_live(col, scene)
    d = paths.bake_dir_abs(scene)
    if d:
        col.label(text=f"Cache: {hr.bake_dir or d}", icon="FILE_CACHE")
    msg = playback.status(scene)
    if not msg and hr.playback and d and playback.render_unlocked(scene):
        msg = playback.LOCK_MESSAGE
    for part in msg.split("\n") if msg else []:
        for i, line in enumerate(_wrap(part, 60)):
            col.label(text=line, icon="ERROR" if i == 0 else "BLANK1")
    error = STATE.errors.get(scene.name_full)
    for i, line in enumerate(_wrap(f"Bake failed: {error}", 60) if error else []):
        col.label(text=line, icon="ERROR" if i == 0 else "BLANK1")
    notes = STATE.notes.get(scene.name_full) or []
    for part in notes[:4]:
        for i, line in enumerate(_wrap(part, 60)):
            col.label(text=line, icon="INFO" if i == 0 else "BLANK1")
    if len(notes) > 4:
        col.label(text=f"... and {len(notes) - 4} more (see the Info editor)", icon="BLANK1")
    row = col.row(align=True)
    row.operator("hr.add_preview", icon="SHADING_RENDERED")
    row.operator("hr.remove_preview", text="", icon="X")
    row = col.row(align=True)
    row.prop(hr, "playback")
    row.operator("hr.load_frame", text="", icon="FILE_REFRESH")
    row.operator("hr.clear_bake", text="", icon="X")
    row.operator("hr.delete_bake", text="", icon="TRASH")
    _draw_precompute(col, scene)


_described = {}  # file -> ((mtime, size), describe()): the panel redraws often, a file is read once


def precompute_text(scene):
    """The panel's line on the scene precompute of the cache folder the next bake uses: whether it
    is there and readable, its size and age ('' without a saved .blend). Whether it matches the
    scene is known when a bake or Live reads the scene (they say so)."""
    d = paths.default_cache_dir(scene)
    if not d:
        return ""
    path = os.path.join(d, pc.FILENAME)
    try:
        st = os.stat(path)
    except OSError:
        return "No scene precompute: the next bake builds it"
    key = (st.st_mtime_ns, st.st_size)
    if _described.get(path, (None,))[0] != key:
        _described[path] = (key, pc.describe(d))
    info = _described[path][1]
    if info is None:
        return "No scene precompute: the next bake builds it"
    if info["problem"]:
        return f"Scene precompute unusable ({info['problem']}): the next bake builds it again"
    age = pc.age_text(time.time() - (info["created"] or st.st_mtime))
    return f"Scene precompute: {info['bytes'] / 1e6:.1f} MB, built {age} ago; reused while the geometry holds"


def _draw_precompute(col, scene):
    text = precompute_text(scene)
    if not text:
        return
    row = col.row(align=True)
    row.label(text=text, icon="MOD_BUILD")
    row.operator("hr.rebuild_precompute", text="", icon="FILE_REFRESH")


def _draw_live(col, scene):
    """The Live Relight button, the build's progress bar and the session's state."""
    sess = live.session(scene)
    row = col.row(align=True)
    row.operator("hr.live_toggle", text="Live Relight", icon="LIGHT_AREA", depress=sess is not None)
    if sess is None:
        msg = live.message(scene)
        for i, line in enumerate(_wrap(msg, 60) if msg else []):
            col.label(text=line, icon="INFO" if i == 0 else "BLANK1")
        return
    if sess.building:
        w = sess.worker
        eta = "" if w.eta != w.eta else f" \u00b7 about {w.eta:.0f} s left"
        col.progress(
            factor=w.fraction, type="BAR", text=f"{100 * w.fraction:.0f}% \u00b7 building the hierarchy{eta}"
        )
    icon = "ERROR" if (sess.error or sess.fatal or sess.problems) else "INFO"
    for part in [sess.text()] + ([sess.problems] if sess.problems else []) + sess.light_notes[:2]:
        for i, line in enumerate(_wrap(part, 60)):
            col.label(text=line, icon=icon if i == 0 else "BLANK1")


def _wrap(text, width):
    import textwrap

    return textwrap.wrap(text, width) or [text]


class HR_PT_radiosity(bpy.types.Panel):
    bl_label = "HR Radiosity"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    def draw(self, context):
        _draw_bake(self.layout, context)


class HR_PT_radiosity_settings(bpy.types.Panel):
    bl_label = "Settings"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_parent_id = "HR_PT_radiosity"

    def draw(self, context):
        hr = context.scene.hr
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(hr, "method")
        layout.prop(hr, "quality")
        sub = layout.column(align=True)
        if hr.quality == "CUSTOM":
            sub.prop(hr, "feps")
            sub.prop(hr, "aeps")
        else:  # the preset's thresholds, read only (the bake takes the whole preset)
            from ..core.refine import RefineParams

            p = RefineParams.preset(hr.quality.lower())
            sub.enabled = False
            sub.label(text=f"Link threshold (Feps): {p.feps:g}")
            sub.label(text=f"Smallest element (Aeps): {p.aeps:g}")
        layout.prop(hr, "contacts")
        layout.prop(hr, "final_gather")
        layout.prop(hr, "output")
        layout.prop(hr, "radiance_mode")
        if hr.output == "TEXTURE":
            layout.prop(hr, "texel_density")
            layout.prop(hr, "texture_resolution")
            layout.prop(hr, "texture_format")
        else:
            layout.prop(hr, "domain")
            row = layout.row()
            row.active = bool(hr.final_gather)  # without it the bake uses no spacing (BakeConfig.spacing)
            row.prop(hr, "vertex_spacing")
            if hr.vertex_spacing > 0 and hr.final_gather:  # Live makes no helpers: it finds the bake's
                note = layout.row()
                note.enabled = False
                note.label(text="Live Relight: the finer corners once a bake has added them", icon="INFO")
        layout.prop(hr, "cache_folder")
        layout.prop(hr, "threads")
        # an operator for the checkbox: turned on, it starts from the scene's range (props.py)
        row = layout.row()
        row.operator(
            "hr.custom_frame_range",
            icon="CHECKBOX_HLT" if hr.use_frame_range else "CHECKBOX_DEHLT",
            emboss=False,
            depress=hr.use_frame_range,
        )
        sub = layout.column(align=True)
        if hr.use_frame_range:
            sub.prop(hr, "frame_start")
            sub.prop(hr, "frame_end")
        else:  # what the bake takes: the scene's range
            sub.enabled = False
            sub.label(text=f"Frames {context.scene.frame_start}-{context.scene.frame_end} (the scene's)")


class HR_PT_radiosity_lights(bpy.types.Panel):
    """The Blender lights the bake uses (issue 20), each with its switch to leave it out."""

    bl_label = "Lights"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_parent_id = "HR_PT_radiosity"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        from .scene_in import _walk_collections

        from .lights_in import world_summary

        layout = self.layout
        row = layout.row()
        row.prop(context.scene.hr, "use_world", text="")
        row.label(text=world_summary(context.scene), icon="WORLD")
        lights = [o for o in _walk_collections(context.view_layer) if o.type == "LIGHT"]
        if not lights:
            layout.label(text="No Blender lights (emissive meshes and light shapes only)")
            return
        for o in lights:
            row = layout.row()
            used = not o.hr.exclude and not o.hide_render and o.data.energy > 0
            unit = "W/m²" if o.data.type == "SUN" else "W"
            row.label(
                text=f"{o.name}: {o.data.type.lower()}, {o.data.energy:g} {unit}",
                icon="LIGHT" if used else "BLANK1",
            )
            row.prop(o.hr, "exclude", text="Exclude")


class HR_PT_object(bpy.types.Panel):
    bl_label = "HR Radiosity"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.type in ("MESH", "LIGHT")

    def draw(self, context):
        obj = context.object
        layout = self.layout
        layout.prop(obj.hr, "exclude")
        if obj.type == "LIGHT":  # a Blender light takes part unless excluded (docs/lights.md)
            return
        layout.prop(obj.hr, "is_light_shape")
        hr = context.scene.hr
        if hr.output == "TEXTURE":
            layout.prop(obj.hr, "lightmap_resolution")
            if obj.hr.lightmap_resolution == 0:  # what the bake gives it: sized by area
                from .texture import resolution_for, scene_bound

                d = scene_bound(hr.texture_resolution, hr.texel_density)  # the last bake's, if lowered
                n = resolution_for(obj, hr.texture_resolution, d)
                how = f"{d:.3g} texels/m" if d > 0 else "the Texture Size"
                how += ": the scene's bound" if d != hr.texel_density else ""
                layout.label(text=f"Lightmap {n} x {n} ({how})")
        row = layout.row(align=True)
        row.operator("hr.mark_light_shape")
        row.operator("hr.mark_light_shape", text="Unmark").clear = True


class HR_PT_view3d(bpy.types.Panel):
    bl_label = "HR Radiosity"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "HR"

    def draw(self, context):
        _draw_bake(self.layout, context)
        self.layout.operator("hr.mark_light_shape", icon="LIGHT_AREA")


classes = (HR_PT_radiosity, HR_PT_radiosity_settings, HR_PT_radiosity_lights, HR_PT_object, HR_PT_view3d)
