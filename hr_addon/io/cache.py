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

Frames of the previous cache that the new bake did not cover are kept when the geometry and
settings (method, quality, output, objects) are identical, so baking frames 1-50 and 51-100
separately yields the same cache as baking 1-100 once; otherwise they are discarded and
CacheWriter.messages says why. Kept frames whose file is missing or damaged are reported by
CacheWriter.damaged_frames() so that the bake re-bakes them.

Farms (docs/farm.md): processes baking disjoint frame ranges of one scene into one cache folder
commit one at a time under the folder's lock, each merging the frames of the cache as it is at
that moment, so the last commit holds every node's frames. A node whose settings differ from a
bake committed into the folder while it ran is refused (CacheError; its frames are not written):
frames of other settings are never mixed in, nor is another node's work discarded. A previous bake
that was already there when the bake started is replaced, as a re-bake with new settings should.

Safety and ownership (a bake writes beside the cache and swaps it in at the end; it only ever
deletes or replaces what a bake of this extension wrote) are cache_folder.py's: its names are
importable from here too.
"""

import io
import json
import math
import os
import re
import shutil
import struct
import time
import uuid
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .cache_folder import (  # noqa: F401  (re-exported: hr_addon.io.cache is the cache's one import)
    HOST,
    MANIFEST,
    MARKER,
    TEX_DIR,
    CacheError,
    _manifest_of,
    check_writable,
    folder_lock,
    lock_path,
    folder_problem,
    is_cache_folder,
    new_temp_dir,
    owned_files,
    pid_alive,
    recover,
    refuse_problem,
    remove_stale_temp,
    swap_in,
    temp_dirs,
)
from .files import atomic_write, link_or_copy

FORMAT = 1
_ID_PREFIX = "hr_radiosity bake "  # a frame file's zip comment: this prefix, then the bake id
DOMAINS = ("CORNER", "POINT", "TEXTURE")  # where the values go: face corners, vertices, texels
_FRAME_NAME = re.compile(r"^[A-Za-z0-9_.-]+\.npz$")  # a file in the cache folder itself, never a path


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
    comment = (_ID_PREFIX + str(bake_id)).encode("ascii") if bake_id else b""
    atomic_write(path, lambda fh: write_npz(fh, out, comment))


# np.savez's file (an uncompressed zip of .npy members) written member by member here: zipfile's
# Python work per member cost a frame of the furnished 100k room (3,882 objects) 60 ms of its 77
_LOCAL = struct.Struct("<4s5H3L2H")  # local file header, central directory entry, end record
_CENTRAL = struct.Struct("<4s6H3L5H2L")
_END = struct.Struct("<4s4H2LH")
ZIP32 = (0xFFFF, 0xFFFFFFFF)  # members and bytes a zip without the zip64 records can hold


def write_npz(fh, arrays, comment=b""):
    """Write {name: C-contiguous array} into the binary file fh as np.savez does (member
    "name.npy", stored), with the zip comment `comment`; np.load and zipfile read it alike. Beyond
    ZIP32 zipfile writes it (zip64)."""
    headers = {}  # .npy header bytes per shape and dtype (many objects share theirs)

    def npy(a):
        key = (a.shape, a.dtype.str)
        if key not in headers:
            buf = io.BytesIO()
            np.lib.format.write_array_header_1_0(buf, np.lib.format.header_data_from_array_1_0(a))
            headers[key] = buf.getvalue()
        return headers[key], a.reshape(-1).view(np.uint8)  # (its bytes, also of an empty array)

    members = [(f"{name}.npy", *npy(a)) for name, a in arrays.items()]
    size = sum(2 * len(n.encode()) + _LOCAL.size + _CENTRAL.size + len(h) + d.nbytes for n, h, d in members)
    if len(members) > ZIP32[0] or size > ZIP32[1]:
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
            for name, head, data in members:
                with z.open(name, "w", force_zip64=True) as m:
                    m.write(head)
                    m.write(data)
            z.comment = comment
        return
    t = time.localtime()  # DOS time and date, as zipfile stamps its members
    clock = t.tm_hour << 11 | t.tm_min << 5 | t.tm_sec // 2
    day = (t.tm_year - 1980) << 9 | t.tm_mon << 5 | t.tm_mday
    central, offset = [], 0
    for name, head, data in members:
        raw = name.encode()
        n, crc = len(head) + data.nbytes, zlib.crc32(data, zlib.crc32(head))
        # flags (UTF-8 names marked, as zipfile does), stored, time, date, CRC-32, sizes, name length
        common = (0 if name.isascii() else 0x800, 0, clock, day, crc, n, n, len(raw))
        fh.write(_LOCAL.pack(b"PK\x03\x04", 20, *common, 0) + raw)
        fh.write(head)
        fh.write(data)
        central.append(_CENTRAL.pack(b"PK\x01\x02", 20 | 3 << 8, 20, *common, 0, 0, 0, 0, 0, offset) + raw)
        offset += _LOCAL.size + len(raw) + n
    cd = b"".join(central)
    fh.write(cd)
    k = len(central)
    fh.write(_END.pack(b"PK\x05\x06", 0, 0, k, k, len(cd), offset, len(comment)) + comment)


def read_npz(path):
    """({name: array}, zip comment bytes) of an .npz file (write_npz's or np.savez's), the arrays
    np.load gives, without its per-member work (3,882 objects: a frame read 510 ms of CPU): the
    file read once, each stored member checked against its CRC-32 and viewed as its array (writeable,
    of one buffer; members of the same header parsed once). Raises ValueError (or zipfile's and
    OSError) for a damaged file, as np.load would."""
    with open(path, "rb") as fh:
        data = bytearray(os.fstat(fh.fileno()).st_size)
        if fh.readinto(data) != len(data):
            raise ValueError("file shorter than its size")
    buf = memoryview(data)
    with zipfile.ZipFile(io.BytesIO(data)) as z:  # the central directory, names as zipfile decodes them
        headers, out = {}, {}
        for info in z.infolist():
            if info.compress_type == zipfile.ZIP_STORED:
                at = info.header_offset
                if bytes(buf[at : at + 4]) != b"PK\x03\x04":
                    raise ValueError(f"bad member header of '{info.filename}'")
                *_, n_name, n_extra = _LOCAL.unpack_from(buf, at)
                at += _LOCAL.size + n_name + n_extra
                member = buf[at : at + info.file_size]
                if len(member) != info.file_size or zlib.crc32(member) != info.CRC:
                    raise ValueError(f"bad CRC-32 of '{info.filename}'")
            else:
                member = memoryview(bytearray(z.read(info)))  # (not written by us: zipfile reads it)
            # the .npy header: magic, version, its length (2 bytes in version 1, else 4), the dict
            wide = member[6:7] != b"\x01"
            size = 8 + (4 if wide else 2) + int.from_bytes(member[8 : 12 if wide else 10], "little")
            key = bytes(member[:size])
            if key not in headers:
                f, fmt = io.BytesIO(key), np.lib.format
                one = fmt.read_magic(f) == (1, 0)
                headers[key] = (fmt.read_array_header_1_0 if one else fmt.read_array_header_2_0)(f)
            shape, fortran, dtype = headers[key]
            if dtype.hasobject:
                raise ValueError(f"'{info.filename}' holds Python objects")
            a = np.frombuffer(member, dtype, math.prod(shape), size)
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            out[name] = a.reshape(shape[::-1]).T if fortran else a.reshape(shape)
        return out, z.comment


def _comment_bake_id(comment):
    """The bake id in a frame file's zip comment (bytes), or None (no id: an earlier version's file)."""
    c = comment.decode("ascii", "replace")
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
        return f"belongs to another bake (it carries no bake id; this bake's is {want[:8]})"
    return f"belongs to another bake (bake id {found[:8]}; this bake's is {want[:8]})"


def frame_filename(frame):
    return f"frame_{frame:06d}.npz" if frame >= 0 else f"frame_m{-frame:06d}.npz"


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
    for key in ("geometry", "light_shapes"):
        diff = changed_objects(old[key], new[key]) if key in old and key in new else []
        if diff:
            why.append(f"other {key.replace('_', ' ')}: " + "; ".join(diff))
    if old.get("lights", {}) != new.get("lights", {}):  # Blender lights (issue 20)
        ls = changed_objects(old.get("lights", {}), new.get("lights", {}))
        why.append("other Blender lights" + (": " + "; ".join(ls) if ls else ""))
    if not why and old.get("objects") != new.get("objects"):
        why.append("other objects or texture settings")
    if not why and old.get("signature") != new.get("signature"):
        why.append("other geometry or settings")
    return "; ".join(why)


def npz_problem(path, objects=None, bake_id=None):
    """'' if the frame file at `path` is complete (a zip of (count, 4) float32 arrays, sizes as the
    manifest says, every member's CRC-32 right) and, if `bake_id` is given, holds that bake id; else
    what is wrong. Reads the file once (read_npz: 3,882 objects, 40 ms; the zip's directory and
    each member's headers read one by one took 160)."""
    path = Path(path)
    if not path.is_file():
        return "missing"
    try:
        arrays, comment = read_npz(path)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        return f"unreadable ({exc})"
    for name, a in arrays.items():
        want = (objects or {}).get(name, {}).get("count")
        if a.ndim != 2 or a.shape[1] != 4 or a.dtype != np.float32 or (want is not None and len(a) != want):
            return f"bad array for '{name}'"
    why = _id_problem(_comment_bake_id(comment), bake_id)
    return f"'{path.name}' {why}" if why else ""


class CacheWriter:
    def __init__(self, final_dir, objects: dict, domain: str, signature: str, info: dict = None):
        self.final = Path(final_dir)
        check_writable(self.final)
        self.removed_temp = remove_stale_temp(self.final)
        self.tmp = new_temp_dir(self.final)
        # the bake the cache held when this one started: another one at commit was made meanwhile
        self.start_id = (_manifest_of(self.final) or {}).get("bake_id")
        self.objects = objects
        self.domain = domain
        self.signature = signature
        self.info = dict(info or {})
        self.bake_id = new_bake_id()
        self.frame_ids = {}  # frame file -> bake id, for files kept from the previous bake
        self.frames = {}
        self.lights = {}  # frame -> digest of its light (light shapes, Blender lights, World)
        self.kept = 0
        self.messages = []

    def write(self, frame, arrays, light=None):
        name = frame_filename(frame)
        write_frame(self.tmp / name, arrays, self.bake_id)
        self.frames[int(frame)] = name
        if light is not None:
            self.lights[int(frame)] = light
        return name

    def reuse(self, frame, prev_frame):
        self.frames[int(frame)] = self.frames[int(prev_frame)]
        if int(prev_frame) in self.lights:
            self.lights[int(frame)] = self.lights[int(prev_frame)]

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

    def relit_frames(self, baking, light_at):
        """Frames of the previous bake that this bake would keep (not in `baking`) but whose light
        differs now: light_at(frame) gives the frame's light digest as write() takes it. A light
        edited after a bake (a lamp's power, a shape's keyframes) leaves the kept frames stale; the
        bake re-bakes them instead. Frames of caches from before the digests are not checked."""
        old, why = self.previous()
        if old is None or why:
            return []
        sigs = old.manifest.get("frame_lights") or {}
        todo = [f for f in sorted(old.frames) if f not in baking and f not in self.frames and str(f) in sigs]
        return [f for f in todo if light_at(f) != sigs[str(f)]]

    def _merge_previous(self):
        old, why = self.previous()
        if old is None:
            return
        left = sorted(f for f in old.frames if f not in self.frames)
        if why:
            if old.manifest.get("bake_id") != self.start_id:
                raise CacheError(
                    f"Another bake committed frames {frame_ranges(old.frames)} into the cache folder "
                    f"'{self.final}' while this one ran, and it used {why}. This bake's frames "
                    f"{frame_ranges(self.frames)} were not written: bake every frame range of a farm "
                    "job with the same settings, or into another Cache Folder (--cache-dir)."
                )
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
            if str(f) in old.manifest.get("frame_lights", {}):
                self.lights[f] = old.manifest["frame_lights"][str(f)]
            self.kept += 1
        if lost:
            self.messages.append(
                f"Frames {frame_ranges(lost)} of the previous bake became unreadable during "
                "this bake and are not in it: bake them again."
            )

    def commit(self, before=None):
        """Under the folder's lock: before(self) (the texture files of kept frames), merge the kept
        frames of the cache as it is now, write the manifest, swap directories; then delete what the
        previous bake wrote and give every other file back to the cache folder."""
        with folder_lock(self.final):
            return self._commit(before)

    def _commit(self, before):
        refuse_problem(self.final)  # the folder may have changed during the bake
        if before is not None:
            before(self)
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
        if self.lights:
            manifest["frame_lights"] = {str(k): v for k, v in sorted(self.lights.items())}
        write_json(self.tmp / MANIFEST, manifest)
        stuck = swap_in(self.tmp, self.final)
        if stuck:
            self.messages.append(
                f"Files in the cache folder that no bake wrote have the names of this bake's files; "
                f"they were kept in '{stuck[0].parent}'."
            )
        return manifest

    def abort(self):
        shutil.rmtree(self.tmp, ignore_errors=True)


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
                data, comment = read_npz(path)
                found = _comment_bake_id(comment)
                # aligned copies (once per file read, 2.5 ms at 100k): read_npz's views sit at the
                # members' unaligned offsets, which numpy exports as buffer format '=f', and Blender's
                # foreach_set takes only 'f' whole (else element by element: 40 ms against 15 ms)
                data = {k: np.array(a, np.float32) for k, a in data.items()}
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
