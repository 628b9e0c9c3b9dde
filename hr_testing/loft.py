"""A loft room, built for the third unseen-scene check (session 34, branch unseen3): a room nobody
tuned on, modelled the way an artist models one in Blender, with what real scenes have and the
other test rooms lack.

    scene, info = loft_scene()            # builds into the open file (emptied); the context scene
    scene, info = loft_scene(small=True)  # a few thousand triangles (the test suite)

The room (6 x 4.5 m) is turned 20 degrees about z (every object is parented to the empty 'Loft':
no wall lies on an axis). Its ceiling slopes from 2.2 m over the south wall up to 3.4 m, 3 m in,
then runs flat to the north wall (the east and west walls are pentagons: n-gons). In it: a window
opening in the south wall (reveals 20 cm deep, a sill with a Bevel, mullions with an Array, a
radiator of fins with an Array), two rafters along the slope sunk 2 cm into it, a 1 mm rug lying on
the floor at 8 degrees, a round dining table (n-gon top) under a pendant shade (Solidify), four
chairs instanced from one collection (one of them mirrored, scale x -1), a desk (its top bevelled,
one leg with a Mirror in x and y) at -12 degrees with a monitor whose screen is a light shape, a
bookshelf (boards: an Array) with ~45 books tilted at odd angles, two armchairs (the second the
first mirrored: scale -1.1, 1, 1), a cabinet with two materials (white body, red doors), a wall
shelf, picture frames, storage boxes, plants of many small leaves (each leaf a closed 2 mm solid; the
soil lies inside its pot, whose top is closed: a modelling slip kept, session 34's Cycles references
are of this scene; nothing lights the soil and no camera sees it).
Principled materials, base colours (albedos) 0.05 to 0.85, saturated reds, blues, greens, yellows.

Light: a point light in the pendant shade (80 W), a spot light from the flat ceiling onto the
bookshelf (250 W), a sun (4 W/m^2) through the window opening, the monitor's screen (a light
shape, every frame); a skylight in the slope (a light shape whose blind opens: keyed scale 0 along
the slope at frame 1, closed; 0.5 at frame 3, half open). The world is black. Frames 1-3.
Deterministic (seed 11). VIEWS: two cameras (world coordinates), like two_rooms'.
"""

import math

import numpy as np

from .blend import load_bpy

W, D = 6.0, 4.5  # the room's extent in its own frame (x, y), floor at z = 0
HL, HH, YK = 2.2, 3.4, 3.0  # ceiling height over the south wall, the flat part's, where the slope ends
TURN = 20.0  # degrees: the room's rotation about z (world)
ORIGIN = (0.0, 0.0, 0.0)  # the room's south-west floor corner (world)
WIN = (1.6, 3.0, 0.8, 2.0)  # the window opening in the south wall: x0, x1, z0, z1 (room frame)
REVEAL = 0.2  # the opening's depth (outwards, -y)
SKY = (
    2.2,
    3.4,
    0.6,
    1.6,
)  # the skylight in the slope: x0, x1, s0, s1 (metres along the slope from the south)
SKY_ON = 3  # the frame at which the skylight's blind is half open (closed at frame 1)
SUN = dict(strength=4.0, color=(1.0, 0.92, 0.8), elevation=35.0, azimuth=12.0, angle=0.0093)
SPOT = dict(location=(1.4, 3.9, 3.3), target=(0.2, 3.6, 1.2), energy=250.0, size=50.0, blend=0.3, radius=0.05)
PENDANT = dict(location=(2.5, 2.0, 1.72), energy=80.0, radius=0.04, color=(1.0, 0.86, 0.7))
FRAMES = (1, 3)


def _world(p):
    """A point of the room's frame in world coordinates."""
    a = math.radians(TURN)
    x, y, z = p
    return (
        ORIGIN[0] + x * math.cos(a) - y * math.sin(a),
        ORIGIN[1] + x * math.sin(a) + y * math.cos(a),
        ORIGIN[2] + z,
    )


# camera location, target (room frame, turned into world coordinates), lens (mm)
_VIEWS_ROOM = {
    "loft_a": ((5.4, 0.5, 1.6), (1.5, 3.6, 1.3), 18),  # from the south-east corner: desk, shelf, slope
    "loft_b": ((1.0, 4.2, 2.0), (3.6, 0.3, 0.7), 18),  # from the north-west: window, table, sun patch
}
VIEWS = {k: (_world(c), _world(t), lens) for k, (c, t, lens) in _VIEWS_ROOM.items()}

# albedos
WALL, CEIL, FLOOR = (0.8, 0.78, 0.74), (0.85, 0.85, 0.85), (0.45, 0.3, 0.18)
WOOD, DARKWOOD, BLACK = (0.55, 0.38, 0.22), (0.15, 0.09, 0.05), (0.05, 0.05, 0.05)
RED, BLUE, GREEN, YELLOW = (0.75, 0.06, 0.05), (0.04, 0.12, 0.7), (0.06, 0.45, 0.1), (0.85, 0.72, 0.04)
WHITE, GREY, ORANGE, TEAL = (0.85, 0.85, 0.83), (0.4, 0.4, 0.42), (0.8, 0.35, 0.05), (0.05, 0.5, 0.5)
LEAF = (0.1, 0.35, 0.06)


def _material(name, colour, emission=None, strength=0.0, _cache={}):
    from .artist_room import _material as principled

    import bpy

    key = (name, colour, emission, strength)
    m = _cache.get(key)
    if m is None or m.name not in bpy.data.materials:
        m = _cache[key] = principled(name, colour, emission=emission, strength=strength)
    return m


def _oriented(verts, polys, normals):
    """polys wound so that each one's Newell normal points along its desired normal."""
    out = []
    for p, n in zip(polys, normals):
        q = verts[list(p)]
        nw = np.cross(q - q.mean(0), np.roll(q, -1, 0) - q.mean(0)).sum(0)
        out.append(list(p) if nw @ np.asarray(n, float) >= 0 else list(p)[::-1])
    return out


def _mesh_object(name, verts, polys, mats, parent, mat_index=None, location=(0, 0, 0)):
    """A new mesh object from vertices and polygons (its own mesh), materials by slot."""
    import bpy

    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in verts], [], [list(map(int, p)) for p in polys])
    for m in mats:
        me.materials.append(m)
    if mat_index is not None:
        me.polygons.foreach_set("material_index", np.asarray(mat_index, np.int32))
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    ob.parent, ob.location = parent, location
    return ob


_CUBE_V = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], float)
_CUBE_F = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]  # outward


def _box(name, size, location, mat, parent, rot=(0, 0, 0), mats=None, mat_index=None):
    """A welded unit cube scaled in object mode (non-uniform scale, as an artist scales one)."""
    ob = _mesh_object(name, _CUBE_V, _CUBE_F, mats or [mat], parent, mat_index, location)
    ob.scale = size
    ob.rotation_euler = tuple(math.radians(r) for r in rot)
    return ob


def _cylinder(name, radius, height, seg, location, mat, parent, top=True):
    """A cylinder standing on location, its caps n-gons (as Blender's Add > Cylinder makes them)."""
    t = np.linspace(0, 2 * np.pi, seg, endpoint=False)
    ring = np.c_[radius * np.cos(t), radius * np.sin(t), np.zeros(seg)]
    v = np.concatenate([ring, ring + [0, 0, height]])
    i = np.arange(seg)
    j = (i + 1) % seg
    polys = [list(r) for r in np.c_[i, j, seg + j, seg + i]] + [list(i[::-1])]
    if top:
        polys.append(list(seg + i))
    return _mesh_object(name, v, polys, [mat], parent, location=location)


def _leaves(name, rng, n, centre, spread, mat, parent):
    """One object of n small leaves around a crown: each leaf a closed 2 mm solid (a flattened
    octahedron, 8 triangles), 5-11 cm long, at random directions and tilts."""
    vs, fs = [], []
    for k in range(n):
        d = rng.normal(size=3)
        d[2] = abs(d[2]) + 0.3
        d /= np.linalg.norm(d)
        base = np.asarray(centre) + spread * rng.uniform(0.3, 1.0) * d * [1, 1, 0.8]
        L, w = rng.uniform(0.05, 0.11), rng.uniform(0.018, 0.035)
        u = d + rng.normal(scale=0.4, size=3)
        u /= np.linalg.norm(u)
        s = np.cross(u, rng.normal(size=3))
        s /= np.linalg.norm(s)
        nrm = np.cross(u, s)
        pts = [base, base + 0.5 * L * u + 0.5 * w * s, base + L * u, base + 0.5 * L * u - 0.5 * w * s]
        pts += [base + 0.5 * L * u + 0.001 * nrm, base + 0.5 * L * u - 0.001 * nrm]
        o = len(vs)
        vs += pts
        a, b, c, e, t, btm = range(o, o + 6)
        fs += [(a, b, t), (b, c, t), (c, e, t), (e, a, t), (b, a, btm), (c, b, btm), (e, c, btm), (a, e, btm)]
    v = np.asarray(vs)
    out = []  # outward: each triangle faces away from its leaf's mid point (the two apexes' mean)
    for f in fs:
        q = v[list(f)]
        mid = v[6 * (f[0] // 6) + 4 : 6 * (f[0] // 6) + 6].mean(0)
        nw = np.cross(q[1] - q[0], q[2] - q[0])
        out.append(f if nw @ (q.mean(0) - mid) >= 0 else f[::-1])
    return _mesh_object(name, v, out, [mat], parent)


def _plant(tag, rng, location, pot_r, pot_h, n_leaves, pot_col, parent, seg):
    x, y, z = location
    _cylinder(f"{tag} pot", pot_r, pot_h, seg, (x, y, z), _material(f"{tag} pot", pot_col), parent)
    _cylinder(
        f"{tag} soil", pot_r * 0.92, 0.01, seg, (x, y, z + pot_h - 0.02), _material("Soil", DARKWOOD), parent
    )
    _leaves(
        f"{tag} leaves",
        rng,
        n_leaves,
        (x, y, z + pot_h + 2.2 * pot_r),
        2.4 * pot_r,
        _material("Leaf", LEAF),
        parent,
    )


def _chair_collection(scene, seg):
    """A chair (bevelled seat, a back, one leg mirrored in x and y) in its own collection, excluded
    from the view layer (the original away): its instances render."""
    import bpy

    col = bpy.data.collections.new("Chair set")
    scene.collection.children.link(col)
    wood = _material("Chair wood", WOOD)
    red = _material("Chair seat", RED)
    seat = _box("Chair seat", (0.44, 0.42, 0.05), (0, 0, 0.45), red, None)
    bev = seat.modifiers.new("Bevel", "BEVEL")
    bev.width, bev.segments = 0.01, 2
    back = _box("Chair back", (0.42, 0.03, 0.38), (0, 0.2, 0.72), wood, None, rot=(-8, 0, 0))
    # one leg, its vertices off the origin: the Mirror (about the origin) makes four
    leg = _mesh_object(
        "Chair leg", _CUBE_V * (0.035, 0.035, 0.45) + (0.18, 0.17, 0.225), _CUBE_F, [wood], None
    )
    m = leg.modifiers.new("Mirror", "MIRROR")
    m.use_axis = (True, True, False)
    for ob in (seat, back, leg):
        scene.collection.objects.unlink(ob)
        col.objects.link(ob)
    scene.view_layers[0].layer_collection.children["Chair set"].exclude = True
    bpy.context.view_layer.update()  # else selecting objects afterwards (Mark as Light Shape) crashes
    return col


def _shell(loft):
    wall, ceil, floor = _material("Wall paint", WALL), _material("Ceiling", CEIL), _material("Floor", FLOOR)
    x0, x1, z0, z1 = WIN
    up = (0, 0, 1)
    _mesh_object(
        "Floor", np.array([(0, 0, 0), (W, 0, 0), (W, D, 0), (0, D, 0)], float), [(0, 1, 2, 3)], [floor], loft
    )
    v = np.array([(0, 0, HL), (W, 0, HL), (W, YK, HH), (0, YK, HH), (W, D, HH), (0, D, HH)], float)
    slope_n = (0, HH - HL, -YK)
    polys = _oriented(v, [(0, 1, 2, 3), (3, 2, 4, 5)], [slope_n, (0, 0, -1)])
    _mesh_object("Ceiling", v, polys, [ceil], loft)
    v = np.array([(0, D, 0), (W, D, 0), (W, D, HH), (0, D, HH)], float)
    _mesh_object("Wall north", v, _oriented(v, [(0, 1, 2, 3)], [(0, -1, 0)]), [wall], loft)
    for name, x, n in (("Wall west", 0.0, (1, 0, 0)), ("Wall east", W, (-1, 0, 0))):
        v = np.array([(x, 0, 0), (x, D, 0), (x, D, HH), (x, YK, HH), (x, 0, HL)], float)
        _mesh_object(name, v, _oriented(v, [(0, 1, 2, 3, 4)], [n]), [wall], loft)  # a pentagon
    # the south wall around the opening: four quads
    xs, zs = (0, x0, x1, W), (0, z0, z1, HL)
    v, polys = [], []
    for (a, b), (c, d) in (((0, 1), (0, 3)), ((2, 3), (0, 3)), ((1, 2), (0, 1)), ((1, 2), (2, 3))):
        o = len(v)
        v += [(xs[a], 0, zs[c]), (xs[b], 0, zs[c]), (xs[b], 0, zs[d]), (xs[a], 0, zs[d])]
        polys.append((o, o + 1, o + 2, o + 3))
    v = np.array(v, float)
    _mesh_object("Wall south", v, _oriented(v, polys, [(0, 1, 0)] * 4), [wall], loft)
    # the opening's reveals, facing into it
    r = -REVEAL
    v = np.array(
        [(x0, 0, z0), (x1, 0, z0), (x1, r, z0), (x0, r, z0)]  # bottom, faces +z
        + [(x0, 0, z1), (x1, 0, z1), (x1, r, z1), (x0, r, z1)]  # top, faces -z
        + [(x0, 0, z0), (x0, 0, z1), (x0, r, z1), (x0, r, z0)]  # left, faces +x
        + [(x1, 0, z0), (x1, 0, z1), (x1, r, z1), (x1, r, z0)],  # right, faces -x
        float,
    )
    quads = [(0, 1, 2, 3), (4, 5, 6, 7), (8, 9, 10, 11), (12, 13, 14, 15)]
    _mesh_object(
        "Window reveal", v, _oriented(v, quads, [up, (0, 0, -1), (1, 0, 0), (-1, 0, 0)]), [wall], loft
    )


def loft_scene(small=False, seed=11):
    """Build the loft into the current (emptied) file; returns (scene, info)."""
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy = load_bpy()
    from mathutils import Vector

    rng = np.random.default_rng(seed)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.world = None  # black: the sun is the only light from outside
    scene.hr.quality = "DRAFT"
    seg = 12 if small else 32
    n_leaves = 20 if small else 420
    n_books = 8 if small else 64
    loft = bpy.data.objects.new("Loft", None)
    scene.collection.objects.link(loft)
    loft.location, loft.rotation_euler = ORIGIN, (0, 0, math.radians(TURN))
    _shell(loft)
    x0, x1, z0, z1 = WIN
    wood, white = _material("Wood", WOOD), _material("White", WHITE)
    # the window: a bevelled sill, mullions (an Array), a radiator of fins (an Array)
    sill = _box("Window sill", (x1 - x0 + 0.2, 0.26, 0.04), ((x0 + x1) / 2, -0.05, z0 - 0.02), white, loft)
    sill.modifiers.new("Bevel", "BEVEL").width = 0.008
    mul = _box("Mullions", (0.04, 0.05, z1 - z0), (x0 + 0.35, -0.1, (z0 + z1) / 2), white, loft)
    arr = mul.modifiers.new("Array", "ARRAY")
    arr.count, arr.relative_offset_displace = 3, (8.75, 0, 0)  # 0.35 m apart
    fin = _box("Radiator", (0.025, 0.08, 0.5), (x0 + 0.1, 0.08, 0.4), _material("Radiator", WHITE), loft)
    arr = fin.modifiers.new("Array", "ARRAY")
    arr.count, arr.relative_offset_displace = 18, (2.6, 0, 0)
    # rafters along the slope, sunk 2 cm into it
    ang = math.degrees(math.atan2(HH - HL, YK))
    L = math.hypot(YK, HH - HL)
    for i, x in enumerate((1.2, 4.6)):
        cy, cz = YK / 2, (HL + HH) / 2 - 0.06 / math.cos(math.radians(ang))
        _box(
            f"Rafter {i}",
            (0.12, L, 0.16),
            (x, cy, cz),
            _material("Dark wood", DARKWOOD),
            loft,
            rot=(ang, 0, 0),
        )
    # the rug: 1 mm, lying on the floor, turned 8 degrees
    _box("Rug", (2.6, 1.8, 0.001), (2.5, 2.0, 0.0005), _material("Rug", BLUE), loft, rot=(0, 0, 8))
    # the round dining table (n-gon top) under a pendant, four chairs instanced from one collection
    _cylinder("Table top", 0.55, 0.04, 2 * seg, (2.5, 2.0, 0.7), wood, loft)
    _cylinder("Table stem", 0.05, 0.7, seg // 2, (2.5, 2.0, 0.0), _material("Black", BLACK), loft)
    _cylinder("Table foot", 0.3, 0.03, seg, (2.5, 2.0, 0.0), _material("Black", BLACK), loft)
    chairs = _chair_collection(scene, seg)
    for k, a in enumerate((17.0, 107.0, 197.0, 293.0)):
        inst = bpy.data.objects.new(f"Chair {k + 1}", None)
        inst.instance_type, inst.instance_collection = "COLLECTION", chairs
        r = 0.72
        inst.location = (2.5 + r * math.cos(math.radians(a)), 2.0 + r * math.sin(math.radians(a)), 0)
        inst.rotation_euler = (0, 0, math.radians(a - 90))  # its back away from the table
        if k == 3:
            inst.scale = (-1, 1, 1)  # mirrored
        inst.parent = loft
        scene.collection.objects.link(inst)
    # items on the table: plates, cups, a bowl
    palette = [WHITE, RED, BLUE, GREEN, YELLOW, ORANGE, TEAL, GREY]
    for k in range(4):
        a = math.radians(30 + 90 * k)
        px, py = 2.5 + 0.33 * math.cos(a), 2.0 + 0.33 * math.sin(a)
        _cylinder(f"Plate {k}", 0.11, 0.015, seg, (px, py, 0.74), white, loft)
        c = palette[int(rng.integers(len(palette)))]
        _cylinder(
            f"Cup {k}", 0.04, 0.09, seg // 2, (px + 0.14, py - 0.05, 0.74), _material(f"Cup {k}", c), loft
        )
    _cylinder("Bowl", 0.12, 0.07, seg, (2.5, 2.0, 0.74), _material("Bowl", ORANGE), loft)
    # the pendant: a cord and a cone shade (Solidify), the point light in its mouth
    lx, ly, lz = PENDANT["location"]
    ceiling = HL + ly / YK * (HH - HL)
    _cylinder(
        "Pendant cord", 0.006, ceiling - lz - 0.2, 8, (lx, ly, lz + 0.22), _material("Black", BLACK), loft
    )
    t = np.linspace(0, 2 * np.pi, seg, endpoint=False)
    v = np.concatenate(
        [
            np.c_[0.22 * np.cos(t), 0.22 * np.sin(t), np.zeros(seg)],
            np.c_[0.04 * np.cos(t), 0.04 * np.sin(t), np.full(seg, 0.22)],
        ]
    )
    i = np.arange(seg)
    j = (i + 1) % seg
    shade = _mesh_object(
        "Pendant shade",
        v,
        np.c_[i, j, seg + j, seg + i],
        [_material("Shade", YELLOW)],
        loft,
        location=(lx, ly, lz - 0.02),
    )
    sol = shade.modifiers.new("Solidify", "SOLIDIFY")
    sol.thickness = 0.006
    # the desk at -12 degrees: a bevelled top, one leg mirrored in x and y, a monitor (its screen a
    # light shape), a keyboard, a mug, books
    desk = bpy.data.objects.new("Desk", None)
    scene.collection.objects.link(desk)
    desk.parent, desk.location, desk.rotation_euler = loft, (4.4, 3.85, 0), (0, 0, math.radians(-12))
    top = _box("Desk top", (1.8, 0.8, 0.035), (0, 0, 0.74), _material("Desk", (0.7, 0.62, 0.5)), desk)
    bev = top.modifiers.new("Bevel", "BEVEL")
    bev.width, bev.segments = 0.012, 3
    leg = _box("Desk leg", (0.05, 0.05, 0.72), (0.82, 0.33, 0.36), _material("Black", BLACK), desk)
    m = leg.modifiers.new("Mirror", "MIRROR")
    m.use_axis, m.mirror_object = (True, True, False), desk
    _box("Monitor stand", (0.22, 0.18, 0.012), (0, 0.2, 0.7635), _material("Black", BLACK), desk)
    _box("Monitor neck", (0.05, 0.03, 0.2), (0, 0.24, 0.86), _material("Black", BLACK), desk)
    mon = _box("Monitor", (0.64, 0.035, 0.38), (0, 0.22, 1.1), _material("Monitor", (0.08, 0.08, 0.09)), desk)
    screen_v = [
        (-0.46, -0.5, -0.43),
        (0.46, -0.5, -0.43),
        (0.46, -0.5, 0.43),
        (-0.46, -0.5, 0.43),
    ]  # its front face
    _shape("Monitor screen", screen_v, (0.75, 0.85, 1.0), 3.0, mon)
    _box(
        "Keyboard",
        (0.44, 0.14, 0.02),
        (0.02, -0.12, 0.7675),
        _material("Keyboard", GREY),
        desk,
        rot=(0, 0, 4),
    )
    _cylinder("Desk mug", 0.04, 0.1, seg // 2, (0.6, -0.15, 0.7575), _material("Mug", RED), desk)
    for k in range(4):
        c = palette[int(rng.integers(len(palette)))]
        _box(
            f"Desk book {k}",
            (0.24, 0.17, 0.03),
            (-0.62, 0.05, 0.7725 + 0.03 * k),
            _material(f"Book {c}", c),
            desk,
            rot=(0, 0, 9 * k - 11),
        )
    _plant("Desk plant", rng, (-0.7, 0.28, 0.7575), 0.06, 0.12, n_leaves // 3, TEAL, desk, seg)
    # the bookshelf against the west wall, under the flat ceiling: boards an Array, books
    bx1, by0, by1, bh = 0.34, 3.1, 4.3, 2.0  # x from the wall, y, height
    sw = _material("Shelf", WHITE)
    _box("Shelf side 0", (bx1, 0.025, bh), (bx1 / 2, by0 + 0.0125, bh / 2), sw, loft)
    _box("Shelf side 1", (bx1, 0.025, bh), (bx1 / 2, by1 - 0.0125, bh / 2), sw, loft)
    _box(
        "Shelf back",
        (0.012, by1 - by0 - 0.05, bh),
        (0.006, (by0 + by1) / 2, bh / 2),
        _material("Shelf back", GREY),
        loft,
    )
    board = _box(
        "Shelf boards",
        (bx1 - 0.012, by1 - by0 - 0.05, 0.022),
        (0.012 + (bx1 - 0.012) / 2, (by0 + by1) / 2, 0.06),
        sw,
        loft,
    )
    arr = board.modifiers.new("Array", "ARRAY")
    arr.count, arr.relative_offset_displace = 5, (0, 0, 20.0)  # 0.44 m apart
    per = max(1, n_books // 4)
    for j in range(4):
        zb = 0.06 + 0.011 + 0.44 * j
        y = by0 + 0.04
        for n in range(per):
            t_ = rng.uniform(0.02, 0.05)
            h = rng.uniform(0.18, 0.3)
            d = rng.uniform(0.15, 0.24)
            if y + t_ > by1 - 0.06:
                break
            tilt = 0.0 if n % 5 else rng.uniform(-25, -8)  # a leaning book now and then
            c = palette[int(rng.integers(len(palette)))]
            cz = zb + h / 2 * math.cos(math.radians(tilt)) + 0.001
            _box(
                f"Book {j}_{n}",
                (d, t_, h),
                (0.02 + d / 2, y + t_ / 2, cz),
                _material(f"Book {c}", c),
                loft,
                rot=(tilt, 0, 0),
            )
            y += t_ + (0.002 if tilt == 0 else 0.06)
    # two armchairs by the east wall: the second is the first mirrored (scale -1.1, 1, 1)
    fab = _material("Armchair", GREEN)
    v, polys = [], []
    for lo, hi in (
        ((-0.4, -0.4, 0.0), (0.4, 0.4, 0.42)),
        ((-0.4, 0.22, 0.3), (0.4, 0.42, 0.95)),
        ((-0.42, -0.4, 0.1), (-0.28, 0.4, 0.65)),
    ):
        o = len(v)
        lo, hi = np.asarray(lo), np.asarray(hi)
        v += list(lo + (_CUBE_V + 0.5) * (hi - lo))
        polys += [tuple(o + k for k in f) for f in _CUBE_F]  # one arm only: mirroring shows
    v = np.asarray(v)
    a1 = _mesh_object("Armchair", v, polys, [fab], loft, location=(4.9, 1.1, 0))
    a1.rotation_euler = (0, 0, math.radians(203))
    a2 = _mesh_object("Armchair mirrored", v, polys, [fab], loft, location=(5.0, 2.2, 0))
    a2.rotation_euler, a2.scale = (0, 0, math.radians(-61)), (-1.1, 1, 1)
    # a cabinet with two materials (white body, red doors) against the east wall
    _box(
        "Cabinet",
        (0.45, 1.2, 0.9),
        (W - 0.23, 3.3, 0.45),
        None,
        loft,
        mats=[white, _material("Doors", RED)],
        mat_index=[1, 0, 0, 0, 0, 0],
    )  # doors: the -x face
    for k in range(3):  # items on the cabinet
        c = palette[int(rng.integers(len(palette)))]
        _cylinder(
            f"Vase {k}",
            0.05 + 0.02 * k,
            0.12 + 0.1 * k,
            seg // 2,
            (W - 0.25, 2.9 + 0.3 * k, 0.9),
            _material(f"Vase {c}", c),
            loft,
        )
    # a wall shelf on the north wall, items on it; picture frames
    _box("Wall shelf", (1.2, 0.22, 0.025), (2.6, D - 0.11, 1.5), wood, loft)
    for k in range(8):
        c = palette[int(rng.integers(len(palette)))]
        w_ = rng.uniform(0.06, 0.14)
        _box(
            f"Shelf item {k}",
            (w_, 0.12, rng.uniform(0.08, 0.22)),
            (2.08 + 0.15 * k, D - 0.1, 0),
            _material(f"Item {c}", c),
            loft,
            rot=(0, 0, rng.uniform(-30, 30)),
        )
    for ob in [o for o in scene.objects if o.name.startswith("Shelf item")]:
        ob.location.z = 1.5125 + ob.scale[2] / 2
    for k, (x, z, w_, h_, c) in enumerate(
        ((3.9, 1.7, 0.7, 0.5, YELLOW), (1.2, 1.9, 0.5, 0.7, TEAL), (5.0, 2.0, 0.4, 0.4, RED))
    ):
        _box(f"Frame {k}", (w_, 0.025, h_), (x, D - 0.0125, z), _material(f"Picture {k}", c), loft)
    _box("Frame west", (0.025, 0.6, 0.45), (0.0125, 1.6, 1.4), _material("Picture w", ORANGE), loft)
    # storage boxes, a stool, plants
    for k, (x, y, s, c, r) in enumerate(
        ((0.4, 0.5, 0.4, YELLOW, 7), (0.35, 1.0, 0.3, RED, -13), (5.6, 0.35, 0.35, BLUE, 22))
    ):
        _box(
            f"Storage {k}",
            (s, s, 0.8 * s),
            (x, y, 0.4 * s),
            _material(f"Storage {c}", c),
            loft,
            rot=(0, 0, r),
        )
    _cylinder("Stool", 0.18, 0.45, seg, (3.3, 3.5, 0), _material("Stool", ORANGE), loft)
    _plant("Plant 1", rng, (0.5, 2.3, 0), 0.16, 0.35, n_leaves, (0.7, 0.3, 0.15), loft, seg)
    _plant("Plant 2", rng, (3.4, 0.35, 0), 0.12, 0.28, n_leaves, BLUE, loft, seg)
    _plant("Plant 4", rng, (3.9, 0.5, 0), 0.1, 0.24, n_leaves // 2, YELLOW, loft, seg)
    _plant("Plant 3", rng, (5.7, 4.2, 0), 0.14, 0.3, n_leaves, WHITE, loft, seg)
    # light: the skylight (a light shape in the slope; its blind opens), Blender lights
    sx0, sx1, s0, s1 = SKY
    ca, sa = YK / L, (HH - HL) / L  # the slope's direction (y, z)

    def on_slope(x, s):
        return (x, s * ca, HL + s * sa)

    sky = _shape(
        "Skylight",
        [(0, 0, 0), (sx1 - sx0, 0, 0), (sx1 - sx0, -(s1 - s0), 0), (0, -(s1 - s0), 0)],
        (0.8, 0.9, 1.0),
        20.0,
        loft,
    )
    sky.location = on_slope(sx0, s1)  # the blind opens from the upper edge down the slope
    sky.rotation_euler = (math.radians(ang), 0, 0)  # its local -y runs down the slope, in its plane
    sky.scale = (1, 0, 1)
    sky.keyframe_insert("scale", frame=1)
    sky.scale = (1, 0.5, 1)
    sky.keyframe_insert("scale", frame=SKY_ON)
    lp = bpy.data.lights.new("Pendant light", "POINT")
    lp.energy, lp.shadow_soft_size, lp.color = PENDANT["energy"], PENDANT["radius"], PENDANT["color"]
    ob = bpy.data.objects.new("Pendant light", lp)
    scene.collection.objects.link(ob)
    ob.parent, ob.location = loft, PENDANT["location"]
    ls = bpy.data.lights.new("Shelf spot", "SPOT")
    ls.energy, ls.shadow_soft_size = SPOT["energy"], SPOT["radius"]
    ls.spot_size, ls.spot_blend = math.radians(SPOT["size"]), SPOT["blend"]
    ob = bpy.data.objects.new("Shelf spot", ls)
    scene.collection.objects.link(ob)
    ob.parent, ob.location = loft, SPOT["location"]
    d = Vector(SPOT["target"]) - Vector(SPOT["location"])
    ob.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy, sun.color, sun.angle = SUN["strength"], SUN["color"], SUN["angle"]
    ob = bpy.data.objects.new("Sun", sun)
    scene.collection.objects.link(ob)
    e, az = math.radians(SUN["elevation"]), math.radians(SUN["azimuth"])
    d = Vector(
        (math.sin(az) * math.cos(e), math.cos(az) * math.cos(e), -math.sin(e))
    )  # into the room (+y), down
    ob.parent, ob.location = loft, (2.3, -3.0, 4.0)
    ob.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()
    from .blend import look_from

    look_from(scene, "Camera", *VIEWS["loft_a"])
    scene.frame_set(1)
    bpy.context.view_layer.update()
    return scene, _info(scene)


def _shape(name, corners, emission, strength, parent):
    """A flat emissive quad marked as a light shape, parented (corners in its parent's frame)."""
    from .artist_room import _light_shape

    ob = _light_shape(name, corners, emission, strength)
    ob.parent = parent
    return ob


def _info(scene):
    from .artist_room import _info as info

    out = info(scene)
    out["objects"] = len(out["meshes"])
    return out


if __name__ == "__main__":
    print(loft_scene()[1])
