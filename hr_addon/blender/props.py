"""Settings: Scene.hr (bake settings and bake state) and Object.hr (per-object flags)."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from .settings import DEFAULTS, DENSITY, RESOLUTION, TEXEL_DENSITY, TEXTURE_SIZE, VERTEX_SPACING, items

# Blender 4.5+ warns about "//" in path properties unless they declare blend-relative support.
_REL = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()


class HR_SceneSettings(bpy.types.PropertyGroup):
    method: EnumProperty(
        name="Method",
        items=items("method"),
        default=DEFAULTS["method"],
        description="How light-shape changes are applied from one frame to the next",
    )
    # No update callback (it would copy the preset into feps/aeps): the bpy module of Blender 4.2 and
    # 4.5 crashes at exit when a property has one. The panel shows the preset's values instead.
    quality: EnumProperty(
        name="Quality",
        items=items("quality"),
        default=DEFAULTS["quality"],
        description="Refinement preset (Custom: the thresholds below)",
    )
    feps: FloatProperty(
        name="Link threshold (Feps)",
        default=0.02,
        min=1e-4,
        max=1.0,
        precision=4,
        description="Form factor threshold: links transporting more are subdivided (Custom quality)",
    )
    aeps: FloatProperty(
        name="Smallest element (Aeps)",
        default=2e-4,
        min=1e-7,
        max=0.1,
        precision=6,
        description="Smallest element area as a fraction of the total scene area (Custom quality)",
    )
    contacts: BoolProperty(
        name="Contacts",
        default=True,
        description="Find surfaces covered by objects standing on them (a box on a floor, a book on "
        "a shelf) and refine along the contact, so no light leaks under them and the band beside "
        "them is right",
    )
    final_gather: BoolProperty(
        name="Final Gather",
        default=True,
        description="Every output point (vertex corner or texel) gathers its own light: exact direct "
        "light from every emitter with shadow rays, and the bounced light from the hierarchy's "
        "solution through rays traced once per geometry. Sharp shadows and light-shape outlines, "
        "right on small objects. Off: each point shows the hierarchy element it lies in (the classic "
        "hierarchical radiosity output, faster to set up)",
    )
    threads: IntProperty(
        name="Threads",
        default=0,
        min=0,
        max=1024,
        description="Threads for the bake (0: every core, as Cycles' Auto-detect). Live Relight keeps "
        "one core for the interface. The result does not depend on it",
    )
    output: EnumProperty(
        name="Output",
        items=items("output"),
        default=DEFAULTS["output"],
        description="Where the baked radiance goes",
    )
    radiance_mode: EnumProperty(
        name="Values",
        items=items("radiance_mode"),
        default=DEFAULTS["radiance_mode"],
        description="What the bake stores: outgoing radiance, or irradiance for lightmaps that "
        "the material's base colour (textures included) multiplies, or that without the Blender "
        "lights' and the World's direct light (EEVEE renders it)",
    )
    texture_resolution: IntProperty(
        name="Texture Size",
        default=TEXTURE_SIZE,
        min=RESOLUTION[0],
        soft_min=16,
        max=RESOLUTION[1],
        soft_max=4096,
        description="Width and height of the largest lightmap in texels: with a Texel Density, the "
        "most an object's lightmap may reach (objects whose area wants more get this; an object's "
        "Lightmap Size overrides it)",
    )
    texel_density: FloatProperty(
        name="Texel Density",
        default=TEXEL_DENSITY,
        min=0.0,
        soft_min=1.0,
        max=DENSITY[1],
        soft_max=500.0,
        description="Lightmap texels per metre of surface: each object's lightmap is sized by its "
        "area, from 8 texels to the Texture Size (0: every object gets the Texture Size); a scene whose "
        "lightmaps would exceed 8.4 M texels together gets a lower density. An object's Lightmap "
        "Size overrides it",
    )
    vertex_spacing: FloatProperty(
        name="Vertex Spacing",
        default=VERTEX_SPACING,
        min=0.0,
        soft_max=1.0,
        subtype="DISTANCE",
        unit="LENGTH",
        description="Vertex output with Final Gather: objects with edges longer than this show their "
        "light at the corners of their mesh subdivided until none is (in the 'HR Radiance' "
        "geometry-nodes modifier; linear, the shape stays), so light that changes across a large "
        "face shows. 0: the mesh's own corners (as without Final Gather)",
    )
    texture_format: EnumProperty(
        name="Texture Format",
        items=items("texture_format"),
        default=DEFAULTS["texture_format"],
        description="File format of the baked image sequences",
    )
    domain: EnumProperty(
        name="Domain",
        items=items("domain"),
        default=DEFAULTS["domain"],
        description="Domain of the HR_Radiance colour attribute",
    )
    use_frame_range: BoolProperty(
        name="Custom Frame Range",
        default=False,
        description="Bake frames Start..End below instead of the scene frame range",
    )
    # Until set (turning Custom Frame Range on in the panel copies the scene's range), Start and
    # End are the scene's: the bake reads them through custom_range(). No update callback (see
    # quality), and get/set functions crash the bpy module of Blender 4.2 at exit too.
    frame_start: IntProperty(
        name="Start",
        default=1,
        description="First frame of the custom frame range (until set: the scene's Frame Start)",
    )
    frame_end: IntProperty(
        name="End",
        default=250,
        description="Last frame of the custom frame range (until set: the scene's Frame End)",
    )
    cache_folder: StringProperty(
        name="Cache Folder",
        default="//hr_cache/",
        subtype="DIR_PATH",
        options=_REL,
        description="Folder for the per-frame radiance files (relative to the .blend)",
    )
    # Bake state, written by the bake. Relative ("//...") when the .blend is saved.
    bake_dir: StringProperty(
        name="Baked Cache",
        default="",
        subtype="DIR_PATH",
        options=_REL,
        description="Cache directory of the last bake (empty: not baked)",
    )
    use_world: BoolProperty(
        name="World",
        default=True,
        description="The World's background lights the bake through the scene's openings, as in a "
        "render: a uniform colour, or an Environment Texture reduced to a small table (docs/lights.md)",
    )
    playback: BoolProperty(
        name="Playback", default=True, description="Load the baked radiance into HR_Radiance on frame change"
    )
    # Live Relight (live.py). No update callback (see quality): the "Live Relight" button
    # (hr.live_toggle), hr.live_update and, in the UI, a timer act on it.
    live: BoolProperty(
        name="Live Relight",
        default=False,
        description="Keep the hierarchy in memory and update HR_Radiance in the viewport "
        "whenever a light shape is edited (off: the baked playback again)",
    )


class HR_ObjectSettings(bpy.types.PropertyGroup):
    exclude: BoolProperty(
        name="Exclude", default=False, description="Leave this object out of the radiosity solution"
    )
    is_light_shape: BoolProperty(
        name="Light Shape",
        default=False,
        description="Emissive patch lying on scene surfaces; not geometry itself",
    )
    lightmap_resolution: IntProperty(
        name="Lightmap Size",
        default=0,
        min=0,
        max=16384,
        soft_max=4096,
        description="Lightmap width and height in texels for baked textures (0: sized by the "
        "object's area at the scene's Texel Density, at most its Texture Size)",
    )


def custom_range(scene):
    """(start, end) of the custom frame range: Scene.hr's Start and End, each one the scene's own
    until it is set."""
    hr = scene.hr
    return tuple(
        getattr(hr, k) if hr.is_property_set(k) else getattr(scene, k) for k in ("frame_start", "frame_end")
    )


classes = (HR_SceneSettings, HR_ObjectSettings)


def register():
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.Scene.hr = PointerProperty(type=HR_SceneSettings)
    bpy.types.Object.hr = PointerProperty(type=HR_ObjectSettings)


def unregister():
    del bpy.types.Object.hr
    del bpy.types.Scene.hr
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
