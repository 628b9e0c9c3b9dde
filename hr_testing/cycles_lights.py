"""Cornell box lit by a Blender light in place of its emitter (issue 20) against Cycles: reflected
radiance per surface (Cycles DIFFUSE bake, direct + indirect x colour) and our final gather
(two levels + 4 iterations) on a medium solution; WORLD: a uniform sky through the open front;
SUN_HOLE: a sun through a square hole in the ceiling; WORLD_ENV: an environment image
(environment_image) through the open front. Two Cycles seeds give the reference's noise.
daylight_scene(): hr_testing.furnished's daylight room in Blender, lit by its sun and sky
(benchmarks/furnished_lights.py).

The benchmark benchmarks/cycles_lights.py prints run()'s result per light kind; the test
tests/test_cycles_lights.py runs a smaller version."""

import math
import tempfile
import time

import numpy as np

from . import cycles_ref as C
from .blend import load_bpy, mesh_scene, open_sample


def environment_image(width=64, height=32):
    """An equirectangular test sky whose light depends on the direction in every way the mapping
    could get wrong: red from +x, blue from -y (the Cornell box's open front faces -y), a little
    green everywhere, all twice as bright above the horizon. Built through core.sky's own mapping
    inverted (u = 0.5 - atan2(y, x) / 2 pi, v = 0.5 + asin(z) / pi): a mirrored or shifted
    mapping puts the light where Cycles does not."""
    import bpy

    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    phi = (0.5 - u) * 2 * np.pi
    lat = (v - 0.5) * np.pi
    x = np.cos(lat)[:, None] * np.cos(phi)[None]
    y = np.cos(lat)[:, None] * np.sin(phi)[None]
    px = np.zeros((height, width, 4), np.float32)
    px[..., 0] = x > 0
    px[..., 1] = 0.3
    px[..., 2] = y < 0
    px[..., :3] *= np.where(lat > 0, 2.0, 1.0)[:, None, None]
    px[..., 3] = 1
    img = bpy.data.images.new("Test sky", width, height, float_buffer=True)
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def add_world(colour=(0.5, 0.7, 1.0), strength=1.0, image=None):
    """A uniform sky (or an equirectangular image): an Emission node as the World's surface
    (cycles_ref.configure_cycles turns Background nodes off for the other references; an Emission
    node lights Cycles the same way)."""
    import bpy

    world = bpy.data.worlds.new("Sky")
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    nodes = world.node_tree.nodes
    nodes.clear()
    out = nodes.new("ShaderNodeOutputWorld")
    em = nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*colour, 1.0)
    em.inputs["Strength"].default_value = strength
    world.node_tree.links.new(em.outputs[0], out.inputs["Surface"])
    if image is not None:
        env = nodes.new("ShaderNodeTexEnvironment")
        env.image = image
        world.node_tree.links.new(env.outputs["Color"], em.inputs["Color"])
    bpy.context.scene.world = world
    return world


def daylight_scene(size="20k", portal=False):
    """A new empty scene holding furnished.daylight_room(size): one mesh object per room object
    (a Diffuse BSDF of its reflectance), furnished.SUN as a sun light and furnished.SKY as the
    World. portal: a Cycles portal filling the window (an area light that emits nothing: Cycles
    samples the World's light through it, the same result with less noise; the bake skips it;
    docs/lights.md, *A daylight reference through a portal*).
    Returns (scene, info of daylight_room)."""
    bpy = load_bpy()
    from mathutils import Vector

    from . import furnished as F

    mesh, info = F.daylight_room(size)
    scene = mesh_scene(mesh)
    ld = bpy.data.lights.new("Sun", "SUN")
    ld.energy, ld.angle, ld.color = F.SUN["strength"], F.SUN["angle"], F.SUN["color"]
    ob = bpy.data.objects.new("Sun", ld)
    ob.rotation_euler = Vector(F.SUN["direction"]).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(ob)
    add_world(F.SKY["color"], F.SKY["strength"])
    if portal:
        lo, hi = info["window"]
        ld = bpy.data.lights.new("Window portal", "AREA")
        ld.shape, ld.size, ld.size_y = "RECTANGLE", float(hi[0] - lo[0]), float(hi[2] - lo[2])
        ld.cycles.is_portal = True
        ob = bpy.data.objects.new("Window portal", ld)
        ob.location = (lo + hi) / 2
        ob.rotation_euler = Vector((0.0, 1.0, 0.0)).to_track_quat("-Z", "Z").to_euler()  # into the room
        scene.collection.objects.link(ob)
        # with a portal, the World's AUTOMATIC importance map makes Cycles slow (the 2k room, one
        # bake call at 16 spp: 64 s CPU against 4.6 s); a small map gives the same values here
        # (a uniform World, sampled through the portal) at a plain World's cost
        scene.world.cycles.sampling_method, scene.world.cycles.sample_map_resolution = "MANUAL", 64
    bpy.context.view_layer.update()  # the sun's evaluated transform
    return scene, info


def daylight_part(part, info):
    """Light the daylight scene by one part of its light, for a reference with less noise: "sun"
    (the World dark) or "sky" (the sun off, the World dark, and an emissive quad filling the window
    with the sky's radiance, facing the room). A uniform World seen through an opening with nothing
    outside is exactly a Lambertian emitter of its radiance in the opening; Cycles finds that quad
    by light sampling, where it finds the World's window only by chance. "all": as built."""
    import bpy

    from . import furnished as F

    em = next(n for n in bpy.context.scene.world.node_tree.nodes if n.type == "EMISSION")
    em.inputs["Strength"].default_value = F.SKY["strength"] if part == "all" else 0.0
    bpy.data.objects["Sun"].data.energy = 0.0 if part == "sky" else F.SUN["strength"]
    quad = bpy.data.objects.get("Sky window")
    if part != "sky":
        if quad is not None:
            bpy.data.objects.remove(quad)
        return
    if quad is None:
        lo, hi = (np.asarray(v, float) for v in info["window"])
        y = lo[1] - 1e-4  # just outside the wall's plane (y = 0, the room at y > 0)
        me = bpy.data.meshes.new("Sky window")
        corners = [(lo[0], y, lo[2]), (hi[0], y, lo[2]), (hi[0], y, hi[2]), (lo[0], y, hi[2])]
        me.from_pydata(corners, [], [(0, 1, 2, 3)])
        m = bpy.data.materials.new("Sky window")
        if bpy.app.version < (5, 0, 0):
            m.use_nodes = True
        t = m.node_tree
        t.nodes.clear()
        e = t.nodes.new("ShaderNodeEmission")
        e.inputs["Color"].default_value = (*F.SKY["color"], 1.0)
        e.inputs["Strength"].default_value = F.SKY["strength"]
        t.links.new(e.outputs[0], t.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
        me.materials.append(m)
        quad = bpy.data.objects.new("Sky window", me)
        bpy.context.scene.collection.objects.link(quad)
    bpy.context.view_layer.update()


def bake_ours(rs, quality="DRAFT", threads=1, method=None, vertex=False, gather=None, shapes=None):
    """Our bake of the prepared scene `rs` (cycles_ref.prepare) as the Blender bake makes it
    (BakeConfig at `quality` with the scene's other settings: hierarchy, solver_setup, solver
    options, the lights and the World read by collect_lights, the final gather's settings), the
    final gather evaluated at the atlas's texel centres. -> ({name: {leaf_refl, gather_refl, ...,
    direct_SUN, direct_SKY, ...: (N, 3) per texel}}, cost {seconds, ...}, {config, lights,
    warnings}); direct_KIND: the reflected direct light of the lights of that kind. method: the
    light method (None: the scene's). vertex: also the vertex output (gvertex_total: a LoopGather at
    the corners, interpolated over the loop triangles, what a vertex bake shows). gather: texel
    gather keywords over the bake's (a variant). shapes: the frame's light shapes
    (cycles_ref.shape_proxies)."""
    import bpy

    from hr_addon.blender.lights_in import collect_lights
    from hr_addon.blender.settings import BakeConfig, solver_setup
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.lights import Light
    from hr_addon.core.radiosity import RadiositySystem

    vl = bpy.context.view_layer
    warnings = []
    lights = collect_lights(vl, vl.depsgraph, Light, warnings)
    cfg = BakeConfig.resolve(rs.scene.hr, quality=quality, threads=threads, method=method)
    params, min_area_rel, _ = solver_setup(rs.scene_in.mesh, cfg.params)
    t0 = time.process_time()
    system = RadiositySystem(rs.scene_in.mesh, params, threads=threads)
    t1 = time.process_time()
    dyn = DynamicRadiosity(
        system, method=cfg.method, min_area_rel=min_area_rel, warm_moves=False, **cfg.solve_options
    )
    dyn.apply(shapes or {}, lights)
    t2 = time.process_time()
    mine = C.Ours(rs, system, dyn)
    res = mine.evaluate(shapes or {}, smooth=False)
    cache = {}
    gkw = {**cfg.gather, **(gather or {})}
    gres, cost = C.gather_results(rs, mine, dyn, vertex=vertex, cache=cache, threads=threads, **gkw)
    # each light's direct light reflected at the texels (the gather's cached unit light x scale)
    tg = cache["texel"]
    direct = {}
    for rec in dyn.lights.values():
        d = tg.rho * (tg._light(rec)[:, None].astype(np.float64) * rec.scale[None])
        d[tg.dark] = 0.0
        direct[rec.light.kind] = direct.get(rec.light.kind, 0.0) + tg.outputs(d)
    s = 0
    for n in rs.objects:
        res[n].update(gres[n])
        at = rs.atlases[n]
        cen = np.flatnonzero(at.s_centre)
        for kind, d in direct.items():
            tex = np.full((at.n, 3), np.nan)
            tex[at.s_texel[cen]] = d[s : s + len(cen)]
            res[n][f"direct_{kind}"] = tex
        s += len(cen)
    cost.update(build_s=t1 - t0, apply_s=t2 - t1, links=len(system.links))
    info = {
        "config": dict(quality=cfg.quality, method=cfg.method, gather=gkw, params=repr(params)),
        "lights": {k: (L.kind, L.scale.tolist()) for k, L in lights.items()},
        "warnings": warnings,
    }
    return res, cost, info


DIRECT_SHARE = 0.1  # per_object: "sun" / "sky" lit where that light's direct part is >= 10% of ours


def per_object(rs, res, refs, noise_pair=None):
    """Our bake (bake_ours' res) against Cycles references (one {name: (N, 3)} per seed; their mean
    is the reference), per object: ({name: {mre, bias, texels, mean_ref, mean_ours (cycles_ref.metrics
    of the final gather's reflected radiance), leaf_bias (the hierarchy's leaves), share_sun,
    share_sky (our direct light's share), kind ("sun", "sky" or "bounce": lit directly by the sun,
    else by the sky, else by bounce light only), ref_noise (two seeds or more: the reference's own
    noise of the mean), ref_noise_texels (the same from the texels' seed differences),
    scatter_noise (a bound of that from one reference)}}, lit: the objects
    whose reference mean is above 5% of the pooled mean (where a relative error means something),
    {group: cycles_ref.object_summary} of the lit objects
    for all (pooled bias: over every texel), books, others, sun-lit, sky-lit, bounce-lit).
    noise_pair (a, b, factor): ref_noise from two other bakes a and b, x factor (e.g. bakes at a
    quarter of the samples: factor 1/2); default: from the first two of refs."""
    ref = {n: sum(r[n] for r in refs) / len(refs) for n in rs.objects}
    if noise_pair is None and len(refs) > 1:  # the noise of the seeds' mean
        noise_pair = (refs[0], refs[1], 1 / math.sqrt(len(refs)))
    objects = {}
    for n in rs.objects:
        m = C.metrics(res[n]["gather_refl"], ref[n])
        if m is None:  # no texel the Cycles bake wrote
            continue
        o = objects[n] = {k: m[k] for k in ("mre", "bias", "texels", "mean_ref", "mean_ours")}
        ml = C.metrics(res[n]["leaf_refl"], ref[n])
        o["leaf_bias"] = ml["bias"] if ml else float("nan")
        total = np.nanmean(res[n]["gather_refl"])
        for kind in ("SUN", "SKY"):
            d = res[n].get(f"direct_{kind}")
            o[f"share_{kind.lower()}"] = float(np.nanmean(d) / total) if d is not None and total > 0 else 0.0
        o["kind"] = (
            "sun" if o["share_sun"] >= DIRECT_SHARE else "sky" if o["share_sky"] >= DIRECT_SHARE else "bounce"
        )
        if noise_pair is not None:
            o["ref_noise"] = C.noise(noise_pair[0][n], noise_pair[1][n])[1] * noise_pair[2]
        if len(refs) > 1:  # the same from the first two seeds' texel differences: a bake's texels
            # are independent samples, so this has texels - 1 degrees of freedom, ref_noise one
            d = (refs[0][n] - refs[1][n]).mean(1)
            d = d[np.isfinite(d)]
            sd = np.std(d, ddof=1) / math.sqrt(2 * len(d) * len(refs)) if len(d) > 1 else np.nan
            o["ref_noise_texels"] = float(sd / max(np.mean(m["mean_ref"]), 1e-12))
        # one reference alone: the standard error of its mean from its texels' scatter about ours (an
        # upper bound of its noise: it holds our texel-to-texel error too)
        d = (ref[n] - res[n]["gather_refl"]).mean(1)
        d = d[np.isfinite(d)]
        sd = np.std(d, ddof=1) / math.sqrt(len(d)) if len(d) > 1 else np.nan
        o["scatter_noise"] = float(sd / max(np.mean(m["mean_ref"]), 1e-12))
    pooled = C.metrics(
        np.concatenate([res[n]["gather_refl"] for n in objects]), np.concatenate([ref[n] for n in objects])
    )
    lit = [n for n in objects if np.mean(objects[n]["mean_ref"]) > 0.05 * np.mean(pooled["mean_ref"])]
    groups = {
        "all": lit,
        "books": [n for n in lit if "_book" in n],
        "others": [n for n in lit if "_book" not in n],
        "sun-lit": [n for n in lit if objects[n]["kind"] == "sun"],
        "sky-lit": [n for n in lit if objects[n]["kind"] == "sky"],
        "bounce-lit": [n for n in lit if objects[n]["kind"] == "bounce"],
    }
    summary = {g: C.object_summary(objects, names) for g, names in groups.items() if names}
    summary["all"]["pooled_bias"] = pooled["bias"]
    return objects, lit, summary


def ceiling_hole(frac=0.3):
    """The Cornell ceiling with a square hole in its middle (frac of its width and depth): four
    quads framing it, facing the room as the ceiling did."""
    import bpy

    ob = bpy.data.objects["ceiling"]
    M = np.array(ob.matrix_world)
    v = np.array([M[:3, :3] @ np.array(p.co) + M[:3, 3] for p in ob.data.vertices])
    down = (M[:3, :3] @ np.array(ob.data.polygons[0].normal))[2] < 0
    (x0, y0), (x1, y1), z = v[:, :2].min(0), v[:, :2].max(0), float(v[:, 2].mean())
    cx, cy, hx, hy = (x0 + x1) / 2, (y0 + y1) / 2, frac * (x1 - x0) / 2, frac * (y1 - y0) / 2
    outer = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    inner = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)]
    verts = [(x, y, z) for x, y in outer + inner]
    faces = [[i, (i + 1) % 4, 4 + (i + 1) % 4, 4 + i] for i in range(4)]  # counter-clockwise from above
    if down:
        faces = [f[::-1] for f in faces]
    me = bpy.data.meshes.new("ceiling with hole")
    me.from_pydata(verts, [], faces)
    for m in ob.data.materials:
        me.materials.append(m)
    ob.data = me
    from mathutils import Matrix

    ob.matrix_world = Matrix.Identity(4)
    return (cx - hx, cx + hx, cy - hy, cy + hy)


def add_light(kind):
    """The Cornell emitter's place (its centre, 5 mm lower): a light of comparable power. WORLD: no
    light, a uniform sky through the box's open front."""
    import bpy

    for name in ("light", "Window", "Back Patch"):
        bpy.data.objects.remove(bpy.data.objects[name])
    if kind == "WORLD":
        return add_world()
    if kind == "WORLD_ENV":
        return add_world(image=environment_image())
    if kind == "SUN_HOLE":  # a sun from over the back wall: only the ceiling's hole lets it in
        ceiling_hole()
        ld = bpy.data.lights.new("Lamp", "SUN")
        ob = bpy.data.objects.new("Lamp", ld)
        ld.energy, ld.angle, ld.color = 20.0, 0.0, (1.0, 0.85, 0.6)
        ob.rotation_euler = (math.radians(-20), math.radians(10), 0)
        bpy.context.scene.collection.objects.link(ob)
        return ob
    ld = bpy.data.lights.new("Lamp", kind)
    ob = bpy.data.objects.new("Lamp", ld)
    ob.location = (0.278, 0.2795, 0.5438)
    ld.color = (1.0, 0.85, 0.6)
    if kind == "POINT":  # lower: 5 mm under the ceiling its hot spot makes Cycles' indirect noisy
        ld.energy, ld.shadow_soft_size = 20.0, 0.0
        ob.location = (0.278, 0.2795, 0.40)
    elif kind == "AREA":
        ld.shape, ld.size, ld.size_y, ld.energy = "RECTANGLE", 0.13, 0.105, 20.0
    elif kind == "SPOT":  # aimed at the back wall
        ld.energy, ld.shadow_soft_size = 60.0, 0.0
        ld.spot_size, ld.spot_blend = math.radians(50), 0.2
        ob.location = (0.278, 0.1, 0.45)
        ob.rotation_euler = (math.radians(70), 0, 0)  # -Z turned towards +Y (the back wall)
    elif kind == "SUN":
        ld.energy, ld.angle = 2.0, 0.0
        ob.rotation_euler = (math.radians(20), math.radians(15), 0)
    ob.visible_camera = False
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _cached_bake(rs, kind, spp, seed, cache_dir, passes=("DIRECT", "INDIRECT")):
    """C.bake's values, kept in cache_dir (None: not kept) under a key naming the light kind, the
    samples, the seed, the passes, the atlas and add_light's source (an edited light re-bakes)."""
    import hashlib
    import inspect
    import os

    if cache_dir is None:
        return C.bake(rs, spp, seed=seed, passes=passes)[0]
    m = hashlib.sha1(inspect.getsource(add_light).encode())
    for n in rs.objects:
        at = rs.atlases[n]
        m.update(f"{n}:{at.width}x{at.height}:{at.n}:{at.texel:.6g};".encode())
    path = os.path.join(cache_dir, f"{kind}_s{spp}_seed{seed}_{'+'.join(passes)}_{m.hexdigest()[:10]}.npz")
    if os.path.exists(path):
        z = np.load(path)
        return {n: z[n].astype(np.float64) for n in rs.objects}
    vals, dt, _ = C.bake(rs, spp, seed=seed, passes=passes)
    os.makedirs(cache_dir, exist_ok=True)
    np.savez(path, __cpu=dt["cpu"], **{n: v.astype(np.float32) for n, v in vals.items()})
    return vals


def _noise_of_mean(vals):
    """The noise of the seeds' mean of a surface mean (relative, averaged over RGB): the spread
    (ddof 1) of each seed's surface mean / sqrt(seeds); with two seeds C.noise's / sqrt 2."""
    if len(vals) < 2:
        return float("nan")
    ok = np.logical_and.reduce([np.isfinite(v).all(1) for v in vals])
    means = np.array([v[ok].mean(0) for v in vals])
    return float(np.mean(means.std(0, ddof=1) / np.maximum(means.mean(0), 1e-12)) / math.sqrt(len(vals)))


def solve(kind, texel_rel=1 / 56, quality="medium", gather=None):
    """The Cornell sample lit by add_light(kind) alone, prepared for Cycles (cycles_ref.prepare),
    our solution (FE at `quality`) and its final gather at the texel centres (gather: the
    FinalGather's settings, default two levels + 4 iterations). -> namespace of rs, lights,
    system, dyn, ours (cycles_ref.Ours), gather (the texel FinalGather), res, cost (gather_results'),
    setup_cpu_s (opening, preparing and reading the lights: CPU s before the solution)."""
    from types import SimpleNamespace

    bpy = load_bpy()
    from hr_addon.blender.lights_in import collect_lights
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.lights import Light
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    t0 = time.process_time()
    open_sample("cornell", tempfile.mkdtemp())
    add_light(kind)
    rs = C.prepare(bpy.context.scene, texel_rel=texel_rel)
    vl = bpy.context.view_layer
    lights = collect_lights(vl, vl.depsgraph, Light)
    t1 = time.process_time()
    system = RadiositySystem(rs.scene_in.mesh, RefineParams.preset(quality))
    dyn = DynamicRadiosity(system, method="FE")
    dyn.apply({}, lights)
    ours = C.Ours(rs, system, dyn)
    cache = {}
    res, cost = C.gather_results(
        rs, ours, dyn, vertex=False, cache=cache, **(gather or dict(levels=2, iterations=4))
    )
    return SimpleNamespace(
        rs=rs, lights=lights, system=system, dyn=dyn, ours=ours, gather=cache["texel"], res=res, cost=cost,
        setup_cpu_s=t1 - t0,
    )  # fmt: skip


def run(
    kind,
    spp=32,
    texel_rel=1 / 56,
    seeds=(1, 2),
    quality="medium",
    gather=None,
    indirect=False,
    cache_dir=None,
):
    """indirect: also the values mode "Indirect only (for EEVEE)" (core.lights.indirect_incident x
    rho) added to a Cycles bake of the direct light alone (the DIRECT pass, same seeds), against
    the full Cycles bake: "composite" per surface. cache_dir: Cycles' bakes kept there
    (_cached_bake). The reference is the seeds' mean; its noise of a surface mean: the spread of
    the seeds' means (two seeds: their difference)."""
    t0 = time.process_time()
    sv = solve(kind, texel_rel, quality, gather)
    rs, dyn, ours, g, cost, tg = sv.rs, sv.dyn, sv.ours, sv.res, sv.cost, sv.gather
    if indirect:
        from hr_addon.core.lights import indirect_incident

        ind = tg.outputs(tg.rho) * indirect_incident(tg, dyn)  # per texel (its sub-samples averaged)
        s0 = 0
        for n in rs.objects:  # the texel gather's samples: the objects' texel centres in order
            at = rs.atlases[n]
            cen = np.flatnonzero(at.s_centre)
            tex = np.full((at.n, 3), np.nan)
            tex[at.s_texel[cen]] = ind[s0 : s0 + len(cen)]
            g[n]["indirect_refl"] = tex
            s0 += len(cen)
    leaf = ours.evaluate({}, smooth=False)
    ours_s = time.process_time() - t0 - sv.setup_cpu_s
    refs = []
    t1 = time.perf_counter()
    for s in seeds:
        refs.append(_cached_bake(rs, kind, spp, s, cache_dir))
    direct = (
        [_cached_bake(rs, kind, spp, s, cache_dir, passes=("DIRECT",)) for s in seeds] if indirect else None
    )
    cyc_s = time.perf_counter() - t1
    out = {
        "kind": kind,
        "spp": spp,
        "seeds": list(seeds),
        "ours_cpu_s": round(ours_s, 1),
        # the texel gather's precompute (CPU s) and its samples: texels' and the second level's
        "gather_precompute_cpu_s": round(cost["texel_precompute_s"], 2),
        "gather_samples": [cost["texel_samples"], tg.second.n if tg.second is not None else 0],
        "cycles_wall_s": round(cyc_s, 1),
        "surfaces": {},
    }
    for n in rs.objects:
        ref = sum(r[n] for r in refs) / len(refs)
        m = C.metrics(g[n]["gather_refl"], ref)
        ml = C.metrics(leaf[n]["leaf_refl"], ref)
        nz = _noise_of_mean([r[n] for r in refs])
        out["surfaces"][n] = {
            "texels": m["texels"],
            "gather": round(m["bias"], 4),
            # per channel (a coloured sky: a channel's error must not hide in the others' mean)
            "gather_rgb": [round(a / max(b, 1e-12) - 1, 4) for a, b in zip(m["mean_ours"], m["mean_ref"])],
            "leaves": round(ml["bias"], 4),
            "ref_noise_of_mean": round(nz, 4),
        }
        if indirect:
            comp = sum(d[n] for d in direct) / len(direct) + g[n]["indirect_refl"]
            mc = C.metrics(comp, ref)
            out["surfaces"][n]["composite"] = round(mc["bias"], 4)
            out["surfaces"][n]["composite_rgb"] = [
                round(a / max(b, 1e-12) - 1, 4) for a, b in zip(mc["mean_ours"], mc["mean_ref"])
            ]
    return out
