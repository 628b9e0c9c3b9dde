"""Scene in: evaluated meshes -> core MeshInput, light-shape objects -> core LightShape rings.

Geometry is every visible, renderable mesh object (its collections not excluded or render-
disabled, hide_render off) that is neither excluded (Object.hr.exclude) nor a light shape, with
modifiers applied (depsgraph), in world space, plus the mesh instances of the depsgraph
(collection instances, geometry-nodes instances, particle instances: depsgraph.object_instances)
whose instancer takes part. Instances receive and cast light, but only real objects get output
(HR_Radiance or a lightmap): an instance shares its mesh data with the others, which can hold one
value per element; the bake says so. Each instanced mesh is read once and placed per instance.
Per polygon reflectance/emission come from the material slot (see materials.py). Polygons that
must be split are triangulated as Blender's loop_triangles are (what Cycles and EEVEE render).
"""

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import InputError, MeshInput, components, newell
from .materials import read_material, world_lights


class SceneError(InputError):
    """The scene cannot be baked (one-line reason)."""


def _walk_collections(view_layer):
    """Objects of the view layer whose collections render (not excluded, not hide_render)."""
    found = {}

    def walk(lc):
        col = lc.collection
        if lc.exclude or getattr(col, "hide_render", False):
            return
        for o in col.objects:
            found.setdefault(o.name, o)
        for c in lc.children:
            walk(c)

    walk(view_layer.layer_collection)
    return [found[k] for k in sorted(found)]


def geometry_objects(view_layer):
    return [
        o
        for o in _walk_collections(view_layer)
        if o.type == "MESH" and not o.hide_render and not o.hr.exclude and not o.hr.is_light_shape
    ]


def light_shape_objects(view_layer, include_hidden=False):
    return [
        o
        for o in _walk_collections(view_layer)
        if o.type == "MESH"
        and o.hr.is_light_shape
        and not o.hr.exclude
        and (include_hidden or not o.hide_render)
    ]


@dataclass
class EvalMesh:
    verts: np.ndarray  # (V, 3) world
    loop_start: np.ndarray
    loop_total: np.ndarray
    loop_verts: np.ndarray
    material_index: np.ndarray
    materials: list  # material per slot (evaluated), [None] if no slots
    flipped: bool  # negative-determinant transform
    tri_loops: np.ndarray = None  # (T, 3) Blender's loop_triangles (loop indices)


def mesh_topology(me):
    """Local vertex coordinates (V, 3) float32 and loop_start, loop_total, loop_verts (int64) of a Mesh."""
    V, P, L = len(me.vertices), len(me.polygons), len(me.loops)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    ls, lt, lv = np.empty(P, np.int32), np.empty(P, np.int32), np.empty(L, np.int32)
    me.polygons.foreach_get("loop_start", ls)
    me.polygons.foreach_get("loop_total", lt)
    me.loops.foreach_get("vertex_index", lv)
    return co.reshape(-1, 3), ls.astype(np.int64), lt.astype(np.int64), lv.astype(np.int64)


def _mesh_arrays(me):
    """Local coordinates, topology, material indices and loop triangles of a Mesh datablock."""
    co, ls, lt, lv = mesh_topology(me)
    mi = np.zeros(len(ls), np.int32)
    if len(ls):
        me.polygons.foreach_get("material_index", mi)
    me.calc_loop_triangles()
    tri = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("loops", tri)
    return co.astype(np.float64), ls, lt, lv, mi, tri.reshape(-1, 3).astype(np.int64)


def evaluated(obj, depsgraph, read=_mesh_arrays):
    """(evaluated object, read(its evaluated mesh)); the temporary mesh is freed again."""
    ob = obj.evaluated_get(depsgraph)
    me = ob.to_mesh()
    try:
        return ob, read(me)
    finally:
        ob.to_mesh_clear()


def _placed(arrays, matrix, mats):
    co, ls, lt, lv, mi, tri = arrays
    M = np.asarray(matrix, dtype=np.float64)
    verts = co @ M[:3, :3].T + M[:3, 3]
    return EvalMesh(
        verts, ls, lt, lv, np.clip(mi, 0, len(mats) - 1), mats, bool(np.linalg.det(M[:3, :3]) < 0), tri
    )


def read_mesh(obj, depsgraph) -> EvalMesh:
    """Evaluated mesh of `obj` in world space, vectorised with foreach_get."""
    ob, arrays = evaluated(obj, depsgraph)
    return _placed(arrays, ob.matrix_world, [s.material for s in ob.material_slots] or [None])


def _reversed_loops(loop_start, loop_total):
    """Permutation that reverses every polygon's loop order."""
    poly = np.repeat(np.arange(len(loop_start)), loop_total)
    k = np.arange(len(poly)) - loop_start[poly]
    return loop_start[poly] + loop_total[poly] - 1 - k


@dataclass
class Target:
    """Where one object's share of the solution goes: HR_Radiance on its (original) mesh."""

    name: str
    mesh_name: str
    loops: tuple  # (start, stop) of its loops in the MeshInput
    verts: tuple  # (start, stop) of its vertices in the MeshInput
    loop_perm: np.ndarray  # input loop j comes from evaluated loop loop_perm[j]
    eval_loop_verts: np.ndarray
    n_eval_verts: int
    n_corner: int  # output sizes on the original mesh
    n_point: int
    vert_map: np.ndarray = None  # original vertex -> evaluated vertex (topology changed)
    orig_loop_verts: np.ndarray = None

    def extract(self, values, domain):
        """(N, 3) values on the original mesh's domain from the full solution array."""
        if domain == "POINT":
            seg = values[self.verts[0] : self.verts[1]]
            return seg if self.vert_map is None else seg[self.vert_map]
        seg = np.empty((self.loops[1] - self.loops[0], 3), np.float32)
        seg[self.loop_perm] = values[self.loops[0] : self.loops[1]]
        if self.vert_map is None:
            return seg
        # Topology changed by modifiers: average per evaluated vertex, nearest vertex per corner.
        cnt = np.maximum(np.bincount(self.eval_loop_verts, minlength=self.n_eval_verts), 1)
        pv = np.stack([np.bincount(self.eval_loop_verts, seg[:, c], self.n_eval_verts) for c in range(3)], 1)
        pv = (pv / cnt[:, None]).astype(np.float32)
        return pv[self.vert_map][self.orig_loop_verts]


@dataclass
class SceneInput:
    mesh: MeshInput
    targets: list
    warnings: list = field(default_factory=list)
    instances: dict = field(default_factory=dict)  # {(instancer, source): InstanceInfo}


def _surfaces(materials, warnings, cache):
    rho, em = [], []
    for m in materials:
        key = None if m is None else m.name_full
        if key not in cache:
            s = read_material(m)
            cache[key] = s
            warnings.extend(w for w in s.warnings if w not in warnings)
        rho.append(cache[key].reflectance)
        em.append(cache[key].emission)
    return np.array(rho), np.array(em)


def _topology_map(obj, em: EvalMesh, depsgraph):
    """Nearest evaluated vertex for each original vertex (modifiers that change topology)."""
    from mathutils import kdtree

    me = obj.data
    V = len(me.vertices)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    M = np.array(obj.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
    world = co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
    tree = kdtree.KDTree(len(em.verts))
    for i, p in enumerate(em.verts):
        tree.insert(p, i)
    tree.balance()
    vmap = np.array([tree.find(p)[1] for p in world], np.int64)
    olv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", olv)
    return vmap, olv.astype(np.int64)


def _mesh_input(em: EvalMesh, name, warnings, mat_cache):
    """(MeshInput part, loop permutation) of an evaluated mesh in world space."""
    rho_t, em_t = _surfaces(em.materials, warnings, mat_cache)
    perm = _reversed_loops(em.loop_start, em.loop_total) if em.flipped else np.arange(len(em.loop_verts))
    tri = None
    if em.tri_loops is not None:
        # input loop j is evaluated loop perm[j] (perm is its own inverse); a mirrored object's
        # reversed polygons get reversed triangles
        tri = perm[em.tri_loops][:, ::-1] if em.flipped else em.tri_loops
    return MeshInput(
        em.verts,
        em.loop_start,
        em.loop_total,
        em.loop_verts[perm],
        rho_t[em.material_index],
        em_t[em.material_index],
        np.zeros(len(em.loop_start), np.int64),
        [name],
        None if tri is None else np.ascontiguousarray(tri),
    ), perm


@dataclass
class InstanceInfo:
    instancer: str  # the object that instances (collection-instance empty, emitter, ...)
    source: str  # the instanced object
    count: int = 0
    polygons: int = 0  # per instance


def collect_instances(view_layer, depsgraph, mat_cache, warnings):
    """MeshInput parts of the mesh instances of the depsgraph, and {(instancer, source): InstanceInfo}.

    An instance takes part when its instancer renders and is not excluded, and the instanced object
    is neither a light shape nor excluded. Each instanced mesh is read once (its evaluated data is
    shared by all its instances) and placed by each instance's world matrix."""
    ok = {
        o.name
        for o in _walk_collections(view_layer)
        if not o.hide_render and not o.hr.exclude and not o.hr.is_light_shape
    }
    shapes = {o.name for o in _walk_collections(view_layer) if o.hr.is_light_shape}
    meshes, parts, info = {}, [], {}
    for inst in depsgraph.object_instances:
        if not inst.is_instance:
            continue
        ob = inst.object
        if ob is None or ob.type != "MESH" or inst.parent is None:
            continue
        instancer = inst.parent.original
        if instancer.name not in ok:
            continue
        source = ob.original
        if source.hr.exclude or source.hr.is_light_shape or source.name in shapes:
            continue
        me = ob.data
        key = (me.as_pointer(), me.name)
        arrays = meshes.get(key)
        if arrays is None:
            arrays = meshes[key] = _mesh_arrays(me)
        if len(arrays[1]) == 0:
            continue
        em = _placed(arrays, inst.matrix_world, [s.material for s in ob.material_slots] or [None])
        label = f"{instancer.name}/{source.name}"
        i = info.setdefault((instancer.name, source.name), InstanceInfo(instancer.name, source.name))
        i.count += 1
        i.polygons = len(arrays[1])
        part, _ = _mesh_input(em, f"{label}#{i.count}", warnings, mat_cache)
        parts.append(part)
    return parts, info


def instances_warning(info):
    if not info:
        return None
    n = sum(i.count for i in info.values())
    what = ", ".join(f"{i.count} x '{i.source}' (by '{i.instancer}')" for i in list(info.values())[:4])
    more = ", ..." if len(info) > 4 else ""
    return (
        f"{n} instance(s) take part in the light (they receive and cast it) but get no baked output: "
        f"{what}{more}. Instances share their mesh data, which holds one value per element; "
        "make them real (Object > Apply > Make Instances Real) to bake their own light."
    )


def _hidden_instancer(obj):
    """An object that instances (particles shown as objects, vertex/face instancing) and whose own
    mesh does not render (Object > Instancing > Show Instancer: Render off)."""
    if obj.show_instancer_for_render:
        return False
    return obj.instance_type in {"VERTS", "FACES"} or any(
        p.settings.render_type in {"OBJECT", "COLLECTION"} for p in obj.particle_systems
    )


def collect_geometry(view_layer, depsgraph) -> SceneInput:
    objs = [o for o in geometry_objects(view_layer) if not _hidden_instancer(o)]
    depsgraph.update()
    warnings, mat_cache = [], {}
    inst_parts, inst_info = collect_instances(view_layer, depsgraph, mat_cache, warnings)
    if not objs and not inst_parts:
        raise SceneError("No mesh objects to compute radiosity on (all hidden, excluded or light shapes).")
    parts, targets = [], []
    seen_mesh = {}
    instancers = {i.instancer for i in inst_info.values()}
    nloop = nvert = 0
    for oid, obj in enumerate(objs):
        em = read_mesh(obj, depsgraph)
        if len(em.loop_start) == 0:
            if obj.name not in instancers:
                warnings.append(f"Object '{obj.name}' has no faces; skipped.")
            continue
        part, perm = _mesh_input(em, obj.name, warnings, mat_cache)
        parts.append(part)
        me = obj.data
        same_topology = (
            len(me.loops) == len(em.loop_verts)
            and len(me.vertices) == len(em.verts)
            and len(me.polygons) == len(em.loop_start)
        )
        if same_topology:
            olv = np.empty(len(me.loops), np.int32)
            me.loops.foreach_get("vertex_index", olv)
            same_topology = np.array_equal(olv, em.loop_verts)
        t = Target(
            obj.name,
            me.name,
            (nloop, nloop + len(em.loop_verts)),
            (nvert, nvert + len(em.verts)),
            perm,
            em.loop_verts,
            len(em.verts),
            len(me.loops),
            len(me.vertices),
        )
        if not same_topology:
            t.vert_map, t.orig_loop_verts = _topology_map(obj, em, depsgraph)
            warnings.append(
                f"Object '{obj.name}': modifiers change the topology; HR_Radiance is "
                "transferred to the original mesh by nearest vertex."
            )
        if me.name in seen_mesh:
            warnings.append(
                f"Objects '{seen_mesh[me.name]}' and '{obj.name}' share mesh data "
                f"'{me.name}'; HR_Radiance can hold only one of them (make them single user)."
            )
        else:
            seen_mesh[me.name] = obj.name
        targets.append(t)
        nloop += len(em.loop_verts)
        nvert += len(em.verts)
    parts += inst_parts  # after the targets' parts: their offsets stay valid
    w = instances_warning(inst_info)
    if w:
        warnings.append(w)
    if not parts:
        raise SceneError("No mesh objects with faces to compute radiosity on.")
    mesh = parts[0]
    for p in parts[1:]:
        mesh = mesh.concat(p)
    return SceneInput(mesh, targets, warnings, inst_info)


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


def collect_light_shapes(view_layer, depsgraph, LightShape, warnings=None, objects=None):
    """{stable id: LightShape} of the light shapes active in the current (evaluated) frame.

    objects: the light-shape objects of view_layer if the caller knows them (Live Relight between
    two edits of known shapes: walking every collection of a big scene costs more than reading the
    shapes); default: light_shape_objects(view_layer)."""
    shapes = {}
    mat_cache = {}
    warnings = [] if warnings is None else warnings
    for obj in light_shape_objects(view_layer) if objects is None else objects:
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
            )
        if flat:
            warnings.append(
                f"Light shape '{obj.name}' has no area on frame {depsgraph.scene.frame_current} "
                "(scaled to 0 or squashed to a line): off on that frame."
            )
    return shapes


def shapes_signature(shapes):
    """Hashable digest of a frame's light state (identical frames -> identical digest)."""
    import hashlib

    h = hashlib.sha1()
    for key in sorted(shapes):
        s = shapes[key]
        h.update(key.encode())
        h.update(np.asarray(s.emission, np.float64).tobytes())
        for r in s.rings:
            h.update(np.asarray(r, np.float64).tobytes())
            h.update(b"|")
    return h.hexdigest()


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
    (evaluated) frame: transform, colour, power/strength, radius, spot size and blend, sun angle,
    area shape and size, all as evaluated (keyframes and drivers followed). Lights with no power,
    hidden from render or not lighting diffuse surfaces are left out. `warnings` gets what a light
    has that the bake does not follow (light_features), once per light."""
    import math

    out = {}
    warnings = [] if warnings is None else warnings
    for obj in light_objects(view_layer) if objects is None else objects:
        ob = obj.evaluated_get(depsgraph)
        if ob.hide_render or not getattr(ob, "visible_diffuse", True):
            continue
        ld = ob.data
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
    return out


def lights_signature(lights):
    """Hashable digest of the lights' state (identical frames -> identical digest)."""
    import hashlib

    h = hashlib.sha1()
    for key in sorted(lights):
        L = lights[key]
        h.update(key.encode())
        h.update(repr(L.geom_key).encode())
        h.update(np.asarray(L.scale, np.float64).tobytes())
    return h.hexdigest()


def light_check(view_layer, scene, depsgraph, geometry_emits):
    """(error, warnings) about the scene's light before a bake. error ('' if none): nothing emits
    and no Blender light shines, so the bake would be black. warnings: the World the bake ignores,
    what Blender lights have that the bake does not follow (light_features), light shapes that
    cannot emit (light_shape_problem)."""
    lights = [o for o in light_objects(view_layer) if o.data.energy > 0 and max(o.data.color) > 0]
    world = world_lights(scene.world)
    warnings, shapes_emit = [], False
    for o in light_shape_objects(view_layer, include_hidden=True):
        emits, why = light_shape_problem(o, depsgraph)
        shapes_emit |= emits
        if why:
            warnings.append(f"Light shape '{o.name}': {why}.")
    for o in lights:
        for f in light_features(o):
            warnings.append(f"Light '{o.name}': {f} is not supported by the bake.")
    ignored = "The World's background lights the render but is ignored by the bake (not supported yet)"
    if not (geometry_emits or shapes_emit or lights):
        return (
            "Nothing in the scene emits light, so the bake would be black: no Blender light (with "
            "power > 0, rendered), no mesh with an emissive material (an Emission shader, or a "
            "Principled BSDF with Emission Strength > 0) and no light shape that emits."
            + (f" {ignored}." if world else "")
            + " Add a light, give a mesh an emissive material, or mark a flat emissive mesh as a "
            "light shape.",
            warnings,
        )
    if world:
        warnings.insert(0, ignored + ": only Blender lights, emissive materials and light shapes give light.")
    return "", warnings
