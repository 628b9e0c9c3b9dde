"""Two rooms joined by a doorway, built for issue 19's unseen-scene check (session 31, branch unseen):
a furnished interior nobody tuned on, unlike the furnished sample and the artist room in the
features that failed before (contacts, clutter, thin strips, small gaps, shadows of thin parts).

    mesh, info = two_rooms()        # MeshInput (z up, metres) and a dict of facts (numpy only)
    scene, info = two_rooms_scene() # the Blender scene: meshes, light shapes, lights, a camera

Living room A (5 x 4 m) and bedroom B (3 x 3.2 m) side by side, 2.6 m high, joined by a
1 x 2 m doorway through a 20 cm partition (an L of floor: B is shallower than A). Room shells
are 20 cm grids; the doorway's reveals are their own object, built facing into the wall (a modelling
slip kept: session 31's Cycles references are of this scene): the bake turns them around (its
warning), the references' one-sided materials show their backs black: camera_compare's `--flip-ref doorway`
renders them turned, as the bake reads them (docs/accuracy.md, session 31). In A: a sofa of parts sunk into
each other (base, back, arms, cushions), a 2.8 m table covered with ~60 small items (cups,
plates with bowls sunk in them, spheres, boxes, a few touching), a floor-to-ceiling pillar of 64
thin strips 25 cm from two walls, shelves 45 cm deep with 30 cm gaps (boxes deep inside), a
venetian blind (12 slats 8 mm thick) in front of the west window, a pleated curtain, a rug, a
floor lamp. In B: a bed of sunk-in parts, a solid staircase of eight steps along the north wall,
a wardrobe, a desk with small items. Albedos from 0.03 (black cushions, a black box) to 0.85,
and saturated reds, blues, greens and yellows.

Light: frame 1 a point light (the floor lamp, 120 W, radius 5 cm) in A and an area light
(1 x 0.5 m, 150 W) under B's ceiling; from frame 3 also two light shapes in A: a ceiling panel
(1.2 x 0.6 m) and the west window (1.6 x 1.2 m) behind the blind. Deterministic (seed 7).
"""

import numpy as np

from .furnished import Builder, Footprints, box, cylinder, grid_quad, icosphere

H = 2.6  # ceiling height
A = (0.0, 5.0, 0.0, 4.0)  # room A: x0, x1, y0, y1
B = (5.2, 8.2, 0.0, 3.2)  # room B
DOOR = (1.4, 2.4, 2.0)  # the doorway through the partition x 5.0-5.2: y0, y1, height
CELL = 0.2  # the room shells' grid
WINDOW = (1.0, 2.6, 0.9, 2.1)  # the west window light shape on x = 0: y0, y1, z0, z1
PANEL = (1.9, 3.1, 1.2, 1.8)  # the ceiling light shape in A: x0, x1, y0, y1
SHAPES_ON = 3  # the frame from which the light shapes are on
LAMP = dict(location=(4.6, 0.4, 1.55), energy=120.0, radius=0.05, color=(1.0, 0.85, 0.65))
AREA = dict(location=(6.7, 1.6, 2.55), energy=150.0, size=(1.0, 0.5), color=(0.9, 0.95, 1.0))
VIEWS = {  # camera location, target, lens (mm)
    "unseen_a": ((4.7, 1.2, 1.75), (0.8, 2.2, 0.7), 18),
    "unseen_b": ((8.05, 2.05, 1.85), (5.2, 1.5, 0.85), 20),
}

WALL, FLOOR, CEIL = (0.78, 0.76, 0.72), (0.42, 0.3, 0.2), (0.85, 0.85, 0.85)
WOOD, DARK, BLACK = (0.5, 0.33, 0.18), (0.08, 0.07, 0.07), (0.03, 0.03, 0.03)
RED, BLUE, GREEN, YELLOW = (0.7, 0.06, 0.04), (0.05, 0.15, 0.65), (0.08, 0.5, 0.12), (0.85, 0.7, 0.05)
WHITE = (0.85, 0.85, 0.82)


def _shell(b, name, o, u, v, holes=(), rho=WALL):
    """A plane of CELL-sized quads (normal u x v: into the room), cells whose centre lies in a hole
    box (lo, hi) left out."""
    vv, q = grid_quad(
        np.asarray(o, float),
        np.asarray(u, float),
        np.asarray(v, float),
        round(np.linalg.norm(u) / CELL),
        round(np.linalg.norm(v) / CELL),
    )
    c = vv[q].mean(1)
    keep = np.ones(len(q), bool)
    for lo, hi in holes:
        keep &= ~np.all((c > lo) & (c < hi), 1)
    b.add(name, vv, [q[keep]], rho)


def _room(b, tag, x0, x1, y0, y1, west_hole=(), east_hole=()):
    W, D = x1 - x0, y1 - y0
    _shell(b, f"{tag}_floor", (x0, y0, 0), (W, 0, 0), (0, D, 0), rho=FLOOR)
    _shell(b, f"{tag}_ceiling", (x0, y0, H), (0, D, 0), (W, 0, 0), rho=CEIL)
    _shell(b, f"{tag}_wall_south", (x0, y0, 0), (0, 0, H), (W, 0, 0))
    _shell(b, f"{tag}_wall_north", (x0, y1, 0), (W, 0, 0), (0, 0, H))
    _shell(b, f"{tag}_wall_west", (x0, y0, 0), (0, D, 0), (0, 0, H), west_hole)
    _shell(b, f"{tag}_wall_east", (x1, y0, 0), (0, 0, H), (0, D, 0), east_hole)


def _quads(*quads):
    """Vertices and one face list of flat quads given by their corners (CCW seen from the front)."""
    v = np.concatenate([np.asarray(q, float) for q in quads])
    return v, [np.arange(len(v)).reshape(-1, 4)]


def _prism(profile, z0, z1):
    """A closed solid over a closed 2D polyline band: profile (n, 2, 2) pairs (outer, inner) of
    points along a strip (a pleated curtain's cross-section), extruded from z0 to z1."""
    p = np.asarray(profile, float)
    n = len(p)
    out, inn = p[:, 0], p[:, 1]
    ring = np.concatenate([out, inn[::-1]])  # the band's outline, one way round
    m = len(ring)
    v = np.concatenate([np.c_[ring, np.full(m, z0)], np.c_[ring, np.full(m, z1)]])
    i = np.arange(m)
    j = (i + 1) % m
    sides = np.c_[i, j, m + j, m + i]
    k = np.arange(n - 1)  # caps: the quads between the outline's two halves
    a, b_, c, d = k, k + 1, m - 2 - k, m - 1 - k
    bottom = np.c_[a, d, c, b_]
    top = np.c_[m + a, m + b_, m + c, m + d]
    # orientation: outward normals if the ring runs counter-clockwise seen from above
    x, y = ring[:, 0], ring[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        sides, bottom, top = sides[:, ::-1], bottom[:, ::-1], top[:, ::-1]
    return v, [sides, bottom, top]


def two_rooms(seed=7):
    rng = np.random.default_rng(seed)
    b = Builder()
    dy0, dy1, dz = DOOR
    hole = ((A[1] - 0.1, dy0, -0.1), (B[0] + 0.1, dy1, dz))
    _room(b, "A", *A, east_hole=(hole,))
    _room(b, "B", *B, west_hole=(hole,))
    xa, xb = A[1], B[0]
    b.add(
        "doorway",
        *_quads(
            # each faces away from the opening (into the wall): see the docstring
            [(xa, dy0, 0), (xb, dy0, 0), (xb, dy0, dz), (xa, dy0, dz)],  # faces -y
            [(xb, dy1, 0), (xa, dy1, 0), (xa, dy1, dz), (xb, dy1, dz)],  # faces +y
            [(xa, dy0, dz), (xb, dy0, dz), (xb, dy1, dz), (xa, dy1, dz)],  # faces +z
            [(xa, dy0, 0), (xa, dy1, 0), (xb, dy1, 0), (xb, dy0, 0)],  # faces -z
        ),
        FLOOR,
    )
    # --- room A ---------------------------------------------------------------------------
    # sofa against the south wall: parts sunk into each other
    sx, sy = 1.3, 0.05
    b.add("sofa_base", *box([sx, sy, 0], [sx + 2.0, sy + 0.9, 0.42], 2), RED)
    b.add("sofa_back", *box([sx + 0.1, sy, 0.3], [sx + 1.9, sy + 0.22, 0.88], 2), RED)
    b.add("sofa_arm0", *box([sx - 0.05, sy, 0.1], [sx + 0.2, sy + 0.9, 0.62], 1), RED)
    b.add("sofa_arm1", *box([sx + 1.8, sy, 0.1], [sx + 2.05, sy + 0.9, 0.62], 1), RED)
    for i in range(3):
        x = sx + 0.2 + i * 0.535
        b.add(f"sofa_cushion{i}", *box([x, sy + 0.2, 0.36], [x + 0.53, sy + 0.86, 0.52], 2), BLACK)
    b.add("sofa_pillow", *box([sx + 0.3, sy + 0.2, 0.45], [sx + 0.7, sy + 0.32, 0.8], 1), YELLOW)
    b.add("rug", *box([1.0, 1.15, 0], [3.6, 2.2, 0.012], 4), BLUE)
    # long table covered with small items
    tx0, ty0, tx1, ty1, th = 1.0, 2.45, 3.8, 3.3, 0.76
    b.add("table_top", *box([tx0, ty0, th - 0.04], [tx1, ty1, th], 4), WOOD)
    for i, (lx, ly) in enumerate(
        [(tx0 + 0.05, ty0 + 0.05), (tx1 - 0.1, ty0 + 0.05), (tx0 + 0.05, ty1 - 0.1), (tx1 - 0.1, ty1 - 0.1)]
    ):
        b.add(f"table_leg{i}", *box([lx, ly, 0], [lx + 0.05, ly + 0.05, th - 0.04]), WOOD)
    top = Footprints(rng, (tx0 + 0.03, ty0 + 0.03), (tx1 - 0.03, ty1 - 0.03), gap=0.004)
    palette = [WHITE, RED, BLUE, GREEN, YELLOW, DARK, (0.6, 0.55, 0.5), (0.3, 0.2, 0.5)]
    for k in range(70):
        kind = k % 5
        col = palette[int(rng.integers(len(palette)))]
        if kind == 0:  # a cup
            r = rng.uniform(0.035, 0.05)
            s = top.place(2 * r, 2 * r)
            if s:
                b.add(f"item{k}_cup", *cylinder([s[0] + r, s[1] + r, th], r, 0.1, 16), col)
        elif kind == 1:  # a plate and a bowl sunk into it
            r = rng.uniform(0.09, 0.12)
            s = top.place(2 * r, 2 * r)
            if s:
                c = [s[0] + r, s[1] + r, th]
                b.add(f"item{k}_plate", *cylinder(c, r, 0.015, 24), WHITE)
                b.add(f"item{k}_bowl", *icosphere([c[0], c[1], th + 0.03], 0.6 * r, 2), col)
        elif kind == 2:  # a ball
            r = rng.uniform(0.03, 0.06)
            s = top.place(2 * r, 2 * r)
            if s:
                b.add(f"item{k}_ball", *icosphere([s[0] + r, s[1] + r, th + r], r, 2), col)
        elif kind == 3:  # a small box, sometimes a second one leaning into it
            w, d, h = rng.uniform(0.04, 0.14, 3)
            s = top.place(w, d)
            if s:
                b.add(f"item{k}_box", *box([s[0], s[1], th], [s[0] + w, s[1] + d, th + h]), col)
                if k % 2:
                    b.add(
                        f"item{k}_lid",
                        *box(
                            [s[0] - 0.01, s[1] - 0.01, th + h - 0.01],
                            [s[0] + w + 0.01, s[1] + d + 0.01, th + h + 0.012],
                        ),
                        DARK,
                    )
        else:  # a bottle: a tall thin cylinder
            r = rng.uniform(0.02, 0.035)
            s = top.place(2 * r, 2 * r)
            if s:
                b.add(
                    f"item{k}_bottle", *cylinder([s[0] + r, s[1] + r, th], r, rng.uniform(0.2, 0.32), 12), col
                )
    # a pillar of 64 strips, floor to ceiling, 25 cm from the north and west walls
    b.add("pillar", *cylinder([0.4, 3.6, 0], 0.15, H, 64, caps=False), WHITE)
    # shelves against the north wall: 45 cm deep, 30 cm between boards, boxes deep inside
    hx0, hx1, hy0, hy1 = 1.2, 2.6, A[3] - 0.45, A[3]
    b.add("shelf_side0", *box([hx0, hy0, 0], [hx0 + 0.03, hy1, 1.9]), WOOD)
    b.add("shelf_side1", *box([hx1 - 0.03, hy0, 0], [hx1, hy1, 1.9]), WOOD)
    b.add("shelf_back", *box([hx0 + 0.03, hy1 - 0.02, 0], [hx1 - 0.03, hy1, 1.9]), WHITE)
    for j in range(6):
        z = 0.05 + j * 0.32
        b.add(f"shelf_board{j}", *box([hx0 + 0.03, hy0, z], [hx1 - 0.03, hy1 - 0.02, z + 0.025]), WOOD)
        if j < 5:
            x = hx0 + 0.06
            for n in range(3):
                w = rng.uniform(0.15, 0.3)
                if x + w > hx1 - 0.05:
                    break
                h = rng.uniform(0.1, 0.25)
                y = hy1 - 0.03 - rng.uniform(0.15, 0.35)
                col = palette[int(rng.integers(len(palette)))]
                b.add(f"shelf_box{j}_{n}", *box([x, y, z + 0.025], [x + w, hy1 - 0.03, z + 0.025 + h]), col)
                x += w + rng.uniform(0.05, 0.15)
    # a venetian blind in front of the west window: 12 slats 8 mm thick, 8 cm deep
    wy0, wy1, wz0, wz1 = WINDOW
    for i in range(12):
        z = wz0 + 0.05 + i * 0.1
        b.add(f"blind_slat{i}", *box([0.04, wy0 - 0.05, z], [0.12, wy1 + 0.05, z + 0.008]), WHITE)
    # a pleated curtain beside it: a 1 cm band zigzagging 6 cm deep
    ys = np.linspace(wy1 + 0.1, wy1 + 0.8, 15)
    xs = 0.05 + 0.06 * (np.arange(15) % 2)
    prof = [((x, y), (x + 0.01, y)) for x, y in zip(xs, ys)]
    b.add("curtain", *_prism(prof, 0.03, 2.45), (0.55, 0.1, 0.3))
    # a floor lamp under the point light
    lx, ly, lz = LAMP["location"]
    b.add("lamp_pole", *cylinder([lx, ly, 0], 0.015, lz - 0.12, 8), BLACK)
    b.add("lamp_foot", *cylinder([lx, ly, 0], 0.15, 0.02, 24), BLACK)
    # boxes on the floor of A
    for k, (x, y, s, col) in enumerate(
        [(4.3, 3.3, 0.4, DARK), (3.9, 1.5, 0.3, YELLOW), (0.3, 0.3, 0.35, GREEN)]
    ):
        b.add(f"floorbox{k}", *box([x, y, 0], [x + s, y + s, 0.8 * s]), col)
    b.add("floorbox0_top", *box([4.35, 3.35, 0.31], [4.6, 3.6, 0.5]), RED)  # sunk into floorbox0
    # --- room B ---------------------------------------------------------------------------
    bx1 = B[1]
    b.add("bed_frame", *box([6.2, 0.3, 0], [bx1 - 0.05, 1.9, 0.35], 2), WOOD)
    b.add("bed_head", *box([bx1 - 0.1, 0.25, 0], [bx1, 1.95, 1.0], 2), DARK)
    b.add("bed_mattress", *box([6.25, 0.35, 0.3], [bx1 - 0.1, 1.85, 0.55], 3), WHITE)
    b.add("bed_blanket", *box([6.22, 0.32, 0.45], [7.4, 1.88, 0.58], 3), BLUE)
    b.add("bed_pillow0", *box([7.55, 0.45, 0.5], [bx1 - 0.15, 1.05, 0.66], 1), WHITE)
    b.add("bed_pillow1", *box([7.55, 1.15, 0.5], [bx1 - 0.15, 1.75, 0.66], 1), YELLOW)
    # a solid staircase along the north wall, up towards x
    for k in range(8):
        x = 5.45 + 0.22 * k
        b.add(f"step{k}", *box([x, B[3] - 0.9, 0], [x + 0.22, B[3], 0.26 * (k + 1)], 1), (0.6, 0.58, 0.55))
    # a wardrobe in B's south-west corner and a desk with items
    b.add("wardrobe", *box([5.25, 0.05, 0], [6.05, 0.65, 2.1], 2), (0.2, 0.3, 0.25))
    b.add("desk_top", *box([7.3, 2.2, 0.72], [8.15, 3.15, 0.75], 2), WOOD)
    b.add("desk_body", *box([7.85, 2.25, 0], [8.1, 3.1, 0.72], 1), DARK)  # a drawer block under it
    b.add("desk_leg", *box([7.32, 2.22, 0], [7.37, 2.27, 0.72]), DARK)
    b.add("desk_screen", *box([7.9, 2.4, 0.75], [7.95, 2.95, 1.1]), BLACK)
    b.add("desk_mug", *cylinder([7.5, 2.5, 0.75], 0.04, 0.1, 16), RED)
    b.add("desk_book", *box([7.45, 2.7, 0.75], [7.7, 3.0, 0.78]), GREEN)
    mesh = b.build()
    return mesh, {
        "triangles": int(np.sum(mesh.loop_total - 2)),
        "objects": len(mesh.object_names),
        "polygons": len(mesh.loop_total),
    }


def _key_on(ob, frame):
    """hide_render keys: hidden before `frame`, shown from it."""
    ob.hide_render = True
    ob.keyframe_insert("hide_render", frame=1)
    ob.hide_render = False
    ob.keyframe_insert("hide_render", frame=frame)


def two_rooms_scene():
    """two_rooms() in a new Blender scene (hr_testing.blend.mesh_scene) with its light shapes (on
    from SHAPES_ON), the point and area lights and the first view's camera; frames 1-4, draft."""
    from .artist_room import _light_shape
    from .blend import load_bpy, look_from, mesh_scene

    mesh, info = two_rooms()
    scene = mesh_scene(mesh)
    bpy = load_bpy()
    scene.frame_start, scene.frame_end = 1, 4
    scene.hr.quality = "DRAFT"
    x0, x1, y0, y1 = PANEL
    _key_on(
        _light_shape(
            "Ceiling panel", [(x0, y0, H), (x0, y1, H), (x1, y1, H), (x1, y0, H)], (1.0, 0.95, 0.88), 10.0
        ),
        SHAPES_ON,
    )  # faces -z
    wy0, wy1, wz0, wz1 = WINDOW
    _key_on(
        _light_shape(
            "Window", [(0, wy0, wz0), (0, wy1, wz0), (0, wy1, wz1), (0, wy0, wz1)], (0.85, 0.92, 1.0), 14.0
        ),
        SHAPES_ON,
    )  # faces +x
    lp = bpy.data.lights.new("Floor lamp", "POINT")
    lp.energy, lp.shadow_soft_size, lp.color = LAMP["energy"], LAMP["radius"], LAMP["color"]
    ob = bpy.data.objects.new("Floor lamp", lp)
    ob.location = LAMP["location"]
    scene.collection.objects.link(ob)
    la = bpy.data.lights.new("Bedroom panel", "AREA")
    la.shape, (la.size, la.size_y) = "RECTANGLE", AREA["size"]
    la.energy, la.color = AREA["energy"], AREA["color"]
    ob = bpy.data.objects.new("Bedroom panel", la)
    ob.location = AREA["location"]  # an area light faces its -z: down
    scene.collection.objects.link(ob)
    look_from(scene, "Camera", *VIEWS["unseen_a"])
    scene.frame_set(1)
    return scene, info


if __name__ == "__main__":
    print(two_rooms()[1])
