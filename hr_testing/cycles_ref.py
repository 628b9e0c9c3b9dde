"""Cycles reference bakes and texel-level comparison with the radiosity solution (bpy required).

Used by benchmarks/cycles_compare.py, tests/test_cycles_agreement.py and tests/test_blender_albedo.py
(its own checks: tests/test_cycles_ref.py). Nothing here changes
hr_addon; the scene is read with the add-on's own reader (scene_in), so both sides see the same
polygons, reflectances and emissions.

Pipeline per scene:
1. `Atlas.build(obj, texel)`: a UV layer "HR_Ref" on every compared mesh. Coplanar connected
   polygons form one chart, projected orthographically (uniform world-space texel size `texel`
   over the whole scene), charts shelf-packed into one float image per object with 2 texels of
   padding, so every texel centre lies in at most one chart and UVs are affine per chart.
   The atlas is rasterised at k x k sub-texels: each sub-texel centre inside a loop triangle gets
   (polygon, loop triangle, barycentrics, world point). A texel counts when its centre is inside
   a triangle (what Cycles bakes with margin 0); its value on our side is the mean over its
   sub-texels inside the object (Cycles jitters samples over the texel with the box filter).
2. `reference_materials()`: per object and slot a Cycles material with the reflectance and
   emission that hr_addon.blender.materials reads: Diffuse BSDF (roughness 0) + Emission, and
   black on the back face (Geometry > Backfacing), i.e. one-sided like a radiosity surface.
   `shape_proxies(frame)`: every light shape active at the frame becomes an emission-only
   surface (Transparent + one-sided Emission) 1e-4 x scene diagonal in front of its wall, so
   the wall under it still reflects and the emission adds, as in the radiosity model.
3. `bake()`: Diffuse bake, Direct + Indirect + Color (= reflected radiance rho H / pi), float
   Non-Color images initialised to alpha 0, margin 0, clamping off, 64 bounces, box filter 1 px,
   fixed thread count. Returns reflected radiance per texel and the bake's wall time.
4. `evaluate()`: our leaf radiance (piecewise constant: the quadtree leaf holding each sub-texel
   point, via DynamicRadiosity.evaluate / events.locate) and our vertex output (HR_Radiance
   corner values interpolated over Blender's loop triangles, what a render shows), averaged per
   texel, plus the exact emission at each texel (polygon emission + active shapes covering it).
"""

from dataclasses import dataclass, field
import time

import numpy as np

from hr_addon.core.geometry import components, newell
from hr_addon.core.output import radiance_at

UV_NAME = "HR_Ref"
REF_TAG = "hr_ref"


# --------------------------------------------------------------------------------------------
# Atlas
# --------------------------------------------------------------------------------------------


def _world_mesh(obj):
    me = obj.data
    V, P, L = len(me.vertices), len(me.polygons), len(me.loops)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    M = np.array(obj.matrix_world, dtype=np.float64)
    verts = co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    ls, lt, lv = np.empty(P, np.int32), np.empty(P, np.int32), np.empty(L, np.int32)
    me.polygons.foreach_get("loop_start", ls)
    me.polygons.foreach_get("loop_total", lt)
    me.loops.foreach_get("vertex_index", lv)
    me.calc_loop_triangles()
    T = len(me.loop_triangles)
    tl, tp = np.empty(T * 3, np.int32), np.empty(T, np.int32)
    me.loop_triangles.foreach_get("loops", tl)
    me.loop_triangles.foreach_get("polygon_index", tp)
    return verts, ls.astype(np.int64), lt.astype(np.int64), lv.astype(np.int64), tl.reshape(-1, 3), tp


@dataclass
class Atlas:
    name: str
    width: int
    height: int
    k: int  # sub-texels per texel side
    texel: float  # world length of a texel side
    # per texel (N)
    tx: np.ndarray = None  # texel column
    ty: np.ndarray = None  # texel row (row 0 = v 0, as Blender stores pixels)
    # per sub-sample (S)
    s_texel: np.ndarray = None  # texel index 0..N-1
    s_poly: np.ndarray = None  # object polygon
    s_loops: np.ndarray = None  # (S, 3) loop indices of the loop triangle
    s_bary: np.ndarray = None  # (S, 3)
    s_point: np.ndarray = None  # (S, 3) world
    s_centre: np.ndarray = None  # bool: the texel's centre sample
    s_axes: np.ndarray = None  # (S, 2, 3) world vectors of one texel step in u and v at the sample
    s_tri: np.ndarray = None  # (S, 3, 3) world corners of the sample's loop triangle (s_bary's order)
    area: float = 0.0
    n_poly: int = 0

    @property
    def n(self):
        return len(self.tx)

    @staticmethod
    def build(obj, texel, k=3, pad=2):
        """UV layer UV_NAME on obj (made active for render/bake) and the texel -> surface map."""
        verts, ls, lt, lv, tri_loops, tri_poly = _world_mesh(obj)
        P = len(ls)
        polys = [lv[s : s + n] for s, n in zip(ls, lt)]
        nrm = np.zeros((P, 3))
        area = np.zeros(P)
        for i, p in enumerate(polys):
            n = newell(verts[p])
            area[i] = 0.5 * np.linalg.norm(n)
            nrm[i] = n / max(2 * area[i], 1e-300)
        off = np.einsum("ij,ij->i", nrm, np.array([verts[p].mean(0) for p in polys]))
        scale = max(float(np.abs(verts).max()), 1e-9)
        # charts: shared edges of coplanar polygons
        pairs = []
        owner = {}
        for i, p in enumerate(polys):
            for a, b in zip(p, np.roll(p, -1)):
                key = (min(a, b), max(a, b))
                j = owner.get(key)
                if j is not None and nrm[i] @ nrm[j] > 1 - 1e-3 and abs(off[i] - off[j]) < 1e-3 * scale:
                    pairs.append((i, j))
                owner[key] = i
        roots = components(P, *np.array(pairs, np.int64).reshape(-1, 2).T)
        charts = [np.flatnonzero(roots == r) for r in np.unique(roots)]
        # project each chart to 2D (texel units)
        loop_uv = np.zeros((len(lv), 2))
        rects = []
        for c in charts:
            n = nrm[c].mean(0)
            n /= np.linalg.norm(n)
            e = verts[polys[c[0]][1]] - verts[polys[c[0]][0]]
            u = e - (e @ n) * n
            u /= np.linalg.norm(u)
            v = np.cross(n, u)
            loops = np.concatenate([np.arange(ls[i], ls[i] + lt[i]) for i in c])
            p2 = np.column_stack([verts[lv[loops]] @ u, verts[lv[loops]] @ v]) / texel
            p2 -= p2.min(0)
            loop_uv[loops] = p2
            ext = p2.max(0)
            rects.append((loops, int(np.ceil(ext[0])) + 2 * pad, int(np.ceil(ext[1])) + 2 * pad))
        # shelf packing into the smallest square that fits (tallest first)
        order = sorted(range(len(rects)), key=lambda i: -rects[i][2])
        side = max(
            int(np.ceil(np.sqrt(sum(r[1] * r[2] for r in rects)))), max(max(r[1], r[2]) for r in rects)
        )
        while True:
            x = y = shelf = 0
            place = {}
            ok = True
            for i in order:
                w, h = rects[i][1], rects[i][2]
                if x + w > side:
                    x, y, shelf = 0, y + shelf, 0
                if y + h > side or w > side:
                    ok = False
                    break
                place[i] = (x, y)
                x += w
                shelf = max(shelf, h)
            if ok:
                break
            side += max(1, side // 32)
        for i, (loops, w, h) in enumerate(rects):
            loop_uv[loops] += np.array(place[i], float) + pad
        W = H = side
        uv = loop_uv / np.array([W, H], float)
        me = obj.data
        layer = me.uv_layers.get(UV_NAME) or me.uv_layers.new(name=UV_NAME)
        layer.data.foreach_set("uv", uv.astype(np.float32).ravel())
        me.uv_layers.active = layer
        layer.active_render = True
        at = Atlas(obj.name, W, H, k, texel, area=float(area.sum()), n_poly=P)
        at._rasterise(loop_uv, verts, lv, tri_loops, tri_poly)
        return at

    def _rasterise(self, loop_uv, verts, lv, tri_loops, tri_poly):
        k = self.k
        s_idx, s_tri, s_bary = [], [], []
        for t, lo in enumerate(tri_loops):
            a, b, c = loop_uv[lo] * k  # sub-texel units
            lo_x, lo_y = np.floor(np.minimum(np.minimum(a, b), c)).astype(int)
            hi_x, hi_y = np.ceil(np.maximum(np.maximum(a, b), c)).astype(int)
            xs, ys = np.meshgrid(np.arange(lo_x, hi_x + 1), np.arange(lo_y, hi_y + 1), indexing="ij")
            p = np.column_stack([xs.ravel() + 0.5, ys.ravel() + 0.5])
            d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
            if abs(d) < 1e-12:
                continue
            l1 = ((p[:, 0] - a[0]) * (c[1] - a[1]) - (p[:, 1] - a[1]) * (c[0] - a[0])) / d
            l2 = ((b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])) / d
            l0 = 1 - l1 - l2
            inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
            if not inside.any():
                continue
            s_idx.append(np.column_stack([xs.ravel()[inside], ys.ravel()[inside]]))
            s_tri.append(np.full(int(inside.sum()), t))
            s_bary.append(np.column_stack([l0, l1, l2])[inside])
        if not s_idx:
            raise NoTexels(self.name)
        sub = np.concatenate(s_idx)
        tri = np.concatenate(s_tri)
        bary = np.clip(np.concatenate(s_bary), 0, 1)
        # one triangle per sub-texel (edges shared by two triangles: keep the first)
        key = sub[:, 1] * (self.width * k) + sub[:, 0]
        _, first = np.unique(key, return_index=True)
        sub, tri, bary, key = sub[first], tri[first], bary[first], key[first]
        tx, ty = sub[:, 0] // k, sub[:, 1] // k
        centre = (sub[:, 0] % k == k // 2) & (sub[:, 1] % k == k // 2)
        tkey = ty * self.width + tx
        texels = np.unique(tkey[centre])  # texels whose centre is inside the object
        keep = np.isin(tkey, texels)
        self.tx, self.ty = texels % self.width, texels // self.width
        self.s_texel = np.searchsorted(texels, tkey[keep])
        tri, bary = tri[keep], bary[keep] / bary[keep].sum(1, keepdims=True)
        self.s_centre = centre[keep]
        self.s_poly = tri_poly[tri].astype(np.int64)
        self.s_loops = tri_loops[tri].astype(np.int64)
        self.s_bary = bary
        self.s_tri = verts[lv[self.s_loops]]
        self.s_point = np.einsum("sk,skj->sj", bary, self.s_tri)
        # the texel's sides on the surface: d(world)/d(texel units) of the sample's triangle
        uvt = loop_uv[self.s_loops]  # (S, 3, 2) texel units
        U = np.stack([uvt[:, 1] - uvt[:, 0], uvt[:, 2] - uvt[:, 0]], 2)
        wt = verts[lv[self.s_loops]]
        E = np.stack([wt[:, 1] - wt[:, 0], wt[:, 2] - wt[:, 0]], 2)
        self.s_axes = np.swapaxes(np.einsum("sik,skj->sij", E, np.linalg.inv(U)), 1, 2)

    def texel_mean(self, values):
        """(S, C) sub-sample values -> (N, C) texel means."""
        values = np.asarray(values, float)
        cnt = np.bincount(self.s_texel, minlength=self.n)
        out = np.stack([np.bincount(self.s_texel, values[:, c], self.n) for c in range(values.shape[1])], 1)
        return out / np.maximum(cnt, 1)[:, None]

    def texel_weights(self):
        """World area per texel (same for every texel: uniform density), for area averages."""
        return np.full(self.n, self.texel**2)


# --------------------------------------------------------------------------------------------
# Cycles reference scene
# --------------------------------------------------------------------------------------------


def configure_cycles(scene, samples, seed=0, threads=1, bounces=64):
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = int(samples)
    c.seed = int(seed)
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = c.diffuse_bounces = bounces
    # the light shapes' proxies are transparent: their passes are not light bounces
    c.transparent_max_bounces = max(bounces, 64)
    c.glossy_bounces = c.transmission_bounces = c.volume_bounces = 0
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(threads)
    scene.view_settings.view_transform = "Standard"
    world = scene.world
    if world is not None and world.node_tree is not None:
        for n in world.node_tree.nodes:
            if n.type == "BACKGROUND":
                n.inputs["Strength"].default_value = 0.0


def _new_material(name):
    import bpy

    m = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        m.use_nodes = True
    m[REF_TAG] = True
    t = m.node_tree
    for n in list(t.nodes):
        t.nodes.remove(n)
    out = t.nodes.new("ShaderNodeOutputMaterial")
    out.target = "ALL"
    return m, t, out


def one_sided_material(name, rho, emission, transparent=False):
    """Front: Diffuse(rho) + Emission(emission) (or Transparent + Emission); back: black
    (or Transparent): a one-sided radiosity surface in Cycles."""
    m, t, out = _new_material(name)
    geo = t.nodes.new("ShaderNodeNewGeometry")
    if transparent:
        base = t.nodes.new("ShaderNodeBsdfTransparent")
        base.inputs["Color"].default_value = (1, 1, 1, 1)
        back = t.nodes.new("ShaderNodeBsdfTransparent")
        back.inputs["Color"].default_value = (1, 1, 1, 1)
    else:
        base = t.nodes.new("ShaderNodeBsdfDiffuse")
        base.inputs["Color"].default_value = (*map(float, rho), 1)
        base.inputs["Roughness"].default_value = 0.0
        back = t.nodes.new("ShaderNodeBsdfDiffuse")
        back.inputs["Color"].default_value = (0, 0, 0, 1)
    em = t.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*map(float, emission), 1)
    em.inputs["Strength"].default_value = 1.0
    add = t.nodes.new("ShaderNodeAddShader")
    t.links.new(base.outputs[0], add.inputs[0])
    t.links.new(em.outputs[0], add.inputs[1])
    mix = t.nodes.new("ShaderNodeMixShader")
    t.links.new(geo.outputs["Backfacing"], mix.inputs["Fac"])
    t.links.new(add.outputs[0], mix.inputs[1])
    t.links.new(back.outputs[0], mix.inputs[2])
    t.links.new(mix.outputs[0], out.inputs["Surface"])
    return m


def reference_material(name, src, textured=False):
    """The one-sided reference copy of the user's material `src` as our reader reads it
    (hr_addon.blender.materials.read_material); `textured`: the front's colour is src's image
    texture through the same UV map ("UVMap"), as the user's material shows it."""
    from hr_addon.blender.materials import read_material

    s = read_material(src)
    ref = one_sided_material(name, s.reflectance, s.emission)
    if textured:
        t = ref.node_tree
        tex = t.nodes.new("ShaderNodeTexImage")
        tex.image = next(n for n in src.node_tree.nodes if n.type == "TEX_IMAGE").image
        uvn = t.nodes.new("ShaderNodeUVMap")
        uvn.uv_map = "UVMap"
        t.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
        front = next(
            n for n in t.nodes if n.type == "BSDF_DIFFUSE" and n.inputs["Color"].default_value[0] > 0
        )
        t.links.new(tex.outputs["Color"], front.inputs["Color"])
    return ref


class NoTexels(Exception):
    pass


@dataclass
class RefScene:
    """A sample scene prepared for reference bakes and for our solution."""

    scene: object
    view_layer: object
    objects: list  # compared geometry objects (names)
    atlases: dict  # name -> Atlas
    images: dict  # name -> bpy image
    scene_in: object  # hr_addon.blender.scene_in.SceneInput
    poly_offset: dict  # object name -> first polygon in scene_in.mesh
    diag: float = 1.0
    proxies: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    not_compared: list = field(
        default_factory=list
    )  # objects smaller than a texel (they still light the rest)


def prepare(scene, texel_rel=1 / 100, k=3, texel=None, only=None):
    """Atlases, images and reference materials for every geometry object of `scene` (must be the
    context scene), or for the objects named in `only` (the others light them but are neither
    baked nor compared: a test's Cycles time goes to the objects it checks). Geometry read at the
    scene's start frame, as the bake does."""
    import bpy
    from hr_addon.blender.scene_in import collect_geometry, geometry_objects
    from hr_addon.blender.materials import read_material

    vl = bpy.context.view_layer
    scene.frame_set(scene.frame_start)
    sin = collect_geometry(vl, vl.depsgraph)
    objs = geometry_objects(vl)
    names = [t.name for t in sin.targets]
    allv = sin.mesh.verts[sin.mesh.loop_verts]
    diag = float(np.linalg.norm(allv.max(0) - allv.min(0)))
    texel = texel or texel_rel * diag
    poly_offset = {}
    lstart = sin.mesh.loop_start
    for t in sin.targets:
        poly_offset[t.name] = int(np.searchsorted(lstart, t.loops[0]))
    rs = RefScene(scene, vl, names, {}, {}, sin, poly_offset, diag, warnings=list(sin.warnings))
    for obj in objs:
        if obj.name not in names:
            continue
        img = None
        if only is not None and obj.name not in only:
            names.remove(obj.name)
        elif obj.modifiers:
            raise RuntimeError(f"{obj.name}: modifiers are not supported by the comparison (apply them)")
        else:
            try:
                at = Atlas.build(obj, texel, k)
            except NoTexels:
                # lights the others but is not compared (no sub-texel sample falls on it)
                names.remove(obj.name)
                rs.not_compared.append(obj.name)
                continue
            rs.atlases[obj.name] = at
            img = bpy.data.images.new(f"REF_{obj.name}", at.width, at.height, alpha=True, float_buffer=True)
            img.colorspace_settings.name = "Non-Color"
            rs.images[obj.name] = img
        # one reference material per slot, single user, with the bake target node active (objects
        # not compared: the one-sided material alone)
        slots = obj.material_slots
        mats = [s.material for s in slots] or [None]
        new = []
        for i, m in enumerate(mats):
            s = read_material(m)
            rm = one_sided_material(f"REF_{obj.name}_{i}", s.reflectance, s.emission)
            if img is not None:
                tex = rm.node_tree.nodes.new("ShaderNodeTexImage")
                tex.image = img
                rm.node_tree.nodes.active = tex
                tex.select = True
            new.append(rm)
        if not slots:
            obj.data.materials.append(new[0])
        else:
            for i, rm in enumerate(new):
                slots[i].link = "OBJECT"
                slots[i].material = rm
    return rs


def clear_image(img):
    w, h = img.size
    img.pixels.foreach_set(np.zeros(w * h * 4, np.float32))


def shape_proxies(rs: RefScene, frame):
    """Replace the previous proxies with emitting, otherwise transparent, copies of the light
    shapes active at `frame`. Returns the core LightShape dict of the frame (our input)."""
    import bpy
    from hr_addon.blender.lights_in import collect_light_shapes
    from hr_addon.blender.scene_in import light_shape_objects, read_mesh
    from hr_addon.blender.materials import read_material
    from hr_addon.core.events import LightShape

    for ob in rs.proxies:
        me = ob.data
        bpy.data.objects.remove(ob, do_unlink=True)
        bpy.data.meshes.remove(me)
    rs.proxies = []
    rs.scene.frame_set(frame)
    dg = rs.view_layer.depsgraph
    shapes = collect_light_shapes(rs.view_layer, dg, LightShape, rs.warnings)
    eps = 1e-4 * rs.diag
    for obj in light_shape_objects(rs.view_layer):
        if obj.evaluated_get(dg).hide_render:
            continue
        em = read_mesh(obj, dg)
        polys = [
            list(em.loop_verts[s : s + n][::-1] if em.flipped else em.loop_verts[s : s + n])
            for s, n in zip(em.loop_start, em.loop_total)
        ]
        verts, faces, mats = [], [], []
        for i, p in enumerate(polys):
            # a polygon keyed flat (scale 0, squashed to a line: a blind closed) emits nothing, as
            # the core reads it (lights_in.collect_light_shapes); its normal would be NaN and put
            # NaN vertices in the proxy Cycles renders
            sv = np.linalg.svd(em.verts[p] - em.verts[p].mean(0), compute_uv=False)
            if sv[1] <= 1e-9 * max(sv[0], 1e-300):
                continue
            n = _surface_front(rs, em.verts[p])
            base = len(verts)
            pts = em.verts[p] + eps * n
            if newell(pts) @ n < 0:  # emit towards the surface's front, as the core does
                pts = pts[::-1]
            verts += list(pts)
            faces.append(list(range(base, base + len(p))))
            mats.append(int(em.material_index[i]))
        me = bpy.data.meshes.new(f"REFPROXY_{obj.name}")
        me.from_pydata([tuple(v) for v in verts], [], faces)
        for slot, m in enumerate(em.materials):
            e = read_material(m).emission
            me.materials.append(
                one_sided_material(f"REFPROXY_{obj.name}_{slot}", (0, 0, 0), e, transparent=True)
            )
        me.polygons.foreach_set("material_index", np.array(mats, np.int32))
        ob = bpy.data.objects.new(f"REFPROXY_{obj.name}", me)
        ob[REF_TAG] = True
        rs.scene.collection.objects.link(ob)
        ob.hr.exclude = True
        rs.proxies.append(ob)
    return shapes


def shape_orientation(rs: RefScene, shapes):
    """{shape key: True if the shape faces like the surface it lies on, False if it is wound
    against it (the core still emits on the surface's side; see _surface_front).}"""
    out = {}
    for k, s in shapes.items():
        ring = np.asarray(s.rings[0], float)
        n = newell(ring)
        out[k] = bool(_surface_front(rs, ring) @ n > 0)
    return out


def _surface_front(rs: RefScene, ring, plane_tol=1e-3):
    """Front normal of the surface a light-shape polygon lies on. The core (events._find_surface)
    takes coplanar surfaces facing either way and emits on the side the surface faces (preferring a
    surface facing like the shape), so a shape wound against its wall still lights the room."""
    n = newell(ring)
    n /= np.linalg.norm(n)
    c = ring.mean(0)
    m = rs.scene_in.mesh
    best = None
    for s, k in zip(m.loop_start, m.loop_total):
        q = m.verts[m.loop_verts[s : s + k]]
        qn = newell(q)
        qn /= max(np.linalg.norm(qn), 1e-300)
        if abs(qn @ n) >= 0.999 and np.abs((q - c) @ n).max() <= plane_tol * rs.diag:
            if qn @ n > 0:
                return n
            best = qn
    return n if best is None else -n


def bake(
    rs: RefScene, samples, seed=0, threads=1, passes=("DIRECT", "INDIRECT"), bounces=64, seed_per_object=False
):
    """Bake reflected radiance (rho H / pi) of every compared object (passes: Cycles' Diffuse
    bake's light passes, both by default; bounces: Cycles' max and diffuse bounces, 0 direct light
    only, 1 one reflection more: benchmarks/cycles_bounce_check.py). Returns ({name: (N, 3)},
    {"wall": s, "cpu": s} of the bake call, {name: baked mask (N,)}).

    Cycles draws a texel's samples from its pixel (x, y) in the image it bakes and the seed, and
    every object bakes into its own image, so the texels at one (x, y) of all objects share their
    random numbers: errors of alike objects (a bookcase's books) are correlated and do not pool
    down. seed_per_object: object i baked alone with seed x (objects) + i (one bake call each):
    independent errors."""
    import bpy

    configure_cycles(rs.scene, samples, seed, threads, bounces)
    rb = rs.scene.render.bake
    rb.margin = 0
    rb.use_clear = False
    rb.target = "IMAGE_TEXTURES"
    rb.use_selected_to_active = False
    groups = [[n] for n in rs.objects] if seed_per_object else [rs.objects]
    t0, c0 = time.perf_counter(), time.process_time()
    for i, names in enumerate(groups):
        # per object: seeds of different `seed`s never meet (object i of seed 1 and i - 1 of seed 2)
        rs.scene.cycles.seed = int(seed) * len(groups) + i if seed_per_object else int(seed)
        # the light-shape originals must not take part (their ray visibility is off already)
        for ob in bpy.context.view_layer.objects:
            ob.select_set(False)
        for name in names:
            bpy.data.objects[name].select_set(True)
            clear_image(rs.images[name])
        bpy.context.view_layer.objects.active = bpy.data.objects[names[0]]
        bpy.ops.object.bake(
            type="DIFFUSE",
            pass_filter={*passes, "COLOR"},
            margin=0,
            use_clear=False,
            target="IMAGE_TEXTURES",
        )
    rs.scene.cycles.seed = int(seed)
    dt = {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}
    out, mask = {}, {}
    for name in rs.objects:
        img, at = rs.images[name], rs.atlases[name]
        px = np.empty(at.width * at.height * 4, np.float32)
        img.pixels.foreach_get(px)
        px = px.reshape(at.height, at.width, 4)
        v = px[at.ty, at.tx]
        out[name] = v[:, :3].astype(np.float64)
        mask[name] = v[:, 3] > 0.5
    return out, dt, mask


# --------------------------------------------------------------------------------------------
# Our side
# --------------------------------------------------------------------------------------------


def _patch_of(patches, polys, points):
    """Patch (quadtree root) holding each point of input polygons `polys`."""
    pp = patches.poly
    first = np.searchsorted(pp, polys, "left")
    last = np.searchsorted(pp, polys, "right")
    best = first.copy()
    if (last - first > 1).any():
        best_s = np.full(len(polys), -np.inf)
        for j in range(int((last - first).max())):
            cand = np.minimum(first + j, len(pp) - 1)
            valid = first + j < last
            C = patches.corners[cand]
            e = np.roll(C, -1, axis=1) - C
            w = points[:, None, :] - C
            s = np.einsum("nkj,nj->nk", np.cross(e, w), patches.normal[cand])
            el = np.linalg.norm(e, axis=-1)
            s = np.where(el > 0, s / np.where(el > 0, el, 1), np.inf)
            m = s.min(1)
            upd = valid & (m > best_s)
            best[upd], best_s[upd] = cand[upd], m[upd]
    missing = first >= last
    return best, missing


class Ours:
    """Our solution for one RefScene: a built RadiositySystem and (if the scene has light shapes)
    a DynamicRadiosity on it."""

    def __init__(self, rs: RefScene, system, dyn=None):
        self.rs, self.system, self.dyn = rs, system, dyn
        mesh = rs.scene_in.mesh
        pt = system.patches
        self.samples = {}
        for name in rs.objects:
            at = rs.atlases[name]
            P = at.s_poly + rs.poly_offset[name]
            patch, missing = _patch_of(pt, P, at.s_point)
            self.samples[name] = (patch, missing, P)
        self.base_emission_poly = mesh.emission

    def evaluate(self, shapes=None, smooth=True):
        """{name: dict(leaf_total, leaf_refl, vertex_total, emission[, smooth_refl, smooth_total])}, each
        (N, 3) per texel: leaf radiance (total, and reflected = minus the leaf's emission as the method
        applied it), vertex output interpolated, exact emission, and the texture output's smooth
        in-leaf interpolation (core.output.radiance_at) of reflected and total radiance."""
        from hr_addon.core.events import locate

        rs = self.rs
        names = rs.objects
        allp = np.concatenate([self.samples[n][0] for n in names])
        allx = np.concatenate([rs.atlases[n].s_point for n in names])
        want_smooth, smooth = smooth, None
        if self.dyn is not None:
            B, E = self.dyn.evaluate(allx, allp)
            loops = self.dyn.loop_radiance("CORNER")
            if want_smooth and not self.dyn.naive_active:
                h, Bn = self.dyn.system.h, self.dyn.B
                smooth = (
                    radiance_at(h, Bn - self.dyn.emission() * h.exposure[: h.n], allp, allx, smooth=True),
                    radiance_at(h, Bn, allp, allx, smooth=True),
                )
        else:
            h = self.system.h
            leaf = locate(h, allp, allx)
            if self.system.B is None:
                self.system.solve()
            B = h.values_at(self.system.B, leaf, allx)
            E = self.system.base_emission()[:, leaf].T
            loops = self.system.loop_radiance("CORNER")
            if want_smooth:
                smooth = (
                    radiance_at(
                        h,
                        self.system.B - self.system.base_emission() * h.exposure[: h.n],
                        allp,
                        allx,
                        smooth=True,
                    ),
                    radiance_at(h, self.system.B, allp, allx, smooth=True),
                )
        out, s = {}, 0
        targets = {t.name: t for t in rs.scene_in.targets}
        for name in names:
            at = rs.atlases[name]
            patch, missing, P = self.samples[name]
            m = len(patch)
            b, e = B[s : s + m], E[s : s + m]
            sm = None if smooth is None else (smooth[0][s : s + m], smooth[1][s : s + m])
            s += m
            corner = targets[name].extract(loops, "CORNER").astype(np.float64)
            vert = np.einsum("sk,skc->sc", at.s_bary, corner[at.s_loops])
            etrue = self.base_emission_poly[P] + shape_emission(shapes or {}, at.s_point, rs.diag)
            b = np.where(missing[:, None], np.nan, b)
            out[name] = {
                "leaf_total": at.texel_mean(b),
                "leaf_refl": at.texel_mean(b - e),
                "vertex_total": at.texel_mean(vert),
                "emission": at.texel_mean(etrue),
            }
            if sm is not None:  # the texture output's interpolation (core.output.radiance_at)
                out[name]["smooth_refl"] = at.texel_mean(np.where(missing[:, None], np.nan, sm[0]))
                out[name]["smooth_total"] = at.texel_mean(np.where(missing[:, None], np.nan, sm[1]))
        return out


def gather_results(rs, ours, dyn, rays=128, shadow_rays=32, vertex=True, cache=None, texel_area=True, **kw):
    """The final gather (hr_addon.core.gather) on our solution: per object and texel
    gather_refl / gather_total (a FinalGather at every texel's centre) and gvertex_total (a
    LoopGather at the mesh's corners, interpolated over Blender's loop triangles as vertex_total).
    cache: a dict keeping the gathers between frames (their precompute depends on geometry only).
    kw: more FinalGather settings (levels=2: the two-level gather). texel_area: texels straddling a
    contact's edge gather over their area (core.gather.texel_samples), False: at centres only.
    Returns ({name: {...}}, {"precompute_s", "evaluate_s", "weights_mb", "samples"} of each)."""
    import time as _t

    from hr_addon.core.gather import LoopGather, texel_gather

    cache = {} if cache is None else cache
    names = rs.objects
    cen = {n: np.flatnonzero(rs.atlases[n].s_centre) for n in names}
    cost = {}
    if "texel" not in cache:
        allp = np.concatenate([ours.samples[n][0][cen[n]] for n in names])
        allx = np.concatenate([rs.atlases[n].s_point[cen[n]] for n in names])
        c0 = _t.process_time()
        axes = np.concatenate([rs.atlases[n].s_axes[cen[n]] for n in names]) if texel_area else None
        tris = np.concatenate([rs.atlases[n].s_tri[cen[n]] for n in names]) if texel_area else None
        cache["texel"] = texel_gather(
            dyn, allp, allx, axes=axes, tris=tris, rays=rays, shadow_rays=shadow_rays, **kw
        )
        cost["texel_precompute_s"] = _t.process_time() - c0
    g = cache["texel"]
    c0 = _t.process_time()
    refl = g.evaluate(dyn, "reflected")
    c1 = _t.process_time()
    total = g.evaluate(dyn, "radiance")
    cost["texel_evaluate_s"] = (_t.process_time() - c0) / 2
    # a bake's frame evaluates one kind: the first call carries the new shapes' direct light and
    # responses, a second kind reuses them
    cost["texel_evaluate_first_s"] = c1 - c0
    cost["texel_samples"], cost["texel_weights_mb"] = g.n, g.weights_bytes / 1e6
    cost["texels"] = g.n_out
    if "edge_texels" in g.stats:  # texel_edges.edge_direct: (tested, edge texels, rays), CPU s
        cost["edge_texels"] = g.stats["edge_texels"][1]
        cost["edge_texels_cpu_s"] = g.stats["edge_texels_cpu"]
    loops = None
    if vertex:
        if "loops" not in cache:
            c0 = _t.process_time()
            cache["loops"] = LoopGather(dyn, rays=rays, shadow_rays=shadow_rays, **kw)
            cost["loop_precompute_s"] = _t.process_time() - c0
        lg = cache["loops"]
        c0 = _t.process_time()
        loops = lg.loop_radiance(dyn)
        cost["loop_evaluate_s"] = _t.process_time() - c0
        cost["loop_samples"], cost["loop_weights_mb"] = lg.n, lg.weights_bytes / 1e6
    targets = {t.name: t for t in rs.scene_in.targets}
    out, s = {}, 0
    for name in names:
        at = rs.atlases[name]
        m = len(cen[name])
        tex = np.full((at.n, 3), np.nan)
        r = {}
        for key, arr in (("gather_refl", refl), ("gather_total", total)):
            tex = np.full((at.n, 3), np.nan)
            tex[at.s_texel[cen[name]]] = arr[s : s + m]
            r[key] = tex
        r["gather_dark_frac"] = float(g.out_dark[s : s + m].mean()) if m else 0.0
        s += m
        if loops is not None:
            corner = targets[name].extract(loops, "CORNER").astype(np.float64)
            vert = np.einsum("sk,skc->sc", at.s_bary, corner[at.s_loops])
            r["gvertex_total"] = at.texel_mean(vert)
        out[name] = r
    return out, cost


def shape_emission(shapes, points, diag, plane_tol=1e-3):
    """Exact emitted radiance of the light shapes at surface points (N, 3)."""
    E = np.zeros((len(points), 3))
    for s in shapes.values():
        outer = np.asarray(s.rings[0], float)
        n = sum(newell(np.asarray(r, float)) for r in s.rings[:1])
        n /= np.linalg.norm(n)
        c = outer.mean(0)
        u = outer[1] - outer[0]
        u -= (u @ n) * n
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        d = np.abs((points - c) @ n)
        near = d <= plane_tol * diag
        if not near.any():
            continue
        p2 = np.column_stack([(points[near] - c) @ u, (points[near] - c) @ v])
        inside = np.zeros(len(p2), bool)
        for r in s.rings:
            r2 = np.column_stack([(np.asarray(r) - c) @ u, (np.asarray(r) - c) @ v])
            a, b = r2, np.roll(r2, -1, 0)
            y = p2[:, 1:2]
            crosses = (a[:, 1][None] > y) != (b[:, 1][None] > y)
            t = (y - a[:, 1][None]) / np.where(b[:, 1] != a[:, 1], b[:, 1] - a[:, 1], 1)[None]
            x = a[:, 0][None] + t * (b[:, 0] - a[:, 0])[None]
            inside ^= (crosses & (p2[:, :1] < x)).sum(1) % 2 == 1
        idx = np.flatnonzero(near)[inside]
        E[idx] += np.asarray(s.emission, float)[None]
    return E


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------


def metrics(ours, ref, mask=None):
    """Error of ours against ref, (N, 3) per texel in radiance units. mre: relative error of the
    surface's mean radiance (mean over RGB of |mean ours - mean ref| / mean ref); rmse over texels
    and channels; p95 of the per-texel error (mean abs over RGB); rel_rmse = rmse / mean ref."""
    ok = np.isfinite(ours).all(1) & np.isfinite(ref).all(1)
    if mask is not None:
        ok &= mask
    o, r = ours[ok], ref[ok]
    if len(o) == 0:
        return None
    mo, mr = o.mean(0), r.mean(0)
    d = o - r
    rmse = float(np.sqrt(np.mean(d**2)))
    return {
        "texels": int(len(o)),
        "mean_ref": mr.tolist(),
        "mean_ours": mo.tolist(),
        "mre": float(np.mean(np.abs(mo - mr) / np.maximum(mr, 1e-12))),
        "bias": float(np.mean((mo - mr) / np.maximum(mr, 1e-12))),
        "rmse": rmse,
        "rel_rmse": rmse / max(float(mr.mean()), 1e-12),
        "p95": float(np.percentile(np.abs(d).mean(1), 95)),
    }


def object_summary(per, names):
    """Per-object errors over the objects `names` (per: {name: metrics()}): how many, the
    texel-weighted error of the mean, the share within 5%, the median error, the median signed
    error and the pooled bias (texel-weighted mean ours / mean reference - 1, grey)."""
    ll = [n for n in names if n in per]
    w = np.array([per[n]["texels"] for n in ll], float)
    e = np.array([per[n]["mre"] for n in ll])
    mo = sum(w_ * np.mean(per[n]["mean_ours"]) for w_, n in zip(w, ll))
    mr = sum(w_ * np.mean(per[n]["mean_ref"]) for w_, n in zip(w, ll))
    return {
        "objects": len(ll),
        "weighted": float(np.sum(w * e) / w.sum()),
        "within_5": float(np.mean(e < 0.05)),
        "median": float(np.median(e)),
        "median_signed": float(np.median([per[n]["bias"] for n in ll])),
        "pooled_bias": float(mo / mr - 1),
    }


def lit_objects(ref, share=0.05):
    """Objects of ref {name: (N, 3)} whose mean radiance is above `share` of the mean over all
    texels: those lit well enough for a relative error to mean something (near-black objects,
    Cycles' noise)."""
    mean = {n: float(np.nanmean(v[np.isfinite(v).all(1)])) for n, v in ref.items() if np.isfinite(v).any()}
    allv = np.concatenate([v[np.isfinite(v).all(1)] for v in ref.values()])
    return sorted(n for n, m in mean.items() if m > share * float(allv.mean()))


def noise_scale(err, spp, ref_spp=None):
    """Cycles' error at one sample, from an error `err` measured at `spp` samples: Cycles is an
    unbiased estimate of independent samples, so its error against the truth is scale / sqrt(spp)
    (a per-object mean's error is normal, and a median of such errors scales alike). ref_spp:
    err was measured against a Cycles reference of ref_spp samples, whose independent noise adds
    in quadrature: err = scale sqrt(1 / spp + 1 / ref_spp)."""
    return err / np.sqrt(1 / spp + (1 / ref_spp if ref_spp else 0.0))


def spp_at_error(err, scale, ref_spp=None):
    """The sample count at which Cycles' error (noise_scale's `scale`) equals `err`. ref_spp: both
    measured against the same Cycles reference of ref_spp samples (its noise in both; equally: err
    with the reference's noise removed in quadrature against Cycles' error against the truth);
    inf when err is within the reference's own noise. None: err taken as it reads (the noise it
    holds counted as ours)."""
    d = (err / scale) ** 2 - (1 / ref_spp if ref_spp else 0.0)
    return 1 / d if d > 0 else float("inf")


def write_json(path, obj):
    """obj as compact JSON, numbers to 4 significant digits: a benchmark's dump stays small."""
    import json

    def rnd(x):
        if isinstance(x, (float, np.floating)):
            return float(f"{x:.4g}")
        if isinstance(x, (list, tuple)):
            return [rnd(v) for v in x]
        if isinstance(x, dict):
            return {k: rnd(v) for k, v in x.items()}
        return x

    with open(path, "w") as fh:
        json.dump(rnd(obj), fh, separators=(",", ":"), default=float)


def noise(a, b, mask=None):
    """Per-bake noise from two seeds: RMS of (a - b) / sqrt 2, and of the surface mean."""
    ok = np.isfinite(a).all(1) & np.isfinite(b).all(1)  # texels the bake did not write are NaN
    if mask is not None:
        ok &= mask
    d = (a - b)[ok]
    return float(np.sqrt(np.mean(d**2) / 2)), float(
        np.mean(np.abs(d.mean(0)) / np.maximum((a[ok] + b[ok]).mean(0) / 2, 1e-12)) / np.sqrt(2)
    )
