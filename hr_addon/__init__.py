"""Dynamic Hierarchical Radiosity: a Blender extension.

The physics lives in `hr_addon.core`, the bake files in `hr_addon.io` and the lightmap texel work in
`hr_addon.lightmap` (numpy only). The Blender glue (`hr_addon.blender`) is imported only when
Blender registers the extension, so the rest can be imported and tested without bpy.
"""


def register():
    from .blender import register as _register

    _register()


def unregister():
    from .blender import unregister as _unregister

    _unregister()
