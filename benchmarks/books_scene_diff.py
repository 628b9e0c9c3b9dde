"""What differs, as Blender and Cycles see them, between the furnished sample .blend and the
builder's room (hr_testing.blend.mesh_scene of furnished_room("20k"), benchmarks/books_mirror.py's
scene), both prepared for a books-only reference bake (cycles_ref.prepare + configure_cycles, no
bake): per object its RNA settings, world geometry per polygon, normals, smoothing, attributes, UV
layers, modifiers and materials (node trees); the scene's Cycles, render, bake, view-layer and
World settings. docs/gather.md, "The books' -x / +x gap is the reference's shared random numbers".

    .venv/bin/python benchmarks/books_scene_diff.py dump sample|built OUT.pkl
    .venv/bin/python benchmarks/books_scene_diff.py compare A.pkl B.pkl
"""

import os
import pickle
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

SKIP = {"rna_type", "name_full", "session_uid", "is_evaluated", "original", "users", "tag", "is_runtime_data"}


def rna(o):
    """{property: value} of o's plain RNA properties (pointers named, collections left out)."""
    out = {}
    if o is None:
        return None
    for p in o.bl_rna.properties:
        k = p.identifier
        if k in SKIP or p.type == "COLLECTION":
            continue
        try:
            v = getattr(o, k)
        except Exception as e:  # noqa: BLE001 (some properties raise outside a context)
            v = f"<{type(e).__name__}>"
        if p.type == "POINTER":
            v = getattr(v, "name", None if v is None else type(v).__name__)
        elif isinstance(v, set):
            v = tuple(sorted(v))
        elif hasattr(v, "__len__") and not isinstance(v, str):
            try:
                v = tuple(np.round(np.array(v, float).ravel(), 6))
            except (TypeError, ValueError):
                v = repr(v)
        elif isinstance(v, float):
            v = round(v, 6)
        out[k] = v
    return out


def tree(nt):
    if nt is None:
        return None
    nodes = {}
    for n in nt.nodes:
        ins = {}
        for s in n.inputs:
            dv = getattr(s, "default_value", None)
            if dv is not None and not isinstance(dv, (str, bool, int, float)):
                dv = tuple(np.round(np.array(dv, float).ravel(), 6))
            ins[s.identifier] = (dv, s.is_linked, s.enabled)
        nodes[n.name] = {"type": n.bl_idname, "inputs": ins} | {
            k: v
            for k, v in rna(n).items()
            if k not in ("location", "width", "height", "dimensions", "select")
        }
    links = sorted(
        (lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier)
        for lk in nt.links
    )
    return {"nodes": nodes, "links": links}


def dump_mesh(ob):
    me = ob.data
    P, L, V = len(me.polygons), len(me.loops), len(me.vertices)
    co = np.empty(V * 3, np.float32)
    me.vertices.foreach_get("co", co)
    M = np.array(ob.matrix_world, float)
    wv = co.reshape(-1, 3).astype(float) @ M[:3, :3].T + M[:3, 3]
    ls, lt, lv = np.empty(P, np.int32), np.empty(P, np.int32), np.empty(L, np.int32)
    me.polygons.foreach_get("loop_start", ls)
    me.polygons.foreach_get("loop_total", lt)
    me.loops.foreach_get("vertex_index", lv)
    sm = np.empty(P, bool)
    me.polygons.foreach_get("use_smooth", sm)
    mi = np.empty(P, np.int32)
    me.polygons.foreach_get("material_index", mi)
    cn = np.array([tuple(c.vector) for c in me.corner_normals]) if hasattr(me, "corner_normals") else None
    me.calc_loop_triangles()
    tl = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("loops", tl)
    return {
        "rna": rna(me),
        "poly_verts": [wv[lv[s : s + n]] for s, n in zip(ls, lt)],
        "loop_verts_local": lv,
        "smooth": sm,
        "material_index": mi,
        "corner_normals": cn,
        "tri_loops": tl.reshape(-1, 3),
        "attributes": sorted((a.name, a.domain, a.data_type) for a in me.attributes),
        "uv_layers": [(u.name, u.active, u.active_render) for u in me.uv_layers],
        "materials": [m.name if m else None for m in me.materials],
    }


def dump(scene):
    import bpy

    vl = bpy.context.view_layer
    d = {"scene": {}, "objects": {}, "materials": {}, "order": [o.name for o in vl.objects]}
    for k, o in (
        ("cycles", scene.cycles),
        ("render", scene.render),
        ("bake", scene.render.bake),
        ("view", scene.view_settings),
        ("display", scene.display_settings),
        ("units", scene.unit_settings),
        ("view_layer", vl),
        ("view_layer_cycles", getattr(vl, "cycles", None)),
        ("world", scene.world),
        ("world_cycles", getattr(scene.world, "cycles", None)),
        ("world_light", getattr(scene.world, "light_settings", None)),
    ):
        d["scene"][k] = rna(o)
    d["scene"]["world_tree"] = tree(scene.world.node_tree) if scene.world else None
    for ob in vl.objects:
        e = {"type": ob.type, "rna": rna(ob), "matrix": np.array(ob.matrix_world, float)}
        e["modifiers"] = [(m.name, m.type) for m in ob.modifiers]
        e["slots"] = [(s.link, s.material.name if s.material else None) for s in ob.material_slots]
        if ob.type == "MESH":
            e["mesh"] = dump_mesh(ob)
        elif ob.data is not None:
            e["data"] = rna(ob.data)
        d["objects"][ob.name] = e
    for m in bpy.data.materials:
        d["materials"][m.name] = {
            "rna": rna(m),
            "cycles": rna(getattr(m, "cycles", None)),
            "tree": tree(m.node_tree),
        }
    return d


def cmp_dict(a, b, where, out, ignore=()):
    for k in sorted(set(a or {}) | set(b or {})):
        if k in ignore:
            continue
        va, vb = (a or {}).get(k, "<missing>"), (b or {}).get(k, "<missing>")
        if va != vb:
            out.append(f"{where}.{k}: {va!r} | {vb!r}")


def compare(a, b):
    out = []
    for k in sorted(set(a["scene"]) | set(b["scene"])):
        if k == "world_tree":
            if a["scene"][k] != b["scene"][k]:
                out.append(f"world tree: {a['scene'][k]} | {b['scene'][k]}")
        else:
            cmp_dict(a["scene"][k], b["scene"][k], k, out, ignore=("filepath", "name"))
    oa, ob_ = a["objects"], b["objects"]
    only_a, only_b = sorted(set(oa) - set(ob_)), sorted(set(ob_) - set(oa))
    out.append(f"objects only in A: {only_a}")
    out.append(f"objects only in B: {only_b}")
    common = [n for n in a["order"] if n in ob_]
    ia = {n: i for i, n in enumerate(n for n in a["order"] if n in ob_)}
    ib = {n: i for i, n in enumerate(n for n in b["order"] if n in oa)}
    out.append(f"object order equal over common objects: {all(ia[n] == ib[n] for n in common)}")
    geo = []
    for n in common:
        x, y = oa[n], ob_[n]
        cmp_dict(x["rna"], y["rna"], f"obj {n}", out, ignore=("name", "data"))
        for k in ("type", "modifiers"):
            if x[k] != y[k]:
                out.append(f"obj {n} {k}: {x[k]} | {y[k]}")
        if not np.allclose(x["matrix"], y["matrix"]):
            out.append(f"obj {n} matrix differs")
        if "mesh" not in x or "mesh" not in y:
            continue
        mx, my = x["mesh"], y["mesh"]
        cmp_dict(mx["rna"], my["rna"], f"mesh {n}", out, ignore=("name",))
        for k in ("attributes", "uv_layers"):
            if mx[k] != my[k]:
                out.append(f"mesh {n} {k}: {mx[k]} | {my[k]}")
        if len(mx["poly_verts"]) != len(my["poly_verts"]):
            out.append(f"mesh {n} polygons {len(mx['poly_verts'])} | {len(my['poly_verts'])}")
            continue
        d = max(
            (np.abs(p - q).max() if p.shape == q.shape else np.inf)
            for p, q in zip(mx["poly_verts"], my["poly_verts"])
        )
        geo.append((d, n))
        if not np.array_equal(mx["smooth"], my["smooth"]) or mx["smooth"].any():
            out.append(f"mesh {n} smooth: {mx['smooth'].sum()} | {my['smooth'].sum()} of {len(mx['smooth'])}")
        if not np.array_equal(mx["tri_loops"], my["tri_loops"]):
            out.append(f"mesh {n} loop triangles differ")
        if not np.array_equal(mx["loop_verts_local"], my["loop_verts_local"]):
            out.append(f"mesh {n} local loop vertex indices differ")
        if mx["corner_normals"] is not None and my["corner_normals"] is not None:
            dn = np.abs(mx["corner_normals"] - my["corner_normals"]).max()
            if dn > 1e-6:
                out.append(f"mesh {n} corner normals differ by {dn:.3g}")
        mats_x = [a["materials"][m]["tree"] if m in a["materials"] else m for _, m in x["slots"]]
        mats_y = [b["materials"][m]["tree"] if m in b["materials"] else m for _, m in y["slots"]]
        if mats_x != mats_y:
            out.append(f"obj {n} slot materials' trees differ: {x['slots']} | {y['slots']}")
    geo.sort(reverse=True)
    out.append(f"largest polygon-vertex differences (m): {[(f'{d:.3g}', n) for d, n in geo[:12]]}")
    out.append(f"objects with geometry differing > 1e-6 m: {sum(d > 1e-6 for d, _ in geo)} of {len(geo)}")
    return out


def main():
    if sys.argv[1] == "dump":
        import cycles_compare as CC
        from hr_testing import cycles_ref as C

        if sys.argv[2] == "sample":
            sc = CC.open_scene("furnished")
            texel = dict(texel_rel=1 / 150)
        else:
            from hr_testing.blend import mesh_scene
            from hr_testing.furnished import furnished_room

            mi, _ = furnished_room("20k")
            sc = mesh_scene(mi)
            texel = dict(texel=0.0553)
        names = [o.name for o in sc.objects if "_book" in o.name]
        rs = C.prepare(sc, only=names, **texel)
        C.configure_cycles(rs.scene, 128, 1, 1, 64)
        d = dump(rs.scene)
        d["atlases"] = {n: (a.width, a.height, a.n, a.texel) for n, a in rs.atlases.items()}
        with open(sys.argv[3], "wb") as f:
            pickle.dump(d, f)
    else:
        with open(sys.argv[2], "rb") as f:
            a = pickle.load(f)
        with open(sys.argv[3], "rb") as f:
            b = pickle.load(f)
        for line in compare(a, b):
            print(line)
        diff = [n for n in a["atlases"] if a["atlases"][n] != b["atlases"].get(n)]
        print("atlases differing:", [(n, a["atlases"][n], b["atlases"].get(n)) for n in diff])


if __name__ == "__main__":
    main()
