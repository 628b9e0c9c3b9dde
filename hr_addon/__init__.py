"""Dynamic Hierarchical Radiosity: a Blender extension.

The physics lives in `hr_addon.core` (numpy only). Blender glue is imported only when Blender
registers the extension, so the core can be imported and tested without bpy.
"""


def register():
    from .blender import register as _register
    _register()


def unregister():
    from .blender import unregister as _unregister
    _unregister()
