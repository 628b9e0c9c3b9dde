"""The scene precompute's object graph (docs/precompute.md): capture() walks a built
RadiositySystem (and a final gather) into plain numpy arrays plus a JSON description of how the
objects fit together (numpy arrays by name, scalars in JSON, objects of the extension's core
classes by class and attributes, shared objects once); restore() rebuilds the objects from it
without running the build (the ray backend is rebuilt from the triangles it was built from)."""

import importlib

import numpy as np

_PKG = __name__.rsplit(".io.", 1)[0]  # "hr_addon", or the extension's package path inside Blender

# Attributes that depend on the light (caches of a solution, of light shapes, of one
# DynamicRadiosity) or are rebuilt cheaply on first use: reset, never stored. By class name, so
# that moving a class between modules does not change the rule.
_TRANSIENT = {
    "RadiositySystem": {"B": None, "report": None, "_op": None},
    "Hierarchy": {"_levels": None},
    # (not _ext, the solver's far-link terms: geometry only, set by the build's base solution, and
    # seconds to make again at 100k on a re-bake's first light event)
    "Links": {"_csr": None},
    "Contacts": {"_tables": dict},
    "ClusterTree": {"_group_runs_": None, "_grad_rows": None, "_centre9": None},
    # (not _cols_read: after a read the columns are its compacted ones, read through its rows)
    "FinalGather": {
        "_shape_cache": dict,
        "_responses": dict,
        "_responses_of": None,
        "_naive_key": None,
        "_naive_V": None,
        "_split": None,
        "_near_x": None,
        "_loop_weights": None,
        "_shift": None,
        "_loop_parts": dict,
        "_mean_weights": None,
        "_mean_runs": None,
        "_near_own": None,
    },
}
_TRANSIENT["LoopGather"] = _TRANSIENT["FinalGather"]


class PrecomputeError(RuntimeError):
    """A precompute that cannot be written, read or used; the message says why."""


def capture(system, gather=None):
    """(arrays {name: ndarray}, graph) of a built RadiositySystem and optionally the final gather
    built on it (FinalGather / LoopGather over the system or its DynamicRadiosity), taken before any
    light event: the hierarchy must still be the build's."""
    if gather is not None and getattr(gather, "system", system) is not system:
        raise ValueError("the gather was built on another system")
    if gather is not None and gather.n_hr != system.h.n:
        raise ValueError("capture before light events: the hierarchy has nodes the build did not make")
    arrays, memo = {}, {}

    def arr(a):
        key = id(a)
        if key not in memo:
            memo[key] = (a, f"a{len(arrays)}")  # holding `a` keeps its id unique until the end
            arrays[memo[key][1]] = np.ascontiguousarray(a)
        return {"$a": memo[key][1]}

    def enc(v, path):
        if v is None or isinstance(v, (bool, int, float, str)):
            return v
        if isinstance(v, np.ndarray):
            return arr(v)
        if isinstance(v, np.generic):
            return {"$g": arr(np.asarray(v))["$a"]}
        if isinstance(v, tuple):
            return {"$t": [enc(x, f"{path}[{i}]") for i, x in enumerate(v)]}
        if isinstance(v, list):
            return [enc(x, f"{path}[{i}]") for i, x in enumerate(v)]
        if isinstance(v, dict):
            return {"$d": [[enc(k, path), enc(x, f"{path}[{k!r}]")] for k, x in v.items()]}
        cls = type(v)
        if cls.__name__ == "Progress":
            return {"$progress": None}
        if cls.__module__.startswith(_PKG + ".core.visibility") and hasattr(v, "occluded"):
            return {"$backend": _backend_key(v), "triangles": arr(v.triangles)}
        if not cls.__module__.startswith(_PKG + ".core."):
            raise TypeError(f"{path}: cannot store a {cls.__module__}.{cls.__qualname__}")
        key = id(v)
        if key in memo:
            return {"$ref": memo[key][1]}
        memo[key] = (v, f"o{len(memo)}")
        state = dict(vars(v))
        skip = _TRANSIENT.get(cls.__name__, {})
        if cls.__name__ == "Hierarchy":  # only the live nodes; restore pads to the capacity
            state = {k: (x[: v.n] if k in _hier_fields(v) else x) for k, x in state.items()}
        return {
            "$o": memo[key][1],
            "cls": cls.__module__[len(_PKG) + 1 :] + ":" + cls.__qualname__,
            "state": {k: enc(x, f"{path}.{k}") for k, x in state.items() if k not in skip},
        }

    graph = {"system": enc(system, "system"), "gather": enc(gather, "gather")}
    return arrays, graph


def _hier_fields(h):
    return {name for name, _, _ in type(h)._fields}


def _backend_key(b):
    for k, c in importlib.import_module(type(b).__module__)._BACKENDS.items():
        if type(b) is c:
            return k
    raise TypeError(f"unknown ray backend {type(b).__name__}")


def restore(arrays, graph):
    """(system, gather or None) rebuilt from capture()'s output; the ray backend is made again from
    the triangles it was built from. Raises PrecomputeError if the graph names code that does not
    exist (a precompute of other code)."""
    objs = {}
    backends = {}

    def dec(v):
        if v is None or isinstance(v, (bool, int, float, str)):
            return v
        if isinstance(v, list):
            return [dec(x) for x in v]
        if "$a" in v:
            return arrays[v["$a"]]
        if "$g" in v:
            return arrays[v["$g"]][()]
        if "$t" in v:
            return tuple(dec(x) for x in v["$t"])
        if "$d" in v:
            return {_key(dec(k)): dec(x) for k, x in v["$d"]}
        if "$progress" in v:
            return importlib.import_module(_PKG + ".core.progress").NO_PROGRESS
        if "$backend" in v:
            tris = arrays[v["triangles"]["$a"]]
            key = (v["$backend"], id(tris))
            if key not in backends:
                vis = importlib.import_module(_PKG + ".core.visibility")
                try:
                    backends[key] = vis.make_backend(tris, v["$backend"])
                except (ImportError, ValueError, OSError) as exc:
                    raise PrecomputeError(f"ray backend {v['$backend']} unavailable here ({exc})") from None
            return backends[key]
        if "$ref" in v:
            return objs[v["$ref"]]
        mod, _, qual = v["cls"].partition(":")
        try:
            cls = getattr(importlib.import_module(f"{_PKG}.{mod}"), qual)
        except (ImportError, AttributeError):
            raise PrecomputeError(f"written by other code (class {v['cls']} not found)") from None
        o = object.__new__(cls)
        objs[v["$o"]] = o
        state = {k: dec(x) for k, x in v["state"].items()}
        for k, x in _TRANSIENT.get(cls.__name__, {}).items():
            state[k] = x() if callable(x) else x
        if cls.__name__ == "Hierarchy":
            for name in _hier_fields(o):
                a = state[name]
                full = np.zeros((state["_cap"],) + a.shape[1:], a.dtype)
                full[: len(a)] = a
                state[name] = full
        o.__dict__.update(state)
        return o

    return dec(graph["system"]), dec(graph["gather"])


def _key(k):
    return tuple(k) if isinstance(k, list) else k
