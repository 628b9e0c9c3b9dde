"""Baked lightmaps without bpy: UV charts and packing (charts.py), texels of UV triangles and
dilation (raster.py), per-frame texel plans and their image sequences (plan.py). The Blender side
(UV layers, evaluated meshes, the helper material) is blender/texture.py."""


class TextureError(ValueError):
    """Texture output is not possible for an object (one-line reason)."""
