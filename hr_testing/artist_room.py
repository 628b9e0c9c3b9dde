"""A room made the way an artist makes one in Blender (issues 19, 20): primitives with modifiers
(Bevel, Subdivision Surface, Array, Solidify, Mirror), smooth and flat shading with Smooth by
Angle and sharp edges, parented and rotated objects with non-uniform and negative scales, linked
duplicates and a collection instance, n-gons, Suzanne, a UV sphere lamp, a text object converted
to a mesh and one left as text, a curve, Principled BSDFs with base colour image textures, two
light shapes (a ceiling panel and a wall patch that moves), a Blender area light (its strength
keyframed) and a point light, objects touching and sunk into each other, a thin shelf, a glass.

    scene, info = artist_room()          # the context scene, built into the open file
    scene, info = artist_room(small=True) # a few thousand triangles (the test suite)

Deterministic: the same file every time (no random numbers, fixed sizes). Frames 1-4: the wall
patch moves along the wall, the area light's strength rises. info["meshes"]: the mesh objects
the Cycles comparison can bake (benchmarks/unseen_vs_cycles.py), info["triangles"].
"""

import math

import numpy as np

from .blend import load_bpy

W, D, H = 5.0, 4.0, 2.7  # the room (x, y, z), floor at z = 0, centred on x, y
FRAMES = (1, 4)


def _material(name, colour, image=None, emission=None, strength=0.0, transmission=0.0, roughness=0.5):
    """A Principled BSDF as Blender makes it (its default node tree), its Base Color from `image`
    through the UV map when given."""
    import bpy

    m = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        m.use_nodes = True
    t = m.node_tree
    p = next(n for n in t.nodes if n.type == "BSDF_PRINCIPLED")
    p.inputs["Base Color"].default_value = (*colour, 1.0)
    p.inputs["Roughness"].default_value = roughness
    if transmission:
        p.inputs["Transmission Weight"].default_value = transmission
        p.inputs["IOR"].default_value = 1.45
    if emission is not None:
        p.inputs["Emission Color"].default_value = (*emission, 1.0)
        p.inputs["Emission Strength"].default_value = strength
    if image is not None:
        tex = t.nodes.new("ShaderNodeTexImage")
        tex.image = image
        t.links.new(tex.outputs["Color"], p.inputs["Base Color"])
    return m


def _checker(name, n=64, a=(0.75, 0.6, 0.4), b=(0.35, 0.2, 0.1), squares=8):
    """A packed 8-bit sRGB checker image (a wood-ish floor, a painting)."""
    import bpy

    img = bpy.data.images.new(name, n, n)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = ((i * squares // n + j * squares // n) % 2)[..., None]
    rgb = np.where(c == 1, np.asarray(a), np.asarray(b))
    px = np.concatenate([rgb, np.ones((n, n, 1))], 2).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def _link(ob, collection=None):
    import bpy

    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def _op_object(op, **kw):
    """Run a primitive operator (as the Add menu does) and return the new active object."""
    import bpy

    op(**kw)
    return bpy.context.view_layer.objects.active


def _select_only(ob):
    import bpy

    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    ob.select_set(True)
    bpy.context.view_layer.objects.active = ob


def _smooth(ob, angle=None):
    """Shade Smooth, or Shade Auto Smooth (the Smooth by Angle modifier) at `angle` degrees."""
    import bpy

    _select_only(ob)
    if angle is None:
        bpy.ops.object.shade_smooth()
    else:
        bpy.ops.object.shade_auto_smooth(angle=math.radians(angle))


def _flip_normals(ob):
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bmesh.ops.reverse_faces(bm, faces=bm.faces)
    bm.to_mesh(ob.data)
    bm.free()


def _light_shape(name, corners, emission, strength, collection=None):
    """A flat emissive quad marked as a light shape (Object > HR Radiosity > Mark as Light Shape)."""
    import bpy

    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(c) for c in corners], [], [(0, 1, 2, 3)])
    me.materials.append(_material(f"{name} emission", (0, 0, 0), emission=emission, strength=strength))
    ob = _link(bpy.data.objects.new(name, me), collection)
    _select_only(ob)
    bpy.ops.hr.mark_light_shape()
    return ob


def artist_room(small=False):
    """Build the room into the current (emptied) file; returns (scene, info)."""
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy = load_bpy()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    sub = 0 if small else 2  # subdivision levels (0: the modifier is there, the mesh unchanged)
    seg = 12 if small else 32  # segments of cylinders and spheres
    res = 1 if small else 12  # text and curve resolution
    floor_img, art_img = _checker("Floor wood"), _checker("Painting", a=(0.2, 0.4, 0.7), b=(0.9, 0.8, 0.3))
    wall = _material("Wall paint", (0.8, 0.78, 0.72))
    floor = _material("Floor", (0.5, 0.4, 0.3), image=floor_img)
    wood = _material("Wood", (0.45, 0.28, 0.15))
    fabric = _material("Fabric", (0.25, 0.35, 0.6))
    metal = _material("Metal", (0.7, 0.7, 0.72), roughness=0.3)
    red = _material("Red plastic", (0.7, 0.12, 0.1))
    glass = _material("Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0)

    # the room: a cube, scaled in object mode (non-uniform), its normals flipped inward, the floor
    # a separate plane with a textured Principled base colour
    room = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0, location=(0, 0, H / 2))
    room.name = "Room"
    room.scale = (W, D, H)
    _flip_normals(room)
    room.data.materials.append(wall)
    fl = _op_object(bpy.ops.mesh.primitive_plane_add, size=1.0, location=(0, 0, 0.001))
    fl.name, fl.scale = "Floor", (W - 0.002, D - 0.002, 1)
    fl.data.materials.append(floor)
    fl.modifiers.new("Subdivide", "SUBSURF").levels = 0  # an artist's leftover (simple, level 0)
    fl.modifiers["Subdivide"].subdivision_type = "SIMPLE"

    # a table: a bevelled slab on four legs (one leg, Mirror in x and y), the top rotated 15 degrees
    table = bpy.data.objects.new("Table", None)  # an empty as parent, rotated
    table.location, table.rotation_euler = (-0.6, 0.3, 0), (0, 0, math.radians(15))
    _link(table)
    top = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0)
    top.name, top.parent, top.location, top.scale = "Table top", table, (0, 0, 0.74), (1.4, 0.8, 0.04)
    top.data.materials.append(wood)
    bev = top.modifiers.new("Bevel", "BEVEL")
    bev.width, bev.segments = 0.01, 2
    leg = _op_object(bpy.ops.mesh.primitive_cylinder_add, vertices=seg // 2, radius=0.03, depth=0.72)
    leg.name, leg.parent, leg.location = "Table leg", table, (0.62, 0.34, 0.36)
    leg.data.materials.append(wood)
    mir = leg.modifiers.new("Mirror", "MIRROR")
    mir.use_axis = (True, True, False)
    mir.mirror_object = table
    _smooth(leg, 30)

    # Suzanne, subdivided and smooth, sunk 3 cm into the table top, turned
    suz = _op_object(bpy.ops.mesh.primitive_monkey_add, size=0.35)
    suz.name, suz.parent = "Suzanne", table
    suz.location, suz.rotation_euler = (
        (-0.3, 0.0, 0.76 + 0.15 - 0.03),
        (math.radians(-20), 0, math.radians(30)),
    )
    suz.data.materials.append(red)
    suz.modifiers.new("Subdivision", "SUBSURF").levels = sub
    _smooth(suz)
    # a glass on the table (a cylinder, Solidify: its wall), touching the top
    gl = _op_object(
        bpy.ops.mesh.primitive_cylinder_add, vertices=seg, radius=0.04, depth=0.12, end_fill_type="NOTHING"
    )
    gl.name, gl.parent, gl.location = "Glass", table, (0.3, 0.15, 0.76 + 0.06)
    gl.data.materials.append(glass)
    gl.modifiers.new("Solidify", "SOLIDIFY").thickness = 0.004
    _smooth(gl)
    # books: one mesh, two linked duplicates (Alt+D), standing on the table, one leaning
    book = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0)
    book.name, book.parent = "Book", table
    book.location, book.scale = (0.45, -0.2, 0.76 + 0.11), (0.04, 0.16, 0.22)
    book.data.materials.append(fabric)
    for i, (dx, tilt) in enumerate(((0.05, 0.0), (0.12, 20.0))):
        d = book.copy()  # shares book.data
        d.name, d.location = f"Book linked {i + 1}", (0.45 + dx, -0.2, 0.76 + 0.11)
        d.rotation_euler = (0, math.radians(tilt), 0)
        _link(d)

    # a chair (seat + back + array of slats), parented and rotated, and its mirror (scale x -1)
    def chair(name, loc, rot, sx):
        root = bpy.data.objects.new(name, None)
        root.location, root.rotation_euler, root.scale = loc, (0, 0, math.radians(rot)), (sx, 1.1, 1.0)
        _link(root)
        seat = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0)
        seat.name, seat.parent, seat.location, seat.scale = (
            f"{name} seat",
            root,
            (0, 0, 0.45),
            (0.45, 0.42, 0.04),
        )
        seat.data.materials.append(wood)
        seat.modifiers.new("Bevel", "BEVEL").width = 0.008
        slat = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0)
        slat.name, slat.parent = f"{name} back slat", root
        slat.location, slat.scale = (-0.18, 0.19, 0.72), (0.04, 0.02, 0.5)
        slat.data.materials.append(wood)
        arr = slat.modifiers.new("Array", "ARRAY")
        arr.count, arr.relative_offset_displace = 5, (2.25, 0, 0)
        legs = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0)
        legs.name, legs.parent = f"{name} legs", root
        legs.location, legs.scale = (0.2, 0.18, 0.22), (0.035, 0.035, 0.44)
        legs.data.materials.append(metal)
        m = legs.modifiers.new("Mirror", "MIRROR")
        m.use_axis, m.mirror_object = (True, True, False), root
        return root

    chair("Chair", (-0.6, -0.45, 0), 10, 1.0)
    chair("Chair mirrored", (-0.6, 1.05, 0), 190, -1.0)

    # a thin shelf on the east wall (a plane with Solidify 18 mm), vases on it: a collection instanced twice
    shelf = _op_object(bpy.ops.mesh.primitive_plane_add, size=1.0, location=(W / 2 - 0.15, 0.2, 1.5))
    shelf.name, shelf.scale = "Shelf", (0.3, 1.4, 1)
    shelf.data.materials.append(wood)
    so = shelf.modifiers.new("Solidify", "SOLIDIFY")
    so.thickness, so.offset = 0.018, -1.0
    vases = bpy.data.collections.new("Vase set")
    scene.collection.children.link(vases)
    vase = _op_object(
        bpy.ops.mesh.primitive_uv_sphere_add, segments=seg // 2, ring_count=seg // 4, radius=0.07
    )
    vase.name = "Vase"
    bpy.context.scene.collection.objects.unlink(vase)
    vases.objects.link(vase)
    vase.location, vase.scale = (0, 0, 0.07 * 1.4), (1, 1, 1.4)
    vase.data.materials.append(red)
    _smooth(vase)
    scene.view_layers[0].layer_collection.children["Vase set"].exclude = True  # the original set away
    for i, y in enumerate((-0.2, 0.5)):
        inst = bpy.data.objects.new(f"Vases {i + 1}", None)
        inst.instance_type, inst.instance_collection = "COLLECTION", vases
        inst.location = (W / 2 - 0.15, y, 1.5)
        _link(inst)

    # an n-gon rug (a 12-sided circle filled with one n-gon), flat on the floor
    rug = _op_object(
        bpy.ops.mesh.primitive_circle_add,
        vertices=12,
        radius=0.9,
        fill_type="NGON",
        location=(-0.6, 0.3, 0.004),
    )
    rug.name = "Rug"
    rug.data.materials.append(fabric)
    # a sofa against the west wall: bevelled, subdivided base with sharp edges, Smooth by Angle
    sofa = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0, location=(-W / 2 + 0.45, 0.2, 0.22))
    sofa.name, sofa.scale = "Sofa", (0.8, 2.0, 0.44)
    sofa.data.materials.append(fabric)
    for e in sofa.data.edges:
        e.use_edge_sharp = True
    sofa.modifiers.new("Bevel", "BEVEL").width = 0.04
    _smooth(sofa, 40)
    back = _op_object(bpy.ops.mesh.primitive_cube_add, size=1.0, location=(-W / 2 + 0.12, 0.2, 0.6))
    back.name, back.scale = "Sofa back", (0.2, 2.0, 0.8)
    back.rotation_euler = (0, math.radians(-8), 0)  # leaning, sunk into the seat
    back.data.materials.append(fabric)
    back.modifiers.new("Subdivision", "SUBSURF").levels = sub
    _smooth(back, 35)
    # a painting: a plane with the image on the north wall (touching it)
    art = _op_object(
        bpy.ops.mesh.primitive_plane_add,
        size=1.0,
        location=(0.8, D / 2 - 0.01, 1.5),
        rotation=(math.radians(90), 0, math.radians(180)),
    )
    art.name, art.scale = "Painting", (1.0, 0.7, 1)
    art.data.materials.append(_material("Painting", (0.5, 0.5, 0.5), image=art_img))
    # text: one converted to a mesh (on the wall), one left as text (a FONT object) on the floor
    txt = bpy.data.curves.new("Sign", "FONT")
    txt.body, txt.extrude, txt.size, txt.resolution_u = "HR", 0.02, 0.3, res
    sign = _link(bpy.data.objects.new("Sign", txt))
    sign.location, sign.rotation_euler = (-1.8, D / 2 - 0.02, 1.8), (math.radians(90), 0, math.radians(180))
    sign.data.materials.append(metal)
    _select_only(sign)
    bpy.ops.object.convert(target="MESH")
    sign = bpy.context.view_layer.objects.active
    txt2 = bpy.data.curves.new("Floor text", "FONT")
    txt2.body, txt2.extrude, txt2.size, txt2.resolution_u = "unseen", 0.01, 0.25, res
    ft = _link(bpy.data.objects.new("Floor text", txt2))
    ft.location = (0.9, -1.4, 0.0)
    ft.data.materials.append(red)
    # a curve left as a curve: a bevelled Bezier (a cable) from the lamp to the floor
    cu = bpy.data.curves.new("Cable", "CURVE")
    cu.dimensions, cu.bevel_depth, cu.bevel_resolution, cu.resolution_u = "3D", 0.008, 2, res
    sp = cu.splines.new("BEZIER")
    sp.bezier_points.add(1)
    for p, co in zip(sp.bezier_points, ((1.6, -1.5, 1.6), (2.2, -1.6, 0.0))):
        p.co, p.handle_left_type, p.handle_right_type = co, "AUTO", "AUTO"
    cable = _link(bpy.data.objects.new("Cable", cu))
    cable.data.materials.append(metal)
    # a floor lamp: a pole (cylinder) and a UV sphere shade that glows (an emissive Principled)
    pole = _op_object(
        bpy.ops.mesh.primitive_cylinder_add,
        vertices=seg // 2,
        radius=0.015,
        depth=1.6,
        location=(1.6, -1.5, 0.8),
    )
    pole.name = "Lamp pole"
    pole.data.materials.append(metal)
    shade = _op_object(
        bpy.ops.mesh.primitive_uv_sphere_add,
        segments=seg,
        ring_count=seg // 2,
        radius=0.15,
        location=(1.6, -1.5, 1.7),
    )
    shade.name = "Lamp shade"
    shade.data.materials.append(
        _material("Lamp glow", (0.9, 0.85, 0.7), emission=(1.0, 0.85, 0.6), strength=6.0)
    )
    _smooth(shade)
    # a box sunk into the floor and a crate on top of it, touching
    crate = _op_object(bpy.ops.mesh.primitive_cube_add, size=0.5, location=(1.9, 1.4, 0.2))
    crate.name = "Crate"
    crate.data.materials.append(wood)
    crate2 = _op_object(bpy.ops.mesh.primitive_cube_add, size=0.3, location=(1.85, 1.45, 0.45 + 0.15))
    crate2.name, crate2.rotation_euler = "Crate small", (0, 0, math.radians(25))
    crate2.data.materials.append(red)

    # light: a ceiling panel (light shape), a wall patch that moves (light shape), an area light
    # on the south wall whose strength rises, a point light in a corner
    z = H - 0.0  # on the ceiling (the room's inside face)
    _light_shape(
        "Ceiling panel",
        [(-0.5, -0.4, z), (0.5, -0.4, z), (0.5, 0.4, z), (-0.5, 0.4, z)],
        (1.0, 0.95, 0.9),
        8.0,
    )
    x = -W / 2
    patch = _light_shape(
        "Wall patch", [(x, -1.2, 1.0), (x, -0.6, 1.0), (x, -0.6, 1.8), (x, -1.2, 1.8)], (1.0, 0.7, 0.4), 12.0
    )
    patch.location = (0, 0, 0)
    patch.keyframe_insert("location", frame=1)
    patch.location = (0, 0.9, 0)
    patch.keyframe_insert("location", frame=4)
    la = bpy.data.lights.new("Area light", "AREA")
    la.shape, la.size, la.size_y, la.energy = "RECTANGLE", 0.8, 0.4, 60.0
    area = _link(bpy.data.objects.new("Area light", la))
    area.location, area.rotation_euler = (0.3, -D / 2 + 0.05, 2.0), (math.radians(-90), 0, 0)  # faces +y
    la.keyframe_insert("energy", frame=1)
    la.energy = 150.0
    la.keyframe_insert("energy", frame=4)
    lp = bpy.data.lights.new("Corner light", "POINT")
    lp.energy, lp.shadow_soft_size, lp.color = 40.0, 0.05, (1.0, 0.9, 0.8)
    _link(bpy.data.objects.new("Corner light", lp)).location = (2.0, -1.5, 2.3)
    scene.frame_set(FRAMES[0])
    bpy.context.view_layer.update()
    return scene, _info(scene)


def _info(scene):
    """Triangles of every renderable mesh (evaluated, instances included), the compared objects."""
    import bpy

    dg = bpy.context.evaluated_depsgraph_get()
    tris = 0
    for inst in dg.object_instances:
        ob = inst.object
        if ob.type not in ("MESH", "FONT", "CURVE"):
            continue
        me = ob.to_mesh()
        if me is not None:
            me.calc_loop_triangles()
            tris += len(me.loop_triangles)
        ob.to_mesh_clear()
    vl = bpy.context.view_layer  # not the Vase of the excluded collection (its instances render)
    meshes = sorted(o.name for o in vl.objects if o.type == "MESH" and not o.hr.is_light_shape)
    return {"triangles": tris, "meshes": meshes}
