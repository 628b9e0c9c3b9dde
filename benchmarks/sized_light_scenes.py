"""Which scenes' values the sized point / spot light of session 38 (branch sph38) changes: every
Blender point or spot light with a radius in the test scenes (the loft, the two rooms, the artist
room, the sample .blends), and each object's unoccluded direct light from it before (main c7fcd9c:
I cos / (d^2 + r^2) at the centre's cos, 0 behind the centre's horizon) and now
(lights.sized_point_unit: the disc or sphere cut by the horizon), over area-uniform points of its
faces, the spot's cone at the centre for both (its per-ray cone is a shadow-ray effect, not here).
Shadows are left out: an upper bound on the direct light's change where the horizon cuts the
emitter. The kernel-weighted shadow rays change penumbrae only (the same ray points, new weights).

Run: .venv/bin/python benchmarks/sized_light_scenes.py [points per m^2] -> one RESULT JSON line per
scene and light, the objects whose direct light moves by > 0.1%."""

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from hr_addon.core import lights as lt  # noqa: E402
from hr_testing.blend import load_bpy  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def triangles(bpy, depsgraph):
    """{object name: (T, 3, 3) world triangles} of the visible meshes."""
    out = {}
    for ob in depsgraph.objects:
        if ob.type != "MESH" or ob.hide_render:
            continue
        me = ob.to_mesh()
        me.calc_loop_triangles()
        M = np.array(ob.matrix_world)
        v = np.array([M[:3, :3] @ np.array(x.co) + M[:3, 3] for x in me.vertices]).reshape(-1, 3)
        t = np.array([tuple(lt_.vertices) for lt_ in me.loop_triangles], np.int64).reshape(-1, 3)
        if len(t):
            out[ob.name] = v[t]
        ob.to_mesh_clear()
    return out


def sized_lights(bpy, depsgraph):
    out = []
    for ob in depsgraph.objects:
        if ob.type == "LIGHT" and ob.data.type in ("POINT", "SPOT") and ob.data.shadow_soft_size > 0:
            ld = ob.data
            M = np.array(ob.matrix_world)
            kw = dict(position=M[:3, 3], direction=-M[:3, 2], radius=float(ld.shadow_soft_size))
            kw["soft_falloff"] = bool(getattr(ld, "use_soft_falloff", True))
            if ld.type == "SPOT":
                kw.update(spot_size=float(ld.spot_size), spot_blend=float(ld.spot_blend))
            out.append(lt.Light(ld.type, (1, 1, 1), 1.0, name=ob.name, **kw))
    return out


def points(tris, density, rng):
    a = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    k = np.maximum(rng.poisson(a * density), 1)
    i = np.repeat(np.arange(len(tris)), k)
    u, v = rng.random(len(i)), rng.random(len(i))
    f = u + v > 1
    u[f], v[f] = 1 - u[f], 1 - v[f]
    t = tris[i]
    x = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    ok = np.linalg.norm(n, axis=1) > 0
    n[ok] /= np.linalg.norm(n[ok], axis=1)[:, None]
    w = np.repeat(a / k, k)
    return x[ok], n[ok], w[ok]


def compare(name, tris, L, density):
    rng = np.random.default_rng(1)
    rows, tot_b, tot_a = {}, 0.0, 0.0
    for ob, t in tris.items():
        x, n, w = points(t, density, rng)
        d = L.position - x
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
        cos = np.einsum("ij,ij->i", d, n) / dist
        spot = lt.spot_factor(L, -(d / dist[:, None]) @ L.direction) if L.kind == "SPOT" else 1.0
        fall = dist**2 + L.radius**2 if L.soft_falloff else np.maximum(dist**2, L.radius**2)
        before = np.maximum(cos, 0) * lt.POINT_INTENSITY / fall / np.pi * spot
        after = lt.sized_point_unit(L, dist, cos) * spot
        b, a = float((before * w).sum()), float((after * w).sum())
        tot_b, tot_a = tot_b + b, tot_a + a
        if a > 0 and abs(a / max(b, 1e-300) - 1) > 1e-3:
            rows[ob] = {
                "after_over_before": round(a / b - 1, 4) if b > 0 else None,
                "share_of_the_lights_direct_light": round(a / 1.0, 12),  # divided below
                "points_lit_now_not_before": int(((after > 0) & (before == 0)).sum()),
            }
    for r in rows.values():
        r["share_of_the_lights_direct_light"] = round(r["share_of_the_lights_direct_light"] / tot_a, 5)
    return {
        "scene": name,
        "light": L.name,
        "kind": L.kind,
        "radius": L.radius,
        "soft_falloff": L.soft_falloff,
        "all_objects_after_over_before": round(tot_a / tot_b - 1, 5),
        "objects_moving": rows,
    }


def main(density):
    bpy = load_bpy()
    scenes = []

    def built(name, make):
        make()
        scenes.append(name)
        dg = bpy.context.evaluated_depsgraph_get()
        return triangles(bpy, dg), sized_lights(bpy, dg)

    from hr_testing import artist_room, loft, two_rooms

    makers = [
        ("loft", lambda: loft.loft_scene()),
        ("two_rooms", lambda: two_rooms.two_rooms_scene()),
        ("artist_room", lambda: artist_room.artist_room()),
    ]
    for p in sorted((ROOT / "sample_blends").glob("*.blend")):
        makers.append((p.stem, lambda p=p: bpy.ops.wm.open_mainfile(filepath=str(p))))
    for name, make in makers:
        tris, lights = built(name, make)
        if not lights:
            print("RESULT " + json.dumps({"scene": name, "sized_point_or_spot_lights": 0}), flush=True)
        for L in lights:
            print("RESULT " + json.dumps(compare(name, tris, L, density)), flush=True)


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 4000.0)
