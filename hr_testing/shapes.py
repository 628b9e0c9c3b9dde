"""Light-shape outlines and the office benchmark scene (numpy only; tests and benchmarks, not shipped).

2D outlines (M, 2) are built in a wall's own frame and lifted to world-space rings with `on_plane`.
A frame is (origin, u, v): u x v is the wall's front normal, so a counter-clockwise 2D outline is
counter-clockwise seen from the front (the convention LightShape rings follow).
"""

import numpy as np

from .scenes import WHITE, SceneBuilder, _orient


def rect(w, h, centre=(0.0, 0.0), angle=0.0):
    """Rectangle w x h rotated by `angle` (radians) about its centre."""
    p = np.array([(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)])
    return _place(p, centre, angle)


def ellipse(a, b, centre=(0.0, 0.0), angle=0.0, n=48):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return _place(np.column_stack([a * np.cos(t), b * np.sin(t)]), centre, angle)


def star(r_out, r_in, points=5, centre=(0.0, 0.0), angle=0.0):
    t = np.arange(2 * points) * np.pi / points
    r = np.where(np.arange(2 * points) % 2 == 0, r_out, r_in)
    return _place(np.column_stack([r * np.cos(t), r * np.sin(t)]), centre, angle)


def cross(w, h, bar, centre=(0.0, 0.0), angle=0.0):
    """A plus sign w x h with arms `bar` wide (concave, 12 corners)."""
    a, b, c = w / 2, h / 2, bar / 2
    p = np.array(
        [
            (c, -b),
            (c, -c),
            (a, -c),
            (a, c),
            (c, c),
            (c, b),
            (-c, b),
            (-c, c),
            (-a, c),
            (-a, -c),
            (-c, -c),
            (-c, -b),
        ]
    )
    return _place(p, centre, angle)


def window(w, h, bar, centre=(0.0, 0.0), angle=0.0, shear=0.0):
    """Sunlight through a four-pane window: an outer (sheared, rotated) frame with a cross-shaped hole
    for the mullions. Returns [outer, hole]."""
    outer = rect(w, h)
    hole = cross(w - 2 * bar, h - 2 * bar, bar)
    m = np.array([[1.0, shear], [0.0, 1.0]])
    return [_place(outer @ m.T, centre, angle), _place(hole @ m.T, centre, angle)]


def _place(p, centre, angle):
    c, s = np.cos(angle), np.sin(angle)
    return p @ np.array([[c, s], [-s, c]]) + np.asarray(centre, float)


def on_plane(rings2d, frame):
    """Lift 2D rings (list of (M, 2), or one (M, 2)) to world space with frame (origin, u, v)."""
    o, u, v = (np.asarray(x, float) for x in frame)
    if isinstance(rings2d, np.ndarray) and rings2d.ndim == 2:
        rings2d = [rings2d]
    return [o + np.asarray(r, float)[:, :1] * u + np.asarray(r, float)[:, 1:2] * v for r in rings2d]


# Cornell box walls (scenes.cornell_box, metres, z up). 2D coordinates are metres from the wall's corner.
CORNELL_GREEN_WALL = (np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))  # x = 0, faces +x
CORNELL_BACK_WALL = (
    np.array([0.0, 0.5592, 0.0]),
    np.array([1.0, 0.0, 0.0]),
    np.array([0.0, 0.0, 1.0]),
)  # faces -y
CORNELL_FLOOR = (np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))  # z = 0, faces +z


def office_scene(subdiv=2):
    """A 5 x 4 x 2.8 m office: walls, floor, ceiling with a dim panel light, two desks and two flat
    monitors whose screens face the room (-y). Returns (MeshInput, screen frames): each frame is
    (origin, u, v) of a screen with 2D extent [0, 0.56] x [0, 0.34]."""
    W, D, H = 5.0, 4.0, 2.8
    centre = np.array([W / 2, D / 2, H / 2])
    sb = SceneBuilder()

    def box(name, lo, hi, rho, faces=(0, 1, 2, 3, 4, 5), sub=1):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        c = (lo + hi) / 2
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        quads = [
            [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],  # bottom
            [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],  # top
            [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],  # front (-y)
            [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],  # back (+y)
            [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)],  # left (-x)
            [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)],
        ]  # right (+x)
        for k in faces:
            q = np.array(quads[k])
            sb.add_quad(f"{name}_{k}", _orient(q, 2 * q.mean(0) - c), rho, subdiv=sub)

    room = [
        [(0, 0, 0), (W, 0, 0), (W, D, 0), (0, D, 0)],
        [(0, 0, H), (W, 0, H), (W, D, H), (0, D, H)],
        [(0, 0, 0), (W, 0, 0), (W, 0, H), (0, 0, H)],
        [(0, D, 0), (W, D, 0), (W, D, H), (0, D, H)],
        [(0, 0, 0), (0, D, 0), (0, D, H), (0, 0, H)],
        [(W, 0, 0), (W, D, 0), (W, D, H), (W, 0, H)],
    ]
    names = ["floor", "ceiling", "wall_south", "wall_north", "wall_west", "wall_east"]
    rhos = [(0.45, 0.4, 0.35), WHITE, WHITE, (0.6, 0.65, 0.7), WHITE, WHITE]
    for name, q, rho in zip(names, room, rhos):
        sb.add_quad(name, _orient(np.array(q, float), centre), rho, subdiv=subdiv)
    panel = np.array([(2.0, 1.5, H - 0.01), (3.0, 1.5, H - 0.01), (3.0, 2.5, H - 0.01), (2.0, 2.5, H - 0.01)])
    sb.add_quad("ceiling_panel", _orient(panel, centre), (0.8, 0.8, 0.8), (1.5, 1.5, 1.4))
    frames = []
    for i, x in enumerate((1.2, 3.2)):
        box(f"desk{i}", (x - 0.7, 2.6, 0.72), (x + 0.7, 3.4, 0.76), (0.55, 0.4, 0.25), faces=(0, 1, 2, 4, 5))
        box(
            f"monitor{i}",
            (x - 0.3, 3.0, 0.85),
            (x + 0.3, 3.04, 1.23),
            (0.05, 0.05, 0.05),
            faces=(0, 1, 2, 3, 4, 5),
        )
        box(f"stand{i}", (x - 0.04, 3.02, 0.76), (x + 0.04, 3.06, 0.85), (0.1, 0.1, 0.1), faces=(2, 3, 4, 5))
        # screen = the monitor's front face (y = 3.0, facing -y) inset by a 2 cm bezel
        frames.append((np.array([x - 0.28, 3.0, 0.87]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])))
    return sb.build(), frames
