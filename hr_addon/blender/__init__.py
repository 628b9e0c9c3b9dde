"""Blender glue: reads the scene, writes results, UI. All physics is in ..core."""


def register():
    pass


def unregister():
    pass
