"""The scene precompute (issue 22, docs/precompute.md): what the light does not change, built once
and kept in the cache folder as one file, reused while the geometry, materials, settings and code
hold (no bpy).

The file `precompute.hrpc` is an uncompressed zip: `header.json` (versions, the settings and
per-object signatures it was built from, every array's dtype, shape and CRC-32, and the object
graph) and one `.npy` per array. capture() walks a built RadiositySystem (and a final gather) into
that graph: numpy arrays by name, scalars in JSON, objects of the extension's core classes by
class and attributes, shared objects once; restore() rebuilds the objects from it without running
the build (the ray backend is rebuilt from the triangles it was built from). A file that cannot be
read whole, fails a checksum or was written by other code is reported with the reason and rebuilt,
never used.

Farms: load_or_build() builds under a lock file (O_EXCL; holder pid, host, start time; its mtime
is the heartbeat) so that processes sharing a cache folder build once; a waiter takes over a lock
whose holder died (same host: pid gone; any host: heartbeat older than `stale` seconds).
"""

import ast
import contextlib
import dataclasses
import hashlib
import json
import os
import socket
import threading
import time
import uuid
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .cache_folder import folder_lock, holder, is_cache_folder, mark, pid_alive
from .files import atomic_write
from .precompute_graph import PrecomputeError, capture, restore  # noqa: F401  (the module's API)

FILENAME = "precompute.hrpc"
LOCKNAME = "precompute.lock"
MAGIC = "hr_radiosity precompute"
# the host-visibility segments light events traced (gather/hostvis.py), kept for the next bake: a
# side file (the precompute is written once, by its build; this after every bake that traced new
# segments), valid only beside the precompute file it was traced on (keep, below)
KEPTNAME = "precompute.hrhv"
KEPT_MAGIC = "hr_radiosity host visibility"
KEPT_VERSION = 1
FORMAT_VERSION = 2  # 2: DynamicRadiosity's base solutions and the gather's static direct light
NONE_YET = "no precompute yet"
_HOST = socket.gethostname() or "host"

# -- versions and signatures -------------------------------------------------------------------------


def extension_version():
    """The extension's version from blender_manifest.toml beside the package ('unknown' if absent)."""
    path = Path(__file__).resolve().parents[2] / "blender_manifest.toml"
    try:
        for line in path.read_text().splitlines():
            if line.strip().startswith("version"):
                return line.split("=", 1)[1].strip().strip('"')
    except OSError:
        pass
    return "unknown"


# The code that makes what a precompute holds, relative to the package: the build
# (RadiositySystem), the final gather and the base solve, with every module of the package they
# import (followed); the base's key and reuse rule (DynamicRadiosity._base_solution), the texel
# points of texture output and the file's writer and reader (alone: their imports make nothing that
# is stored). A change anywhere else (light events, Blender lights, outputs, the cache, the glue)
# keeps precomputes valid; a change of what is stored that this cannot see (a numpy or ray
# library's behaviour, a rule moved elsewhere) bumps FORMAT_VERSION.
CODE_FOLLOWED = ("core/radiosity.py", "core/gather/__init__.py", "core/events/solves.py")
CODE_ALONE = (
    "core/events/dynamic.py",
    "lightmap/plan.py",
    "lightmap/raster.py",
    "io/precompute.py",
    "io/precompute_graph.py",
)


def code_files(root=None):
    """The package's source files whose code changes what a precompute holds (CODE_FOLLOWED and the
    modules they import, transitively; CODE_ALONE), sorted. root: the package folder."""
    root = Path(root) if root is not None else Path(__file__).resolve().parents[1]
    todo = [root / p for p in CODE_FOLLOWED]
    seen = set()
    while todo:
        f = todo.pop()
        if f not in seen:
            seen.add(f)
            todo.extend(_imported(f, root))
    return sorted(seen | {root / p for p in CODE_ALONE})


def _imported(path, root):
    """Files of the package's modules that the module `path` imports (anywhere in it)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = path.parents[node.level - 1]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == root.name:
            base = root.parent
        elif isinstance(node, ast.Import):
            out += [_module(root.parent.joinpath(*a.name.split("."))) for a in node.names]
            continue
        else:
            continue
        target = base.joinpath(*(node.module or "").split(".")) if node.module else base
        out += [_module(target)] + [_module(target / a.name) for a in node.names]  # `from . import m`
    return [f for f in out if f is not None and root in f.parents]


def _module(p):
    for f in (p.with_suffix(".py"), p / "__init__.py"):
        if f.is_file():
            return f
    return None


def code_digest(root=None):
    """Digest of code_files(): a change of the code that makes or reads what is stored makes older
    files stale, even without a version bump."""
    root = Path(root) if root is not None else Path(__file__).resolve().parents[1]
    d = hashlib.sha256()
    for p in code_files(root):
        d.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return d.hexdigest()[:16]


def mesh_signatures(mesh):
    """{object name: {geometry, reflectance, emission}} digests of what a build reads of each object
    of a core.geometry.MeshInput: its polygons' world positions (float64, loop order), sizes,
    triangulation and faces (face_group); the reflectance and the emission per polygon."""
    P = len(mesh.loop_start)
    oid = np.asarray(mesh.object_id, np.int64)
    loop_poly = np.repeat(np.arange(P), mesh.loop_total)
    pos = np.asarray(mesh.verts, np.float64)[np.asarray(mesh.loop_verts)]
    n = len(mesh.object_names)

    def by_obj(o):  # (order, bounds): items grouped by object, object i at order[bounds[i]:bounds[i + 1]]
        return np.argsort(o, kind="stable"), np.searchsorted(np.sort(o), np.arange(n + 1))

    (po, pb), (lo, lb) = by_obj(oid), by_obj(oid[loop_poly])
    tl = np.zeros((0, 3), np.int64) if mesh.tri_loops is None else np.asarray(mesh.tri_loops, np.int64)
    tri_poly = loop_poly[tl[:, 0]]
    tri_rel = tl - np.asarray(mesh.loop_start)[tri_poly][:, None]  # the triangulation, per polygon
    to, tb = by_obj(oid[tri_poly])
    sizes = np.asarray(mesh.loop_total).astype(np.int64)
    rho, em = np.asarray(mesh.reflectance, np.float64), np.asarray(mesh.emission, np.float64)
    face = mesh.face_groups().astype(np.int64) - np.arange(P)  # 0: the polygon is its own face
    out = {}
    for i, name in enumerate(mesh.object_names):
        pol, loops, tri = po[pb[i] : pb[i + 1]], lo[lb[i] : lb[i + 1]], to[tb[i] : tb[i + 1]]
        g = hashlib.sha256(np.ascontiguousarray(pos[loops]).tobytes())
        g.update(sizes[pol].tobytes() + np.ascontiguousarray(tri_rel[tri]).tobytes())
        if face[pol].any():  # the user's faces (the orientation check's votes), when grouped
            g.update(face[pol].tobytes())
        out[str(name)] = {
            "geometry": g.hexdigest()[:16],
            "reflectance": _digest(rho[pol]),
            "emission": _digest(em[pol]),
        }
    return out


def _digest(a):
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def settings_of(params, tol=1e-7, gather=None, **extra):
    """Flat {name: value} of everything a build depends on besides the scene: the RefineParams
    fields, the solver tolerance, the final gather's settings (prefixed 'gather.') and `extra`
    (e.g. quality, method, ray backend)."""
    s = {k: _plain(v) for k, v in dataclasses.asdict(params).items()}
    s["tol"] = float(tol)
    for k, v in (gather or {}).items():
        s[f"gather.{k}"] = _plain(v)
    s.update({k: _plain(v) for k, v in extra.items()})
    return s


def _plain(v):
    return v.item() if isinstance(v, np.generic) else v


def expected(mesh, params, tol=1e-7, gather=None, **extra):
    """What a valid precompute for this scene and these settings must say (validate's `expected`)."""
    want = {
        "format_version": FORMAT_VERSION,
        "extension": extension_version(),
        "code": code_digest(),
        "settings": settings_of(params, tol, gather, **extra),
        "objects": mesh_signatures(mesh),
    }
    return json.loads(json.dumps(want))  # as a header reads back (tuples as lists)


def _names(names, limit=5):
    names = sorted(names)
    s = ", ".join(f"'{n}'" for n in names[:limit])
    return s + (f" and {len(names) - limit} more" if len(names) > limit else "")


def validate(header, want):
    """None if a precompute with `header` serves `want` (from expected()), else why not, naming
    the version, setting or object that changed."""
    if header.get("magic") != MAGIC:
        return "not a precompute of this extension"
    for key, label in (("format_version", "format version"), ("extension", "extension version")):
        if header.get(key) != want[key]:
            return f"{label} {header.get(key)} -> {want[key]}"
    if header.get("code") != want["code"]:
        return "the extension's code changed since it was built"
    old, new = header.get("settings", {}), want["settings"]
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k, "unset") != new.get(k, "unset")]
    if changed:
        # (a quality change moves several at once: draft -> custom five since farlink's dark_ratio)
        more = f" and {len(changed) - 6} more" if len(changed) > 6 else ""
        return ", ".join(f"{k} {old.get(k, 'unset')} -> {new.get(k, 'unset')}" for k in changed[:6]) + more
    old, new = header.get("objects", {}), want["objects"]
    if set(old) != set(new):
        parts = []
        if set(new) - set(old):
            parts.append(f"object {_names(set(new) - set(old))} added")
        if set(old) - set(new):
            parts.append(f"object {_names(set(old) - set(new))} removed")
        return "; ".join(parts)
    for what, text in (
        ("geometry", "moved or changed shape"),
        ("reflectance", "changed reflectance (material)"),
        ("emission", "changed emission (material)"),
    ):
        names = [n for n in new if old[n].get(what) != new[n][what]]
        if names:
            return f"object {_names(names)} {text}"
    return None


# -- capture / restore -------------------------------------------------------------------------------


# -- the file ----------------------------------------------------------------------------------------


def folder_problem(cache_dir):
    """'' if a precompute may be written into `cache_dir` (absent, empty or a cache folder whose
    precompute file, if any, is ours), else why not."""
    d = Path(cache_dir)
    if d.exists() and not d.is_dir():
        return f"'{d}' is a file, not a cache folder"
    if d.is_dir() and any(d.iterdir()) and not is_cache_folder(d):
        return f"'{d}' holds files no radiosity bake wrote: the precompute is not written there"
    f = d / FILENAME
    if f.is_symlink() or (f.exists() and not f.is_file()):
        return f"'{f}' is not a file a bake wrote: left alone"
    return ""


_ZIP64_FROM = 1 << 30  # members larger: zip64 sizes declared up front (a streamed member's size is unknown)


def write(cache_dir, arrays, graph, want, info=None):
    """Write the precompute atomically into `cache_dir` (created and marked as a cache folder if
    absent). want: expected()'s dict, stored as the header's versions, settings and signatures."""
    d = Path(cache_dir)
    why = folder_problem(d)  # this module's own (the precompute file), not cache_folder's
    if why:
        raise PrecomputeError(why)
    header = dict(want)
    header.update(magic=MAGIC, created=time.time(), host=_HOST, info=info or {}, graph=graph)

    with folder_lock(d):  # never into a folder another process's commit is swapping out
        mark(d)
        atomic_write(d / FILENAME, _filler(arrays, header))
    return d / FILENAME


def _filler(arrays, header, compression=zipfile.ZIP_STORED):
    """fill(fh) writing the zip of `arrays` and `header` (write's format; keep's deflated)."""

    def fill(fh):
        # each array streamed into its member (no copy of the precompute in memory; zipfile
        # computes the member's CRC while writing); the header, which lists the CRCs, last
        metas = {}
        with zipfile.ZipFile(fh, "w", compression, allowZip64=True, compresslevel=1) as z:
            for name, a in arrays.items():
                with z.open(name + ".npy", "w", force_zip64=a.nbytes > _ZIP64_FROM) as m:
                    np.lib.format.write_array(m, a, allow_pickle=False)
                crc = z.getinfo(name + ".npy").CRC
                metas[name] = {"dtype": a.dtype.str, "shape": list(a.shape), "crc32": crc}
            z.writestr("header.json", json.dumps({**header, "arrays": metas}))

    return fill


@contextlib.contextmanager
def _damaged(path):
    """Reading `path`: a missing file stays FileNotFoundError, our own PrecomputeError passes, any
    other failure of the zip or its arrays becomes PrecomputeError naming the file."""
    try:
        yield
    except (FileNotFoundError, PrecomputeError):
        raise
    except (OSError, zipfile.BadZipFile, KeyError, ValueError, EOFError, zlib.error) as exc:
        raise PrecomputeError(f"'{Path(path).name}' is damaged or truncated ({exc})") from None


def read_header(path, magic=MAGIC):
    """The header of a precompute file (magic: or of the kept segments' file), or raise
    PrecomputeError saying what is wrong with it."""
    with _damaged(path), zipfile.ZipFile(path) as z:
        h = json.loads(z.read("header.json"))
    if not isinstance(h, dict) or h.get("magic") != magic:
        raise PrecomputeError(
            f"'{Path(path).name}' is not a {'precompute' if magic == MAGIC else 'file'} of this extension"
        )
    return h


def header_id(path):
    """The digest of a precompute file's header (its versions, key, arrays' CRCs, creation time and
    host): what names that very file."""
    with _damaged(path), zipfile.ZipFile(path) as z:
        return hashlib.sha256(z.read("header.json")).hexdigest()[:16]


def read(path, magic=MAGIC):
    """(arrays, header) of a precompute file (magic: or of the kept segments' file); every array
    checked against its dtype, shape and CRC-32. Raises PrecomputeError naming the damaged part."""
    h = read_header(path, magic)
    arrays = {}
    with _damaged(path), zipfile.ZipFile(path) as z:
        for name, meta in h["arrays"].items():
            if z.getinfo(name + ".npy").CRC != meta["crc32"]:
                raise PrecomputeError(f"'{Path(path).name}': array {name} fails its checksum")
            # streamed into the array (no copy of the member's bytes); zipfile checks the data
            # against that CRC on reaching the member's end
            with z.open(name + ".npy") as m:
                a = np.lib.format.read_array(m, allow_pickle=False)
                if m.read(1):
                    raise PrecomputeError(f"'{Path(path).name}': array {name} has trailing bytes")
            if a.dtype.str != meta["dtype"] or list(a.shape) != meta["shape"]:
                raise PrecomputeError(f"'{Path(path).name}': array {name} has the wrong dtype or shape")
            arrays[name] = a
    return arrays, h


def levels(gather):
    """The final gather and its lower levels (FinalGather.second), top first."""
    out = []
    while gather is not None:
        out.append(gather)
        gather = getattr(gather, "second", None)
    return out


def prepare(gather):
    """Compute now what a final gather computes on its first frame from the static scene alone: the
    static emitters' direct light at every level's samples (keyed like the rest by the objects'
    emission) and the reads' compacted columns (FinalGather._read_cols: made here, before the
    first frame's temporaries, not on top of them), so that the precompute captured afterwards
    holds them."""
    for g in levels(gather):
        g.direct_static()
        g._read_cols()


def use_threads(system, gather, threads):
    """Run a loaded precompute on `threads` (core.parallel's count; values do not depend on it): the
    file holds the count of the process that built it (and its kept host stores)."""
    if system is not None:
        system.backend.threads = threads
    for g in levels(gather):
        g.threads = threads
    for g in _host_levels(gather):
        for H in getattr(g, "_host_stores", {}).values():
            H.threads = threads


def load(cache_dir, want, log=None):
    """(system, gather, None) from the cache folder's precompute if it is valid for `want`, else
    (None, None, reason): absent, damaged, or which version, setting or object changed. The gather
    gets the host-visibility segments kept beside it (load_kept; log(str): what became of them)."""
    path = Path(cache_dir) / FILENAME

    def restored():
        why = validate(read_header(path), want)
        if why:
            return None, None, why
        arrays, header = read(path)
        system, gather = restore(arrays, header["graph"])
        if gather is not None:
            gather._precompute_id = header_id(path)
            line = load_kept(cache_dir, gather)
            if line and log is not None:
                log(line)
        return system, gather, None

    try:
        return restored()
    except FileNotFoundError:
        return None, None, NONE_YET
    except PrecomputeError as exc:
        return None, None, str(exc)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a graph this code cannot follow
        return None, None, f"'{FILENAME}' cannot be restored ({type(exc).__name__}: {exc})"


def describe(cache_dir, want=None):
    """For the panel: None when the cache folder has no precompute, else {path, bytes, created
    (epoch seconds), host, problem}; problem is '' when it is valid for `want` (or readable, without
    `want`), else why not."""
    path = Path(cache_dir) / FILENAME
    if not path.is_file():
        return None
    out = {"path": str(path), "bytes": path.stat().st_size, "created": None, "host": None, "problem": ""}
    try:
        h = read_header(path)
    except PrecomputeError as exc:
        out["problem"] = str(exc)
        return out
    out.update(created=h.get("created"), host=h.get("host"))
    out["problem"] = (validate(h, want) if want is not None else None) or ""
    return out


def remove(cache_dir):
    """Delete the cache folder's precompute (Delete Bake, Rebuild) if it is ours: a file of that
    name in a cache folder (and its kept segments). Returns whether a file was deleted."""
    d = Path(cache_dir)
    path = d / FILENAME
    if not is_cache_folder(d) or path.is_symlink() or not path.is_file():
        return False
    path.unlink()
    _remove_kept(d)
    return True


# -- the kept host-visibility segments (session 30 hvkeep) -------------------------------------------


def _host_levels(gather):
    from ..core.gather import hostvis  # (io runs without the gather: imported where it is used)

    return hostvis.host_levels(gather) if gather is not None else []


def _size(n):
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.0f} kB"


def _remove_kept(d):
    """Delete the kept segments' file of cache folder d if it is ours (a file of that name in a
    cache folder), with the precompute (remove). A precompute rebuilt over it leaves it: ignored
    (another precompute's), replaced by the next bake that traces segments (a build that a cancel
    ends keeps the previous bake's files whole)."""
    path = Path(d) / KEPTNAME
    if is_cache_folder(d) and not path.is_symlink() and path.is_file():
        path.unlink()


def load_kept(cache_dir, gather):
    """Put the host-visibility segments kept in the cache folder (KEPTNAME) on a gather just
    restored from the folder's precompute: only if they were traced on that very file (its header's
    digest), under the same host visibility settings and from the same samples; a stale, damaged
    or foreign file is ignored (never used) and said. Returns the line to log, or None (no file)."""
    from ..core.gather import hostvis

    path = Path(cache_dir) / KEPTNAME
    if not path.is_file():
        return None
    t0 = time.perf_counter()
    try:
        h = read_header(path, KEPT_MAGIC)
        if h.get("version") != KEPT_VERSION:
            why = f"format version {h.get('version')} -> {KEPT_VERSION}"
        elif h.get("precompute") != getattr(gather, "_precompute_id", None):
            why = "traced on another precompute (rebuilt since)"
        elif h.get("params") != json.loads(json.dumps(hostvis.params())):
            old, new = h.get("params") or {}, hostvis.params()
            why = ", ".join(f"{k} {old.get(k, 'unset')} -> {v}" for k, v in new.items() if old.get(k) != v)
        else:
            arrays, _ = read(path, KEPT_MAGIC)
            n = hostvis.restore_kept(gather, arrays)
            took, size = time.perf_counter() - t0, _size(path.stat().st_size)
            return f"host visibility segments loaded ({n} tiles, {size}, {took:.2f} s)"
    except PrecomputeError as exc:
        why = str(exc)
    except (KeyError, IndexError, TypeError, ValueError) as exc:  # arrays that do not fit this gather
        for g in _host_levels(gather):  # (none half restored)
            g.__dict__.pop("_host_stores", None)
        why = f"'{KEPTNAME}' does not fit this precompute ({type(exc).__name__}: {exc})"
    return f"host visibility segments not used: {why}"


def keep(cache_dir, gather, log=print, warn=None, cap=None):
    """After a bake: write the host-visibility segments its light events traced (with those loaded)
    beside the precompute, atomically (KEPTNAME; the most recently read tiles up to cap bytes,
    hostvis.DISK), if they traced any and the folder's precompute is still the one the gather came
    from. log(str): what was written; warn(str): why it could not be (the bake goes on: only the
    next bake's speed depends on it). Returns the path written or None."""
    from ..core.gather import hostvis

    warn = warn or log
    pid = getattr(gather, "_precompute_id", None)
    if gather is None or pid is None:
        return None  # (no precompute stored: nothing to keep the segments beside)
    t0 = time.perf_counter()
    arrays, info = hostvis.kept(gather, cap)
    if not info["rays"]:
        return None
    d = Path(cache_dir)
    path = d / KEPTNAME
    try:
        with folder_lock(d):
            if path.is_symlink() or (path.exists() and not path.is_file()):
                raise PrecomputeError(f"'{path}' is not a file a bake wrote: left alone")
            if header_id(d / FILENAME) != pid:
                raise PrecomputeError("the precompute was replaced meanwhile")
            header = dict(magic=KEPT_MAGIC, version=KEPT_VERSION, precompute=pid, params=hostvis.params())
            header.update(created=time.time(), host=_HOST, info=info)
            # deflated (level 1): the bits are mostly runs (at 100k 20x smaller for 0.04 s)
            atomic_write(path, _filler(arrays, header, zipfile.ZIP_DEFLATED))
    except (OSError, PrecomputeError) as exc:
        warn(f"Host visibility segments not stored: {exc}")
        return None
    left = f", {info['left_out']} older tiles left out" if info["left_out"] else ""
    log(
        f"host visibility segments stored ({info['tiles']} tiles, {_size(path.stat().st_size)}"
        f"{left}, {time.perf_counter() - t0:.2f} s)"
    )
    return path


# -- the build lock ----------------------------------------------------------------------------------


class Lock:
    """The build lock of a cache folder: created with O_EXCL, holding {pid, host, started, token};
    its mtime is the heartbeat, refreshed every `beat` seconds while held."""

    def __init__(self, cache_dir, beat=2.0):
        self.path = Path(cache_dir) / LOCKNAME
        self.token = uuid.uuid4().hex
        self.beat = beat
        self._stop = threading.Event()
        self._thread = None

    def try_acquire(self):
        info = {"pid": os.getpid(), "host": _HOST, "started": time.time(), "token": self.token}
        with folder_lock(self.path.parent):  # the folder's changes (a commit's swap) wait
            try:
                mark(self.path.parent)
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                return False
            with os.fdopen(fd, "w") as fh:
                json.dump(info, fh)
        self._thread = threading.Thread(target=self._heartbeat, daemon=True)
        self._thread.start()
        return True

    def _heartbeat(self):
        while not self._stop.wait(self.beat):
            try:
                os.utime(self.path)
            except OSError:  # absent for a moment while a commit swaps the folder (it moves the lock)
                pass

    def release(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        with folder_lock(self.path.parent):
            if (holder(self.path) or {}).get("token") == self.token:
                self.path.unlink(missing_ok=True)

    def dead_holder(self, stale):
        """Why the current holder counts as dead ('' if it is alive or there is none)."""
        h = holder(self.path)
        try:
            age = time.time() - self.path.stat().st_mtime
        except FileNotFoundError:
            return ""
        if h is None:  # unreadable: being written right now, or left half written by a crash
            return f"unreadable lock, no heartbeat for {age:.0f} s" if age > stale else ""
        if h.get("host") == _HOST and not pid_alive(int(h.get("pid", -1))):
            return f"the builder (pid {h.get('pid')}) is gone"
        if age > stale:
            return f"no heartbeat from {h.get('host')} pid {h.get('pid')} for {age:.0f} s"
        return ""

    def take_over(self, stale):
        """Remove a dead holder's lock (only that one: it is renamed away and checked, and put
        back if another process's fresh lock was taken by mistake). Returns the reason or ''."""
        if not self.dead_holder(stale):  # the common case while waiting: no folder lock taken
            return ""
        with folder_lock(self.path.parent):
            return self._take_over(stale)

    def _take_over(self, stale):
        why = self.dead_holder(stale)
        if not why:
            return ""
        old = holder(self.path)
        aside = self.path.with_name(f".{LOCKNAME}.{self.token}.stale")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return ""
        if holder(aside) != old:  # someone replaced it in between: theirs, give it back
            try:
                os.link(aside, self.path)
            except OSError:
                pass
            aside.unlink(missing_ok=True)
            return ""
        aside.unlink(missing_ok=True)
        return why


def age_text(seconds):
    """'40 s', '3 min', '2 h', '5 days' (the panel and the bake's messages)."""
    s = max(0.0, float(seconds))
    for unit, size in (("days", 86400), ("h", 3600), ("min", 60)):
        if s >= 2 * size or (unit != "days" and s >= size):
            return f"{s / size:.0f} {unit}"
    return f"{s:.0f} s"


def _loaded(d):
    """'precompute loaded (built 3 min ago on host, in 88 s)': the bake's and Live's message."""
    try:
        h = read_header(d / FILENAME)
    except (OSError, PrecomputeError):
        return "precompute loaded"
    took = (h.get("info") or {}).get("build_seconds")
    took = f", in {took:.0f} s" if isinstance(took, (int, float)) else ""
    return f"precompute loaded (built {age_text(time.time() - h.get('created', time.time()))} ago{took})"


def _say_loaded(log, d, said, how=""):
    log(_loaded(d) + how)
    for line in said:  # (the kept segments': after the precompute's)
        log(line)


def _building(why):
    return f"precompute {'built' if why == NONE_YET else 'rebuilt'}: {why}"


def load_or_build(
    cache_dir, want, build, log=print, stale=30.0, poll=0.2, beat=2.0, info=None, force=False, warn=None
):
    """(system, gather, how) for the scene `want` (expected()) describes: the cache folder's
    precompute if valid; else built by `build()` -> (system, gather) under the lock and written
    (when the folder allows it). Processes sharing the folder build once: the others wait for the
    file, or take the lock over when its holder died. log(str) says what happened and why: the
    first message is "precompute loaded (built ... ago)" or "precompute rebuilt: <reason>".
    force: build even if a valid precompute exists (Rebuild); the old one stays until the new one
    replaces it. warn(str): where a precompute that could not be stored is said (default: log)."""
    warn = warn or log
    d = Path(cache_dir)
    said = []  # (the kept segments' line, said after the precompute's)
    system, gather, why = (None, None, "rebuild asked") if force else load(d, want, said.append)
    if system is not None:
        _say_loaded(log, d, said)
        return system, gather, "loaded"
    problem = folder_problem(d)
    if problem:
        log(_building(why))
        warn(f"Precompute not stored: {problem}")
        system, gather = build()
        return system, gather, "built"
    lock = Lock(d, beat)
    said_wait = False
    while not lock.try_acquire():
        taken = lock.take_over(stale)
        if taken:
            log(f"Precompute lock taken over: {taken}")
            continue
        if not said_wait:
            h = holder(lock.path) or {}
            log(f"Waiting for the precompute being built by {h.get('host', '?')} pid {h.get('pid', '?')}")
            said_wait = True
        time.sleep(poll)
        system, gather, _ = (None, None, None) if force else load(d, want, said.append)
        if system is not None:
            _say_loaded(log, d, said, " (built by another process)")
            return system, gather, "loaded"
    try:
        system, gather, _ = (None, None, None) if force else load(d, want, said.append)  # finished meanwhile
        if system is not None:
            _say_loaded(log, d, said)
            return system, gather, "loaded"
        log(_building(why))
        for p in d.glob(f".{FILENAME}.*.tmp"):  # a killed writer's (only the lock holder writes)
            p.unlink(missing_ok=True)
        t0 = time.perf_counter()
        system, gather = build()
        info = {**(info or {}), "build_seconds": time.perf_counter() - t0}
        try:
            arrays, graph = capture(system, gather)
            path = write(d, arrays, graph, want, info)
            if gather is not None:  # (its segments kept beside this file: keep)
                gather._precompute_id = header_id(path)
        except (OSError, TypeError, ValueError, PrecomputeError) as exc:  # the bake goes on without it
            warn(f"Precompute not stored: {exc}")
        return system, gather, "built"
    finally:
        lock.release()
