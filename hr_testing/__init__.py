"""Test scenes and references shared by tests/, benchmarks/ and scripts/ (numpy; cycles_ref needs bpy).

    scenes          Cornell box, closed box, spheres, parallel plates (SceneBuilder)
    shapes          light-shape outlines (rect, ellipse, star, cross, window) and the office scene
    furnished       furnished rooms of ~2k to ~1M triangles, and their builders (Builder, box, ...)
    contact_scenes  objects touching each other: floor with solids, box under a sky, furnace room
    cycles_ref      Cycles reference bakes and the texel-level comparison with our solution (bpy)

Import it with the repository root on sys.path (tests/conftest.py puts it there; benchmarks and
scripts insert it). Not part of the extension: blender_manifest.toml's allow-list leaves it out.
"""
