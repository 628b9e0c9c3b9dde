"""Light in: light-shape objects -> core LightShape rings, Blender lights and the World -> core
Light, and the checks of what lights the scene before a bake (nothing emits, unsupported light
features, World node setups not followed, shapes that cannot emit, emitters animated in ways the
bake does not follow).
"""

import hashlib

import numpy as np

from ..core.geometry import components, newell
from .materials import _Reader, image_reduced, read_material
from .scene_in import (
    EvalMesh,
    _surfaces,
    _walk_collections,
    geometry_objects,
    light_shape_objects,
    read_mesh,
)


# --- light shapes -------------------------------------------------------------------------------


def _drop_collinear(ring, tol=1e-9):
    while len(ring) > 3:
        a, b = np.roll(ring, 1, 0), np.roll(ring, -1, 0)
        cr = np.linalg.norm(np.cross(ring - a, b - ring), axis=1)
        scale = np.linalg.norm(ring - a, axis=1) * np.linalg.norm(b - ring, axis=1)
        bad = np.flatnonzero(cr <= tol * np.maximum(scale, 1e-300))
        if not len(bad):
            break
        ring = np.delete(ring, bad[0], 0)
    return ring


def _group_outline(verts, polys):
    """Boundary rings (outer first, then holes) of a connected set of coplanar polygons.

    polys: list of vertex-index lists with consistent winding. Returns None when the boundary is
    not a set of simple loops (the caller then passes the polygons one by one).
    """
    edges = {}
    for p in polys:
        for a, b in zip(p, p[1:] + p[:1]):
            if (a, b) in edges:
                return None  # inconsistent winding or duplicate face
            edges[(a, b)] = True
    nxt = {}
    for a, b in edges:
        if (b, a) not in edges:
            if a in nxt:
                return None  # two boundary loops touch at a vertex
            nxt[a] = b
    rings = []
    while nxt:
        start = next(iter(nxt))
        ring = [start]
        v = nxt.pop(start)
        while v != start:
            if v not in nxt:
                return None
            ring.append(v)
            v = nxt.pop(v)
        rings.append(verts[ring])
    normal = sum(newell(verts[p]) for p in polys)
    areas = [float(newell(r) @ normal) for r in rings]
    outer = [r for r, a in zip(rings, areas) if a > 0]
    holes = [r for r, a in zip(rings, areas) if a < 0]
    if len(outer) != 1:
        return None
    return [_drop_collinear(outer[0])] + [_drop_collinear(h) for h in holes]


def mesh_outlines(em: EvalMesh):
    """[(group_polys, rings, material_slot)] for an evaluated light-shape mesh.

    Polygons are grouped when they share an edge, lie in one plane and use one material; each
    group becomes one outline (outer ring + holes). Groups whose outline is not simple fall back
    to one ring per polygon.
    """
    P = len(em.loop_start)
    polys = [
        list(em.loop_verts[s : s + n][::-1] if em.flipped else em.loop_verts[s : s + n])
        for s, n in zip(em.loop_start, em.loop_total)
    ]
    nrm, off = np.zeros((P, 3)), np.zeros(P)
    for i, p in enumerate(polys):
        n = newell(em.verts[p])
        ln = np.linalg.norm(n)
        nrm[i] = n / ln if ln > 0 else 0
        off[i] = nrm[i] @ em.verts[p].mean(0)
    scale = float(np.abs(em.verts).max()) if len(em.verts) else 1.0
    pairs = []
    edge_owner = {}
    for i, p in enumerate(polys):
        for a, b in zip(p, p[1:] + p[:1]):
            j = edge_owner.get((b, a))
            if (
                j is not None
                and em.material_index[i] == em.material_index[j]
                and nrm[i] @ nrm[j] > 1 - 1e-9
                and abs(off[i] - off[j]) <= 1e-7 * max(scale, 1.0)
            ):
                pairs.append((i, j))
            edge_owner[(a, b)] = i
    i, j = np.array(pairs, np.int64).reshape(-1, 2).T
    label = components(P, i, j)
    order = np.argsort(label, kind="stable")  # groups by their first polygon
    groups = [g.tolist() for g in np.split(order, np.flatnonzero(np.diff(label[order])) + 1)] if P else []
    out = []
    for g in groups:
        rings = _group_outline(em.verts, [polys[i] for i in g]) if len(g) > 1 else None
        if rings is not None:
            out.append((g, rings, int(em.material_index[g[0]])))
        else:
            out += [([i], [_drop_collinear(em.verts[polys[i]])], int(em.material_index[i])) for i in g]
    return out


def collect_light_shapes(view_layer, depsgraph, LightShape, warnings=None, objects=None, moving=None):
    """{stable id: LightShape} of the light shapes active in the current (evaluated) frame.

    objects: the light-shape objects of view_layer if the caller knows them (Live Relight between
    two edits of known shapes: walking every collection of a big scene costs more than reading the
    shapes); default: light_shape_objects(view_layer).
    moving: the names of the shapes that move (moving_shapes, read once per bake or Live session
    by the caller); None: read from these objects now."""
    shapes = {}
    mat_cache = {}
    warnings = [] if warnings is None else warnings
    objects = light_shape_objects(view_layer) if objects is None else objects
    moving = moving_shapes(objects) if moving is None else moving
    for obj in objects:
        if obj.type != "MESH" or not obj.hr.is_light_shape or obj.hr.exclude or obj.hide_render:
            continue
        ob = obj.evaluated_get(depsgraph)
        if ob.hide_render:
            continue
        em = read_mesh(obj, depsgraph)
        if len(em.loop_start) == 0:
            continue
        _, em_t = _surfaces(em.materials, warnings, mat_cache)
        flat = False
        for g, rings, slot in mesh_outlines(em):
            e = em_t[slot]
            if not (e > 0).any():
                continue
            # points in one spot or on a line (keyed to scale 0, squashed): off, not an error; a
            # bowtie (no net area, but points spread in a plane) stays the shape check's error
            sv = np.linalg.svd(rings[0] - rings[0].mean(0), compute_uv=False)
            if sv[1] <= 1e-9 * max(sv[0], 1e-300):
                flat = True
                continue
            key = f"{obj.name}:{g[0]}"  # first polygon of the outline: stable while the mesh is
            shapes[key] = LightShape(
                rings=[np.ascontiguousarray(r, np.float64) for r in rings],
                emission=np.asarray(e, np.float64),
                name=obj.name,
                moves=obj.name in moving,
            )
        if flat:
            warnings.append(
                f"Light shape '{obj.name}' has no area on frame {depsgraph.scene.frame_current} "
                "(scaled to 0 or squashed to a line): off on that frame."
            )
    return shapes


OUTLINE_FRAMES = 48  # a moving shape's outline (a spot's cone) read at this many frames at most
CONE_LIGHTS = ("SPOT", "POINT", "AREA", "SUN")  # light_edges' Blender lights (session 36: a point light's
# shadow edge across a box, the loft's shelf items, went unseen while only spots' cones were read)
SUN_CONE = 2.0  # light_edges' cos for a sun (no cos is above 1): a direction, no position


def light_edges(scene, view_layer):
    """([rings], (K, 7) cones): where the light shapes' and Blender lights' light ends, over the
    scene's frames, for the vertex output's finer faces (own_values._cluttered): each light shape's
    outline ((M, 3) world rings: the outline, then its holes) and each Blender light's cone
    (position, direction, cos of its half angle: a spot's; a point light's every direction, cos -1;
    an area light's half space before it, cos 0; a sun's direction alone: position 0, its light's
    direction, cos SUN_CONE), whose shadows' edges near_clutter finds too (_cone_edges), at the
    current frame, a moving one's (moving_shapes; a light keyed or driven) at every frame of the
    scene's range instead (at most OUTLINE_FRAMES, evenly spread; not the bake's frames nor the
    current one: the corners are static, the same from the UI and the worker). Hidden ones and their
    emission or power are not looked at (shown or lit on another frame). The frame is restored."""
    shapes = light_shape_objects(view_layer, include_hidden=True)
    spots = [o for o in light_objects(view_layer, include_hidden=True) if o.data.type in CONE_LIGHTS]
    if not shapes and not spots:
        return [], np.zeros((0, 7))
    depsgraph = view_layer.depsgraph
    memo = {}
    moving = [o for o in shapes if _object_moves(o, memo)]
    moving += [o for o in spots if _object_moves(o, memo) or _animated(o.data)]  # (any light kind)
    rings, cones, seen = [], [], set()

    def read(objs):
        for obj in objs:
            if obj.type == "LIGHT":
                ob = obj.evaluated_get(depsgraph)
                M = np.array(ob.matrix_world, np.float64)
                d = -M[:3, 2] / max(float(np.linalg.norm(M[:3, 2])), 1e-300)
                kind = ob.data.type
                if kind == "SUN":
                    cones.append(np.r_[0.0, 0.0, 0.0, d, SUN_CONE])
                else:
                    cos = {"SPOT": np.cos(0.5 * float(getattr(ob.data, "spot_size", np.pi))), "AREA": 0.0}
                    cones.append(np.r_[M[:3, 3], d, cos.get(kind, -1.0)])
                continue
            for _, r, _ in mesh_outlines(read_mesh(obj, depsgraph)):
                key = b"".join(np.ascontiguousarray(x, np.float64).tobytes() for x in r)
                if key not in seen:
                    seen.add(key)
                    rings.append([np.asarray(x, np.float64) for x in r])

    read([o for o in shapes + spots if o not in moving])
    if moving:  # (only at these frames, whichever is the current one: the UI's and the worker's agree)
        now = scene.frame_current
        frames = np.unique(np.linspace(scene.frame_start, scene.frame_end, OUTLINE_FRAMES).round())
        for f in frames.astype(int).tolist():
            if f != scene.frame_current:
                scene.frame_set(f)
            read(moving)
        if scene.frame_current != now:
            scene.frame_set(now)
    cones = np.unique(np.array(cones).reshape(-1, 7), axis=0)
    return rings, cones


def _digest(state, parts):
    """sha1 over `state`'s keys in order, each followed by the bytes `parts(value)` gives."""
    h = hashlib.sha1()
    for key in sorted(state):
        h.update(key.encode())
        for b in parts(state[key]):
            h.update(b)
    return h.hexdigest()


def _f64(a):
    return np.asarray(a, np.float64).tobytes()


def shapes_signature(shapes):
    """Hashable digest of a frame's light state (identical frames -> identical digest); a moving
    shape's says so (its light is another estimator's: a kept frame of a bake before it moved is
    baked again; still shapes keep the digest they had)."""
    return _digest(
        shapes,
        lambda s: (
            [_f64(s.emission)]
            + [b for r in s.rings for b in (_f64(r), b"|")]
            + ([b"moves"] if getattr(s, "moves", False) else [])
        ),
    )


# --- which light shapes move --------------------------------------------------------------------
# Read from the scene (its animation data, constraints, modifiers), once per bake or Live session,
# never from the frames a bake holds: a frame's values do not depend on its bake's frame range. A
# moving shape's direct light comes from the visibility toward its wall (core LightShape.moves).
# Cheap and conservative: what may move counts as moving.

# an object's keyed or driven properties that leave its outline in place (on / off, viewport looks,
# the extension's own settings); any other counts as moving it
_STILL_PATHS = ("hide_render", "hide_viewport", "hide_select", "color", "pass_index", "hr.")
# modifiers whose result depends on their settings and the objects they name only (any other,
# geometry nodes among them, may change with time; a texture named makes any of them moving)
_STILL_MODIFIERS = frozenset(
    "ARMATURE ARRAY BEVEL BOOLEAN CAST CORRECTIVE_SMOOTH CURVE DATA_TRANSFER DECIMATE EDGE_SPLIT HOOK "
    "LAPLACIANDEFORM LAPLACIANSMOOTH LATTICE MASK MESH_DEFORM MIRROR MULTIRES NORMAL_EDIT REMESH SCREW "
    "SHRINKWRAP SIMPLE_DEFORM SKIN SMOOTH SOLIDIFY SUBSURF SURFACE_DEFORM TRIANGULATE UV_PROJECT UV_WARP "
    "VERTEX_WEIGHT_EDIT VERTEX_WEIGHT_MIX VERTEX_WEIGHT_PROXIMITY WEIGHTED_NORMAL WELD WIREFRAME".split()
)
# constraints that read time, an action, a clip or a cache: moving whatever they name
_TIME_CONSTRAINTS = frozenset(
    "ACTION ARMATURE CAMERA_SOLVER FOLLOW_PATH FOLLOW_TRACK OBJECT_SOLVER SPLINE_IK TRANSFORM_CACHE".split()
)


def moving_shapes(objects):
    """frozenset of the names of the light-shape objects whose world outline may change over the
    animation: keyframes or drivers on their transform or delta transform (any property but
    _STILL_PATHS), on a parent's up the chain, a constraint reading time or naming an object that
    moves, a rigid body, their mesh's or shape keys' animation, a modifier not in _STILL_MODIFIERS
    (geometry nodes) or naming an object that moves or changes shape. Strength, colour and
    visibility keyframes (materials, hide_render) do not move a shape."""
    memo = {}
    return frozenset(o.name for o in objects if _object_moves(o, memo))


def scene_moving_shapes(view_layer):
    """moving_shapes of every light shape of view_layer, hidden ones too (shown on another frame)."""
    return moving_shapes(light_shape_objects(view_layer, include_hidden=True))


def _fcurves(ad):
    """The F-curves of an ID's animation data: its drivers, its action's (its slot's where known)
    and its NLA strips' actions' (meta strips' too)."""
    if ad is None:
        return []
    out, acts = list(ad.drivers), [(ad.action, getattr(ad, "action_slot", None))]
    todo = [s for t in ad.nla_tracks for s in t.strips]
    while todo:
        s = todo.pop()
        todo += list(s.strips)
        acts.append((s.action, getattr(s, "action_slot", None)))
    for action, slot in acts:
        if action is None:
            continue
        if not hasattr(action, "layers"):  # (Blender before 4.4)
            out += list(action.fcurves)
            continue
        for layer in action.layers:
            for strip in layer.strips:
                bags = [strip.channelbag(slot)] if slot is not None else list(strip.channelbags)
                out += [fc for bag in bags if bag is not None for fc in bag.fcurves]
    return out


def _keyed(ad, still=()):
    """True if animation data keys or drives a property whose path does not start with `still`."""
    return any(not fc.data_path.startswith(still) for fc in _fcurves(ad))


def _named(block):
    """(objects, a texture is named) of a modifier or constraint: its Object pointers and the objects
    of its Collection ones."""
    objs, texture = [], False
    for p in block.bl_rna.properties:
        t = p.fixed_type.identifier if p.type == "POINTER" and p.fixed_type is not None else ""
        v = getattr(block, p.identifier, None) if t in ("Object", "Collection", "Texture") else None
        if v is not None:
            objs += [v] if t == "Object" else list(v.all_objects) if t == "Collection" else []
            texture |= t == "Texture"
    return objs, texture


def _memo(fn):
    """Memoised per (function, object) in the call's `memo`; an object met again on its own chain
    (a cycle) counts as moving."""

    def wrapped(ob, memo):
        key = (fn.__name__, ob.name_full)
        if key not in memo:
            memo[key] = True
            memo[key] = bool(fn(ob, memo))
        return memo[key]

    return wrapped


@_memo
def _placement_moves(ob, memo):
    """The object's world transform may change."""
    par = ob.parent
    return (
        _keyed(ob.animation_data, _STILL_PATHS)
        or ob.rigid_body is not None
        or (
            par is not None
            and (_placement_moves(par, memo) or ob.parent_type != "OBJECT" and _form_moves(par, memo))
        )
        or any(not c.mute and (c.type in _TIME_CONSTRAINTS or _names_moving(c, memo)) for c in ob.constraints)
    )


@_memo
def _form_moves(ob, memo):
    """The object's geometry in its own space may change (its data's or shape keys' animation, its
    modifiers)."""
    data = ob.data
    keys = getattr(data, "shape_keys", None)
    return (
        (data is not None and _keyed(getattr(data, "animation_data", None)))
        or (keys is not None and _keyed(keys.animation_data))
        or any(
            m.type not in _STILL_MODIFIERS or _names_moving(m, memo) for m in ob.modifiers if m.show_render
        )
    )


def _names_moving(block, memo):
    objs, texture = _named(block)
    return texture or any(_object_moves(o, memo) for o in objs)


def _object_moves(ob, memo):
    return _placement_moves(ob, memo) or _form_moves(ob, memo)


# --- what lights the scene ----------------------------------------------------------------------


def _animated(*blocks):
    """True if one of the ID blocks (None allowed) has keyframes or drivers."""
    return any(
        b is not None and b.animation_data and (b.animation_data.action or b.animation_data.drivers)
        for b in blocks
    )


def _emits(mat):
    """True if `mat` emits, or may on another frame (its emission is animated or driven)."""
    return mat is not None and bool((read_material(mat).emission > 0).any() or _animated(mat, mat.node_tree))


def _moves(obj):
    while obj is not None:
        if _animated(obj):
            return True
        obj = obj.parent
    return False


def frozen_emitters(view_layer, frame):
    """Warnings naming the emitting geometry (not light shapes) whose material or object is animated:
    ordinary geometry is read once, at the bake's start frame, so that animation is not followed."""
    out, emits = [], {}
    for o in geometry_objects(view_layer):
        mats = {s.material for s in o.material_slots} - {None}
        for m in mats - emits.keys():
            emits[m] = _emits(m)
        lit = [m for m in mats if emits[m]]
        what = [f"material '{m.name}'" for m in lit if _animated(m, m.node_tree)] + (
            ["it moves"] if lit and _moves(o) else []
        )
        if what:
            out.append(
                f"Object '{o.name}' emits light and is animated ({', '.join(what)}), but ordinary geometry "
                f"is read once, on frame {frame}: its light stays as on that frame. Make it a light shape "
                "(a flat emitter on a surface) to follow it."
            )
    return out


def _flat(em: EvalMesh):
    """True if every connected piece of a light-shape mesh lies in one plane and faces one way (a
    closed box or a bent strip does not: each of its faces becomes a shape of its own)."""
    P, V = len(em.loop_start), len(em.verts)
    if P < 2:
        return True
    # polygons joined through their vertices; a label is the piece's smallest polygon index
    label = components(P + V, np.repeat(np.arange(P), em.loop_total), P + em.loop_verts)
    n = np.array([newell(em.verts[em.loop_verts[s : s + k]]) for s, k in zip(em.loop_start, em.loop_total)])
    piece = np.zeros((P + V, 3))
    np.add.at(piece, label[:P], n)  # area-weighted: a closed box sums to 0
    ln = np.linalg.norm(piece, axis=1)
    piece /= np.maximum(ln, 1e-300)[:, None]
    unit = n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    faces_one_way = np.einsum("ij,ij->i", unit, piece[label[:P]]) > 1 - 1e-6
    degenerate = np.linalg.norm(n, axis=1) == 0
    used = np.zeros(V, bool)
    used[em.loop_verts] = True
    vl = label[P:][used]
    d = np.einsum("ij,ij->i", em.verts[used], piece[vl])
    lo, hi = np.full(P + V, np.inf), np.full(P + V, -np.inf)
    np.minimum.at(lo, vl, d)
    np.maximum.at(hi, vl, d)
    tol = 1e-5 * float(np.ptp(em.verts[used], axis=0).max()) + 1e-6 * float(np.abs(em.verts).max())
    return bool((faces_one_way | degenerate).all() and (hi[vl] - lo[vl] <= tol).all())


def light_shape_problem(obj, depsgraph):
    """(emits, why): whether the light shape `obj` emits (or may on another frame), and '' or why
    it cannot give its light as a light shape (no emission, or not flat)."""
    em = read_mesh(obj, depsgraph)
    used = np.unique(em.material_index) if len(em.loop_start) else []
    if not any(_emits(em.materials[int(i)]) for i in used):
        return False, (
            "its material does not emit (no Emission shader, or Emission Strength 0), so it adds "
            "no light; give it an emissive material"
        )
    if not _flat(em):
        return True, (
            "it is not flat (its faces do not lie in one plane, like a closed box); a light shape is "
            "a flat patch on a surface, so each face is taken as a shape of its own"
        )
    return True, ""


def materials_emit(depsgraph):
    """True if a mesh of the depsgraph (instances included) that is not a light shape has a material
    that emits: a quick, generous check before a background bake (the bake checks the polygons)."""
    seen = set()
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob is None or ob.type != "MESH" or ob.original.hr.is_light_shape:
            continue
        for m in {s.material for s in ob.material_slots} - seen:
            seen.add(m)
            if _emits(m):
                return True
    return False


def light_objects(view_layer, include_hidden=False):
    """Blender Light objects of the view layer that render (collections not excluded or hidden)
    and are not excluded from the bake (Object.hr.exclude, the panel's per-light switch);
    include_hidden: hidden for render too (they may be shown on another frame)."""
    return [
        o
        for o in _walk_collections(view_layer)
        if o.type == "LIGHT" and (include_hidden or not o.hide_render) and not o.hr.exclude
    ]


def light_features(obj, ld=None):
    """Names of what the bake does not follow of the light `obj` (its evaluated data `ld`): light
    nodes (IES profiles among them), light linking, blackbody temperature, an area light's spread,
    unnormalised power, shadows switched off, a square spot, a spot's non-uniform scale."""
    ld = ld or obj.data
    out = []
    if getattr(ld, "use_nodes", False):
        out.append("light nodes (IES profiles, textures: the node setup is ignored)")
    link = getattr(obj, "light_linking", None)
    if link is not None and (link.receiver_collection is not None or link.blocker_collection is not None):
        out.append("light linking (it lights every object)")
    if getattr(ld, "use_temperature", False):
        out.append("blackbody temperature (its Color is used)")
    if ld.type == "AREA" and float(getattr(ld, "spread", np.pi)) < np.pi - 1e-6:
        out.append("area spread below 180 degrees (lights as 180)")
    if not getattr(ld, "normalize", True):
        out.append("unnormalized power (taken as normalized)")
    if not getattr(ld, "use_shadow", True):
        out.append("shadows off (it casts shadows)")
    if ld.type == "SPOT" and getattr(ld, "use_square", False):
        out.append("a square spot (a round cone is used)")
    if ld.type == "SPOT":
        sc = np.asarray(obj.matrix_world.to_scale())
        if np.ptp(sc[:2]) > 1e-6 * max(float(np.abs(sc[:2]).max()), 1e-30):
            out.append("non-uniform scale of the spot's cone (a round cone is used)")
    return out


def collect_lights(view_layer, depsgraph, Light, warnings=None, objects=None):
    """{"light:" + name: core.lights.Light} of the Blender lights that render in the current
    (evaluated) frame, and the World's sky (world_sky, keys "world..."): transform, colour,
    power/strength, radius, spot size and blend, sun angle, area shape and size, all as evaluated
    (keyframes and drivers followed). Lights with no power, hidden from render or not lighting
    diffuse surfaces are left out. `warnings` gets what a light
    has that the bake does not follow (light_features), once per light."""
    import math

    out = {}
    warnings = [] if warnings is None else warnings
    for obj in light_objects(view_layer) if objects is None else objects:
        ob = obj.evaluated_get(depsgraph)
        if ob.hide_render or not getattr(ob, "visible_diffuse", True):
            continue
        ld = ob.data
        if ld.type == "AREA" and getattr(getattr(ld, "cycles", None), "is_portal", False):
            continue  # a Cycles portal emits nothing: it guides the sampling of the World
        factor = 2.0 ** float(getattr(ld, "exposure", 0.0)) * float(getattr(ld, "diffuse_factor", 1.0))
        strength = float(ld.energy) * factor
        if not strength > 0 or not max(ld.color) > 0:
            continue
        for f in light_features(ob, ld):
            warnings.append(f"Light '{obj.name}': {f} is not supported by the bake.")
        M = np.array(ob.matrix_world, np.float64)
        pos = M[:3, 3]
        z = M[:3, 2]
        direction = -z / max(float(np.linalg.norm(z)), 1e-300)
        kw = dict(
            color=np.array(ld.color[:3], np.float64),
            strength=strength,
            position=pos,
            direction=direction,
            name=obj.name,
        )
        if ld.type in ("POINT", "SPOT"):
            soft = bool(getattr(ld, "use_soft_falloff", True))
            kw.update(radius=float(ld.shadow_soft_size), soft_falloff=soft)
        if ld.type == "SPOT":
            kw.update(spot_size=float(ld.spot_size), spot_blend=float(ld.spot_blend))
        if ld.type == "SUN":
            kw.update(angle=float(ld.angle))
        if ld.type == "AREA":
            from ..core.lights import area_outline

            kw.update(outline=area_outline(ld.shape, ld.size, ld.size_y, M))
        try:
            out["light:" + obj.name] = Light(ld.type, **kw)
        except ValueError as exc:
            warnings.append(f"Light '{obj.name}': {exc}; left out.")
        if not all(math.isfinite(v) for v in (strength, *pos)):
            out.pop("light:" + obj.name, None)
            warnings.append(f"Light '{obj.name}': its position or power is not finite; left out.")
    out.update(world_sky(depsgraph.scene, Light, warnings))
    return out


# --- the World ----------------------------------------------------------------------------------

_table_cache = {}  # image key -> reduced table (H, W, 3): an HDR is read once, not per frame


def _environment_table(img):
    """(reduced lat-long table (core.sky.reduce_table), [its sun] or []) of an image, or None
    without pixels: a sun drawn into the image is split off as a sun (core.sky.split_sun)."""
    from ..core.sky import reduce_table, split_sun

    def reduce(px):
        rest, sun = split_sun(px)
        return reduce_table(rest), [sun] if sun is not None else []

    return image_reduced(img, reduce, _table_cache, 8)


def _output_shader(world, reader=None):
    """The shader node feeding the World's active output (None without one)."""
    tree = world.node_tree
    outs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"] if tree is not None else []
    out = next((n for n in outs if n.is_active_output), outs[0] if outs else None)
    return None if out is None else (reader or _Reader(world)).source(out.inputs["Surface"])[0]


def read_world(world):
    """(colour (3,), strength, table (H, W, 3) or None, suns, problems [str]) of the light a World
    gives a diffuse scene: a Background (or Emission) node into the active World Output, its Color
    unlinked (uniform), or fed by an equirectangular Environment Texture with its default vector
    (the image reduced to a small table, a sun drawn into it split off: suns [(unit direction
    toward it, irradiance (3,), angle)]). Anything else is its average colour (an image's mean,
    an RGB node, a mix of those; else the socket's own colour) and a problem naming it."""
    import bpy

    black = (np.zeros(3), 0.0, None, [], [])
    if world is None:
        return black
    tree = world.node_tree
    if tree is None or (bpy.app.version < (5, 0, 0) and not world.use_nodes):
        return np.array(world.color[:3], np.float64), 1.0, None, [], []
    r = _Reader(world)
    node = _output_shader(world, r)
    problems = []
    if node is None or node.mute:
        return black
    if node.type not in ("BACKGROUND", "EMISSION"):
        # a mix of shaders, a light-path trick: its first Background node stands for it
        bg = next((n for n in tree.nodes if n.type == "BACKGROUND" and not n.mute), None)
        problems.append(
            f"a '{node.bl_label}' node into the World Output is not followed"
            + ("; its first Background node is used" if bg else "; it gives no light")
        )
        if bg is None:
            return (*black[:4], problems)
        node = bg
    strength = r.value(node.inputs["Strength"])
    src, _ = r.source(node.inputs["Color"])
    colour, table, suns = None, None, []
    if src is not None and src.type == "TEX_ENVIRONMENT" and src.image is not None:
        table, suns = _environment_table(src.image) or (None, [])
        follow = src.projection == "EQUIRECTANGULAR" and not src.inputs["Vector"].is_linked
        if table is None:
            problems.append(f"the Environment Texture's image '{src.image.name}' has no pixels")
            colour = np.array(node.inputs["Color"].default_value[:3], np.float64)
        elif not follow:
            from ..core.sky import sphere_mean

            problems.append(
                f"the Environment Texture '{src.name}' ({src.projection.lower().replace('_', ' ')}"
                + (", its Vector input linked" if src.inputs["Vector"].is_linked else "")
                + ") is taken as its image's average colour"
            )
            colour = sphere_mean(table) + sum(irr for _, irr, _ in suns) / (4 * np.pi)
            table, suns = None, []
    else:
        colour = r.color(node.inputs["Color"])
    problems += [w.split(": ", 1)[-1] for w in r.warnings]  # the reader names the "Material"
    if table is not None:
        return np.ones(3), strength, table, suns, problems
    return colour, strength, None, [], problems


def world_sky(scene, Light, warnings=None):
    """{key: core.lights.Light} of kind SKY for the scene's World ({} when it gives no light or
    Scene.hr.use_world is off): "world" for a uniform sky or a table of one colour, "world:R",
    "world:G", "world:B" for a coloured table (core.sky.environment_parts). `warnings` gets one
    line naming the World and what of its node setup the bake does not follow."""
    from ..core.sky import environment_parts

    world = scene.world
    if world is None or not scene.hr.use_world:
        return {}
    colour, strength, table, suns, problems = read_world(world)
    if problems:  # a setup the reader cannot follow: rendered with Cycles instead (world_probe)
        colour, strength, table, suns, problems = _probed(world, colour, strength, problems)
    if not (strength > 0 and np.isfinite(strength)):
        return {}
    if problems and warnings is not None:
        what = "as rendered" if table is not None else "with a uniform sky of the colour it could read"
        warnings.append(f"World '{world.name}': {'; '.join(problems)} (the bake lights the scene {what}).")
    out = {}
    for i, (d, irr, angle) in enumerate(suns):  # a sun disc or an HDR's sun: exact shadow rays
        top = float(irr.max())
        out[f"world:sun{i}"] = Light(
            "SUN", irr / top, strength * top, direction=-d, angle=angle, name=f"{world.name} (sun)"
        )
    if table is None:
        if colour.max() > 0:
            out["world"] = Light("SKY", colour, strength, name=world.name)
        return out
    parts = environment_parts(table)
    keys = ["world"] if len(parts) == 1 else [f"world:{'RGB'[int(np.argmax(c))]}" for c, _ in parts]
    out.update({k: Light("SKY", c, strength, sky=t, name=world.name) for k, (c, t) in zip(keys, parts)})
    return out


def _probed(world, colour, strength, problems):
    """read_world's result for a World it could not follow, replaced by its Cycles render
    (world_probe): (colour, strength, table, suns, problems left). The output Background's own
    Strength stays a separate scale when nothing feeds it; else the render carries it."""
    from . import world_probe

    node = _output_shader(world)
    sock = node.inputs.get("Strength") if getattr(node, "type", "") in ("BACKGROUND", "EMISSION") else None
    if sock is not None and sock.is_linked:
        sock = None
    try:
        table, suns = world_probe.probe(world, sock)
    except (RuntimeError, OSError, AttributeError, KeyError, TypeError, ValueError) as exc:  # no crash
        return colour, strength, None, [], problems + [f"rendering it with Cycles failed ({exc})"]
    left = []
    if any(n.type == "LIGHT_PATH" for n in world.node_tree.nodes):
        left.append("a Light Path node: the World is rendered as the camera sees it")
    return np.ones(3), strength if sock is not None else 1.0, table, suns, left


def world_lights(world):
    """True if `world` lights a render: its background, as read_world reads it, is not black."""
    if world is None:
        return False
    colour, strength, table, *_ = read_world(world)
    return bool(strength > 0 and np.isfinite(strength) and (table is not None or colour.max() > 0))


def world_takes_part(scene):
    """True when the scene's World lights the bake (Lights > World on, a background not black)."""
    return scene.world is not None and scene.hr.use_world and world_lights(scene.world)


def world_summary(scene):
    """One line for the panel: what the World gives the bake."""
    world = scene.world
    if world is None:
        return "World: none"
    colour, strength, table, suns, problems = read_world(world)
    if table is not None:
        what = f"environment {table.shape[1]} x {table.shape[0]}" + (" and its sun" if suns else "")
    else:
        what = "uniform ({:.3g}, {:.3g}, {:.3g})".format(*colour)
    if problems:  # world_sky renders it with Cycles for the bake; the panel does not
        return f"World '{world.name}': a node setup rendered with Cycles for the bake"
    return f"World '{world.name}': {what} x {strength:g}"


def lights_signature(lights):
    """Hashable digest of the lights' state (identical frames -> identical digest)."""
    return _digest(lights, lambda L: [repr(L.geom_key).encode(), _f64(L.scale)])


def light_check(view_layer, scene, depsgraph, geometry_emits):
    """(error, warnings) about the scene's light before a bake. error ('' if none): nothing emits,
    no Blender light shines and the World gives no light, so the bake would be black. warnings:
    what Blender lights have that the bake does not follow (light_features), light shapes that
    cannot emit (light_shape_problem); the World's own warnings come with collect_lights."""
    lights = [o for o in light_objects(view_layer) if o.data.energy > 0 and max(o.data.color) > 0]
    world = world_lights(scene.world)
    sky = world_takes_part(scene)
    warnings, shapes_emit = [], False
    for o in light_shape_objects(view_layer, include_hidden=True):
        emits, why = light_shape_problem(o, depsgraph)
        shapes_emit |= emits
        if why:
            warnings.append(f"Light shape '{o.name}': {why}.")
    for o in lights:
        for f in light_features(o):
            warnings.append(f"Light '{o.name}': {f} is not supported by the bake.")
    off = "The World's background lights the render, but the bake leaves it out (Lights > World is off)"
    if not (geometry_emits or shapes_emit or lights or sky):
        return (
            "Nothing in the scene emits light, so the bake would be black: no Blender light (with "
            "power > 0, rendered), no mesh with an emissive material (an Emission shader, or a "
            "Principled BSDF with Emission Strength > 0), no light shape that emits and no World "
            "background." + (f" {off}." if world else "") + " Add a light, give a mesh an emissive "
            "material, mark a flat emissive mesh as a light shape, or give the World a colour.",
            warnings,
        )
    if world and not sky:
        warnings.insert(0, off + ".")
    return "", warnings
