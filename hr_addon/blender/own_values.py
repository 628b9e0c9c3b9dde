"""Vertex output where an object's mesh cannot hold its values: objects whose modifiers change the
topology (Subdivision Surface, Solidify, Bevel, Array, Mirror) and linked duplicates (one mesh,
several objects).

HR_Radiance lives on the mesh. The modifiers interpolate the original mesh's values again (a
subdivided face shows its cage's corners, Solidify's second shell and Array / Mirror copies the
light of what they copy: the artist room's sofa back +22%, its shelf +22% against Cycles), and a
mesh shared by several objects holds one object's values (a linked book +46%). Such an object gets
a helper object "HR Radiance <object>" (in no scene: nothing renders it) whose mesh has the
topology of the object's evaluated mesh, and a geometry-nodes modifier "HR Radiance", last in the
object's stack, that stores the helper's HR_Radiance as the evaluated mesh's: every evaluated
corner (or vertex) shows its own value. The bake and Live write the values into the helper like into
any mesh (Target.key names it; playback.objects_by_name finds it in bpy.data), so playback, renders
and a file opened without the extension show them.

Vertex Spacing (Scene.hr.vertex_spacing > 0): a value per corner cannot show light that changes
across a coarse face (a one-quad wall, a table top: the furnished room's vertex output 62-67% of
its objects within 5% of Cycles from a camera, docs/accuracy.md). Objects with an edge longer than
the spacing get the modifier too, in the group that first subdivides their coarse faces: each face
by the level its own longest edge needs to come under the spacing (Subdivide Mesh per level class:
linear, planar faces stay where they were; a book's short faces stay as they are beside its long
ones). The classes are joined again and the vertices their seams had in common merged; a coarser
face's edge keeps a T-junction with a finer neighbour's (no crack: the finer vertices lie on it).
The light is gathered at the finer corners and shown there. With the final gather the hierarchy
(patches, links, contacts, the second level's samples) is built on the mesh the modifier receives
(before_subdivision; session 22, branch dec25): only the corner samples lie on the finer mesh
(core.gather.OutputLayout). Without it the hierarchy's leaves are the output, so the bake uses no
spacing there (settings.BakeConfig.spacing: the classic output stays the mesh's own corners).
0.25 m is the default since session 23 (branch def26); the objects subdivided are named in a log
line, not a warning. Live Relight makes no helpers; once a bake has added them it uses the same
split (live_session._build: collect_geometry(transport=True), live_worker.BuildSpec.output).

A corner budget (corner_budget; session 23, branch vx26): the level is capped per face (MAX_LEVEL),
not per scene, so a large object of many faces (a 1 km terrain of 10 m quads) would get 4^6 faces
per face at 0.25 m. The corners the spacing would make are counted first (the group's level rule,
numpy over each object's faces); when the scene's total would exceed BUDGET_FACTOR x the scene's
own corners (at least BUDGET_FLOOR, at most BUDGET_CAP), one common spacing is raised until it
fits, and what that leaves goes to the smallest steps finer (session 31, branch vbudget: before,
the largest objects' spacings were raised first, so at 0.1 m the furnished room's walls, floor and
ceiling got no subdivision while its books kept theirs); one log line names them with their
spacings. A normal room is within it at 0.15 m.

Playback (session 32, branch playfix): the helper holds the subdivided mesh already, so while the
mesh the group receives is the one the bake subdivided (a hash per corner, GUARD, the same as the
helper's: _from_helper) the group outputs the helper's mesh instead of subdividing again at every
frame change (the 100k room's 2,413 objects: ~3 s of a 4.5 s change). The helper keeps the
object's materials (sync_materials) so the evaluated mesh's are right. An edit after the bake
(positions, UVs and the other attributes the guard reads, material indices, a deforming modifier
or shape key below the group) changes the hash: the group subdivides it, as before; the next bake
makes the helper anew.

Where the light changes (near_clutter; session 31, branch vbudget; per face since session 32, branch
clutter): a face other surfaces cover in part within a spacing in front (a wall behind a bookcase's
books, a floor under furniture, a back panel between shelf boards: rays from points about the finer
spacing apart, along its normal and tilted 45 degrees; some occluded, some not) gets up to
CLUTTER_LEVELS levels finer: the integer face attribute FINER ("HR_Finer") the bake writes on the
user's mesh, which the group's level rule reads (each face at spacing / 2^FINER; 0 where absent), so
the corners go only to those faces (session 31 gave whole objects spacing / 4: the furnished floor
35k corners for 5.7 of its 27 m^2). A ray that meets a surface holding one of the face's edges (a
wall standing on the floor's edge: a concave junction) does not count (session 33, branch outline:
the small rooms' floors, walls and ceilings were cut along every junction). Faces a light shape's
outline crosses, or a spot light's cone lights in part, on any frame of the scene's range
(lights_in.light_edges) weigh 1 too: the light changes across them. From what the budget leaves
(since session 33 no share of the scene's corners: until then 1 x its corners at the spacing, which
an object far away raised), each face as many levels as its area, weighed by how much of it is in
part, is worth per corner added (CLUTTER_WORTH), the most such area per corner first. Not for a
mesh several objects share nor one whose modifiers change its faces (their faces are not the
mesh's). Taken once, where the bake starts (the scene's first frame): the corners stay static;
Delete Bake removes FINER with the modifier. FINER is one of the mesh's attributes the playback
guard hashes (_guard_names): a re-bake that changes it makes the helper anew.
"""

import functools
import heapq
from functools import partial

import bpy
import numpy as np

from .names import ATTRIBUTE, FACE, FINER, GUARD, N_VALUES, TAG

GROUP_VERSION = 1
# the subdividing group by faces (SPACING, SCALE) storing FACE, each face finer by the mesh's FINER,
# its output the helper's mesh while the guard holds (_from_helper: GUARD the corners' hashes' sum
# and variance); 8: an n-gon's level by its span too (_ngon_span); 6: GUARD a hash per corner; 5:
# the GUARDS slots always hashed, 4: without FINER, 3: always subdividing, 2: without FACE, 1: one
# LEVEL_V1 per object
FINER_VERSION = 8
GUARD_DOMAIN = "POINT"  # GUARD's (one value: on each point, read at index 0)
GUARDED = 4  # the subdividing group's string inputs "Attribute 1" ..: the received mesh's own
GUARDS = "Attribute"  # attributes its guard hashes too (_guard_names; more: no guard, _helper)
SPACING = "Spacing"  # the subdividing group's inputs: the spacing (m; 0: no subdivision) and
SCALE = "Scale"  # the object's scale at the bake (edges in world metres; fixed: a fixed topology)
MAX_LEVEL = 6  # 4^6 faces per face: a 6.4 m quad at 0.1 m; coarser faces keep longer edges
LEVEL_V1 = "Level"  # version 1's input: one Subdivide Mesh level for the whole object
MERGE = 1e-6  # seam vertices this close (object units) are one again: the same corner, split
# the corner budget (corner_budget): the finer corners of a scene at most BUDGET_FACTOR x its own
# corners, never less than BUDGET_FLOOR and never more than BUDGET_CAP (docs/accuracy.md, session 23:
# a corner added costs 1.7-5.0 KB of the bake's peak, furnished 20k at 0.35-0.15 m, 2.2 KB at 0.15 m:
# 1 M corners some 2-5 GB over spacing 0's; the furnished 20k, 100k and artist rooms at 0.15 m make
# 6.0, 4.4 and 5.4 x their own corners: within x8; a small scene may always have 200,000, the 20k
# room's at 0.2 m, 1.16 GB)
BUDGET_FACTOR = 8.0
BUDGET_FLOOR = 200_000
BUDGET_CAP = 1_000_000
RAISE = 1 + 2**-20  # a raised spacing this much above a face's threshold: its level is off (float32)
# light where it varies (near_clutter; session 31, branch vbudget, per face since session 32, branch
# clutter; docs/accuracy.md): a face covered in part close in front (a wall's behind a bookcase's
# books) gets the spacing / 2^CLUTTER_LEVELS (the furnished close view's wall_north, its 0.23 m grid
# behind books 5-18 cm off it: -36% against Cycles at frame 3 at 0.25 m), the largest faces first
CLUTTER_LEVELS = 2
# ... from what the budget leaves (no share of the scene's corners: until session 33 at most 1 x
# the corners at the spacing, which an object far away raised), each face as many levels finer as
# add at most 1 / CLUTTER_WORTH x the corners a grid of quads at the finest spacing over its weighed
# area has (4 a quad): not a thin face Subdivide Mesh already cut finely across (a 0.4 x 1.6 m side
# at level 3: one level; a book's spine: none)
CLUTTER_WORTH = 0.5
# ... but a thin face (a bottle's 24 x 1.4 cm side, a book's spine) by its length, not its area: its
# every level a choice (the budget takes them last: the least area per corner). Its two corner rows
# cannot show a shadow's edge across it, which a camera sees where only part of it shows (two_rooms'
# bottles behind the table's items, -6 to -13% at 0.25 m; docs/accuracy.md, session 34, branch tworooms)
THIN_RATIO = 4.0
# the thin faces' corners added: at most this share of the scene's corners at the spacing (of BUDGET_FLOOR in
# a smaller scene): the furnished sample's books took 134k -> 256k corners without it
THIN_SHARE = 0.1
THIN_LEVEL = 1  # a thin face at most this level at the spacing (the pillar's 2.6 m strips: not)
CLUTTER_REACH = 1.0  # near_clutter's rays this many spacings long: surfaces closer are "close in front"
CLUTTER_GRID = 32  # near_clutter's points: a triangle cut into at most this many pieces along an edge
# near_clutter's rays that meet a surface holding one of their face's edges (within JUNCTION x the
# spacing: a wall standing on the floor's edge) do not count: a concave junction, not a shadow's edge
JUNCTION = 0.01
# faces close to a Blender point or spot light (light_edges' cones but suns' and area lights'): its
# light falls off as 1 / d^2 across a face as large as its distance, and a corner's value, read
# OUTPUT_INSET of the way into the face (core.gather.layouts), is not the light at the corner: the
# loft's lamp shade, 28 cm faces 16 cm from the bulb, cut once by the spacing, read its inside +25%
# along the rim a camera sees (docs/accuracy.md, session 37). Such a face gets up to CLUTTER_LEVELS
# levels finer, the fewest that leave pieces at most NEAR_LIGHT x its centre's distance from the
# light (near_light_finer)
NEAR_LIGHT = 0.25


def geometry_group(name, version, socket, socket_type, store, value, finer=False, output=None):
    """The geometry-node group `name`, made anew unless one tagged with `version` exists: inputs
    Geometry and `socket` (of `socket_type`), output the Geometry with the named attribute `store`
    = (name, data type, domain) set to value(nodes, link, group input) -> (the nodes it made, the
    socket of the value). finer: inputs SPACING and SCALE too, and the geometry's coarse faces
    subdivided first (_finer_faces). output: output(group, nodes, link, group input, that geometry)
    -> (the nodes it made, the socket the group outputs instead). Plain nodes: a file opened
    without the extension evaluates the same."""
    g = bpy.data.node_groups.get(name)
    if g is not None and g.get(TAG) == version:
        return g
    if g is not None:  # an older version's: renamed, so the new one gets the name (users keep theirs)
        g.name = f"{name} (v{g.get(TAG)})"
    g = bpy.data.node_groups.new(name, "GeometryNodeTree")
    g[TAG] = version
    g.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    g.interface.new_socket(socket, in_out="INPUT", socket_type=socket_type)
    if finer:
        g.interface.new_socket(SPACING, in_out="INPUT", socket_type="NodeSocketFloat").min_value = 0
        g.interface.new_socket(SCALE, in_out="INPUT", socket_type="NodeSocketVector").default_value = (
            1,
            1,
            1,
        )
    g.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, link = g.nodes, g.links.new
    gi, go = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    geometry, first = gi.outputs["Geometry"], []
    if finer:
        first, geometry = _finer_faces(nodes, link, gi)
    made, out = value(nodes, link, gi)
    st = nodes.new("GeometryNodeStoreNamedAttribute")
    attribute, st.data_type, st.domain = store
    st.inputs["Name"].default_value = attribute
    link(geometry, st.inputs["Geometry"])
    link(out, st.inputs["Value"])
    last, after = st.outputs["Geometry"], []
    if output is not None:
        after, last = output(g, nodes, link, gi, last)
    link(last, go.inputs["Geometry"])
    for k, nd in enumerate((gi, *first, *made, st, *after, go)):
        nd.location = (200 * k, 0)
    return g


def _add_node(nodes, made, kind, **props):
    """A new node of `kind` in `nodes` with these properties, appended to `made`."""
    nd = nodes.new(kind)
    for k, v in props.items():
        setattr(nd, k, v)
    made.append(nd)
    return nd


def _finer_faces(nodes, link, gi):
    """Nodes subdividing the group input's faces each by the level L its longest edge needs (edge
    * SCALE, metres) to come under SPACING: L = the number of k in 0 .. MAX_LEVEL - 1 for which an
    edge of the face (or an n-gon's span, _ngon_span) is longer than SPACING * 2^k (0 for SPACING
    0). The faces of each level class
    are separated and subdivided together (Subdivide Mesh), joined in a fixed order, and the
    vertices on the classes' seams (captured before: their faces' levels differ) merged again.
    Each face's index is stored first as FACE (Subdivide Mesh gives it to the finer faces).
    Returns (the nodes, the output geometry socket)."""
    made = []
    node = partial(_add_node, nodes, made)

    def math(op, a, b, c=None):
        nd = node("ShaderNodeMath", operation=op)
        for i, x in enumerate((a, b, c)[: 3 if c is not None else 2]):
            if isinstance(x, (int, float)):
                nd.inputs[i].default_value = x
            else:
                link(x, nd.inputs[i])
        return nd.outputs[0]

    def on(domain, field, kind="FLOAT"):  # the field evaluated on `domain` (read elsewhere: its mean there)
        nd = node("GeometryNodeFieldOnDomain", domain=domain, data_type=kind)
        link(field, nd.inputs[0])
        return nd.outputs[0]

    def vec(op, a, b):
        nd = node("ShaderNodeVectorMath", operation=op)
        link(a, nd.inputs[0])
        link(b, nd.inputs[1])
        return nd.outputs[0]

    spacing = gi.outputs[SPACING]
    ends = node("GeometryNodeInputMeshEdgeVertices")
    d = node("ShaderNodeVectorMath", operation="SUBTRACT")
    link(ends.outputs["Position 1"], d.inputs[0])
    link(ends.outputs["Position 2"], d.inputs[1])
    ds = node("ShaderNodeVectorMath", operation="MULTIPLY")
    link(d.outputs[0], ds.inputs[0])
    link(gi.outputs[SCALE], ds.inputs[1])
    length = node("ShaderNodeVectorMath", operation="LENGTH")
    link(ds.outputs[0], length.inputs[0])
    edge = math("MULTIPLY", length.outputs["Value"], math("GREATER_THAN", spacing, 0.0))  # 0: none
    # an n-gon's span (_ngon_span) at each of its corners: |P + P_next - 2 C| x SCALE, C the face's
    # mean position, P_next the next corner's (0 on a triangle or quad: their levels as before)
    pos = node("GeometryNodeInputPosition").outputs[0]
    nxt = node("GeometryNodeOffsetCornerInFace")
    link(node("GeometryNodeInputIndex").outputs[0], nxt.inputs["Corner Index"])
    nxt.inputs["Offset"].default_value = 1
    at = node("GeometryNodeFieldAtIndex", domain="CORNER", data_type="FLOAT_VECTOR")
    link(pos, at.inputs["Value"])
    link(nxt.outputs[0], at.inputs["Index"])
    centre = on("FACE", pos, "FLOAT_VECTOR")
    arm = vec("SUBTRACT", vec("ADD", pos, at.outputs[0]), vec("ADD", centre, centre))
    span = node("ShaderNodeVectorMath", operation="LENGTH")
    link(vec("MULTIPLY", arm, gi.outputs[SCALE]), span.inputs[0])
    ngon = math("GREATER_THAN", node("GeometryNodeInputMeshFaceNeighbors").outputs["Vertex Count"], 4.5)
    span = math("MULTIPLY", math("MULTIPLY", span.outputs["Value"], ngon), math("GREATER_THAN", spacing, 0.0))
    # the face's FINER e (the mesh's face attribute near_clutter's faces get; 0 where absent): its
    # level counts the k in -e .. MAX_LEVEL - 1 - e, at SPACING / 2^e what k in 0 .. MAX_LEVEL - 1 is
    finer = node("GeometryNodeInputNamedAttribute", data_type="INT")
    finer.inputs["Name"].default_value = FINER
    e = on("FACE", finer.outputs["Attribute"])
    level = None
    for k in range(-CLUTTER_LEVELS, MAX_LEVEL):  # any edge of the face (or an n-gon's span at any
        # corner) longer than SPACING * 2^k: their mean on the face > 0
        at_k = math("MULTIPLY", spacing, float(2.0**k))
        longer = on("EDGE", math("GREATER_THAN", edge, at_k))
        wider = on("CORNER", math("GREATER_THAN", span, at_k))
        step = math("GREATER_THAN", math("ADD", on("FACE", longer), on("FACE", wider)), 0.0)
        if k < 0:  # counted where e >= -k
            step = math("MULTIPLY", step, math("GREATER_THAN", e, -k - 0.5))
        if k > MAX_LEVEL - 1 - CLUTTER_LEVELS:  # counted where e <= MAX_LEVEL - 1 - k
            step = math("MULTIPLY", step, math("LESS_THAN", e, MAX_LEVEL - k - 0.5))
        level = step if level is None else math("ADD", level, step)
    level = on("FACE", level)
    # a seam vertex: its faces' levels differ (their mean square above their mean's square)
    mean = on("POINT", level)
    square = on("FACE", math("MULTIPLY", level, level))  # (squared on the faces, then averaged)
    spread = math("SUBTRACT", on("POINT", square), math("MULTIPLY", mean, mean))
    seam = on("POINT", math("GREATER_THAN", spread, 1e-3))
    face = node("GeometryNodeStoreNamedAttribute", data_type="INT", domain="FACE")
    face.inputs["Name"].default_value = FACE
    link(gi.outputs["Geometry"], face.inputs["Geometry"])
    link(node("GeometryNodeInputIndex").outputs[0], face.inputs["Value"])
    cap = node("GeometryNodeCaptureAttribute", domain="POINT")
    cap.capture_items.new("BOOLEAN", "Seam")
    link(face.outputs["Geometry"], cap.inputs["Geometry"])
    link(seam, cap.inputs[1])
    join = node("GeometryNodeJoinGeometry")
    rest, parts = cap.outputs["Geometry"], []
    for k in range(1, MAX_LEVEL + 1):
        sep = node("GeometryNodeSeparateGeometry", domain="FACE")
        link(rest, sep.inputs["Geometry"])
        link(math("COMPARE", level, float(k), 0.5), sep.inputs["Selection"])
        sub = node("GeometryNodeSubdivideMesh")
        link(sep.outputs["Selection"], sub.inputs["Mesh"])
        sub.inputs["Level"].default_value = k
        parts.append(sub.outputs["Mesh"])
        rest = sep.outputs["Inverted"]
    for part in reversed([rest, *parts]):  # (a multi-input socket lists its links last first)
        link(part, join.inputs[0])
    merge = node("GeometryNodeMergeByDistance")  # (mode All, the default)
    link(join.outputs[0], merge.inputs["Geometry"])
    link(cap.outputs[1], merge.inputs["Selection"])
    merge.inputs["Distance"].default_value = MERGE
    return made, merge.outputs["Geometry"]


def _version(finer):
    return FINER_VERSION if finer else GROUP_VERSION


def _group_name(domain, finer):
    return f"{N_VALUES} {domain.lower()}" + (" subdivided" if finer else "")


def _group(domain, finer=False):
    """Node group: HR_Radiance = the helper's HR_Radiance at the same index, on `domain`; finer:
    of the mesh whose coarse faces are subdivided first (_finer_faces)."""

    def value(nodes, link, gi):
        info = nodes.new("GeometryNodeObjectInfo")
        link(gi.outputs["Values"], info.inputs["Object"])
        attr = nodes.new("GeometryNodeInputNamedAttribute")
        attr.data_type = "FLOAT_COLOR"
        attr.inputs["Name"].default_value = ATTRIBUTE
        sample = nodes.new("GeometryNodeSampleIndex")
        sample.data_type, sample.domain = "FLOAT_COLOR", domain
        link(info.outputs["Geometry"], sample.inputs["Geometry"])
        link(attr.outputs["Attribute"], sample.inputs[1])
        link(nodes.new("GeometryNodeInputIndex").outputs[0], sample.inputs["Index"])
        return (info, attr, sample), sample.outputs[0]

    store = (ATTRIBUTE, "FLOAT_COLOR", domain)
    return geometry_group(
        _group_name(domain, finer),
        _version(finer),
        "Values",
        "NodeSocketObject",
        store,
        value,
        finer,
        _from_helper if finer else None,
    )


def _hashed(node, link, value, seed, kind):
    """The Hash output of a new Hash Value node (node: a partial _add_node) of value (`kind`),
    seeded by seed unless None."""
    h = node("FunctionNodeHashValue", data_type=kind)
    link(value, h.inputs["Value"])
    if seed is not None:
        link(seed, h.inputs["Seed"])
    return h.outputs["Hash"]


def _from_helper(g, nodes, link, gi, subdivided):
    """The subdividing group's output end: the helper's mesh itself (Object Info, Original) while
    the mesh the group receives is the one the helper was made from, else `subdivided` (its faces
    subdivided, the values stored) with GUARD stored on it. GUARD: the sum and the variance (float32,
    Attribute Statistic) of a hash per corner of the mesh received (seeded by its domain sizes,
    SPACING and SCALE: each corner's position, vertex, face, material index, smoothness and the
    attributes the GUARDS inputs name, if any), on every GUARD_DOMAIN element; the guard holds when
    the helper's mesh has the same GUARD (version 6: the hashes per corner, compared at every corner
    index: 1.23 against 1.06 s per write of the baked 100k room, docs/live.md, session 33; an edit
    goes unseen only if both sums round to the same floats). The helper's mesh is the bake's
    subdivided one (_helper), with the object's materials and its HR_Radiance written every frame:
    the same mesh and values without subdividing again (docs/scale.md, sessions 31-32: a frame
    change at 100k 4.5 -> 1.5 s). An edit after the bake (positions, a deforming modifier or shape
    key, UVs, material indices) changes GUARD: the subdivision shows it. The Switch evaluates only
    the branch it takes."""
    for k in range(GUARDED):
        sock = g.interface.new_socket(f"{GUARDS} {k + 1}", in_out="INPUT", socket_type="NodeSocketString")
        sock.default_value = ""  # (no attribute: the slots are skipped, below)
    made = []
    if not hasattr(bpy.types, "FunctionNodeHashValue"):  # Blender 4.2 (Hash Value is 4.3's): no
        return made, subdivided  # guard, every evaluation subdivides (no GUARD: helpers never stale)
    node = partial(_add_node, nodes, made)
    hashed = partial(_hashed, node, link)
    received = gi.outputs["Geometry"]
    size = node("GeometryNodeAttributeDomainSize", component="MESH")
    link(received, size.inputs["Geometry"])
    seed = None
    for n in ("Point Count", "Edge Count", "Face Count", "Face Corner Count"):
        seed = hashed(size.outputs[n], seed, "INT")
    seed = hashed(gi.outputs[SCALE], hashed(gi.outputs[SPACING], seed, "FLOAT"), "VECTOR")
    # the slots, unless the first is empty (_ensure: then all are; else the others name an attribute
    # every mesh has, "position"): a lazy Switch, so that a mesh without such attributes evaluates
    # none of their nodes (the guard's cost is per node and object: docs/live.md, session 32)
    skip = node("GeometryNodeSwitch", input_type="INT")
    used = node("FunctionNodeCompare", data_type="STRING", operation="NOT_EQUAL")
    link(gi.outputs[f"{GUARDS} 1"], next(i for i in used.inputs if i.identifier == "A_STR"))
    link(used.outputs[0], skip.inputs["Switch"])
    link(seed, skip.inputs["False"])
    for k in range(GUARDED):
        attr = node("GeometryNodeInputNamedAttribute", data_type="FLOAT_COLOR")
        link(gi.outputs[f"{GUARDS} {k + 1}"], attr.inputs["Name"])
        seed = hashed(attr.outputs["Attribute"], seed, "RGBA")
    link(seed, skip.inputs["True"])
    seed = skip.outputs[0]
    seed = hashed(node("GeometryNodeInputShadeSmooth").outputs[0], seed, "INT")
    seed = hashed(node("GeometryNodeInputMaterialIndex").outputs[0], seed, "INT")
    seed = hashed(node("GeometryNodeFaceOfCorner").outputs["Face Index"], seed, "INT")
    seed = hashed(node("GeometryNodeVertexOfCorner").outputs["Vertex Index"], seed, "INT")
    corner = hashed(node("GeometryNodeInputPosition").outputs[0], seed, "VECTOR")
    # one value for the mesh: the sum and the variance of the corners' hashes (as floats), against
    # the helper's GUARD (the same, stored when the helper's mesh was made). No field sampled from
    # the helper per corner: that and the per-corner compare were ~40% of the guard's cost (a
    # write on the baked 100k room: docs/live.md, session 33)
    stat = node("GeometryNodeAttributeStatistic", data_type="FLOAT", domain="CORNER")
    link(received, stat.inputs["Geometry"])
    link(corner, stat.inputs["Attribute"])
    got = node("ShaderNodeCombineXYZ")
    link(stat.outputs["Sum"], got.inputs[0])
    link(stat.outputs["Variance"], got.inputs[1])
    got.inputs[2].default_value = 1.0  # (a helper without GUARD reads 0: never the same)
    helper = node("GeometryNodeObjectInfo")
    link(gi.outputs["Values"], helper.inputs["Object"])
    stored = node("GeometryNodeInputNamedAttribute", data_type="FLOAT_VECTOR")
    stored.inputs["Name"].default_value = GUARD
    first = node("GeometryNodeSampleIndex", data_type="FLOAT_VECTOR", domain=GUARD_DOMAIN)
    link(helper.outputs["Geometry"], first.inputs["Geometry"])
    link(stored.outputs["Attribute"], first.inputs[1])  # (Index 0: one value, not a field per corner)
    holds = node("FunctionNodeCompare", data_type="VECTOR", operation="EQUAL", mode="ELEMENT")
    link(got.outputs[0], next(i for i in holds.inputs if i.identifier == "A_VEC3"))
    link(first.outputs[0], next(i for i in holds.inputs if i.identifier == "B_VEC3"))
    next(i for i in holds.inputs if i.name == "Epsilon").default_value = 0.0
    keep = node("GeometryNodeStoreNamedAttribute", data_type="FLOAT_VECTOR", domain=GUARD_DOMAIN)
    keep.inputs["Name"].default_value = GUARD
    link(subdivided, keep.inputs["Geometry"])
    link(got.outputs[0], keep.inputs["Value"])
    switch = node("GeometryNodeSwitch", input_type="GEOMETRY")
    link(holds.outputs[0], switch.inputs["Switch"])
    link(keep.outputs["Geometry"], switch.inputs["False"])
    link(helper.outputs["Geometry"], switch.inputs["True"])
    return made, switch.outputs[0]


def _modifier(obj):
    md = obj.modifiers.get(N_VALUES) if obj.type == "MESH" else None
    return md if md is not None and md.type == "NODES" and md.node_group is not None else None


def _socket(md, name="Values"):
    return md.node_group.interface.items_tree[name].identifier


def _spacing(md):
    """The spacing md subdivides its object's faces to (0: the mesh's own corners)."""
    return float(md.get(_socket(md, SPACING), 0)) if SPACING in md.node_group.interface.items_tree else 0.0


def _unsubdivide(md):
    """Set md's subdividing inputs to 0 (SPACING, or version 1's LEVEL_V1 in a file baked then);
    whether one was above."""
    items = md.node_group.interface.items_tree
    keys = [_socket(md, n) for n in (SPACING, LEVEL_V1) if n in items and md.get(_socket(md, n))]
    for k in keys:
        md[k] = type(md[k])(0)
    return bool(keys)


def subdividing(obj):
    """The spacing obj's HR Radiance modifier subdivides its faces to (0: none, or no modifier)."""
    md = _modifier(obj)
    return _spacing(md) if md is not None else 0.0


def _int_attribute(me, name, domain):
    """(N,) int32 me's integer attribute `name` on `domain`, or None."""
    a = me.attributes.get(name)
    if a is None or a.domain != domain or a.data_type != "INT":
        return None
    out = np.empty(len(a.data), np.int32)
    a.data.foreach_get("value", out)
    return out


def _guard_of(me):
    """me's GUARD (3 floats: _from_helper), or None."""
    a = me.attributes.get(GUARD)
    if a is None or a.domain != GUARD_DOMAIN or a.data_type != "FLOAT_VECTOR" or not len(a.data):
        return None
    return np.array(a.data[0].vector, np.float32)


def _faces_of(me):
    """(P,) me's FACE attribute (int64), or None."""
    face = _int_attribute(me, FACE, "FACE")
    return None if face is None else face.astype(np.int64)


# the transport's mesh (before_subdivision): the user's (0), or the user's faces subdivided at this
# multiple of the spacing (2: every face one level coarser than the output's; an experiment of
# session 22, docs/accuracy.md)
TRANSPORT_FACTOR = 0.0


def before_subdivision(objects, depsgraph, read, factor=None):
    """{object name: (read(mesh), FACE of its polygons)} for the objects whose modifier subdivides
    (a Vertex Spacing): the mesh the modifier receives, and the index the group stores as FACE for
    each of its polygons. The bake's transport (the hierarchy) is built on these, the output on the
    finer mesh. An object whose only modifier is this one and without shape keys: its own mesh
    (FACE: each polygon's index); the others evaluated once with their spacing set to 0 (the group
    then stores FACE and subdivides nothing), then set back and evaluated again."""
    factor = TRANSPORT_FACTOR if factor is None else factor
    sub = [o for o in objects if subdividing(o) > 0]
    out = {}
    plain = [o for o in sub if len(o.modifiers) == 1 and getattr(o.data, "shape_keys", None) is None]
    plain = plain if factor <= 0 else []
    for o in plain:
        out[o.name] = (read(o.data), np.arange(len(o.data.polygons), dtype=np.int64))
    rest = [o for o in sub if o.name not in out]
    if not rest:
        return out
    keep = []
    for o in rest:
        md = _modifier(o)
        k = _socket(md, SPACING)
        keep.append((o, md, k, md[k]))
        md[k] = float(md[k]) * factor if factor > 0 else 0.0
        o.update_tag()
    try:
        depsgraph.update()
        for o in rest:
            ob = o.evaluated_get(depsgraph)
            me = ob.to_mesh()
            try:
                out[o.name] = (read(me), _faces_of(me))
            finally:
                ob.to_mesh_clear()
    finally:
        for o, md, k, v in keep:
            md[k] = v
            o.update_tag()
        depsgraph.update()
    return out


def has_coarse_edges(obj, spacing, depsgraph):
    """Whether an edge of a face of obj's evaluated mesh (world space; its modifiers' result, a
    Subdivision Surface's finer faces: without its own subdivision), or an n-gon's span (_ngon_span),
    is longer than `spacing` (False for spacing 0): obj then gets the subdividing group, which gives
    each face its own level (_finer_faces)."""
    if spacing <= 0:
        return False
    ob = obj.evaluated_get(depsgraph)
    me = ob.data
    if not len(me.loops):
        return False
    ev = np.empty(len(me.edges) * 2, np.int32)
    me.edges.foreach_get("vertices", ev)
    used = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("edge_index", used)
    ev = ev.reshape(-1, 2)[np.unique(used)]
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    M = np.array(ob.matrix_world, np.float64)[:3, :3]
    d = (co.reshape(-1, 3)[ev[:, 0]] - co.reshape(-1, 3)[ev[:, 1]]) @ M.T
    if np.sqrt((d * d).sum(1)).max() > spacing:
        return True
    # (or an n-gon spanning more: its centre gets corners, _ngon_span)
    total = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_total", total)
    if not (total > 4).any():
        return False
    start = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_start", start)
    lv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", lv)
    scale = np.linalg.norm(M, axis=0).astype(np.float32)
    return bool(_ngon_span(co.reshape(-1, 3), start, total, lv, scale).max() > spacing)


def _ngon_span(co, start, total, lv, scale):
    """(F,) float32 each n-gon's span (5 or more corners; 0 for the other faces): the largest
    |P + P_next - 2 C| x scale over its corners (P a corner's position, P_next the next corner's, C the
    face's mean position: twice its centre's distance from an edge's midpoint; co local (V, 3)
    float32, scale (3,) float32), as _finer_faces measures it. Subdivide Mesh cuts an n-gon into quads
    from its centre to its edges' midpoints: a table top's 64-gon of 5 cm edges spans 1.1 m, and
    without it got no corner inside (docs/accuracy.md, session 35, branch loftfix). For a triangle
    or a quad it never exceeds the longest edge (for a quad ABCD at AB: |(A - D) + (B - C)| / 2)."""
    span = np.zeros(len(start), np.float32)
    f = np.flatnonzero(total > 4)
    if not len(f):
        return span
    n = total[f].astype(np.int64)
    face = np.repeat(np.arange(len(f)), n)
    c = np.arange(len(face)) - np.repeat(np.cumsum(n) - n, n)  # each corner's place in its face
    first = np.repeat(start[f].astype(np.int64), n)
    p = co[lv[first + c]]
    q = co[lv[first + (c + 1) % np.repeat(n, n)]]
    centre = (np.add.reduceat(p, np.cumsum(n) - n, dtype=np.float32) / n[:, None].astype(np.float32))[face]
    d = (p + q - 2 * centre) * scale
    np.maximum.at(span, f[face], np.sqrt((d * d).sum(1, dtype=np.float32)))
    return span


def face_edges(obj, depsgraph, me=None):
    """((F,) float32 each face's longest edge in world metres as the group measures it (object-space
    edge x the object's scale, _finer_faces; an n-gon's span if longer, _ngon_span), (F,) int64 its
    corners) of obj's evaluated mesh (or of `me`, obj's own)."""
    me = obj.evaluated_get(depsgraph).data if me is None else me
    n_faces = len(me.polygons)
    if not n_faces:
        return np.zeros(0, np.float32), np.zeros(0, np.int64)
    ev = np.empty(len(me.edges) * 2, np.int32)
    me.edges.foreach_get("vertices", ev)
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    co, ev = co.reshape(-1, 3), ev.reshape(-1, 2)
    scale = np.linalg.norm(np.array(obj.matrix_world)[:3, :3], axis=0).astype(np.float32)
    d = (co[ev[:, 0]] - co[ev[:, 1]]) * scale
    length = np.sqrt((d * d).sum(1, dtype=np.float32))
    used = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("edge_index", used)
    start = np.empty(n_faces, np.int32)
    me.polygons.foreach_get("loop_start", start)
    total = np.empty(n_faces, np.int32)
    me.polygons.foreach_get("loop_total", total)
    order = np.argsort(start, kind="stable")  # (reduceat wants the loops' runs in order)
    longest = np.empty(n_faces, np.float32)
    longest[order] = np.maximum.reduceat(length[used], start[order])
    if (total > 4).any():
        lv = np.empty(len(me.loops), np.int32)
        me.loops.foreach_get("vertex_index", lv)
        np.maximum(longest, _ngon_span(co, start, total, lv, scale), out=longest)
    return longest, total.astype(np.int64)


def levels(longest, spacing, finer=0):
    """(F,) each face's level at `spacing` (_finer_faces' rule, in float32 like the nodes): the
    number of k < MAX_LEVEL with longest > spacing / 2^finer x 2^k (finer: the faces' FINER, a
    number or (F,)); 0 for spacing 0."""
    s = np.float32(spacing)
    if s <= 0:
        return np.zeros(len(longest), np.int64)
    s = s / np.float32(2.0) ** np.asarray(finer, np.float32)  # (exact: a power of 2)
    return sum((longest > s * np.float32(2**k)).astype(np.int64) for k in range(MAX_LEVEL))


def corners_at(longest, n, spacing, finer=0):
    """The corners `spacing` makes of faces with these longest edges and corners (and FINER, levels):
    a face of n corners at level L becomes n 4^(L-1) quads (Subdivide Mesh), n 4^L corners."""
    return int((n << (2 * levels(longest, spacing, finer))).sum())


def _steps(longest, n, spacing):
    """(spacings (J,), corners (J,)): the corners at `spacing`, then at each larger spacing where a
    face's level drops (just above longest / 2^k, RAISE), down to every face at level 0; corners
    non-increasing."""
    lv = levels(longest, spacing)
    c0 = int((n << (2 * lv)).sum())
    k = np.arange(MAX_LEVEL)
    t = longest[:, None] / np.float32(2.0) ** k  # step k on while the spacing is below t (exact)
    on = k < lv[:, None]
    t, drop = t[on], (3 * n[:, None] << (2 * k))[on]  # level k + 1 -> k: 3 n 4^k corners fewer
    order = np.argsort(t, kind="stable")
    t, drop = t[order].astype(np.float64), np.cumsum(drop[order])
    last = np.r_[t[1:] != t[:-1], True][: len(t)]  # faces sharing a threshold drop together (none: no
    # face the spacing cuts, one step)
    return np.r_[spacing, t[last] * RAISE], np.r_[c0, c0 - drop[last]]


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


def near_light_finer(longest, centre, normal, cones, spacing, both=False):
    """(F,) int64 FINER of faces close to a light: for each point or spot light of `cones`
    (lights_in.light_edges': position, direction, cos of the half angle; a sun's cos is above 1, an
    area light's 0: left out) before a face (the light on its front, both: on either side, a
    Solidify's two shells sharing its FINER; a spot's cone, widened by the face's half size seen
    from the light, holding its centre) the fewest levels finer, at most CLUTTER_LEVELS, whose pieces
    (longest / 2^level at `spacing`, levels) are at most NEAR_LIGHT x the distance from the face's
    centre to the light. longest (F,) (face_edges'), centre (F, 3), unit normal (F, 3): world."""
    out = np.zeros(len(longest), np.int64)
    if spacing <= 0 or not len(longest):
        return out
    piece = np.stack([longest / 2.0 ** levels(longest, spacing, k) for k in range(CLUTTER_LEVELS + 1)], 1)
    for q in _point_cones(cones):
        v = q[:3] - centre
        dist = np.maximum(np.linalg.norm(v, axis=1), 1e-30)
        h = (v * normal).sum(1)
        lit = (np.abs(h) if both else h) > 0
        if q[6] > -1:  # (a spot's cone: the face's centre seen within it)
            off = np.arccos(np.clip(-(v @ q[3:6]) / dist, -1, 1))
            lit &= off <= np.arccos(q[6]) + np.arcsin(np.minimum(0.5 * longest / dist, 1))
        ok = piece <= NEAR_LIGHT * dist[:, None]
        k = np.where(ok.any(1), np.argmax(ok, 1), CLUTTER_LEVELS)
        out = np.maximum(out, np.where(lit, k, 0))
    return out


def _point_cones(cones):
    """The point and spot lights' rows of light_edges' cones (a sun's cos is above 1; an area light's
    half space, 0: its size, not 1 / d^2, sets its light near it; not measured. A spot's cos is
    never 0: cos(pi / 2) is 6e-17)."""
    c = np.asarray(cones, np.float64).reshape(-1, 7)
    return c[(c[:, 6] <= 1) & (c[:, 6] != 0)]


def _near_lights(objects, depsgraph, spacing, cones):
    """({name: (P,) int8 FINER of its mesh's faces}, corners added): near_light_finer on the mesh's own
    faces of each of `objects` (one object each: FINER is the mesh's; a modifier's result keeps its
    source face's FINER: Solidify's shells both, a Mirror's or an Array's copies their source's,
    measured where the source is), those faces a light is close to. The corners
    added: the evaluated mesh's at `spacing` (an object whose modifiers change its faces: its own
    faces' count x evaluated / own corners)."""
    lights = _point_cones(cones)
    fine, added = {}, 0
    if spacing <= 0 or not len(lights):
        return fine, added
    for o in objects:
        me = o.data
        if not len(me.polygons):
            continue
        M = np.array(o.matrix_world, np.float64)
        box = np.array(o.bound_box, np.float64) @ M[:3, :3].T + M[:3, 3]
        lo, hi = box.min(0), box.max(0)
        # (a light farther from the box than its diagonal / NEAR_LIGHT: no face's piece is longer)
        gap = np.linalg.norm(np.maximum(np.maximum(lo - lights[:, :3], lights[:, :3] - hi), 0), axis=1)
        if (gap * NEAR_LIGHT > np.linalg.norm(hi - lo)).all():
            continue
        longest, cnt = face_edges(o, depsgraph, me)
        co, start, total, lv = mesh_topology(me)
        co = co @ M[:3, :3].T + M[:3, 3]
        face = np.repeat(np.arange(len(start)), total)
        loop = np.repeat(start, total) + np.arange(len(face)) - np.repeat(np.cumsum(total) - total, total)
        centre = np.zeros((len(start), 3))
        np.add.at(centre, face, co[lv[loop]])
        centre /= total[:, None]
        nrm = np.empty(len(me.polygons) * 3, np.float32)
        me.polygons.foreach_get("normal", nrm)
        nrm = nrm.reshape(-1, 3) @ np.linalg.pinv(M[:3, :3])  # (a scale 0: no face, no light)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-30)[:, None]
        k = near_light_finer(longest, centre, nrm, lights, spacing, both=_changes_topology(o, depsgraph))
        if not k.any():
            continue
        fine[o.name] = k.astype(np.int8)
        more = int((cnt << (2 * levels(longest, spacing, k))).sum()) - corners_at(longest, cnt, spacing)
        added += more * len(o.evaluated_get(depsgraph).data.loops) // max(len(me.loops), 1)
    return fine, added


def _world_faces(obj, depsgraph):
    """obj's evaluated mesh in world space: ((V, 3) float64 vertices, (L,) loop vertices, (F,)
    loop starts, (F,) loop totals, (F, 3) unit normals, (T, 3) loop-triangle vertices, (T,) their
    faces)."""
    me = obj.evaluated_get(depsgraph).data
    co, start, total, lv = mesh_topology(me)
    M = np.array(obj.matrix_world, np.float64)
    co = co @ M[:3, :3].T + M[:3, 3]
    nrm = np.empty(len(me.polygons) * 3, np.float32)
    me.polygons.foreach_get("normal", nrm)
    nrm = nrm.reshape(-1, 3) @ np.linalg.inv(M[:3, :3])  # (normals by the inverse transpose)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-30)[:, None]
    me.calc_loop_triangles()
    tri = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", tri)
    tf = np.empty(len(me.loop_triangles), np.int32)
    me.loop_triangles.foreach_get("polygon_index", tf)
    return co, lv, start, total, nrm, tri.reshape(-1, 3), tf.astype(np.int64)


@functools.cache
def _grid(m):
    """(m^2, 3) barycentric weights: the centroids of a triangle's m x m subdivision (inside it)."""
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    keep = i + j < m  # the upright sub-triangles' centroids, then the inverted ones'
    up = np.stack([i[keep] + 1 / 3, j[keep] + 1 / 3], 1)
    down = np.stack([i[i + j < m - 1] + 2 / 3, j[i + j < m - 1] + 2 / 3], 1)
    uv = np.concatenate([up, down]) / m
    return np.c_[1 - uv.sum(1), uv]


def near_clutter(objects, candidates, depsgraph, reach, spacing, cones=()):
    """{name: ((F,) share, (F,) m^2, (F,) bool)} for each object of `candidates`: how much of each
    of its faces other surfaces (any object of `objects`, itself too) cover close in front (the share
    of its rays occluded; 0 for a face no finer level would cut more, or whose whole area is not worth the
    corners (_choices): not looked at), and each face's area. From points spread over each face (the
    centroids of its triangles cut into pieces about spacing / 2^CLUTTER_LEVELS long, at least 2 x 2,
    at most CLUTTER_GRID x CLUTTER_GRID), rays `reach` long (m; at most the face's longest edge,
    face_edges) along its normal and tilted 45 degrees to either side of its two axes (5 rays a
    point): some occluded and some not (a share in (0, 1)) = a shadow's edge likely crosses the face
    (books a few cm before a wall, a board 2 cm from it, shelf boards across a back panel, whose
    shadows the normal's rays pass between); the nearer half, the more of it. A face wholly behind
    something (1) or wholly open (0) is not in part. A ray that meets a surface holding one of the
    face's edges (a concave junction: a floor along a wall; _junction) does not count. Each
    object's evaluated mesh as it is now (the corners stay static: no frame but the one the bake
    starts from; the bake calls it at the scene's first frame). The third array: the faces a spot
    light's cone lights in part at the same points (cones, _cone_edges; lights_in.light_edges)."""
    if not candidates:
        return {}
    from ..core.visibility import make_backend

    tris = [co[t] for co, *_, t, _ in (_world_faces(o, depsgraph) for o in objects)]
    allt = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    backend = make_backend(allt)
    span = 2 * float(np.ptp(allt.reshape(-1, 3), 0).max()) + 1.0 if len(allt) else 1.0  # (a sun's rays)
    out = {}
    for o in candidates:
        co, lv, start, total, nrm, tri, tf = _world_faces(o, depsgraph)
        F = len(start)
        if not F or not len(tri):
            out[o.name] = (np.zeros(F), np.zeros(F), np.zeros(F, bool))
            continue
        longest, cnt = face_edges(o, depsgraph)
        p = co[tri]  # (T, 3, 3)
        e = p[:, [1, 2, 0]] - p
        area = np.bincount(tf, 0.5 * np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1), minlength=F)
        whole = (cnt > 4) & (levels(longest, spacing) == 0)  # (an n-gon left whole: _finer_faces_within)
        thin = _thin(longest, area, spacing) | whole
        gain = _choices(longest, cnt, spacing, area, thin)[1].any(1)[tf]  # (even wholly in part)
        if not gain.any():
            out[o.name] = (np.zeros(F), area, np.zeros(F, bool))
            continue
        tf, p, e = tf[gain], p[gain], e[gain]
        step = spacing / 2**CLUTTER_LEVELS
        m = np.clip(np.ceil(np.linalg.norm(e, axis=2).max(1) / step), 2, CLUTTER_GRID).astype(np.int64)
        pts, fid, axis = [], [], []
        for k in np.unique(m):
            t = np.flatnonzero(m == k)
            g = _grid(int(k))
            pts.append(np.einsum("gk,tkc->tgc", g, p[t]).reshape(-1, 3))
            fid.append(np.repeat(tf[t], len(g)))
            axis.append(np.repeat(e[t, 0], len(g), axis=0))
        pts, fid, axis = np.concatenate(pts), np.concatenate(fid), np.concatenate(axis)
        n = nrm[fid]
        u = axis - (axis * n).sum(1)[:, None] * n  # the face's axes at the point: its triangle's
        u /= np.maximum(np.linalg.norm(u, axis=1), 1e-30)[:, None]  # first edge, and n x it
        v = np.cross(n, u)
        dirs = np.stack([n, n + u, n - u, n + v, n - v], 1)
        dirs /= np.linalg.norm(dirs, axis=2)[..., None]
        far = np.minimum(longest.astype(np.float64), reach)[fid]
        hit = backend.occluded(pts[:, None, :], pts[:, None, :] + dirs * far[:, None, None])
        # the occluded rays that meet a junction at the face's edge do not count (neither way: a
        # book's side behind its neighbour stays wholly covered, a floor along a wall open); only
        # a face in part can change by it
        n_hit = np.bincount(fid, weights=hit.sum(1), minlength=F)
        mixed = (n_hit > 0) & (n_hit < 5 * np.bincount(fid, minlength=F))
        r, k = np.nonzero(hit & mixed[fid, None])
        skip = np.zeros_like(hit)
        if len(r):
            prim, _ = backend.first_hit(pts[r], dirs[r, k], far[r])
            tri_hit = allt[np.maximum(prim, 0)]
            junction = _junction(co, lv, start, total, nrm, fid[r], tri_hit, JUNCTION * spacing)
            skip[r, k] = junction | (prim < 0)  # (or float64 finds no hit: a graze, left out)
        n_hit = np.bincount(fid, weights=(hit & ~skip).sum(1), minlength=F)
        n_ray = np.bincount(fid, weights=5 - skip.sum(1), minlength=F)
        edge = _cone_edges(backend, pts, nrm, fid, F, cones, span)
        out[o.name] = (n_hit / np.maximum(n_ray, 1), area, edge)
    return out


def _cone_edges(backend, pts, nrm, fid, F, cones, span=1.0):
    """(F,) bool: the faces whose points (pts of faces fid) a Blender light (cones: (K, 7) position,
    direction, cos of its half angle; lights_in.light_edges: a point light's cos -1, a sun's
    SUN_CONE and no position) lights in part: some inside its cone, facing it and in its sight, some
    not (its footprint's edge, or a shadow's edge, crosses the face). Every point the light may light
    traces a ray to it (a sun's `span` m long, the scene's size): a shadow's edge crosses faces wholly
    in a cone too (the loft's shelf items under the pendant's shade, a box's faces a point light lights
    in part; session 36)."""
    edge = np.zeros(F, bool)
    for c in np.asarray(cones, np.float64).reshape(-1, 7):
        # a cos above 1 (lights_in.SUN_CONE; not imported: lights_in reads scene_in, which reads
        # this module) is a direction: the light comes from -c[3:6]
        if c[6] > 1.0:
            lit = nrm[fid] @ -c[3:6] > 0
            i = np.flatnonzero(lit)
            if len(i):
                lit[i] &= ~backend.occluded(pts[i], pts[i] - span * c[3:6])
        else:
            to = c[:3] - pts
            dist = np.linalg.norm(to, axis=1)
            lit = ((nrm[fid] * to).sum(1) > 0) & (-(to @ c[3:6]) >= c[6] * dist)
            i = np.flatnonzero(lit)
            if len(i):
                lit[i] &= ~backend.occluded(pts[i], c[:3])
        edge |= (np.bincount(fid, lit, F) > 0) & (np.bincount(fid, ~lit, F) > 0)
    return edge


def _junction(co, lv, start, total, nrm, face, tri, tol):
    """(R,) bool: the triangle tri[r] (R, 3, 3) a ray from face[r] met lies in a plane at an angle
    to the face's (normals nrm) that holds one of the face's edges (both ends within tol, m): it
    meets the face's plane along the face's own edge, a concave junction (a floor along a wall, a
    wall under the ceiling), where the light does not change across the face as a shadow's edge
    would (its corners lie on the junction). A surface meeting the face inside it (a shelf board
    across a back panel) is not one, nor a parallel one just before it (a lamp under a ceiling)."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-30)[:, None]
    across = np.abs((n * nrm[face]).sum(1)) < 0.99  # (8 degrees or more)
    k = total[face]  # (each ray's face's corners, one after another)
    ray = np.repeat(np.arange(len(face)), k)
    c = np.arange(len(ray)) - np.repeat(np.cumsum(k) - k, k)
    plane = np.einsum("ij,ij->i", tri[:, 0], n)
    on = np.abs(np.einsum("ij,ij->i", co[lv[start[face][ray] + c]], n[ray]) - plane[ray]) <= tol
    nxt = np.arange(len(ray)) + np.where(c + 1 == k[ray], 1 - k[ray], 1)  # (an edge: a corner, the next)
    return across & (np.bincount(ray, on & on[nxt], len(face)) > 0)


def budget(own_corners):
    """The finer corners a scene of `own_corners` corners may have (BUDGET_FACTOR, _FLOOR, _CAP)."""
    return int(min(max(BUDGET_FACTOR * own_corners, BUDGET_FLOOR), BUDGET_CAP))


def corner_budget(objects, finer, spacing, depsgraph, limit=None, clutter=None):
    """({name: spacing}, counts, {name: FINER}) for the objects of `finer` (those to subdivide at
    `spacing`): the spacings the budget changes, so that the scene's corners (every object of
    `objects`, each evaluated mesh as the modifier receives it, the finer ones subdivided) stay
    within `limit` (default: budget(the scene's own corners)); a raised spacing at which no face is
    cut any more: None. When the scene at `spacing` exceeds it: one common spacing, the smallest
    above `spacing` whose total fits (each object at the step of _steps it reaches: the same spacing
    for all), then what is left goes to the smallest steps finer that still fit, one after another
    (an object as often as its steps fit); the objects of `clutter` keep `spacing` unless the
    others' coarsest do not make room for them (then they take the common spacing too). When it
    fits: the faces of clutter ({name: ((F,) weight, (F,) m^2)}, _cluttered's; such objects are in
    `finer` too) get up to CLUTTER_LEVELS finer (FINER, (F,) int8) from what is left within the
    budget (each face only as far as its weighed area is worth: _choices), the most weighed area per
    corner first, each the finest that still fits (an object with none: not in the FINER dict).
    Nothing changes (empty) when the scene fits and there is no clutter. counts: (the scene's own
    corners, its corners at `spacing`, its corners with the budget)."""
    if not finer:
        return {}, None, {}
    names = {o.name for o in finer}
    own = sum(len(o.evaluated_get(depsgraph).data.loops) for o in objects)
    fixed = sum(len(o.evaluated_get(depsgraph).data.loops) for o in objects if o.name not in names)
    edges, steps = {}, {}
    for o in finer:
        edges[o.name] = face_edges(o, depsgraph)
        s, c = _steps(*edges[o.name], spacing)
        steps[o.name] = (s, c, s / spacing)  # (r: the steps' spacings as factors of `spacing`)
    want = fixed + sum(int(c[0]) for _, c, _ in steps.values())
    limit = budget(own) if limit is None else int(limit)
    if want <= limit:
        room = limit - want
        fine, got = _finer_faces_within(
            clutter or {}, edges, spacing, room, int(THIN_SHARE * max(want, BUDGET_FLOOR))
        )
        return {}, (own, want, want + got), fine

    # near_clutter's objects keep `spacing` while the others' common spacing can make room
    held = {n for n in clutter or () if n in steps}
    if held and fixed + sum(int(steps[n][1][0 if n in held else -1]) for n in steps) > limit:
        held = set()

    def at(g):  # each object's step at factor g (the last whose spacing is at most spacing x g)
        return {
            n: 0 if n in held else int(np.searchsorted(r, g, side="right")) - 1
            for n, (s, c, r) in steps.items()
        }

    def total(g):
        return fixed + sum(int(steps[n][1][j]) for n, j in at(g).items())

    gs = np.unique(np.concatenate([r for n, (_, _, r) in steps.items() if n not in held] or [[1.0]]))
    lo, hi = 0, len(gs) - 1  # the smallest factor whose total fits (the largest if none does)
    while lo < hi:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if total(gs[mid]) <= limit else (mid + 1, hi)
    pick = at(gs[lo])
    got = total(gs[lo])
    # what is left: the smallest step finer that fits, again and again (a 1 km terrain's 5 m spacing
    # leaves the room beside it its own)
    more = [(int(steps[n][1][j - 1] - steps[n][1][j]), n) for n, j in pick.items() if j > 0]
    heapq.heapify(more)
    while more:
        extra, n = heapq.heappop(more)
        if got + extra > limit:
            continue
        pick[n], got = pick[n] - 1, got + extra
        if pick[n] > 0:
            heapq.heappush(more, (int(steps[n][1][pick[n] - 1] - steps[n][1][pick[n]]), n))
    out = {}
    for n, j in pick.items():
        if j:  # (the last step: every face at level 0, nothing to subdivide)
            out[n] = None if j == len(steps[n][0]) - 1 else float(steps[n][0][j])
    return out, (own, want, got), {}


def _thin(longest, area, spacing):
    """(F,) bool: the faces THIN_RATIO x longer than wide (area / longest), narrower than the finest
    spacing, that the spacing cuts at most THIN_LEVEL times (short: the spacing leaves them whole or
    halves them)."""
    width = area / np.maximum(longest, 1e-30)
    fine = spacing / 2**CLUTTER_LEVELS
    return (width < fine) & (longest > THIN_RATIO * width) & (levels(longest, spacing) <= THIN_LEVEL)


def _choices(longest, cnt, spacing, area, thin=None):
    """((F, CLUTTER_LEVELS) corners each face adds 1 .. CLUTTER_LEVELS levels finer, (F,
    CLUTTER_LEVELS) whether that is a choice: it adds some, and no more than `area` (m^2) is worth
    (CLUTTER_WORTH), or the face is thin (thin (F,) bool, _thin: every level a choice))."""
    base = cnt << (2 * levels(longest, spacing))
    add = [(cnt << (2 * levels(longest, spacing, k))) - base for k in range(1, CLUTTER_LEVELS + 1)]
    add = np.stack(add, 1) if add else np.zeros((len(cnt), 0), np.int64)
    worth = add * (spacing / 2**CLUTTER_LEVELS) ** 2 <= 4 / CLUTTER_WORTH * area[:, None]
    return add, (add > 0) & (worth | (False if thin is None else thin[:, None]))


def _finer_faces_within(clutter, edges, spacing, room, thin_room=0):
    """({name: (F,) int8 FINER}, corners added): the faces of `clutter` (corner_budget's) with a
    weight, each the most levels finer (up to CLUTTER_LEVELS) worth their corners: its area x its
    weight (_cluttered's) per corner added at least CLUTTER_WORTH x the finest spacing^2 / 4. The
    most weighed area per corner first, each the finest of its levels that still fits in `room`
    corners (a face no finer level cuts more, or none worth it: left). Then the thin faces no level
    is worth by area (_thin) the same way, within what is left and at most `thin_room` corners
    between them. An n-gon the spacing leaves whole: the first level that cuts it (a corner at its
    centre) is always a choice."""
    owner, faces, areas, costs, thin = [], [], [], [], []
    for j, (n, (weight, area)) in enumerate(clutter.items()):
        longest, cnt = edges[n]
        f = np.flatnonzero(weight > 0)
        wa = weight[f] * area[f]
        add, ok = _choices(longest[f], cnt[f], spacing, wa)
        # the thin faces no level is worth by area: each level that adds corners a choice (_choices');
        # an n-gon's first (a corner at its centre: its rim's corners alone are spread by Blender's
        # triangulation over long triangles across it, one dark corner at a contact or a shadow's edge
        # over a third of it: the loft's plate under a cup's shadow, -27%; session 36)
        # (within `room` with the others: not the thin faces' share)
        ngon = ((cnt[f] > 4) & (levels(longest[f], spacing) == 0))[:, None] & (add > 0)
        ngon &= np.cumsum(ngon, 1) == 1
        t = ~ok.any(1)[:, None] & (add > 0) & _thin(longest[f], area[f], spacing)[:, None]
        ok |= t | ngon
        keep = ok.any(1)
        owner.append(np.full(keep.sum(), j))
        faces.append(f[keep])
        areas.append(wa[keep])
        costs.append(np.where(ok, add, -1)[keep])  # (-1: not a choice)
        thin.append(t.any(1)[keep])
    fine = {}
    if not sum(map(len, faces)) or room <= 0:
        return fine, 0
    owner, faces = np.concatenate(owner), np.concatenate(faces)
    areas, costs, thin = np.concatenate(areas), np.concatenate(costs), np.concatenate(thin)
    best = CLUTTER_LEVELS - np.argmax(costs[:, ::-1] > 0, 1)  # each face's finest choice
    first = costs[np.arange(len(faces)), best - 1]
    pick = np.zeros(len(faces), np.int64)
    got = 0
    for part, limit in ((~thin, room), (thin, thin_room)):
        sel, r = np.flatnonzero(part), min(room - got, limit)
        if not len(sel) or r <= 0:
            continue
        if first[sel].sum() <= r:
            pick[sel] = best[sel]
            got += int(first[sel].sum())
            continue
        # the most area per corner added first: a face whose corners are far apart (a wall's 0.23 m
        # quad) before one Subdivide Mesh already cut finely across (a 0.4 x 1.6 m side at level 3),
        # a book's thin spine or a cup's small faces
        used = 0
        for i in sel[np.lexsort((faces[sel], owner[sel], -areas[sel] / first[sel]))].tolist():
            for k in range(int(best[i]), 0, -1):
                if 0 < costs[i, k - 1] <= r - used:
                    pick[i], used = k, used + int(costs[i, k - 1])
                    break
        got += used
    on = pick > 0
    for j, n in enumerate(clutter):
        i = np.flatnonzero(on & (owner == j))
        if len(i):
            fine[n] = np.zeros(len(edges[n][0]), np.int8)
            fine[n][faces[i]] = pick[i]
    return fine, got


def values_object(obj, n_loops, n_verts):
    """obj's helper object if it has one whose mesh has the evaluated mesh's n_loops corners and
    n_verts vertices (else None: the values go onto obj's own mesh)."""
    md = _modifier(obj)
    h = md.get(_socket(md)) if md is not None else None
    if h is None or h.type != "MESH" or h.get(TAG) != obj.name:
        return None
    return h if (len(h.data.loops), len(h.data.vertices)) == (n_loops, n_verts) else None


def _changes_topology(obj, depsgraph):
    if not len(obj.modifiers):
        return False
    me, ev = obj.data, obj.evaluated_get(depsgraph).data
    return (len(me.vertices), len(me.loops), len(me.polygons)) != (
        len(ev.vertices),
        len(ev.loops),
        len(ev.polygons),
    )


def ensure_own_values(objects, domain, depsgraph, spacing=0.0, log=None, outlines=(), cones=()):
    """Give every object of `objects` whose modifiers change the topology or whose mesh another of
    them shares a helper and the modifier (made or brought up to date: its domain, its helper's
    topology, last in the stack); with a Vertex Spacing > 0 every object with an edge longer than
    it too, subdividing (has_coarse_edges), each at `spacing` unless the corner budget raises its
    own (corner_budget), and near_clutter's faces the budget grants finer: FINER written on their
    mesh (an object with such faces and no longer edge subdivides by them alone; FINER removed from
    the others' meshes). Returns notes naming the objects that got them now.
    log: callable(str) taking the spacing's note (the objects subdivided) and the budget's line
    instead of the notes: log lines, not warnings (the spacing is the default; they ask nothing
    of the user). outlines, cones: the light shapes' rings and the spot lights' cones over the
    scene's frames (lights_in.light_edges): the faces they cross are finer too (_cluttered), and
    faces close to a point or spot light, if the budget has room (near_light_finer: FINER on the
    mesh's own faces, which reaches an object whose modifiers change its faces too)."""
    users = {}
    for o in objects:
        users[o.data.name_full] = users.get(o.data.name_full, 0) + 1
    own = [o for o in objects if o.data.library is None and o.library is None]
    # the modifiers' own subdivision out first: the user's modifiers' result alone (the level, and
    # whether they change the topology)
    reset = [o for o in own if _modifier(o) is not None and _unsubdivide(_modifier(o))]
    for o in reset:
        o.update_tag()
    if reset:
        depsgraph.update()
    coarse = {o.name: has_coarse_edges(o, spacing, depsgraph) for o in own}
    # (a face attribute of the mesh: not for a mesh several objects share, nor, for clutter, one
    # whose modifiers change its faces; near lights' FINER reaches those through their source faces)
    one_user = [o for o in own if users[o.data.name_full] == 1]
    single = [o for o in one_user if not _changes_topology(o, depsgraph)]
    clutter = _cluttered(objects, single, spacing, depsgraph, outlines, cones)
    finer_ = [o for o in own if coarse[o.name] or o.name in clutter]
    changed, counts, fine = corner_budget(objects, finer_, spacing, depsgraph, clutter=clutter)
    for name, s in changed.items():
        coarse[name] = s is not None
    for name in fine:
        coarse[name] = True
    raised = {n: s for n, s in changed.items() if s is None or s > spacing}
    # faces close to a light (near_light_finer), if the budget left `spacing` as it was and has room
    near, more = {}, 0
    if not changed and len(cones):
        near, more = _near_lights(one_user, depsgraph, spacing, cones)
        have = counts or (sum(len(o.evaluated_get(depsgraph).data.loops) for o in objects),) * 3
        if near and have[2] + more > budget(have[0]):
            near = {}
    lit_fine = dict(fine)
    for name, k in near.items():
        lit_fine[name] = k if name not in fine else np.maximum(fine[name], k)
        coarse[name] = True
    for obj in own:
        _set_finer(obj.data, lit_fine.get(obj.name))
    made, finer, kept = [], [], []
    for obj in own:
        finer_faces = coarse[obj.name]
        shared = users[obj.data.name_full] > 1
        if not finer_faces and not shared and not _changes_topology(obj, depsgraph):
            if obj in reset:  # subdivided by an earlier bake: its helper and modifier go
                remove_own_values([obj])
            continue
        made += _ensure(obj, domain, changed.get(obj.name, spacing) if finer_faces else 0.0)
        finer += [obj.name] if finer_faces else []
        kept.append(obj)
    if finer:
        depsgraph.update()  # the subdivided meshes, for their helpers
    unused = [me for obj in kept if (me := _helper(obj, depsgraph)) is not None]
    bpy.data.batch_remove(unused)  # (one pass over the file's IDs, not one per mesh: 5 ms each at 12k)
    notes = []
    if fine:
        (notes.append if log is None else log)(clutter_line(fine, clutter, spacing))
    if near:
        (notes.append if log is None else log)(near_light_line(near, spacing, more))
    if raised:
        line = budget_line(raised, spacing, counts)
        if log is None:
            notes.append(line)
        else:
            log(line)
    if finer:
        (notes.append if log is None else log)(
            f"Vertex Spacing {spacing:g}: {len(finer)} object(s) with edges longer "
            f"({', '.join(repr(n) for n in finer[:8])}{', ...' if len(finer) > 8 else ''}) show their "
            f"light at the corners of their mesh subdivided in the modifier '{N_VALUES}' (linear: the "
            "shape stays)."
        )
    made = [n for n in made if not coarse[n]]
    if not made:
        return notes
    return notes + [
        f"{len(made)} object(s) whose modifiers change the topology or that share their mesh with "
        f"another object ({', '.join(repr(n) for n in made[:8])}{', ...' if len(made) > 8 else ''}) got "
        f"the geometry-nodes modifier '{N_VALUES}' last in their stack and a helper object "
        f"'{N_VALUES} <object>' (in no scene) that holds their HR_Radiance: every corner of the "
        "modifiers' result, every linked duplicate, shows its own light."
    ]


def _cluttered(objects, own, spacing, depsgraph, outlines=(), cones=()):
    """{name: ((F,) weight, (F,) m^2)} for the objects of `own` with an edge longer than the finer
    spacing (a face it would cut) and a face of weight > 0: how likely the light changes across each
    face: 4 s (1 - s) of near_clutter's share s (within CLUTTER_REACH x spacing in front, points about
    the finer spacing apart: 1 at a half, 0 wholly open or covered), 1 where a light shape's outline
    crosses it (outline_faces) or a spot light's cone lights it in part (near_clutter's third)."""
    if spacing <= 0 or CLUTTER_LEVELS <= 0:
        return {}
    fine = spacing / 2**CLUTTER_LEVELS
    candidates = [o for o in own if has_coarse_edges(o, fine, depsgraph)]
    found = near_clutter(objects, candidates, depsgraph, CLUTTER_REACH * spacing, spacing, cones)
    crossed = outline_faces(candidates, depsgraph, outlines)
    out = {}
    for n, (s, area, edge) in found.items():
        w = np.where(edge | crossed.get(n, False), 1.0, 4 * s * (1 - s))
        if (w > 0).any():
            out[n] = (w, area)
    return out


def outline_faces(objects, depsgraph, outlines):
    """{name: (F,) bool}: the faces of `objects` a light shape's outline crosses (outlines: each
    shape's rings, 3D; core.events.validation.outline_crosses), for those with a face crossed. Only
    objects whose bounding box meets a shape's are read."""
    if not len(outlines):
        return {}
    from ..core.events.validation import outline_crosses

    pts = [np.concatenate(r) for r in outlines]
    pad = np.array([1e-3 * np.linalg.norm(p.max(0) - p.min(0)) + 1e-6 * np.abs(p).max() for p in pts])
    lo = np.array([p.min(0) for p in pts]) - pad[:, None]
    hi = np.array([p.max(0) for p in pts]) + pad[:, None]
    out = {}
    for o in objects:
        M = np.array(o.matrix_world, np.float64)
        box = np.array(o.evaluated_get(depsgraph).bound_box, np.float64) @ M[:3, :3].T + M[:3, 3]
        near = np.flatnonzero(((lo <= box.max(0)) & (hi >= box.min(0))).all(1))
        if not len(near):
            continue
        co, _, start, _, _, tri, tf = _world_faces(o, depsgraph)
        crossed = np.zeros(len(start), bool)
        for i in near.tolist():
            crossed |= outline_crosses(outlines[i], co[tri], tf, len(start))
        if crossed.any():
            out[o.name] = crossed
    return out


def clutter_line(fine, clutter, spacing):
    """The log line naming the objects whose faces near_clutter or a light's edge made finer
    (corner_budget's FINER, _cluttered's areas), the largest area first."""
    area = {n: float(clutter[n][1][f > 0].sum()) for n, f in fine.items()}  # (m^2)
    by = sorted(fine, key=lambda n: (-area[n], n))
    shown = ", ".join(f"{n!r} {int((fine[n] > 0).sum())} faces {area[n]:.2g} m^2" for n in by[:8])
    return (
        f"Vertex Spacing {spacing:g}: {len(fine)} object(s) with surfaces close in front of part of "
        f"their faces or a light's edge across them ({shown}{', ...' if len(by) > 8 else ''}): those "
        f"faces cut to "
        f"{spacing / 2**CLUTTER_LEVELS:g} m (their light changes across them)."
    )


def near_light_line(near, spacing, more):
    """The log line naming the objects whose faces are finer for a light close to them (_near_lights)."""
    by = sorted(near, key=lambda n: (-int((near[n] > 0).sum()), n))
    shown = ", ".join(f"{n!r} {int((near[n] > 0).sum())} faces" for n in by[:8])
    return (
        f"Vertex Spacing {spacing:g}: {len(near)} object(s) with faces close to a light ({shown}"
        f"{', ...' if len(by) > 8 else ''}): those faces cut into pieces at most {NEAR_LIGHT:g} x their "
        f"distance from it (its light falls off across them), at most {more:,} corners more."
    )


def _set_finer(me, finer):
    """Write FINER (None or no face finer: remove it) on mesh `me`, only where it changes."""
    a = me.attributes.get(FINER)
    if finer is None or not finer.any():
        if a is not None:
            me.attributes.remove(a)
            me.update_tag()
        return
    if a is not None and (a.domain != "FACE" or a.data_type != "INT"):
        me.attributes.remove(a)
        a = None
    if a is not None:
        now = np.empty(len(me.polygons), np.int32)
        a.data.foreach_get("value", now)
        if np.array_equal(now, finer):
            return
    else:
        a = me.attributes.new(FINER, "INT", "FACE")
    a.data.foreach_set("value", finer.astype(np.int32))
    me.update_tag()


def spacing_off_note(spacing):
    """The log line of a vertex bake without the final gather whose Vertex Spacing is set."""
    return (
        f"Vertex Spacing {spacing:g} is not used without the Final Gather: the bake shows each mesh's "
        "own corners (the classic output)."
    )


def budget_line(raised, spacing, counts):
    """The log line of a corner budget's raised spacings (corner_budget's results)."""
    own, want, got = counts
    by = sorted(raised.items(), key=lambda kv: (kv[1] is not None, kv[1] or 0.0, kv[0]), reverse=True)
    shown = ", ".join(f"'{n}' {'not subdivided' if s is None else f'{s:.3g} m'}" for n, s in by[:8])
    return (
        f"Vertex Spacing {spacing:g}: the corner budget ({budget(own):,} corners for a scene of "
        f"{own:,}; the spacing would make {want:,}) raised the spacing of {len(raised)} object(s): "
        f"{shown}{', ...' if len(by) > 8 else ''}; {got:,} corners."
    )


def _ensure(obj, domain, spacing=0.0):
    """Make or update obj's modifier (its group subdividing to `spacing` when > 0, at obj's scale
    now); [obj.name] if it was made now, else []. _helper then gives it its helper."""
    md = _modifier(obj)
    new = md is None
    if new:
        md = obj.modifiers.new(N_VALUES, "NODES")
    finer = spacing > 0
    g = md.node_group
    if g is None or g.name != _group_name(domain, finer) or g.get(TAG) != _version(finer):
        h = None if new or md.node_group is None else md.get(_socket(md))
        md.node_group = _group(domain, finer)
        if h is not None:  # (another group: its socket's value kept)
            md[_socket(md)] = h
    if finer:
        scale = tuple(float(x) for x in np.linalg.norm(np.array(obj.matrix_world)[:3, :3], axis=0))
        if _spacing(md) != spacing or tuple(md[_socket(md, SCALE)]) != scale:
            md[_socket(md, SPACING)], md[_socket(md, SCALE)] = spacing, scale
            obj.update_tag()
        names = _guard_names(obj)[:GUARDED]
        names += ["position" if names else ""] * (GUARDED - len(names))  # (none: the group skips them)
        for k in range(GUARDED):
            key = _socket(md, f"{GUARDS} {k + 1}")
            if md[key] != names[k]:
                md[key] = names[k]
                obj.update_tag()
    k = list(obj.modifiers).index(md)
    if k != len(obj.modifiers) - 1:
        obj.modifiers.move(k, len(obj.modifiers) - 1)
    return [obj.name] if new else []


def _guard_names(obj):
    """The attributes of obj's mesh the subdividing group interpolates that its guard does not
    read anyway (UV maps, colours, custom normals, edge flags; not internal ones, ours, or those
    it reads: position, sharp_face, material_index) in name order."""
    skip = {"position", "sharp_face", "material_index", ATTRIBUTE, FACE}
    return sorted(a.name for a in obj.data.attributes if not a.name.startswith(".") and a.name not in skip)


def _helper(obj, depsgraph):
    """Make obj's helper object, or give it a new mesh when the evaluated mesh's topology is not
    its own (subdividing: when its GUARD is not the evaluated mesh's either, the mesh received has
    changed); the helper's mesh keeps the evaluated mesh's materials (sync_materials). An object
    whose mesh has more attributes than the guard reads (GUARDED), or whose modifiers below give
    the subdivided mesh other materials than its mesh's: its helper without GUARD, the guard never
    holds (the group subdivides at every evaluation, as before session 32). Returns
    the mesh it replaced if nothing else uses it (the caller removes them together), else None."""
    md = _modifier(obj)
    ev = obj.evaluated_get(depsgraph)
    n = (len(ev.data.loops), len(ev.data.vertices))
    h = md.get(_socket(md))
    ours = h is not None and h.type == "MESH" and h.get(TAG) == obj.name
    finer = _spacing(md) > 0
    guard = _guard_of(ev.data) if finer else None
    held = _guard_of(h.data) if ours and guard is not None else None
    stale = guard is not None and not np.array_equal(guard, held)
    old, unguarded = None, finer and len(_guard_names(obj)) > GUARDED
    if not ours or (len(h.data.loops), len(h.data.vertices)) != n or stale:
        me = bpy.data.meshes.new_from_object(ev)
        # (a modifier below that sets materials: the helper's, the object's mesh's, would hide them)
        unguarded = unguarded or (finer and list(me.materials) != list(obj.data.materials))
        me.name = f"{N_VALUES} {obj.name}"
        if ours:
            old = h.data
            h.data = me
            old = old if old.users == 0 else None
        else:
            h = bpy.data.objects.new(f"{N_VALUES} {obj.name}", me)
            h[TAG] = obj.name
        md[_socket(md)] = h
        obj.update_tag()
    if unguarded and GUARD in h.data.attributes:
        h.data.attributes.remove(h.data.attributes[GUARD])
        obj.update_tag()
    sync_materials([obj])
    return old


def sync_materials(objects):
    """Give the helper of each of `objects` (those with one) its object's mesh's materials, the
    evaluated mesh's when the group subdivides: while the guard holds the evaluated mesh is the
    helper's (_from_helper), its materials too, so that renders and the stale check read the
    object's own. Called where the bake makes helpers and where an edit may have changed an
    object's materials (playback.on_depsgraph_update, the stale check). Returns the objects
    whose helper changed (tagged for the depsgraph)."""
    changed = []
    for obj in objects:
        md = _modifier(obj)
        h = md.get(_socket(md)) if md is not None else None
        if h is None or h.type != "MESH" or h.get(TAG) != obj.name:
            continue
        mats, have = list(obj.data.materials), h.data.materials
        if list(have) == mats:
            continue
        have.clear()
        for m in mats:
            have.append(m)
        obj.update_tag()
        changed.append(obj)
    return changed


def remove_own_values(objects):
    """Undo ensure_own_values on `objects` (Delete Bake): the modifiers, their helpers, FINER."""
    helpers = []
    for obj in objects:
        if obj.type == "MESH" and obj.data.library is None:
            _set_finer(obj.data, None)
        md = _modifier(obj)
        if md is None:
            continue
        h = md.get(_socket(md))
        obj.modifiers.remove(md)
        if h is not None and h.get(TAG) == obj.name:
            helpers.append(h)
    # in one pass over the file's IDs each (one remove per ID costs ~5 ms at 12k IDs: minutes at 100k)
    meshes = {h.data for h in helpers}
    bpy.data.batch_remove(helpers)
    bpy.data.batch_remove([me for me in meshes if me.users == 0])
