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
"""

import bpy

from .names import ATTRIBUTE, N_VALUES, TAG

GROUP_VERSION = 1


def geometry_group(name, version, socket, socket_type, store, value):
    """The geometry-node group `name`, made anew unless one tagged with `version` exists: inputs
    Geometry and `socket` (of `socket_type`), output the Geometry with the named attribute `store`
    = (name, data type, domain) set to value(nodes, link, group input) -> (the nodes it made, the
    socket of the value). Plain nodes: a file opened without the extension evaluates the same."""
    g = bpy.data.node_groups.get(name)
    if g is not None and g.get(TAG) == version:
        return g
    g = bpy.data.node_groups.new(name, "GeometryNodeTree")
    g[TAG] = version
    g.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    g.interface.new_socket(socket, in_out="INPUT", socket_type=socket_type)
    g.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, link = g.nodes, g.links.new
    gi, go = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    made, out = value(nodes, link, gi)
    st = nodes.new("GeometryNodeStoreNamedAttribute")
    attribute, st.data_type, st.domain = store
    st.inputs["Name"].default_value = attribute
    link(gi.outputs["Geometry"], st.inputs["Geometry"])
    link(out, st.inputs["Value"])
    link(st.outputs["Geometry"], go.inputs["Geometry"])
    for k, nd in enumerate((gi, *made, st, go)):
        nd.location = (200 * k, 0)
    return g


def _group(domain):
    """Node group: HR_Radiance = the helper's HR_Radiance at the same index, on `domain`."""

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
        f"{N_VALUES} {domain.lower()}", GROUP_VERSION, "Values", "NodeSocketObject", store, value
    )


def _modifier(obj):
    md = obj.modifiers.get(N_VALUES) if obj.type == "MESH" else None
    return md if md is not None and md.type == "NODES" and md.node_group is not None else None


def _socket(md):
    return md.node_group.interface.items_tree["Values"].identifier


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


def ensure_own_values(objects, domain, depsgraph):
    """Give every object of `objects` whose modifiers change the topology or whose mesh another of
    them shares a helper and the modifier (made or brought up to date: its domain, its helper's
    topology, last in the stack). Returns notes naming the objects that got them now."""
    users = {}
    for o in objects:
        users[o.data.name_full] = users.get(o.data.name_full, 0) + 1
    made = []
    for obj in objects:
        if obj.data.library is not None or obj.library is not None:
            continue
        shared = users[obj.data.name_full] > 1
        if not shared and not _changes_topology(obj, depsgraph):
            continue
        made += _ensure(obj, domain, depsgraph)
    if not made:
        return []
    return [
        f"{len(made)} object(s) whose modifiers change the topology or that share their mesh with "
        f"another object ({', '.join(repr(n) for n in made[:8])}{', ...' if len(made) > 8 else ''}) got "
        f"the geometry-nodes modifier '{N_VALUES}' last in their stack and a helper object "
        f"'{N_VALUES} <object>' (in no scene) that holds their HR_Radiance: every corner of the "
        "modifiers' result, every linked duplicate, shows its own light."
    ]


def _ensure(obj, domain, depsgraph):
    """Make or update obj's helper and modifier; [obj.name] if they were made now, else []."""
    md = _modifier(obj)
    new = md is None
    if new:
        md = obj.modifiers.new(N_VALUES, "NODES")
    if md.node_group is None or md.node_group.name != f"{N_VALUES} {domain.lower()}":
        md.node_group = _group(domain)
    k = list(obj.modifiers).index(md)
    if k != len(obj.modifiers) - 1:
        obj.modifiers.move(k, len(obj.modifiers) - 1)
    ev = obj.evaluated_get(depsgraph)
    n = (len(ev.data.loops), len(ev.data.vertices))
    h = md.get(_socket(md))
    ours = h is not None and h.type == "MESH" and h.get(TAG) == obj.name
    if not ours or (len(h.data.loops), len(h.data.vertices)) != n:
        me = bpy.data.meshes.new_from_object(ev)
        me.materials.clear()
        me.name = f"{N_VALUES} {obj.name}"
        if ours:
            old = h.data
            h.data = me
            if old.users == 0:
                bpy.data.meshes.remove(old)
        else:
            h = bpy.data.objects.new(f"{N_VALUES} {obj.name}", me)
            h[TAG] = obj.name
        md[_socket(md)] = h
        obj.update_tag()
    return [obj.name] if new else []


def remove_own_values(objects):
    """Undo ensure_own_values on `objects` (Delete Bake): the modifiers, their helpers."""
    for obj in objects:
        md = _modifier(obj)
        if md is None:
            continue
        h = md.get(_socket(md))
        obj.modifiers.remove(md)
        if h is not None and h.get(TAG) == obj.name:
            me = h.data
            bpy.data.objects.remove(h)
            if me.users == 0:
                bpy.data.meshes.remove(me)
