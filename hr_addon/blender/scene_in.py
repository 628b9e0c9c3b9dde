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

import hashlib
from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import InputError, MeshInput
from .materials import read_material
from .names import FACE, TAG
from .own_values import mesh_topology, values_object


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


def out_of_depsgraph(objects, view_layer):
    """Take the bake's geometry `objects` out of view_layer's depsgraph (Object.hide_viewport on)
    once it has read them, the depsgraph updated: their evaluated copies (and their helpers' and
    modifiers' results) are freed while the build, the gather and the frames run, which read no
    geometry from Blender (the frames read light shapes and lights, other objects). Not objects
    with children (a light parented to a table moves with it) nor those Blender will not let
    change (linked). Returns the objects to give back_in_depsgraph. The 100k room: Blender's heap
    0.66 -> 0.29 GB (session 34, branch mem2; docs/scale.md)."""
    hidden, parents = [], {c.parent.name_full for c in view_layer.objects if c.parent is not None}
    for o in objects:
        if o.hide_viewport or o.name_full in parents or not o.is_editable:
            continue
        try:
            o.hide_viewport = True
        except (AttributeError, TypeError, RuntimeError):  # (an override that does not allow it)
            continue
        hidden.append(o)
    if hidden:
        view_layer.update()
    return hidden


def back_in_depsgraph(hidden):
    """Undo out_of_depsgraph (the depsgraph evaluates them again at its next update)."""
    for o in hidden:
        try:
            o.hide_viewport = False
        except ReferenceError:  # (removed meanwhile: nothing to give back)
            pass


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


def _face_attribute(me):
    """(P,) the FACE attribute Vertex Spacing's group stores (own_values: the index of the user's
    face each polygon of the evaluated mesh came from), or None."""
    a = me.attributes.get(FACE)
    if a is None or a.domain != "FACE" or a.data_type != "INT" or not len(me.polygons):
        return None
    face = np.empty(len(me.polygons), np.int32)
    a.data.foreach_get("value", face)
    return face.astype(np.int64)


def _flat_faces(me):
    """(P,) bool: the evaluated mesh's polygons shaded flat (sharp_face), or None (none is): their
    corners' light is their own (MeshInput.flat)."""
    a = me.attributes.get("sharp_face")
    if a is None or a.domain != "FACE" or a.data_type != "BOOLEAN" or not len(me.polygons):
        return None
    flat = np.empty(len(me.polygons), bool)
    a.data.foreach_get("value", flat)
    return flat if flat.any() else None


def _user_faces(me, face=False):
    """(P,) the first polygon of the user's face each polygon of an evaluated mesh came from (the
    FACE attribute Vertex Spacing's group stores, own_values), or None (each polygon its own).
    face: (that, the FACE attribute itself)."""
    raw = _face_attribute(me)
    first = None
    if raw is not None:
        _, first, inverse = np.unique(raw, return_index=True, return_inverse=True)
        first = first[inverse].astype(np.int64)
    return (first, raw) if face else first


def _centres(arrays):
    co, ls, lt, lv = arrays[:4]
    poly = np.repeat(np.arange(len(ls)), lt)
    return np.stack([np.bincount(poly, co[lv, c], len(ls)) for c in range(3)], 1) / lt[:, None]


def _onto_user_faces(face, user_face, fine=None, coarse=None):
    """(P,) the polygon of the mesh before the subdivision (whose FACE is user_face) each finer
    polygon (FACE face) lies on, or None if they do not match. Where several polygons there have
    its FACE (a transport subdivided itself, own_values.TRANSPORT_FACTOR): the one whose centre is
    nearest its centre (fine, coarse: the two meshes' arrays; the linear levels nest)."""
    if face is None or user_face is None or not len(user_face) or user_face.min() < 0:
        return None
    if len(np.unique(user_face)) < len(user_face):
        from ..core.output import equal_key_pairs

        i, j = equal_key_pairs(face, user_face)
        d = ((_centres(fine)[i] - _centres(coarse)[j]) ** 2).sum(1)
        o = np.lexsort((d, i))
        o = o[np.r_[True, i[o][1:] != i[o][:-1]]]
        out = np.full(len(face), -1, np.int64)
        out[i[o]] = j[o]
        return None if (out < 0).any() else out
    at = np.full(int(max(user_face.max(), face.max(initial=0))) + 1, -1, np.int64)
    at[user_face] = np.arange(len(user_face))
    out = at[np.clip(face, 0, len(at) - 1)]
    return None if (face < 0).any() or (out < 0).any() else out


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
    loop_map: np.ndarray = None  # original corner -> evaluated corner (topology changed)
    values_name: str = None  # own_values' helper object that holds the values (evaluated elements)

    @property
    def key(self):
        """The object whose mesh the vertex output writes: the helper, or the object itself."""
        return self.values_name or self.name

    def extract(self, values, domain):
        """(N, 3) values on the original mesh's domain from the full solution array."""
        if domain == "POINT":
            seg = values[self.verts[0] : self.verts[1]]
            return seg if self.vert_map is None else seg[self.vert_map]
        seg = np.empty((self.loops[1] - self.loops[0], 3), np.float32)
        seg[self.loop_perm] = values[self.loops[0] : self.loops[1]]
        if self.vert_map is None:
            return seg
        if self.loop_map is not None:  # topology changed by modifiers: the matching evaluated corner
            return seg[self.loop_map]
        # POINT: average per evaluated vertex, nearest vertex per original vertex.
        cnt = np.maximum(np.bincount(self.eval_loop_verts, minlength=self.n_eval_verts), 1)
        pv = np.stack([np.bincount(self.eval_loop_verts, seg[:, c], self.n_eval_verts) for c in range(3)], 1)
        pv = (pv / cnt[:, None]).astype(np.float32)
        return pv[self.vert_map][self.orig_loop_verts]


class Rows(dict):
    """{object name: (N, 4) float32 RGBA} of FlatExtract.rgba: row slices of `buffer` (the
    targets that take Target.extract: arrays of their own), laid out by `extract`."""

    buffer = None
    extract = None

    def unchanged(self, other):
        """The names whose rows hold the same bits in other (a Rows of the same FlatExtract), else
        None. Writing them again would not change HR_Radiance (Live's write skips them)."""
        fx = self.extract
        if fx is None or getattr(other, "extract", None) is not fx or other.buffer.shape != self.buffer.shape:
            return None
        if not len(fx.span_keys):
            return set()
        # a row's 4 floats as 2 uint64 (one pass, no .any(1): 1.0 against 5.4 ms at 100k)
        diff = self.buffer.reshape(-1).view(np.uint64) != other.buffer.reshape(-1).view(np.uint64)
        changed = np.logical_or.reduceat(diff, 2 * fx.span_starts)
        keys = fx.span_keys
        return {keys[i] for i in np.flatnonzero(~changed)}

    def change(self, other):
        """Per object of extract.span_keys: the largest change of an RGB value of its rows against
        other (a Rows of the same FlatExtract), relative to its level (its largest value in either,
        at least 1% of the median object's: a near-black object's noise is not a change)."""
        fx = self.extract

        def rgb_max(x):  # per row (whole-buffer ops and three columns: 4x faster than [:, :3].max(1))
            return np.maximum(np.maximum(x[:, 0], x[:, 1]), x[:, 2])

        a, b = self.buffer, other.buffer
        d = np.maximum.reduceat(rgb_max(np.abs(a - b)), fx.span_starts)
        level = np.maximum.reduceat(rgb_max(np.maximum(np.abs(a), np.abs(b))), fx.span_starts)
        floor = max(1e-2 * float(np.median(level)), np.finfo(np.float32).tiny)
        return d / np.maximum(level, floor)

    def merged(self, other, take):
        """A Rows holding self's rows for the span objects where take (a bool per span_keys) is True,
        other's elsewhere; the objects without rows of their own (Target.extract) take self's."""
        fx = self.extract
        counts = np.diff(np.append(fx.span_starts, len(self.buffer)))
        res = Rows()
        res.extract = fx
        res.buffer = np.where(np.repeat(take, counts)[:, None], self.buffer, other.buffer)
        spans = dict(zip(fx.span_keys, zip(fx.span_starts, fx.span_starts + counts)))
        for k, v in self.items():
            r = spans.get(k)
            res[k] = v if r is None else res.buffer[r[0] : r[1]]
        return res


class FlatExtract:
    """Every target's values at once: rgba(values) gives {object name: (N, 4) float32 RGBA} as
    row slices of one array (one gather instead of Target.extract and an RGBA copy per object:
    3,882 of them in the furnished room), the same values; the arrays go to foreach_set as they
    are. Targets whose modifiers change the topology take Target.extract."""

    def __init__(self, targets, domain):
        self.domain, self.targets, self.rows, idx, n = domain, list(targets), [], [], 0
        for t in self.targets:
            if t.vert_map is not None:
                self.rows.append(None)
                continue
            if domain == "POINT":
                src = np.arange(*t.verts)
            else:  # Target.extract's seg[loop_perm] = values[loops]
                src = np.empty(t.loops[1] - t.loops[0], np.int64)
                src[t.loop_perm] = np.arange(*t.loops)
            idx.append(src)
            self.rows.append((n, n + len(src)))
            n += len(src)
        self.index = np.concatenate(idx) if idx else np.zeros(0, np.int64)
        # the targets with rows of their own (at least one: reduceat's spans), for Rows.unchanged
        spans = [(t.key, r) for t, r in zip(self.targets, self.rows) if r is not None and r[1] > r[0]]
        self.span_keys = [k for k, _ in spans]
        self.span_starts = np.array([r[0] for _, r in spans], np.int64)

    @property
    def flat(self):
        """Every target's values are rows of the one array (no Target.extract)."""
        return all(r is not None for r in self.rows)

    def rgba(self, values, fill=None):
        """fill(index, out): writes values[index] into out ((R, 3) float32, a view) itself (the
        gather's loop_radiance(rows=, out=): no array of every loop); for flat extracts."""
        out = np.empty((len(self.index), 4), np.float32)
        if fill is not None:
            fill(self.index, out[:, :3])
        else:
            out[:, :3] = values[self.index]
        out[:, 3] = 1.0
        res = Rows()
        res.buffer, res.extract = out, self
        for t, r in zip(self.targets, self.rows):
            if r is None:
                v = t.extract(values, self.domain)
                res[t.key] = np.concatenate([v, np.ones((len(v), 1), np.float32)], 1, dtype=np.float32)
            else:
                res[t.key] = out[r[0] : r[1]]
        return res

    def __call__(self, values):
        """{object name: (N, 3)} as Target.extract gives them (views of rgba's arrays)."""
        return {k: v[:, :3] for k, v in self.rgba(values).items()}


@dataclass
class SceneInput:
    mesh: MeshInput
    targets: list
    warnings: list = field(default_factory=list)
    instances: dict = field(default_factory=dict)  # {(instancer, source): InstanceInfo}
    # {object name (or 'instancer/source'): digest} read in the same walk: the bake's manifest,
    # against which signatures.geometry_signatures tells that the scene changed since the bake
    signatures: dict = field(default_factory=dict)
    # Vertex Spacing with the final gather (collect_geometry(transport=True)): the mesh the
    # hierarchy is built on (the subdivided objects' meshes before their subdivision, the others as
    # in `mesh`) and, per polygon of `mesh` (the output's), its polygon there; None: `mesh` is both
    transport: MeshInput = None
    transport_poly: np.ndarray = None


def _material(m, cache, warnings=None):
    """read_material(m), once per material (cache: name -> MaterialSettings); its warnings are
    added to `warnings` when read."""
    key = None if m is None else m.name_full
    if key not in cache:
        cache[key] = read_material(m)
        if warnings is not None:
            warnings.extend(w for w in cache[key].warnings if w not in warnings)
    return cache[key]


def _surfaces(materials, warnings, cache):
    s = [_material(m, cache, warnings) for m in materials]
    return np.array([x.reflectance for x in s]), np.array([x.emission for x in s])


def _topology_map(obj, em: EvalMesh, depsgraph, near=8):
    """Original -> evaluated elements of an object whose modifiers change the topology: the nearest
    evaluated vertex of each original vertex, and per original corner the evaluated corner among
    those of the `near` nearest evaluated vertices whose face faces most like the corner's face
    (then the nearest). A bevelled box's corner vertex is shared by a lit top and dim sides: the
    vertex average gave every corner their mean (a chair seat -18%, a sofa +19% against Cycles);
    the corner of the face turned the same way keeps each face's own light."""
    from mathutils import kdtree

    from ..core.geometry import loop_tables, polygon_newell

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
    cand = [[i for _, i, _ in tree.find_n(p, near)] for p in world]
    vmap = np.array([c[0] for c in cand], np.int64)
    _, ls, lt, olv = mesh_topology(me)

    def unit_normals(verts, s, t, lv):
        n = polygon_newell(verts, s, t, lv)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    n_orig = unit_normals(world, ls, lt, olv)[loop_tables(ls, lt)[0]]
    n_eval = unit_normals(em.verts, em.loop_start, em.loop_total, em.loop_verts)[
        loop_tables(em.loop_start, em.loop_total)[0]
    ]
    by_vert = np.argsort(em.loop_verts, kind="stable")  # evaluated corners grouped by vertex
    first = np.searchsorted(em.loop_verts[by_vert], np.arange(len(em.verts) + 1))
    lmap = np.empty(len(olv), np.int64)
    for j, v in enumerate(olv):
        loops = np.concatenate([by_vert[first[c] : first[c + 1]] for c in cand[v]])
        if len(loops) == 0:
            lmap[j] = -1
            continue
        facing = n_eval[loops] @ n_orig[j]
        d = np.linalg.norm(em.verts[em.loop_verts[loops]] - world[v], axis=1)
        ok = facing >= facing.max() - 0.05
        lmap[j] = loops[ok][np.argmin(d[ok])]
    return vmap, olv, None if (lmap < 0).any() else lmap


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


def _source_material(m):
    """The material a texture-preview helper copy stands for (the bake reads that one)."""
    if m is None:
        return None
    orig = getattr(m, "original", m)
    if orig.get(TAG) is None:
        return orig
    if orig.get("hr_lightmap_link", "DATA") == "OBJECT":
        return orig.get("hr_lightmap_source")
    return "DATA"


def _materials(ob):
    """Materials of an (evaluated) object's slots as the bake reads them."""
    out = []
    for i, slot in enumerate(ob.material_slots):
        m = _source_material(slot.material)
        if m == "DATA":  # helper on an object-level slot whose original link was the mesh's
            me = ob.original.data
            m = me.materials[i] if i < len(me.materials) else None
        out.append(m)
    return out or [None]


def _material_values(mats, cache):
    h = hashlib.sha1()
    for m in mats:
        s = _material(m, cache)
        h.update(
            np.asarray(s.reflectance, np.float64).tobytes() + np.asarray(s.emission, np.float64).tobytes()
        )
    return h.digest()


def _mesh_digest(arrays):
    co, ls, lt, lv, mi, _ = arrays
    h = hashlib.sha1()
    for a, t in ((ls, np.int64), (lt, np.int64), (lv, np.int64), (mi, np.int64)):
        h.update(np.ascontiguousarray(a, t).tobytes())
    return co, h.digest()


def _placed_digest(co, topo, matrix, matvals):
    M = np.asarray(matrix, np.float64)
    world = (co @ M[:3, :3].T + M[:3, 3]).astype(np.float32)
    h = hashlib.sha1(np.ascontiguousarray(world).tobytes())
    h.update(topo)
    h.update(matvals)
    return h


def _object_digest(ob, arrays, cache):
    """An evaluated object's world-space geometry and material values, as the bake reads them."""
    co, topo = _mesh_digest(arrays)
    return _placed_digest(co, topo, ob.matrix_world, _material_values(_materials(ob), cache))


def _instance_digest(di, mesh_digest, cache):
    co, topo = mesh_digest
    return _placed_digest(co, topo, di.matrix_world, _material_values(_materials(di.object), cache)).digest()


def _joined(instance_digests):
    """{instancer/source: one digest of all its instances (in any order)}"""
    return {k: hashlib.sha1(b"".join(sorted(d))).hexdigest() for k, d in instance_digests.items()}


@dataclass
class InstanceInfo:
    instancer: str  # the object that instances (collection-instance empty, emitter, ...)
    source: str  # the instanced object
    count: int = 0
    polygons: int = 0  # per instance
    kind: str = "MESH"  # the source's type: a text or curve object evaluates to a mesh of its own

    @property
    def converted(self):
        """A text, curve or surface object (not an instance of another object): it renders as a mesh
        but has no mesh data to hold HR_Radiance or a lightmap UV layer."""
        return self.instancer == self.source and self.kind != "MESH"


def participating_instances(view_layer, depsgraph):
    """(depsgraph instance, 'instancer/source') of the mesh instances that take part: the instancer
    renders and is not excluded, the instanced object is neither a light shape nor excluded."""
    ok = {
        o.name
        for o in _walk_collections(view_layer)
        if not o.hide_render and not o.hr.exclude and not o.hr.is_light_shape
    }
    shapes = {o.name for o in _walk_collections(view_layer) if o.hr.is_light_shape}
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
        yield inst, f"{instancer.name}/{source.name}"


def collect_instances(view_layer, depsgraph, mat_cache, warnings, digests=None, digest_cache=None):
    """MeshInput parts of the mesh instances of the depsgraph, and {(instancer, source): InstanceInfo}.

    Each instanced mesh is read once (its evaluated data is shared by all its instances) and placed
    by each instance's world matrix. digests: {'instancer/source': [digest per instance]} to fill
    (the bake's signatures, signatures.py)."""
    meshes, parts, info = {}, [], {}
    for inst, label in participating_instances(view_layer, depsgraph):
        ob = inst.object
        me = ob.data
        key = (me.as_pointer(), me.name)
        if key not in meshes:
            meshes[key] = _mesh_arrays(me), _user_faces(me), _flat_faces(me)
        arrays, faces, flat = meshes[key]
        if len(arrays[1]) == 0:
            continue
        if digests is not None:
            digests.setdefault(label, []).append(_instance_digest(inst, _mesh_digest(arrays), digest_cache))
        em = _placed(arrays, inst.matrix_world, [s.material for s in ob.material_slots] or [None])
        instancer, source = label.split("/", 1)
        i = info.setdefault((instancer, source), InstanceInfo(instancer, source, kind=ob.original.type))
        i.count += 1
        i.polygons = len(arrays[1])
        part, _ = _mesh_input(em, f"{label}#{i.count}", warnings, mat_cache)
        part.face_group, part.flat = faces, flat
        parts.append(part)
    return parts, info


_KIND = {"FONT": "text", "CURVE": "curve", "SURFACE": "surface", "META": "metaball", "CURVES": "hair curves"}


def instances_warning(info):
    """One warning for the instances, one for the text and curve objects: both take part in the
    light without output of their own, but only instances are made real (Make Instances Real does
    nothing to a text object; Convert to Mesh does)."""
    inst = [i for i in info.values() if not i.converted]
    conv = [i for i in info.values() if i.converted]
    out = []
    if inst:
        n = sum(i.count for i in inst)
        what = ", ".join(f"{i.count} x '{i.source}' (by '{i.instancer}')" for i in inst[:4])
        more = ", ..." if len(inst) > 4 else ""
        out.append(
            f"{n} instance(s) take part in the light (they receive and cast it) but get no baked output: "
            f"{what}{more}. Instances share their mesh data, which holds one value per element; "
            "make them real (Object > Apply > Make Instances Real) to bake their own light."
        )
    if conv:
        what = ", ".join(f"'{i.source}' (a {_KIND.get(i.kind, i.kind.lower())} object)" for i in conv[:4])
        more = ", ..." if len(conv) > 4 else ""
        out.append(
            f"{what}{more}: take part in the light (they receive and cast it) but get no baked output, "
            "only mesh objects hold HR_Radiance or a lightmap; convert them to meshes "
            "(Object > Convert > Mesh) to bake their own light."
        )
    return out


def _hidden_instancer(obj):
    """An object that instances (particles shown as objects, vertex/face instancing) and whose own
    mesh does not render (Object > Instancing > Show Instancer: Render off)."""
    if obj.show_instancer_for_render:
        return False
    return obj.instance_type in {"VERTS", "FACES"} or any(
        p.settings.render_type in {"OBJECT", "COLLECTION"} for p in obj.particle_systems
    )


def collect_geometry(view_layer, depsgraph, vertex_output=True, transport=False) -> SceneInput:
    """The scene's geometry and output targets. vertex_output False (a texture bake): no warnings
    about HR_Radiance on meshes (modifiers that change the topology, shared meshes). transport
    (vertex output with the final gather): the objects whose HR Radiance modifier subdivides
    (Vertex Spacing) are read before the subdivision too, for the hierarchy (SceneInput.transport)."""
    from .steps import finish

    return finish(collect_geometry_steps(view_layer, depsgraph, vertex_output, transport))


def collect_geometry_steps(view_layer, depsgraph, vertex_output=True, transport=False):
    """collect_geometry an object at a time: a generator (steps.py) yielding after the depsgraph's
    update, the instances and each object; its return value is the SceneInput (Live Relight's start
    spreads it over timer ticks: 1.9-3.2 s CPU at 100k in one call). The caller must not let the
    scene change between the steps (Live reads again from the start after an edit)."""
    objs = [o for o in geometry_objects(view_layer) if not _hidden_instancer(o)]
    depsgraph.update()
    yield
    coarse = {}
    if transport:
        from .own_values import before_subdivision

        coarse = before_subdivision(objs, depsgraph, _mesh_arrays)
        yield
    tparts, tpoly, tpoly_n, split = [], [], 0, False
    warnings, mat_cache, digest_cache, inst_digests = [], {}, {}, {}
    inst_parts, inst_info = collect_instances(
        view_layer, depsgraph, mat_cache, warnings, inst_digests, digest_cache
    )
    yield
    if not objs and not inst_parts:
        raise SceneError("No mesh objects to compute radiosity on (all hidden, excluded or light shapes).")
    parts, targets, signatures = [], [], {}
    seen_mesh = {}
    instancers = {i.instancer for i in inst_info.values()}
    nloop = nvert = 0
    for oid, obj in enumerate(objs):
        ob, (arrays, (faces, raw), flat) = evaluated(
            obj, depsgraph, lambda me: (_mesh_arrays(me), _user_faces(me, face=True), _flat_faces(me))
        )
        mats = [s.material for s in ob.material_slots] or [None]
        em = _placed(arrays, ob.matrix_world, mats)
        if len(em.loop_start) == 0:
            if obj.name not in instancers:
                warnings.append(f"Object '{obj.name}' has no faces; skipped.")
            continue
        signatures[obj.name] = _object_digest(ob, arrays, digest_cache).hexdigest()
        part, perm = _mesh_input(em, obj.name, warnings, mat_cache)
        part.face_group, part.flat = faces, flat
        parts.append(part)
        user = None
        if obj.name in coarse:  # the transport's part: the mesh before the subdivision
            carr, cface = coarse[obj.name]
            user = _onto_user_faces(raw, cface, arrays, carr) if len(carr[1]) else None
        if user is not None:
            tpart, _ = _mesh_input(_placed(carr, ob.matrix_world, mats), obj.name, warnings, mat_cache)
            tparts.append(tpart)
            tpoly.append(user + tpoly_n)
            tpoly_n += len(tpart.loop_start)
            split = True
        else:
            tparts.append(part)
            tpoly.append(np.arange(len(part.loop_start)) + tpoly_n)
            tpoly_n += len(part.loop_start)
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
        helper = values_object(obj, len(em.loop_verts), len(em.verts))
        if helper is not None:  # its own values per evaluated element (own_values)
            t.values_name, t.n_corner, t.n_point = helper.name, len(em.loop_verts), len(em.verts)
        elif not same_topology:
            t.vert_map, t.orig_loop_verts, t.loop_map = _topology_map(obj, em, depsgraph)
            if vertex_output:
                warnings.append(
                    f"Object '{obj.name}': modifiers change the topology; HR_Radiance is "
                    "transferred to the original mesh's corners, which the modifiers interpolate again "
                    "(Array and Mirror copies show the original part's light); apply them for exact values."
                )
        if helper is None and me.name in seen_mesh:
            if vertex_output:
                warnings.append(
                    f"Objects '{seen_mesh[me.name]}' and '{obj.name}' share mesh data "
                    f"'{me.name}'; HR_Radiance can hold only one of them (make them single user)."
                )
        elif helper is None:
            seen_mesh[me.name] = obj.name
        targets.append(t)
        nloop += len(em.loop_verts)
        nvert += len(em.verts)
        yield oid + 1  # (objects read: Live's progress)
    parts += inst_parts  # after the targets' parts: their offsets stay valid
    warnings += instances_warning(inst_info)
    if not parts:
        raise SceneError("No mesh objects with faces to compute radiosity on.")
    mesh = _joined_parts(parts)
    signatures.update(_joined(inst_digests))
    out = SceneInput(mesh, targets, warnings, inst_info, signatures)
    if split:
        for p in inst_parts:
            tparts.append(p)
            tpoly.append(np.arange(len(p.loop_start)) + tpoly_n)
            tpoly_n += len(p.loop_start)
        out.transport, out.transport_poly = _joined_parts(tparts), np.concatenate(tpoly)
    return out


def _joined_parts(parts):
    """parts[0].concat(parts[1]).concat(parts[2])... in one pass: the same MeshInput (values and
    dtypes), without copying the growing mesh again for every object (quadratic: 3,881 objects
    cost Live's start, on the UI thread, seconds at 100k)."""
    if len(parts) == 1:
        return parts[0]

    def offsets(n):
        return [int(x) for x in np.cumsum([0] + [n(p) for p in parts[:-1]])]

    ov, ol, op, oo = (
        offsets(lambda p: len(p.verts)),
        offsets(lambda p: len(p.loop_verts)),
        offsets(lambda p: len(p.loop_start)),
        offsets(lambda p: len(p.object_names)),
    )
    cat = np.concatenate
    tris = [
        np.asarray(np.asarray(p.tri_loops, np.int64) + ol[i] if i else p.tri_loops, np.int64).reshape(-1, 3)
        for i, p in enumerate(parts)
        if p.tri_loops is not None
    ]
    faces = any(p.face_group is not None for p in parts)
    return MeshInput(
        cat([p.verts for p in parts]),
        cat([p.loop_start + ol[i] if i else p.loop_start for i, p in enumerate(parts)]),
        cat([p.loop_total for p in parts]),
        cat([p.loop_verts + ov[i] if i else p.loop_verts for i, p in enumerate(parts)]),
        cat([p.reflectance for p in parts]),
        cat([p.emission for p in parts]),
        cat([p.object_id + oo[i] if i else p.object_id for i, p in enumerate(parts)]),
        [n for p in parts for n in p.object_names],
        cat(tris) if tris else None,
        cat([p.face_groups() + op[i] if i else p.face_groups() for i, p in enumerate(parts)])
        if faces
        else None,
        cat([p.flats() for p in parts]) if any(p.flat is not None for p in parts) else None,
    )
