"""Baked textures, the Blender side: lightmap UV layers, texel plans from evaluated meshes, the
helper material. The numpy work is in ../lightmap (charts, rasterisation, plans, image sequences),
../io (image files, cache) and core.texels (evaluation at texels).

Per participating object:
- a UV map "HR_Lightmap" (made here by packing planar charts if the mesh has none; the user's own UV
  maps, the active one and the active render one are left as they are). A map the user made and
  named HR_Lightmap is used as is; one made here is re-packed when the mesh or resolution changes;
- one float image per distinct frame: the HR solution evaluated at the texel centres inside the UV
  triangles of the object's patches, plus a ring of texels just outside the islands evaluated at the
  nearest island point, then a few texels of dilation so that bilinear filtering and mip-maps do not
  pull in black (lightmap.plan);
- files <cache>/textures/<object>_<frame:06d>.exr (32-bit float, linear, ZIP) or .png (16-bit,
  sRGB-encoded, values above 1 clipped), written into the bake's temporary directory that replaces
  the cache at the end (see io.cache.CacheWriter), so a cancelled bake keeps the previous one.
The material helper (add_material) gives each object object-level copies of its materials with an
extra branch UV Map (HR_Lightmap) -> Image Texture (the sequence) -> Emission -> Material Output, all
plain nodes, so the result plays back where the extension is not installed.
"""

import hashlib
import math
import os
from contextlib import contextmanager

import bpy
import numpy as np

from ..io.cache import CacheError, CacheReader
from ..lightmap import TextureError
from ..lightmap.charts import MARGIN, NEAR_ANGLE, lightmap_size, pack_lightmap, surface_area
from ..core import parallel
from ..core.geometry import loop_tables
from ..lightmap.plan import TexturePlan, bake_bytes, bounded_density, gather_bytes, triangle_uvs
from ..io.images import srgb_to_linear
from ..lightmap.albedo import albedo_factor, mix_colour, sample_image, texel_uv
from .materials import albedo_texture
from .names import N_ATTR, N_PACK, N_TEX, N_UV, PREVIEW, TAG, UV_NAME
from .own_values import geometry_group
from .paths import bake_dir_abs, blend_relative, frame_texture
from .preview import emission_output, node_named
from .scene_in import evaluated, geometry_objects, mesh_topology
from .settings import DENSITY, TEXTURE_MEMORY

PACK_VERSION = 1


# --- lightmap UV layers --------------------------------------------------------------------------


def read_uv(me, name=UV_NAME):
    layer = me.uv_layers.get(name)
    if layer is None:
        return None
    uv = np.empty(len(me.loops) * 2, np.float32)
    layer.uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)


def _uv_signature(co, ls, lt, lv, scale, res):
    h = hashlib.sha1(f"{PACK_VERSION} {res} {MARGIN}".encode())
    for a in (co.astype(np.float32), ls, lt, lv, np.round(np.asarray(scale, float), 5)):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _uv_hash(uv):
    """The digest of a (L, 2) float32 UV array that the manifest keeps per object ("uv")."""
    return hashlib.sha1(np.ascontiguousarray(uv).tobytes()).hexdigest()


MIN_SIZE = 8  # the smallest lightmap the texel density gives
# (mesh, scale, density, largest size) digest -> (lightmap size, surface area): packed once per process
_sizes = {}


def resolution_for(obj, largest, density=0.0):
    """obj's lightmap size: its own Lightmap Size if set, else the size that gives its charts
    `density` texels per unit of world-space surface (charts.lightmap_size, MIN_SIZE to `largest`,
    the scene's Texture Size), or `largest` itself with density 0. The charts are those of its
    evaluated mesh where separate_copies lays the lightmap out there (the copies need room too)."""
    return _fit(obj, largest, density)[0]


def _fit(obj, largest, density):
    """(resolution_for's size, the surface area it was sized for: NaN where the density did not
    size it)."""
    r = int(getattr(obj.hr, "lightmap_resolution", 0) or 0)
    if r > 0:
        return r, math.nan
    if density <= 0 or obj.type != "MESH" or len(obj.data.polygons) == 0:
        return int(largest), math.nan
    if _pack_modifier(obj) is not None:
        _, (co, ls, lt, lv) = evaluated(obj, bpy.context.evaluated_depsgraph_get(), mesh_topology)
    else:
        co, ls, lt, lv = mesh_topology(obj.data)
    scale = np.array(obj.matrix_world.to_scale(), float)
    key = _uv_signature(co, ls, lt, lv, scale, f"{float(density)!r} {int(largest)}")
    if key not in _sizes:
        w = co * scale
        r = lightmap_size(w, ls, lt, lv, float(density), MIN_SIZE, int(largest))
        _sizes[key] = r, surface_area(w, ls, lt, lv)
    return _sizes[key]


def _sizer(largest, density):
    """_fit(obj, largest, density) per object, objects sharing a mesh sized as the first of them
    asked (ensure_lightmaps packs a shared mesh once, for its first object: a linked duplicate at
    another scale keeps the map's texel margins; its own area counts)."""
    first = {}

    def size(obj):
        if int(getattr(obj.hr, "lightmap_resolution", 0) or 0) > 0 or _pack_modifier(obj) is not None:
            return _fit(obj, largest, density)
        key = obj.data.name_full
        if key not in first:
            first[key] = _fit(obj, largest, density)
            return first[key]
        r, a = first[key]
        if not math.isnan(a):  # its own surface at its own scale
            co, ls, lt, lv = mesh_topology(obj.data)
            a = surface_area(co * np.array(obj.matrix_world.to_scale(), float), ls, lt, lv)
        return r, a

    return size


_bound = {}  # (largest, density, budget) -> the density scene_density last gave


def scene_bound(largest, density):
    """The density the scene's lightmaps were last sized at for these settings (scene_density in
    this session; else the density): what the object panel shows without sizing every object."""
    return _bound.get((int(largest), float(density), TEXTURE_MEMORY), density)


def scene_density(objects, largest, density, budget=None):
    """(density, sizes, note): the Texel Density the objects' lightmaps are sized at, their sizes
    {object.as_pointer(): size} (asked in the order of `objects`), and a note when the memory
    budget lowered the density, naming the objects that shrank. The bake's estimated peak memory
    (lightmap.plan.bake_bytes: the texels it will gather, from each object's surface at its
    density, plan.gathered_estimate, and the scene's polygons) stays within `budget` bytes
    (settings.TEXTURE_MEMORY): beyond it every object sized by area takes one lower density (the
    texels grow about as density^2: a few steps, each from the last estimate). Lightmap Sizes and
    the Texture Size stay; density 0 is not bound. The budget is fixed, not the machine's free
    memory, so the lightmaps are the same on every machine (check_memory refuses what does not
    fit there)."""
    budget = TEXTURE_MEMORY if budget is None else budget
    objs = [o for o in objects if o.type == "MESH" and len(o.data.polygons)]
    polygons = sum(len(o.data.polygons) for o in objs)

    made = {}

    def fits(d):
        if d not in made:
            fit = _sizer(largest, d)
            made[d] = np.array([fit(o) for o in objs], np.float64).reshape(-1, 2).T
        return made[d]

    want = fits(density)[0].astype(int)
    d, got, asked, total = bounded_density(fits, density, budget, polygons, DENSITY[0])
    _bound[(int(largest), float(density), budget)] = d
    got = got[0].astype(int)
    sizes = {o.as_pointer(): int(r) for o, r in zip(objs, got)}
    if d == density:
        return d, sizes, None
    shrunk = sorted((k for k in range(len(objs)) if got[k] < want[k]), key=lambda k: (-want[k], objs[k].name))
    names = ", ".join(f"'{objs[k].name}' {want[k]} -> {got[k]} px" for k in shrunk[:5])
    need, now = bake_bytes(asked, polygons) / 1e9, bake_bytes(total, polygons) / 1e9
    over = f" (still about {now:.3g} GB: Lightmap Sizes, the smallest sizes)" if now > budget / 1e9 else ""
    note = (
        f"Lightmaps: Texel Density {density:g} would gather about {asked / 1e6:.3g} M texels, about "
        f"{need:.3g} GB to bake, more than the texture memory budget of {budget / 1e9:.3g} GB: objects "
        f"sized by area get {d:.3g} texels/m{over}; {len(shrunk)} shrank, the largest {names}. A "
        "Lightmap Size (Object > HR Radiosity) keeps an object's own size."
    )
    return d, sizes, note


def lightmap_sizer(largest, density=0.0, objects=None):
    """The lightmap size per object (a function of the object): resolution_for at the scene's
    density (scene_density over `objects`, the bake's geometry_objects, in their order; None: the
    density as given, no bound). Its .density: the density it sizes at; .note: scene_density's
    note or None."""
    if objects is None:
        fit = _sizer(largest, density)

        def size(obj):
            return fit(obj)[0]

        size.density, size.note = density, None
        return size
    d, sizes, note = scene_density(objects, largest, density)
    other = _sizer(largest, d)

    def size(obj):
        n = sizes.get(obj.as_pointer())
        return other(obj)[0] if n is None else n

    size.density, size.note = d, note
    return size


def check_memory(plan, gather, density):
    """Raise TextureError, naming the objects with the most texels, when the final gather at the
    plan's gathered texels (gather: its settings, None: off; plan.gather_bytes) would need more
    memory than the system has free: before the gather starts, so the bake stops at once and the
    previous one stays.
    density: the scene's Texel Density (0: off, then the advice is to set one)."""
    if gather is None:
        return
    gathered = len(plan.gathered)
    need, room = gather_bytes(gathered, gather["rays"]), parallel.memory_headroom()
    if room is None or need <= room:
        return
    names = ", ".join(f"'{o.name}' ({o.res} px, {o.hi - o.lo:,} texels)" for o in plan.largest())
    lower = "lower the Texel Density" if density > 0 else "set a Texel Density (50 texels per metre: 2 cm)"
    raise TextureError(
        f"Texture output gathers {gathered / 1e6:.3g} M texels, about {need / 1e9:.3g} GB for the "
        f"final gather, and {room / 1e9:.3g} GB are free: {lower} or the Texture Size "
        f"(Render > HR Radiosity), or set a smaller Lightmap Size (Object > HR Radiosity) on the largest "
        f"objects: {names}."
    )


def ensure_lightmap(obj, res):
    """Make sure obj's mesh has the UV map HR_Lightmap. Returns a warning or None.

    A map made by the user is kept; one made here is re-packed when the mesh or the resolution
    changed. The active UV map and the active render UV map stay what they were."""
    me = obj.data
    layer = me.uv_layers.get(UV_NAME)
    if layer is not None and "hr_lightmap" not in me:
        return None  # the user's own lightmap UVs
    if len(me.polygons) == 0:
        return None
    co, ls, lt, lv = mesh_topology(me)
    scale = np.array(obj.matrix_world.to_scale(), float)
    sig = _uv_signature(co, ls, lt, lv, scale, res)
    if layer is not None and me.get("hr_lightmap") == sig:
        return None
    if obj.mode == "EDIT":
        raise TextureError(f"Object '{obj.name}' is in Edit Mode: leave it to make its {UV_NAME} UV map.")
    if me.library is not None or not me.is_editable:
        raise TextureError(
            f"Mesh '{me.name}' of object '{obj.name}' is not editable (linked): "
            f"give it a UV map named {UV_NAME} in its library file."
        )
    uv = pack_lightmap(co * scale, ls, lt, lv, res)
    active = me.uv_layers.active_index
    render = [lay.active_render for lay in me.uv_layers]
    if layer is None:
        layer = me.uv_layers.new(name=UV_NAME, do_init=False)
        if layer is None:
            raise TextureError(f"Mesh '{me.name}' cannot take another UV map (the limit is 8).")
    layer.uv.foreach_set("vector", np.ascontiguousarray(uv, np.float32).ravel())
    if render:  # restore the user's active / render UV maps
        me.uv_layers.active_index = active
        for lay, r in zip(list(me.uv_layers)[: len(render)], render):
            if r:
                lay.active_render = True
    me["hr_lightmap"] = sig
    me.update()
    return None


# --- lightmaps of modifier copies ---------------------------------------------------------------

COPIES = 1.05  # evaluated HR_Lightmap area over the mesh's own above which modifier copies overlap
PACK_GROUP_VERSION = 1


def _uv_area(uv, loop_start, loop_total):
    """Total unsigned UV area of a mesh's polygons (shoelace)."""
    lp, nxt = loop_tables(loop_start, loop_total)
    u = np.asarray(uv, np.float64)
    cross = u[:, 0] * u[nxt, 1] - u[nxt, 0] * u[:, 1]
    return float(np.abs(np.bincount(lp, cross, len(loop_start))).sum() / 2)


def copies_overlap(obj, depsgraph):
    """Whether obj's modifiers put parts of its mesh onto the same HR_Lightmap islands (Array and
    Mirror copies, Solidify's second shell carry the UVs of what they copy): its evaluated UVs
    cover more area than its mesh's own (Subdivision Surface and Bevel keep it)."""
    own = read_uv(obj.data)
    if own is None:
        return False
    _, (uv, (_, ls, lt, _)) = evaluated(obj, depsgraph, lambda me: (read_uv(me), mesh_topology(me)))
    _, ols, olt, _ = mesh_topology(obj.data)
    return uv is not None and _uv_area(uv, ls, lt) > COPIES * _uv_area(own, ols, olt)


def _pack_modifier(obj):
    md = obj.modifiers.get(N_PACK) if obj.type == "MESH" else None
    return md if md is not None and md.type == "NODES" else None


def _pack_group():
    """The node group of the N_PACK modifier: HR_Lightmap made anew on the evaluated mesh, charts cut
    where faces meet at more than charts.NEAR_ANGLE (as our own charts), unwrapped (Angle Based)
    and packed (Pack UV Islands, bounding boxes) with the modifier's Margin."""

    def value(nodes, link, gi):
        angle = nodes.new("GeometryNodeInputMeshEdgeAngle")
        seam = nodes.new("ShaderNodeMath")
        seam.operation = "GREATER_THAN"
        seam.inputs[1].default_value = np.radians(NEAR_ANGLE)
        link(angle.outputs["Unsigned Angle"], seam.inputs[0])
        unwrap = nodes.new("GeometryNodeUVUnwrap")
        link(seam.outputs[0], unwrap.inputs["Seam"])
        pack = nodes.new("GeometryNodeUVPackIslands")
        link(unwrap.outputs["UV"], pack.inputs["UV"])
        link(gi.outputs["Margin"], pack.inputs["Margin"])
        return (angle, seam, unwrap, pack), pack.outputs["UV"]

    store = (UV_NAME, "FLOAT2", "CORNER")
    return geometry_group(N_PACK, PACK_GROUP_VERSION, "Margin", "NodeSocketFloat", store, value)


def _border(obj, depsgraph, res):
    """Texels between the evaluated HR_Lightmap islands and the image's edge."""
    _, uv = evaluated(obj, depsgraph, read_uv)
    return res * float(min(uv.min(), 1 - uv.max())) if uv is not None and len(uv) else 0.0


def separate_copies(obj, largest, density, depsgraph):
    """Give the copies that obj's modifiers make (Array, Mirror, Solidify) texels of their own: a
    geometry-nodes modifier N_PACK, last in the stack, lays HR_Lightmap out on the evaluated mesh
    (_pack_group), its margin set for its lightmap size (resolution_for: islands about 2 x MARGIN
    texels apart, as charts.pack_lightmap packs them). Added where copies_overlap, kept once there
    (the user may remove it). density: the scene's (lightmap_sizer's .density). Returns a note
    when it is added, else None."""
    md, note = _pack_modifier(obj), None
    if md is None:
        if not len(obj.modifiers) or "hr_lightmap" not in obj.data or not copies_overlap(obj, depsgraph):
            return None  # no modifiers, the user's own lightmap UVs, or no copies
        md = obj.modifiers.new(N_PACK, "NODES")
        md.node_group = _pack_group()
        note = (
            f"Object '{obj.name}': its modifiers copy parts of its mesh onto the same {UV_NAME} islands; "
            f"the geometry-nodes modifier '{N_PACK}' added last to its stack lays the lightmap out on "
            "the result, so that every copy gets its own texels."
        )
    k = list(obj.modifiers).index(md)
    if k != len(obj.modifiers) - 1:
        obj.modifiers.move(k, len(obj.modifiers) - 1)
    res = resolution_for(obj, largest, density)  # of the evaluated mesh now
    key = md.node_group.interface.items_tree["Margin"].identifier
    # Pack UV Islands scales its margin with the islands (about margin x res / 2 texels between
    # them, half that to the image's edge): start there, correct from the measured edge
    margin = 4.0 * MARGIN / res
    for _ in range(3):
        md[key] = margin
        obj.update_tag()
        border = _border(obj, bpy.context.evaluated_depsgraph_get(), res)
        if border <= 0 or 0.9 * MARGIN <= border <= 1.5 * MARGIN:
            break
        margin *= MARGIN / border
    return note


def ensure_lightmaps(objects, largest, density=0.0):
    """The HR_Lightmap UV maps of the bake's objects (geometry_objects), each packed for its size
    (lightmap_sizer over them: the scene's bound may lower the density, its note is a warning)."""
    warnings = []
    for _ in range(2):  # again once a modifier N_PACK was added: the sizes of its evaluated mesh
        size, done, added = lightmap_sizer(largest, density, objects), set(), False
        for obj in objects:
            if obj.data.name_full not in done:
                done.add(obj.data.name_full)
                w = ensure_lightmap(obj, size(obj))
                if w:
                    warnings.append(w)
            if len(obj.data.polygons):
                w = separate_copies(obj, largest, size.density, bpy.context.evaluated_depsgraph_get())
                if w:
                    warnings.append(w)
                    added = True
        if not added:
            break
    return warnings + ([size.note] if size.note else [])


def _stems(names):
    out, used = {}, set()
    for n in names:
        base = bpy.path.clean_name(n) or "object"
        s, k = base, 1
        while s.lower() in used:
            s = f"{base}_{k}"
            k += 1
        used.add(s.lower())
        out[n] = s
    return out


# --- texel plans ---------------------------------------------------------------------------------


def _material_uvs(me):
    """{UV map name: (L, 2)} of a mesh, with "" for the active render map (the Image Texture's
    default), and the material index per polygon."""
    out = {}
    for lay in me.uv_layers:
        a = np.empty(len(me.loops) * 2, np.float32)
        lay.uv.foreach_get("vector", a)
        out[lay.name] = a.reshape(-1, 2)
        if lay.active_render:
            out[""] = out[lay.name]
    mi = np.zeros(len(me.polygons), np.int32)
    me.polygons.foreach_get("material_index", mi)
    return out, mi


def _albedo_specs(obj, warned, cache):
    """Per material slot of obj an AlbedoTexture or None; warns once per material that has a
    texture this cannot follow (it keeps the average colour). cache: material -> (spec, why), so
    a material shared by many objects reads its image once."""
    with source_materials([obj]):
        mats = [s.material for s in obj.material_slots]
    specs = []
    for m in mats:
        key = None if m is None else m.name_full
        if key not in cache:
            cache[key] = albedo_texture(m)
        spec, why = cache[key]
        if why and m.name not in warned:
            warned[m.name] = (
                f"Material '{m.name}': {why}; the baked texture shows its average colour (connect an "
                "Image Texture, optionally through one Mix node with a colour, to Base Color)."
            )
        specs.append(spec)
    return specs


def _albedo_factor(specs, uvs, mat_index, poly, loops, bary):
    """(N, 3) albedo / average at the texels (lightmap.albedo), 1 where no texture applies; None if
    no texel has a texture. poly (N,): each texel's polygon of the object; loops (N, 3), bary (N, 3):
    the texel point on the loops of its triangle."""
    slot = np.clip(mat_index[poly], 0, max(len(specs) - 1, 0)) if specs else np.zeros(len(poly), int)
    factor = np.ones((len(poly), 3), np.float32)
    hit = False
    for k, spec in enumerate(specs):
        sel = np.flatnonzero(slot == k)
        if spec is None or not len(sel) or spec.uv_map not in uvs:
            continue
        uv = texel_uv(uvs[spec.uv_map], loops[sel], bary[sel])
        tex = sample_image(spec.pixels, uv, spec.interpolation, spec.extension)
        tex = mix_colour(srgb_to_linear(tex) if spec.srgb else tex, spec.mix)
        factor[sel] = albedo_factor(tex, spec.average)
        hit = True
    return factor if hit else None


def texture_plan(scene_in, patches, view_layer, depsgraph, largest, fmt="EXR", albedo=False, density=0.0):
    """The bake's TexturePlan: every target object's evaluated HR_Lightmap UVs on its patches,
    each object's lightmap size resolution_for(largest, density).
    albedo: textured materials (materials.albedo_texture) modulate their objects' texels by the
    texture's albedo / its average (radiance mode)."""
    plan = TexturePlan(fmt)
    warned, specs_of, size = {}, {}, lightmap_sizer(largest, density, geometry_objects(view_layer))
    mesh = scene_in.mesh
    stems = _stems([t.name for t in scene_in.targets])
    for oid, t in enumerate(scene_in.targets):
        obj = view_layer.objects.get(t.name) or bpy.data.objects[t.name]
        p0 = int(np.searchsorted(mesh.loop_start, t.loops[0]))
        p1 = (
            int(np.searchsorted(mesh.loop_start, t.loops[1]))
            if t.loops[1] < len(mesh.loop_verts)
            else len(mesh.loop_start)
        )
        specs = _albedo_specs(obj, warned, specs_of) if albedo else []
        want = any(sp is not None for sp in specs)
        _, (uv, (_, ls, lt, lv), mat_uvs) = evaluated(
            obj, depsgraph, lambda me: (read_uv(me), mesh_topology(me), _material_uvs(me) if want else None)
        )
        if uv is None:
            plan.warnings.append(
                f"Object '{t.name}': its evaluated mesh has no {UV_NAME} UV map "
                "(a modifier removed it); no texture."
            )
            continue
        if len(ls) != p1 - p0 or len(lv) != t.loops[1] - t.loops[0]:
            plan.warnings.append(f"Object '{t.name}': mesh changed while reading; no texture.")
            continue
        copied = len(obj.data.loops) != len(lv) and _pack_modifier(obj) is None
        if copied and copies_overlap(obj, depsgraph):
            plan.warnings.append(
                f"Object '{t.name}': its modifiers copy parts of its mesh onto the same {UV_NAME} "
                "islands (its own lightmap UVs): the copies show one light (apply the modifiers)."
            )
        tri_uv, corners, tri_patch, skipped, tri_loops = triangle_uvs(
            patches, oid, uv, ls, lt, lv, p0, t.verts[0], t.verts[1] - t.verts[0], loops=True
        )
        if skipped:
            plan.warnings.append(f"Object '{t.name}': {skipped} triangle(s) without UVs skipped.")
        placed = plan.add_object(
            t.name,
            stems[t.name],
            size(obj),
            tri_uv,
            corners,
            tri_patch,
            _uv_hash(uv),
        )
        if want:
            tri, bary = placed
            uvs, mi = mat_uvs
            missing = {sp.uv_map for sp in specs if sp is not None and sp.uv_map not in uvs}
            for name in sorted(missing):
                plan.warnings.append(
                    f"Object '{t.name}': its material's texture uses the UV map '{name or 'default'}', "
                    "which the mesh does not have; the baked texture shows the average colour."
                )
            poly = patches.poly[tri_patch[tri]] - p0
            f = _albedo_factor(specs, uvs, mi, poly, tri_loops[tri], bary)
            if f is not None:
                plan.set_albedo(len(plan.objects) - 1, f)
    plan.warnings += list(warned.values())
    return plan


# --- material helper -----------------------------------------------------------------------------


def _manifest(scene):
    directory = bake_dir_abs(scene)
    if not directory:
        raise CacheError("No radiosity bake: bake first.")
    reader = CacheReader(directory)
    if reader.manifest.get("output") != "TEXTURE":
        raise CacheError(
            "The radiosity bake holds vertex colours, not textures (Output: Baked Textures, then bake)."
        )
    return directory, reader


def is_texture_bake(scene):
    try:
        _manifest(scene)
        return True
    except CacheError:
        return False


def _sequence_image(obj, path, fmt):
    img = next((i for i in bpy.data.images if i.get(TAG) == obj.name), None)
    if img is None:
        img = bpy.data.images.new(f"HR Lightmap {obj.name}", 4, 4, float_buffer=True)
        img[TAG] = obj.name
    fp = blend_relative(path)
    img.source = "FILE"
    img.filepath = fp
    img.source = "SEQUENCE"
    for name in ("sRGB",) if fmt == "PNG" else ("Linear Rec.709", "Linear"):
        try:
            img.colorspace_settings.name = name  # PNG files are sRGB-encoded, EXR linear
            break
        except TypeError:  # colour space not in this configuration
            pass
    img.reload()
    return img


def _wire(mat, img, first, last, mode="RADIANCE"):
    """Add (or update) UV Map -> Image Texture -> Emission -> Material Output, the active output;
    for an irradiance bake the image times the material's base colour plus its emission feeds the
    Emission, for Indirect only that Emission is added to the material's own shader
    (preview.emission_output)."""
    if mat.node_tree is None or (bpy.app.version < (5, 0, 0) and not mat.use_nodes):
        mat.use_nodes = True
    tree = mat.node_tree
    if N_ATTR in tree.nodes:  # a vertex-colour preview copied from the material
        tree.nodes.remove(tree.nodes[N_ATTR])
    x = max((n.location.x for n in tree.nodes if not n.name.startswith(PREVIEW)), default=0) + 300
    uvn = node_named(tree, N_UV, "ShaderNodeUVMap", (x, -400))
    uvn.uv_map = UV_NAME
    tex = node_named(tree, N_TEX, "ShaderNodeTexImage", (x + 200, -400))
    tex.image = img
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    iu = tex.image_user
    iu.frame_duration = last - first + 1
    iu.frame_start = first
    iu.frame_offset = first - 1
    iu.use_cyclic = False
    iu.use_auto_refresh = True
    tree.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    emission_output(mat, tree, tex.outputs["Color"], x + 900, mode)


def _helper(slot):
    m = slot.material
    return m if slot.link == "OBJECT" and m is not None and m.get(TAG) is not None else None


def _helper_slots(obj):
    """(slot, helper material) of each of obj's slots that shows a helper copy."""
    return [(slot, m) for slot in obj.material_slots if (m := _helper(slot)) is not None]


def _show_source(slot, m, clear=False):
    """The slot shows again what the helper m stands in for: the object's own material (link
    OBJECT) or the mesh's (link DATA; clear: the object's slot emptied first)."""
    if m.get("hr_lightmap_link", "DATA") == "OBJECT":
        slot.material = m.get("hr_lightmap_source")
    else:
        if clear:
            slot.material = None
        slot.link = "DATA"


def uv_digest(obj, depsgraph):
    """Digest of obj's evaluated HR_Lightmap UVs, as the bake computes it (None: no such map)."""
    _, uv = evaluated(obj, depsgraph, read_uv)
    return None if uv is None else _uv_hash(uv)


def restore_lightmaps(reader, objects):
    """Make the HR_Lightmap UV map again on the objects of a texture bake that lack it (a bake from
    the command line without --save made it in its own process only). The packing is a function of
    the mesh, its scale and the resolution the manifest keeps, so the map comes out as it was; the
    digest in the manifest tells whether it did. Returns warnings naming the objects that differ."""
    made, warnings = [], []
    for obj in objects:
        info = reader.objects.get(obj.name)
        if info is None or obj.type != "MESH" or obj.data.uv_layers.get(UV_NAME) is not None:
            continue
        try:
            ensure_lightmap(obj, info.get("resolution") or 128)
        except TextureError as exc:
            warnings.append(str(exc))
            continue
        made.append(obj)
    if made:
        dg = bpy.context.evaluated_depsgraph_get()
        changed = [o.name for o in made if reader.objects[o.name].get("uv") not in (None, uv_digest(o, dg))]
        if changed:
            warnings.append(
                f"The {UV_NAME} UV map made again differs from the bake's on {', '.join(map(repr, changed))} "
                "(the mesh changed since the bake?): re-bake."
            )
    return warnings


def add_material(scene, objects=None, warnings=None):
    """Show the scene's texture bake: every object of the bake gets, per material slot, an
    object-level copy of its material whose active output is UV Map (HR_Lightmap) -> Image Texture
    (the image sequence) -> Emission. The mesh's materials are untouched; a lost HR_Lightmap UV map
    is made again (restore_lightmaps; its warnings go to `warnings`). Returns the number of
    objects wired; raises CacheError without a texture bake."""
    directory, reader = _manifest(scene)
    w = restore_lightmaps(reader, [o for o in scene.objects if objects is None or o in objects])
    if warnings is not None:
        warnings += w
    first, last = reader.frame_range
    mode = reader.manifest.get("radiance_mode", "RADIANCE")
    names = None if objects is None else {o.name for o in objects}
    n = 0
    for name, info in reader.objects.items():
        if names is not None and name not in names:
            continue
        obj = scene.objects.get(name)
        if obj is None or obj.type != "MESH":
            continue
        path = frame_texture(directory, info, first)
        if path is None:
            continue
        img = _sequence_image(obj, path, info.get("format", "EXR"))
        if not obj.material_slots:
            obj.data.materials.append(None)
            obj["hr_lightmap_slot"] = len(obj.material_slots) - 1
        for slot in obj.material_slots:
            mat = _helper(slot)
            if mat is None:
                src, link = slot.material, slot.link
                if src is not None:
                    mat = src.copy()
                    mat.name = f"{src.name} (HR {obj.name})"
                else:
                    mat = bpy.data.materials.new(f"HR Lightmap {obj.name}")
                    mat["hr_preview"] = True  # read as "no material" by the bake
                mat[TAG] = obj.name
                mat["hr_lightmap_link"] = link
                if link == "OBJECT" and src is not None:
                    mat["hr_lightmap_source"] = src
                slot.link = "OBJECT"
                slot.material = mat
            _wire(mat, img, first, last, mode)
        n += 1
    return n


def remove_material(objects=None):
    """Undo add_material: the slots show the mesh's (or the object's own) materials again."""
    n = 0
    for obj in list(bpy.data.objects if objects is None else objects):
        if obj.type != "MESH":
            continue
        hit = False
        for slot, m in _helper_slots(obj):
            hit = True
            _show_source(slot, m, clear=True)
            if m.users == 0:
                bpy.data.materials.remove(m)
        k = obj.get("hr_lightmap_slot")
        if k is not None:
            if 0 <= k < len(obj.data.materials) and obj.data.materials[k] is None:
                obj.data.materials.pop(index=k)
            del obj["hr_lightmap_slot"]
        n += hit
    for m in [m for m in bpy.data.materials if m.get(TAG) is not None and m.users == 0]:
        bpy.data.materials.remove(m)
    for img in [i for i in bpy.data.images if i.get(TAG) is not None and i.users == 0]:
        bpy.data.images.remove(img)
    return n


@contextmanager
def source_materials(objects):
    """While reading the scene, slots show the materials the helper copies stand in for."""
    saved = []
    for obj in objects:
        for slot, m in _helper_slots(obj):
            saved.append((slot, m))
            _show_source(slot, m)
    try:
        yield
    finally:
        for slot, m in saved:
            slot.link = "OBJECT"
            slot.material = m


def after_bake(scene, directory):
    """Reload the images of the cache and re-wire existing helper materials (new frame range)."""
    d = os.path.normcase(os.path.abspath(directory))
    for img in bpy.data.images:
        if img.get(TAG) is not None and img.filepath:
            p = os.path.normcase(os.path.abspath(bpy.path.abspath(img.filepath)))
            if p.startswith(d):
                img.reload()
    wired = [o for o in scene.objects if o.type == "MESH" and any(_helper(s) for s in o.material_slots)]
    if wired:
        try:
            add_material(scene, wired)
        except CacheError:
            pass


def lightmap_key(snap, view_layer, largest, density=0.0):
    """The texel gather's dependence on the lightmaps: each target's resolution and UV digest."""
    out, size = {}, lightmap_sizer(largest, density, geometry_objects(view_layer))
    for t in snap.scene_in.targets:
        obj = view_layer.objects.get(t.name) or bpy.data.objects[t.name]
        uv = uv_digest(obj, view_layer.depsgraph)
        out[t.name] = f"{size(obj)} px, uv {uv}"
    return out
