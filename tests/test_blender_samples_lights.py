"""The samples lit by Blender lights (issue 20): policespot (a turning spot at dusk) and daylight
(a sun through a window opening) bake headless at draft, and are lit where their light falls.

Each room corner (the walls, floor and ceiling) is checked against the light's closed form in
Cycles' units (tests/closed_forms.py) at the points the corner's value stands for: with the
default inset the bake gives a corner the mean of samples part of the way from it to the centres of its
polygons, so the closed form is evaluated there. Light reflected from what a point sees (other surfaces, the
sky through the opening) is at most rho L_max, L_max the brightest radiance in the scene (the
brightest baked corner or the sky). Where every such point gets the light in full (inside the
spot's inner cone, or seeing the sun through the opening, with no furniture in the way), the
corner reads
- at least its direct radiance rho E / pi (the final gather's direct light is exact, the rest is
  >= 0): the bake is not black where the light is;
- at most rho E / pi + rho L_max: a direct light counted twice or in other units fails (since
  L_max >= rho E / pi and rho < 1, twice the direct light exceeds the bound).
Where the closed form gives no direct light at all (outside the cone, the sun's rays leaving
outside the opening), the corner reads at most rho L_max: a light (or an opening) in the wrong
place fails.
"""

import numpy as np
import pytest

from test_blender_helpers import load_bpy, make_samples_module, open_sample, shown
from tests import closed_forms as cf

from hr_addon.core.gather.layouts import OUTPUT_INSET

pytestmark = [pytest.mark.bpy, pytest.mark.slow]

ROOM = ("floor", "ceiling", "wall_x0", "wall_x1", "wall_y0", "wall_y1")
MARGIN = 0.01  # furniture boxes grown by 1 cm: a segment grazing a box is not counted as clear


def _corners(obj):
    """Per loop of a room surface's evaluated mesh (at the default Vertex Spacing its faces
    subdivided): the world points its corner value stands for (OUTPUT_INSET of the way to its
    polygon's centre: the finer corners' inset, layouts.default_inset),
    their normal, and the vertex index (loops at a vertex share its value)."""
    import bpy

    me = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    M = np.array(obj.matrix_world)
    co = np.array([v.co for v in me.vertices]) @ M[:3, :3].T + M[:3, 3]
    lv = np.array([lp.vertex_index for lp in me.loops])
    lp = np.array([p.index for p in me.polygons for _ in p.loop_indices])
    centre = np.array([p.center for p in me.polygons]) @ M[:3, :3].T + M[:3, 3]
    normal = np.array([p.normal for p in me.polygons]) @ np.linalg.inv(M[:3, :3])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return co[lv] + OUTPUT_INSET * (centre[lp] - co[lv]), normal[lp], lv


def _boxes(bpy):
    """World-space (lo, hi) of every mesh object that is not a room surface (the furniture)."""
    out = []
    for o in bpy.context.scene.objects:
        if o.type == "MESH" and o.name not in ROOM:
            M = np.array(o.matrix_world)
            c = np.array(o.bound_box) @ M[:3, :3].T + M[:3, 3]
            out.append((c.min(0) - MARGIN, c.max(0) + MARGIN))
    return out


def _clear(p, q, boxes):
    """(N,) True where the segments p -> q (N, 3) meet none of the boxes (slab test)."""
    d = q - p
    ok = np.ones(len(p), bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo, hi in boxes:
            t0, t1 = (lo - p) / d, (hi - p) / d
            near = np.nanmax(np.minimum(t0, t1), axis=1)
            far = np.nanmin(np.maximum(t0, t1), axis=1)
            inside = np.all((p > lo) & (p < hi), axis=1)
            ok &= ~(inside | ((near <= far) & (far >= 0) & (near <= 1)))
    return ok


def _spot(bpy, points, normal):
    """(direct irradiance (N, 3), full (N,), none (N,)) of the scene's one spot light."""
    ob = next(o for o in bpy.context.scene.objects if o.type == "LIGHT")
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    ld = ev.data
    assert ld.type == "SPOT" and ld.shadow_soft_size == 0  # the closed form is a point's
    M = np.array(ev.matrix_world)
    pos, axis = M[:3, 3], -M[:3, 2] / np.linalg.norm(M[:3, 2])
    d = points - pos
    dist = np.linalg.norm(d, axis=1)
    cos = np.einsum("ij,ij->i", -d / dist[:, None], normal)
    cone = np.array([cf.spot_factor(c, ld.spot_size, ld.spot_blend) for c in d @ axis / dist])
    e = cf.point_light_irradiance(ld.energy, dist, np.maximum(cos, 0)) * cone
    full = (cone == 1) & (cos > 0) & _clear(np.broadcast_to(pos, points.shape), points, _boxes(bpy))
    return e[:, None] * np.array(ld.color), full, (cone == 0) | (cos <= 0)


def _sun_through(window):
    """_spot's counterpart for a sun seen through the opening `window` ((lo, hi) on a wall of
    constant y): full where the ray towards the sun leaves through the opening shrunk by the
    sun's half angle (all of the sun's disc is seen) and meets no furniture; none where it leaves
    outside the opening grown by as much."""
    (lo, hi) = np.asarray(window, float)

    def direct(bpy, points, normal):
        ob = next(o for o in bpy.context.scene.objects if o.type == "LIGHT")
        ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
        ld = ev.data
        assert ld.type == "SUN"
        M = np.array(ev.matrix_world)
        to_sun = M[:3, 2] / np.linalg.norm(M[:3, 2])
        t = (lo[1] - points[:, 1]) / to_sun[1]  # along the ray to the window's plane
        q = points + t[:, None] * to_sun
        pad = t * np.tan(ld.angle / 2) + 1e-3
        inner = [(q[:, k] > lo[k] + pad) & (q[:, k] < hi[k] - pad) for k in (0, 2)]
        outer = [(q[:, k] > lo[k] - pad) & (q[:, k] < hi[k] + pad) for k in (0, 2)]
        cos = normal @ to_sun
        e = cf.sun_irradiance(ld.energy, 1.0) * np.maximum(cos, 0)
        full = (t > 0) & (cos > 0) & inner[0] & inner[1] & _clear(points, q, _boxes(bpy))
        none = (t <= 0) | (cos <= 0) | ~(outer[0] & outer[1])
        return e[:, None] * np.array(ld.color), full, none

    return direct


def _brightest(bpy):
    """(3,) the brightest radiance a surface point can see: the brightest baked corner of any
    object, or the World's sky (through the opening)."""
    top = np.max([shown(o)[:, :3].max(0) for o in bpy.context.scene.objects if o.type == "MESH"], 0)
    bg = bpy.context.scene.world.node_tree.nodes["Background"]
    sky = np.array(bg.inputs["Color"].default_value[:3]) * bg.inputs["Strength"].default_value
    return np.maximum(top, sky)


def _check_frame(bpy, direct_light):
    """Fully lit room corners within [rho E / pi, rho E / pi + rho L_max], unlit ones <= rho L_max."""
    rows = []
    for name in ROOM:
        obj = bpy.data.objects[name]
        points, normal, vertex = _corners(obj)
        e, full, none = direct_light(bpy, points, normal)
        node = obj.data.materials[0].node_tree.nodes["Diffuse BSDF"]
        rho = np.array(node.inputs["Color"].default_value[:3])
        value = shown(obj)[:, :3].astype(np.float64)  # (through the HR Radiance modifier)
        assert len(value) == len(vertex)  # one value per corner (domain CORNER)
        nv = vertex.max() + 1
        # every point of the vertex lit in full / not at all
        all_full = np.bincount(vertex, (~full).astype(float), nv) == 0
        all_none = np.bincount(vertex, (~none).astype(float), nv) == 0
        lo = np.full((nv, 3), np.inf)
        hi = np.zeros((nv, 3))
        np.minimum.at(lo, vertex, rho * e / np.pi)
        np.maximum.at(hi, vertex, rho * e / np.pi)
        rows.append(
            (value, all_full[vertex], all_none[vertex], lo[vertex], hi[vertex], np.tile(rho, (len(value), 1)))
        )
    value, full, none, lo, hi, rho = (np.concatenate(x) for x in zip(*rows))
    assert full.sum() >= 8 and none.sum() >= 8, (full.sum(), none.sum())
    # light reflected from what a point sees: at most rho x the brightest radiance there is
    bounce = rho * _brightest(bpy)
    low = np.flatnonzero((value[full] < lo[full] * (1 - 1e-3)).any(1))
    high = np.flatnonzero((value[full] > hi[full] + bounce[full]).any(1))
    dark = np.flatnonzero((value[none] > bounce[none]).any(1))
    assert not len(low), ("darker than the direct light", value[full][low[:5]], lo[full][low[:5]])
    assert not len(high), ("brighter than direct + bounce", value[full][high[:5]], hi[full][high[:5]])
    assert not len(dark), ("lit where no direct light falls", value[none][dark[:5]], bounce[none][dark[:5]])


@pytest.mark.parametrize(
    "name, frames",
    [("policespot", (1, 2)), ("daylight", (12, 13))],
)
def test_light_sample_bakes_lit_where_the_light_falls(tmp_path, name, frames):
    bpy = load_bpy()
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.playback import load_frame

    ms = make_samples_module()
    open_sample(name, tmp_path)
    scene = bpy.context.scene
    assert scene.hr.method == "AUTO" and scene.hr.quality == "DRAFT"
    res = run_bake(scene, log=lambda *a, **k: None, frames=frames)
    assert res.warnings == [] and res.solved >= 1
    direct = _spot if name == "policespot" else _sun_through(ms.DAY_WINDOW)
    for f in frames:
        scene.frame_set(f)
        assert load_frame(scene, f)
        _check_frame(bpy, direct)
