"""Bake files on disk, no bpy: the frame cache and its manifest (cache.py), lightmap image files
(images.py) and the write-then-rename / hard-link helpers both use (files.py)."""
