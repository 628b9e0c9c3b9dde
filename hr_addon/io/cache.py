"""On-disk bake cache (no bpy): one .npz per distinct frame plus a JSON manifest.

Layout of a cache directory (default //hr_cache/<blend name>/):
    manifest.json         domain, objects {name: {mesh, count}}, frames {"1": "frame_000001.npz", ...}
    frame_000001.npz      one float32 (count, 4) RGBA array per object: linear outgoing radiance;
                          the zip comment names the bake that wrote it ("hr_radiosity bake <id>")
Frames whose light state did not change point at the previous frame's file (no new file).

Bake ids: every bake has an id (manifest "bake_id") written into each frame file it writes (as the
zip's comment: no array, so no object name can collide with it and readers of the arrays see only
the objects). The
manifest's "frame_ids" maps each frame file to the id it must hold: a file kept from the previous
bake (see below) keeps that bake's id. A frame file whose id differs (copied from another bake of
objects with the same names) is refused by CacheReader.load and counts as damaged for a re-bake.
Caches of versions before the ids (no "bake_id") are read without the check. Texture bakes'
EXR/PNG sequences cannot hold the id; their .npz frame entries do.

Safety: a bake writes into a sibling temporary directory (.<name>.baking-<host>-<pid>-<ms>) and
only replaces the cache at the end (CacheWriter.commit), every file is written to a temporary name
and os.replace()d (files.atomic_write), so a cancelled or failed bake leaves the previous cache
untouched. Temporary directories left by killed processes of this machine are removed by the next
bake of that cache.

Ownership: a bake only ever deletes or replaces what a bake of this extension wrote. Every cache
folder carries the marker file MARKER and its manifest lists the files the bake wrote ("files").
A bake into an existing folder without the marker (and without a readable manifest of ours: caches
of earlier versions) that is not empty, or onto a plain file, is refused (folder_problem). Files of
anyone else found in a cache folder are moved into the new cache at the swap, never deleted.
Frames of the previous cache that the new bake did not cover are kept when the geometry and
settings (method, quality, output, objects) are identical, so baking frames 1-50 and 51-100
separately yields the same cache as baking 1-100 once; otherwise they are discarded and
CacheWriter.messages says why. Kept frames whose file is missing or damaged are reported by
CacheWriter.damaged_frames() so that the bake re-bakes them.
"""

import io
import json
import os
import re
import shutil
import socket
import time
import uuid
import zipfile
from pathlib import Path

import numpy as np

from .files import atomic_write, link_or_copy

FORMAT = 1
_ID_PREFIX = "hr_radiosity bake "  # a frame file's zip comment: this prefix, then the bake id
MANIFEST = "manifest.json"
MARKER = ".hr_radiosity"  # "this folder is a radiosity cache": written first, into every cache folder
_MARKER_TEXT = b"Written by HR Radiosity bakes. A bake replaces only the files its manifest.json lists.\n"
# names our bakes write (frames, texture sequences, atomic_write temporaries): ours in a marked folder
_OWN_NAME = re.compile(r"^(frame_m?\d{6}(_\d+)?\.npz|\..+\.\d+\.tmp)$")
_OWN_TEXTURE = re.compile(r"^.+_-?\d{5,}\.(exr|png)$")


def _own_name(rel_dir, name):
    """Whether `name` in the sub-folder `rel_dir` (posix, "." for the top) is named as bakes name
    their files."""
    if rel_dir == ".":
        return name in (MANIFEST, MARKER) or bool(_OWN_NAME.match(name))
    return rel_dir == TEX_DIR and bool(_OWN_TEXTURE.match(name) or _OWN_NAME.match(name))

TEX_DIR = "textures"
DOMAINS = ("CORNER", "POINT", "TEXTURE")  # where the values go: face corners, vertices, texels
_FRAME_NAME = re.compile(r"^[A-Za-z0-9_.-]+\.npz$")  # a file in the cache folder itself, never a path


class CacheError(RuntimeError):
    """Missing, corrupt or mismatched cache; the message says which and what to do."""


def write_json(path: Path, data):
    atomic_write(path, json.dumps(data, indent=1, sort_keys=True).encode())


def new_bake_id():
    return uuid.uuid4().hex


def write_frame(path: Path, arrays: dict, bake_id=None):
    """Atomically write {object name: (N, 3|4) values} as float32 RGBA arrays; the bake id, when
    given, goes into the zip's comment."""
    out = {}
    for name, a in arrays.items():
        a = np.asarray(a, np.float32)
        if a.shape[1] == 3:
            a = np.concatenate([a, np.ones((len(a), 1), np.float32)], 1)
        out[name] = np.ascontiguousarray(a)

    def save(fh):
        buf = io.BytesIO()
        np.savez(buf, **out)
        if bake_id:
            with zipfile.ZipFile(buf, "a") as z:
                z.comment = (_ID_PREFIX + str(bake_id)).encode("ascii")
        fh.write(buf.getbuffer())

    atomic_write(path, save)


def _zip_bake_id(z):
    """The bake id in the comment of an open frame zip, or None (no id: an earlier version's file)."""
    c = z.comment.decode("ascii", "replace")
    return c[len(_ID_PREFIX) :] if c.startswith(_ID_PREFIX) else None


def frame_ids(manifest):
    """{frame file: bake id it must hold ("": none, no check)} from a manifest ({} for caches
    written before the ids)."""
    own = manifest.get("bake_id")
    if not isinstance(own, str) or not own:
        return {}
    ids = manifest.get("frame_ids")
    ids = ids if isinstance(ids, dict) else {}
    return {str(v): str(ids.get(str(v), own)) for v in manifest.get("frames", {}).values()}


def _id_problem(found, want):
    """'' if a frame file holding bake id `found` (None: no id) belongs to the bake that wants `want`
    (None: no check), else why not (a phrase following the file's name)."""
    if not want or found == want:
        return ""
    if found is None:
        return "belongs to another bake (it carries no bake id; this bake's is " f"{want[:8]})"
    return f"belongs to another bake (bake id {found[:8]}; this bake's is {want[:8]})"


def frame_filename(frame):
    return f"frame_{frame:06d}.npz" if frame >= 0 else f"frame_m{-frame:06d}.npz"


HOST = re.sub(r"[^A-Za-z0-9_.]", "_", socket.gethostname() or "host")
_TEMP = re.compile(
    r"^\.(?P<name>.+)\.(?P<kind>baking|old)-(?:(?P<host>[A-Za-z0-9_.]+)-)?"
    r"(?P<pid>\d+)-(?P<ms>\d+)$"
)


def temp_dirs(final_dir):
    """[(path, kind, host, pid, ms)] of the temporary directories of the cache `final_dir`: bakes in
    progress or left by killed processes ("baking"), swapped-out old caches ("old")."""
    final = Path(final_dir)
    out = []
    try:
        entries = list(final.parent.iterdir())
    except OSError:
        return out
    for p in entries:
        m = _TEMP.match(p.name)
        if m and m.group("name") == final.name and p.is_dir():
            out.append((p, m.group("kind"), m.group("host") or "", int(m.group("pid")), int(m.group("ms"))))
    return out


def pid_alive(pid):
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # exists (another user's), or cannot tell: keep its folder
    return True


def _manifest_of(folder):
    """The folder's manifest dict, or None if it has none or it is unreadable."""
    try:
        m = json.loads((Path(folder) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) and isinstance(m.get("frames"), dict) else None


def is_cache_folder(folder):
    """Whether `folder` was written by a bake: it has the marker, or a readable manifest of ours
    (caches of versions before the marker)."""
    folder = Path(folder)
    return (folder / MARKER).is_file() or _manifest_of(folder) is not None


def owned_files(folder):
    """Relative paths (posix) of the files in cache folder `folder` that a bake wrote: those its
    manifest lists, the manifest and the marker, and files named as bakes name theirs. Empty for a
    folder that is not a cache folder."""
    folder = Path(folder)
    if not is_cache_folder(folder):
        return set()
    m = _manifest_of(folder) or {}
    listed = set(m.get("files") or ()) | {str(v) for v in m.get("frames", {}).values()} | {MANIFEST, MARKER}
    out = set()
    for root, dirs, files in os.walk(folder):
        rel = Path(root).relative_to(folder)
        for f in files:
            r = (rel / f).as_posix()
            if r in listed or _own_name(rel.as_posix(), f):
                out.add(r)
    return out


def folder_problem(final_dir):
    """'' if a bake may write the cache folder `final_dir` (absent, empty, or a cache folder), else
    why not, naming it."""
    final = Path(final_dir)
    if not final.exists() and not final.is_symlink():
        return ""
    if not final.is_dir():
        return (
            f"'{final}' is a file, not a folder: a bake never replaces a file it did not write. Choose "
            "another Cache Folder (or --cache-dir)."
        )
    if is_cache_folder(final):
        return ""
    try:
        entries = sorted(p.name for p in final.iterdir())
    except OSError as exc:
        return f"Cannot read the cache folder '{final}': {exc.strerror or exc}."
    if not entries:
        return ""
    shown = ", ".join(entries[:3]) + (f" and {len(entries) - 3} more" if len(entries) > 3 else "")
    return (
        f"The cache folder '{final}' holds files no radiosity bake wrote ({shown}): a bake only "
        "replaces its own files. Choose an empty or new Cache Folder (or --cache-dir)."
    )


def _retire(old, final):
    """After a swap: delete what a bake wrote in the swapped-out folder `old`, move everything else
    (the user's files) into `final`. Returns the paths that could not be moved (a name the new bake
    also uses): they stay in a visible folder beside the cache, whose path the message gives."""
    old, final = Path(old), Path(final)
    for r in sorted(owned_files(old), key=lambda r: -r.count("/")):
        try:
            (old / r).unlink()
        except OSError:
            pass
    stuck = []
    for p in sorted(old.iterdir()) if old.is_dir() else ():
        if p.is_dir() and p.name == TEX_DIR and (final / TEX_DIR).is_dir():
            for q in sorted(p.iterdir()):  # the user's files among our texture folder's
                if (final / TEX_DIR / q.name).exists():
                    stuck.append(q)
                else:
                    os.replace(q, final / TEX_DIR / q.name)
            try:
                p.rmdir()
            except OSError:
                pass
            continue
        if (final / p.name).exists():
            stuck.append(p)
        else:
            os.replace(p, final / p.name)
    if not stuck:
        try:
            old.rmdir()
        except OSError:
            pass
        return []
    kept = final.parent / f"{final.name}.kept-{int(time.time())}"
    os.replace(old, kept)
    return [kept / p.relative_to(old) for p in stuck]


def _ours_only(folder):
    """Whether every file under `folder` is named as a bake names its files (temporary folders of
    versions before the marker)."""
    for root, _, files in os.walk(folder):
        rel = Path(root).relative_to(folder).as_posix()
        if not all(_own_name(rel, f) for f in files):
            return False
    return True


def remove_stale_temp(final_dir):
    """Remove the temporary directories of `final_dir` left by processes of this machine that no
    longer run (a bake killed with SIGKILL, a crash). Folders of other machines sharing the cache
    folder (split bakes) are left alone, and so is anything a bake did not write: a swapped-out old
    cache gives its other files back to the cache (_retire). Returns the removed paths."""
    removed = []
    final = Path(final_dir)
    for p, kind, host, pid, _ in temp_dirs(final):
        if host not in ("", HOST) or pid_alive(pid):
            continue
        if kind == "old":
            if not final.exists():
                continue  # recover() puts it back
            _retire(p, final)
        elif (p / MARKER).is_file() or _ours_only(p):
            shutil.rmtree(p, ignore_errors=True)
        if not p.exists():
            removed.append(p)
    return removed


def check_writable(final_dir):
    """Raise CacheError (naming the folder) unless a bake can be written next to `final_dir` and
    swapped in without touching anything a bake did not write: checked before the (long) build."""
    final = Path(final_dir)
    why = folder_problem(final)
    if why:
        raise CacheError(why)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        probe = final.parent / f".{final.name}.probe-{HOST}-{os.getpid()}-{int(time.time() * 1000)}"
        probe.mkdir()
        try:
            (probe / "x").write_bytes(b"x")
        finally:
            shutil.rmtree(probe, ignore_errors=True)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise CacheError(
            f"Cannot write the cache folder '{final}' (in '{final.parent}': {reason}). Choose a "
            "writable Cache Folder (or --cache-dir)."
        ) from None
    if final.exists() and not os.access(final, os.W_OK):
        raise CacheError(
            f"Cannot write the cache folder '{final}': it is read-only. Choose a writable "
            "Cache Folder (or --cache-dir)."
        )


def frame_ranges(frames):
    """'1-3, 7, 9-12' for a set of frame numbers."""
    fs = sorted(set(int(f) for f in frames))
    out = []
    for f in fs:
        if out and f == out[-1][1] + 1:
            out[-1][1] = f
        else:
            out.append([f, f])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in out)


def _names(names, limit=5):
    names = sorted(names)
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return ", ".join(f"'{n}'" for n in names[:limit]) + more


def changed_objects(old: dict, new: dict):
    """Phrases naming the objects whose signature differs between two {name: signature} dicts."""
    parts = []
    changed = [k for k in new if k in old and old[k] != new[k]]
    added = [k for k in new if k not in old]
    gone = [k for k in old if k not in new]
    if changed:
        parts.append(f"{_names(changed)} changed")
    if added:
        parts.append(f"{_names(added)} {'is' if len(added) == 1 else 'are'} new")
    if gone:
        parts.append(f"{_names(gone)} {'is' if len(gone) == 1 else 'are'} gone")
    return parts


def settings_difference(old: dict, new: dict):
    """Why the bake described by manifest `old` cannot share frames with `new` ('' if it can)."""
    why = []
    default = {"radiance_mode": "RADIANCE", "final_gather": False}  # bakes from before the setting
    for key in ("output", "domain", "method", "quality", "radiance_mode", "final_gather"):
        a, b = old.get(key, default.get(key)), new.get(key)
        if key == "domain" and old.get("output") != new.get("output"):
            continue  # follows from the output
        if a is not None and b is not None and a != b:
            a, b = ({True: "on", False: "off"}.get(x, str(x).lower()) for x in (a, b))
            why.append(f"{key.replace('_', ' ')} {a} (this bake: {b})")
    a, b = (old.get("feps"), old.get("aeps")), (new.get("feps"), new.get("aeps"))
    if not why and old.get("quality") == "CUSTOM" and a != b:
        why.append(f"feps {a[0]}, aeps {a[1]} (this bake: {b[0]}, {b[1]})")
    if "geometry" in old and "geometry" in new:
        geo = changed_objects(old["geometry"], new["geometry"])
        if geo:
            why.append("other geometry: " + "; ".join(geo))
    if "light_shapes" in old and "light_shapes" in new:
        ls = changed_objects(old["light_shapes"], new["light_shapes"])
        if ls:
            why.append("other light shapes: " + "; ".join(ls))
    if old.get("lights", {}) != new.get("lights", {}):  # Blender lights (issue 20)
        ls = changed_objects(old.get("lights", {}), new.get("lights", {}))
        why.append("other Blender lights" + (": " + "; ".join(ls) if ls else ""))
    if not why and old.get("objects") != new.get("objects"):
        why.append("other objects or texture settings")
    if not why and old.get("signature") != new.get("signature"):
        why.append("other geometry or settings")
    return "; ".join(why)


def npz_problem(path, objects=None, bake_id=None):
    """'' if the frame file at `path` looks complete (a zip of (count, 4) float32 arrays, sizes as the
    manifest says) and, if `bake_id` is given, holds that bake id; else what is wrong. Reads the zip
    directory, its comment and the array headers, not the data."""
    path = Path(path)
    if not path.is_file():
        return "missing"
    try:
        with zipfile.ZipFile(path) as z:
            found = _zip_bake_id(z)
            for info in z.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                with z.open(info) as fh:
                    fmt = np.lib.format
                    version = fmt.read_magic(fh)
                    read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
                    shape, _, dtype = read(fh)
                    hdr = fh.tell()
                want = (objects or {}).get(name, {}).get("count")
                if (
                    len(shape) != 2
                    or shape[1] != 4
                    or dtype != np.float32
                    or (want is not None and shape[0] != want)
                ):
                    return f"bad array for '{name}'"
                if info.file_size != hdr + shape[0] * 16 or info.compress_size < 0:
                    return f"truncated array for '{name}'"
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        return f"unreadable ({exc})"
    why = _id_problem(found, bake_id)
    return f"'{path.name}' {why}" if why else ""


class CacheWriter:
    def __init__(self, final_dir, objects: dict, domain: str, signature: str, info: dict = None):
        self.final = Path(final_dir)
        check_writable(self.final)
        self.removed_temp = remove_stale_temp(self.final)
        stamp = f"{HOST}-{os.getpid()}-{int(time.time() * 1000)}"
        self.tmp = self.final.parent / f".{self.final.name}.baking-{stamp}"
        self.tmp.mkdir()
        atomic_write(self.tmp / MARKER, _MARKER_TEXT, sync=False)
        self.objects = objects
        self.domain = domain
        self.signature = signature
        self.info = dict(info or {})
        self.bake_id = new_bake_id()
        self.frame_ids = {}  # frame file -> bake id, for files kept from the previous bake
        self.frames = {}
        self.kept = 0
        self.messages = []

    def write(self, frame, arrays):
        name = frame_filename(frame)
        write_frame(self.tmp / name, arrays, self.bake_id)
        self.frames[int(frame)] = name
        return name

    def reuse(self, frame, prev_frame):
        self.frames[int(frame)] = self.frames[int(prev_frame)]

    def _manifest_now(self):
        return dict(
            self.info,
            format=FORMAT,
            domain=self.domain,
            objects=self.objects,
            signature=self.signature,
            bake_id=self.bake_id,
        )

    def previous(self):
        """(CacheReader of the previous bake or None, why its frames cannot be kept: '' if they can)."""
        try:
            old = CacheReader(self.final)
        except CacheError:
            return None, ""
        return old, settings_difference(old.manifest, self._manifest_now())

    def damaged_frames(self, baking=()):
        """{frame: problem} of the previous bake's frames that this bake would keep (not in `baking`)
        but whose file is missing or damaged: the bake re-bakes them instead."""
        old, why = self.previous()
        if old is None or why:
            return {}
        out, seen = {}, {}
        ids = frame_ids(old.manifest)
        for f, name in sorted(old.frames.items()):
            if f in baking or f in self.frames:
                continue
            if name not in seen:
                seen[name] = npz_problem(self.final / name, old.objects, ids.get(name))
            if seen[name]:
                out[f] = seen[name]
        return out

    def _merge_previous(self):
        old, why = self.previous()
        if old is None:
            return
        left = sorted(f for f in old.frames if f not in self.frames)
        if why:
            if left:
                self.messages.append(
                    f"The previous bake's frames {frame_ranges(left)} were discarded: it used {why}."
                )
            return
        renamed, lost = {}, []
        ids = frame_ids(old.manifest)
        for f, name in sorted(old.frames.items()):
            if f in self.frames:
                continue
            if name not in renamed:
                dst = name
                k = 1
                while (self.tmp / dst).exists():
                    dst = name.replace(".npz", f"_{k}.npz")
                    k += 1
                src = self.final / name
                if npz_problem(src, old.objects, ids.get(name)):
                    lost.append(f)
                    continue
                link_or_copy(src, self.tmp / dst)
                renamed[name] = dst
                # a kept file holds the previous bake's id ("": none, a cache of an earlier version)
                self.frame_ids[dst] = ids.get(name, "")
            self.frames[f] = renamed[name]
            self.kept += 1
        if lost:
            self.messages.append(
                f"Frames {frame_ranges(lost)} of the previous bake became unreadable during "
                "this bake and are not in it: bake them again."
            )

    def commit(self):
        """Merge the kept frames of the previous bake, write the manifest, swap directories; then
        delete what the previous bake wrote and give every other file back to the cache folder."""
        why = folder_problem(self.final)  # the folder may have changed during the bake
        if why:
            raise CacheError(why)
        self._merge_previous()
        files = sorted(
            (Path(r).relative_to(self.tmp) / f).as_posix() for r, _, fs in os.walk(self.tmp) for f in fs
        )
        manifest = dict(
            self._manifest_now(),
            frames={str(k): v for k, v in sorted(self.frames.items())},
            frame_ids=dict(sorted(self.frame_ids.items())),
            files=sorted(set(files) | {MANIFEST}),
        )
        write_json(self.tmp / MANIFEST, manifest)
        old = None
        if self.final.exists():
            old = self.final.parent / f".{self.final.name}.old-{HOST}-{os.getpid()}-{int(time.time() * 1000)}"
            os.replace(self.final, old)
        os.replace(self.tmp, self.final)
        if old is not None:
            stuck = _retire(old, self.final)
            if stuck:
                self.messages.append(
                    f"Files in the cache folder that no bake wrote have the names of this bake's files; "
                    f"they were kept in '{stuck[0].parent}'."
                )
        return manifest

    def abort(self):
        shutil.rmtree(self.tmp, ignore_errors=True)


def recover(final_dir):
    """If a crash happened between the two renames of commit(), put the old cache back."""
    final = Path(final_dir)
    if final.exists() or not final.parent.is_dir():
        return False
    olds = sorted((ms, str(p)) for p, kind, _, _, ms in temp_dirs(final) if kind == "old")
    if olds:
        os.replace(olds[-1][1], final)
        return True
    return False


class CacheReader:
    _files = {}  # (path, mtime) -> arrays; small LRU shared by readers

    def __init__(self, directory):
        self.dir = Path(directory)
        recover(self.dir)
        mpath = self.dir / MANIFEST
        if not mpath.is_file():
            raise CacheError(f"No radiosity cache at '{self.dir}' (bake first, or check the cache folder).")
        try:
            m = json.loads(mpath.read_text())
            self.frames = {int(k): str(v) for k, v in m["frames"].items()}
            self.domain = m["domain"]
            self.objects = {str(k): dict(v) for k, v in m["objects"].items()}
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise CacheError(f"Corrupt radiosity cache manifest '{mpath}': {exc}") from None
        bad = sorted({v for v in self.frames.values() if not _FRAME_NAME.match(v)})
        if bad or self.domain not in DOMAINS:
            what = f"frame file name '{bad[0]}'" if bad else f"domain {self.domain!r}"
            raise CacheError(f"Corrupt radiosity cache manifest '{mpath}': {what}.")
        if not self.frames:
            raise CacheError(f"Radiosity cache '{self.dir}' holds no frames.")
        self.manifest = m
        self.frame_ids = frame_ids(m)  # {} for caches written before bake ids
        self._sorted = np.array(sorted(self.frames))

    @property
    def frame_range(self):
        return int(self._sorted[0]), int(self._sorted[-1])

    def nearest(self, frame):
        """The baked frame used for `frame`: itself, else the last baked frame before it (held),
        else the first baked frame."""
        i = np.searchsorted(self._sorted, frame, side="right") - 1
        return int(self._sorted[max(i, 0)])

    def load(self, frame):
        """{object name: (N, 4) float32} for `frame` (clamped / held to the baked frames)."""
        name = self.frames[self.nearest(frame)]
        path = self.dir / name
        try:
            key = (str(path), path.stat().st_mtime_ns)
        except OSError:
            raise CacheError(f"Radiosity cache file '{path}' is missing (re-bake).") from None
        hit = self._files.get(key)
        if hit is None:
            try:
                with np.load(path, allow_pickle=False) as z:
                    found = _zip_bake_id(z.zip)
                    data = {k: np.ascontiguousarray(z[k], np.float32) for k in z.files}
            except Exception as exc:
                raise CacheError(f"Corrupt radiosity cache file '{path}': {exc}") from None
            for k, a in data.items():
                want = self.objects.get(k, {}).get("count")
                if a.ndim != 2 or a.shape[1] != 4 or (want is not None and len(a) != want):
                    raise CacheError(f"Corrupt radiosity cache file '{path}': bad array for '{k}'.")
            if len(self._files) > 32:
                self._files.clear()
            hit = self._files[key] = (data, found)
        data, found = hit
        # checked on every load: the shared LRU may hold the file for a reader of another manifest
        why = _id_problem(found, self.frame_ids.get(name))
        if why:
            raise CacheError(
                f"Radiosity cache file '{path}' {why}: it was copied from another cache. Re-bake "
                "(a bake of any frame range re-bakes such frames)."
            )
        return data
