"""Issue 19: the furnished room's build (RadiositySystem, the gather's transport preset) CPU per
stage, for comparing two checkouts of the code: each stage's process time (inclusive, outermost
call only) and call count, plus the rays each stage traced.

    python benchmarks/build_stages.py SIZE [--root CHECKOUT] [--quality draft] [--json OUT] \
        [--params 'dict(cluster_ratio=1.0)'] [--set farlinks.SECOND_TRACE=False]

--root: the checkout whose hr_addon and hr_testing are imported (default: this one), so the same
script times an older commit's build (session 27, bld32: main against session 21's 5f09ab8).
Stages missing in a checkout are skipped. One thread, no profiler: the wrappers cost a
process_time() call per call of a stage (stages are called at most a few thousand times).
"""

import argparse
import dataclasses
import importlib
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

# (key, module, qualified name): a stage's inclusive CPU; nested stages are inside their parents
STAGES = [
    ("prepare_patches", "hr_addon.core.geometry", "prepare_patches"),
    ("make_backend", "hr_addon.core.visibility", "make_backend"),
    ("orient", "hr_addon.core.orientation", "orient"),
    ("Hierarchy", "hr_addon.core.hierarchy", "Hierarchy.__init__"),
    ("contacts (Refiner.contacts)", "hr_addon.core.refine", "Refiner.contacts"),
    ("  Contacts()", "hr_addon.core.contacts", "Contacts.__init__"),
    ("  refine_contacts", "hr_addon.core.contacts", "refine_contacts"),
    ("  _exposed_grid", "hr_addon.core.refine", "Refiner._exposed_grid"),
    ("ClusterTree", "hr_addon.core.cluster", "ClusterTree.__init__"),
    ("link_clusters", "hr_addon.core.farlinks", "link_clusters"),
    ("  EndTable()", "hr_addon.core.cluster", "EndTable.__init__"),
    ("  EndTable.update", "hr_addon.core.cluster", "EndTable.update"),
    ("  _classify", "hr_addon.core.farlinks", "_classify"),
    ("    Ends", "hr_addon.core.cluster", "Ends.__init__"),
    ("    faces", "hr_addon.core.cluster", "faces"),
    ("    estimate", "hr_addon.core.cluster", "estimate"),
    ("    _variation", "hr_addon.core.farlinks", "_variation"),
    ("    sample_points (cluster)", "hr_addon.core.cluster", "sample_points"),
    ("    visibility_points", "hr_addon.core.cluster", "visibility_points"),
    ("    far_visibility", "hr_addon.core.farlinks", "far_visibility"),
    ("  FarLinks()", "hr_addon.core.farlinks", "FarLinks.__init__"),
    ("refine (patch linking)", "hr_addon.core.refine", "Refiner.refine"),
    ("  _oracle", "hr_addon.core.refine", "Refiner._oracle"),
    ("  _finish", "hr_addon.core.refine", "Refiner._finish"),
    ("    link_form_factors", "hr_addon.core.refine", "link_form_factors"),
    ("    _exposed_form_factors", "hr_addon.core.refine", "Refiner._exposed_form_factors"),
    ("    visibility (patch)", "hr_addon.core.refine", "Refiner.visibility"),
    ("      _front_visibility_2x2", "hr_addon.core.refine", "Refiner._front_visibility_2x2"),
    ("push_corrections", "hr_addon.core.corrections", "push_corrections"),
    ("Hierarchy.compact", "hr_addon.core.hierarchy", "Hierarchy.compact"),
    # across stages
    ("* point_to_polygon", "hr_addon.core.formfactor", "point_to_polygon"),
    ("* Contacts.covered", "hr_addon.core.contacts", "Contacts.covered"),
    ("* rays: occluded", "hr_addon.core.visibility", "RayBackend.occluded"),
    ("* rays: occluded_cm", "hr_addon.core.visibility", "RayBackend.occluded_cm"),
    ("* rays: first_hit", "hr_addon.core.visibility", "RayBackend.first_hit"),
    ("* embree any-hit", "hr_addon.core.visibility", "EmbreeBackend._any_hit"),
    ("* embree nearest", "hr_addon.core.visibility", "EmbreeBackend._nearest"),
]
RAYS = {"* rays: occluded": 0, "* rays: occluded_cm": 1, "* rays: first_hit": 0}


ACTIVE = []  # the stages running (outermost calls)
OWNER_KW = {}  # each running stage's keyword arguments (far_visibility's second)
RAYS_BY = {}  # rays traced by stage


def _split(key, kwargs):
    """far_visibility's calls by caller: the oracle's (_classify), the kept links' shadow tests,
    the second trace (far30's SECOND_TRACE)."""
    if key.strip() != "far_visibility":
        return key
    if "  _classify" in ACTIVE:
        return key + " (oracle)"
    return key + (" (second trace)" if kwargs.get("second") else " (shadows)")


def _wrap(key, fn, acc, arg_rays=None):
    depth = [0]

    def wrapped(*args, **kwargs):
        if depth[0]:
            return fn(*args, **kwargs)
        depth[0] += 1
        ACTIVE.append(key)
        OWNER_KW[key] = kwargs
        t0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            ACTIVE.pop()
            a = acc.setdefault(_split(key, kwargs), [0.0, 0, 0])
            a[0] += time.process_time() - t0
            a[1] += 1
            if arg_rays is not None:
                x = args[1 + arg_rays]  # (self first)
                n = int(x.shape[1] if arg_rays == 1 else np.prod(np.shape(x)[:-1]))
                a[2] += n
                # the rays by the innermost stage that traced them (far_visibility by caller)
                owner = next((k for k in reversed(ACTIVE) if not k.startswith("*")), "(none)")
                owner = _split(owner, OWNER_KW.get(owner, {}))
                RAYS_BY[owner] = RAYS_BY.get(owner, 0) + n
            depth[0] -= 1

    wrapped.__wrapped__ = fn
    return wrapped


def install(acc):
    """Wrap every stage found; module-level functions are replaced in every loaded hr_addon module
    that holds them (callers that imported the name)."""
    found = []
    for key, mod, qual in STAGES:
        try:
            m = importlib.import_module(mod)
        except ImportError:
            continue
        parts = qual.split(".")
        owner = m
        for p in parts[:-1]:
            owner = getattr(owner, p, None)
        if owner is None or not hasattr(owner, parts[-1]):
            continue
        orig = owner.__dict__.get(parts[-1]) if isinstance(owner, type) else getattr(owner, parts[-1])
        if orig is None:
            continue
        w = _wrap(key, orig, acc, RAYS.get(key))
        setattr(owner, parts[-1], w)
        if len(parts) == 1:
            for name, mm in list(sys.modules.items()):
                if name.startswith("hr_addon") and getattr(mm, parts[-1], None) is orig:
                    setattr(mm, parts[-1], w)
        found.append(key)
    return found


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("size", default="20k")
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--json", default=None)
    ap.add_argument("--params", default="dict()", help="RefineParams overrides (a dict)")
    ap.add_argument("--set", action="append", default=[], help="module.NAME=value under hr_addon.core")
    a = ap.parse_args(argv)
    root = str(Path(a.root).resolve())
    sys.path.insert(0, root)
    from hr_testing.furnished import furnished_room
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.params import RefineParams

    # import every module a build uses before wrapping (the wrappers replace imported names)
    for mod in {m for _, m, _ in STAGES} | {"hr_addon.core.radiosity", "hr_addon.core.refine"}:
        try:
            importlib.import_module(mod)
        except ImportError:
            pass
    assert str(Path(sys.modules["hr_addon"].__file__).resolve()).startswith(root)
    sys.path.insert(1, str(Path(__file__).resolve().parent))
    from bench_gather_events import set_constants  # (hr_addon is root's, imported above)

    set_constants(a.set)
    mesh, _ = furnished_room(a.size)
    params = dataclasses.replace(RefineParams.for_gather(a.quality), **eval(a.params))
    acc = {}
    found = install(acc)
    c0 = time.process_time()
    system = RadiositySystem(mesh, params, threads=1)
    cpu = time.process_time() - c0
    st = system.build.refine
    res = dict(
        size=a.size,
        root=root,
        params=a.params,
        set=a.set,
        commit=os.popen(f"git -C {root} rev-parse --short HEAD").read().strip(),
        links=len(system.links),
        far_links=len(system.links.far) if getattr(system.links, "far", None) is not None else 0,
        nodes=int(system.h.n),
        build_cpu_s=round(cpu, 3),
        stages={
            k: dict(cpu_s=round(v[0], 3), calls=v[1], **({"rays": v[2]} if k in RAYS else {}))
            for k, v in acc.items()
        },
        order=[k for f in found for k in acc if k == f or k.startswith(f + " (")],
        refiner_stats={k: (v if isinstance(v, int) else round(float(v), 3)) for k, v in dict(st).items()}
        if isinstance(st, dict)
        else {},
        rays_by_stage={k.strip(): v for k, v in RAYS_BY.items()},
        peak_gb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
        load_average=os.getloadavg(),
        created=time.strftime("%Y-%m-%d %H:%M:%S"),
    )
    print(f"{res['commit']} {a.size}: build {cpu:.2f} s CPU, links {res['links']} (far {res['far_links']})")
    for k in res["order"]:
        v = res["stages"][k]
        print(
            f"  {k:34s} {v['cpu_s']:8.2f} s  {v['calls']:6d} calls"
            + (f"  {v['rays']} rays" if "rays" in v else "")
        )
    print("  rays by stage:", {k.strip(): v for k, v in RAYS_BY.items()})
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
