"""On-disk bake cache (no bpy): one .npz per distinct frame plus a JSON manifest.

Layout of a cache directory (default //hr_cache/<blend name>/):
    manifest.json         domain, objects {name: {mesh, count}}, frames {"1": "frame_000001.npz", ...}
    frame_000001.npz      one float32 (count, 4) RGBA array per object: linear outgoing radiance
Frames whose light state did not change point at the previous frame's file (no new file).

Safety: a bake writes into a sibling temporary directory and only replaces the cache at the end
(CacheWriter.commit), every file is written to a temporary name and os.replace()d, so a
cancelled or failed bake leaves the previous cache untouched. Frames of the previous cache that
the new bake did not cover are kept when the geometry and settings are identical, so baking
frames 1-50 and 51-100 separately yields the same cache as baking 1-100 once.
"""
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

FORMAT = 1
MANIFEST = "manifest.json"


class CacheError(RuntimeError):
    """Missing, corrupt or mismatched cache; the message says which and what to do."""


def _atomic_write_bytes(path: Path, write):
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path: Path, data):
    _atomic_write_bytes(Path(path), lambda fh: fh.write(json.dumps(data, indent=1, sort_keys=True).encode()))


def write_frame(path: Path, arrays: dict):
    """Atomically write {object name: (N, 3|4) values} as float32 RGBA arrays."""
    out = {}
    for name, a in arrays.items():
        a = np.asarray(a, np.float32)
        if a.shape[1] == 3:
            a = np.concatenate([a, np.ones((len(a), 1), np.float32)], 1)
        out[name] = np.ascontiguousarray(a)
    _atomic_write_bytes(Path(path), lambda fh: np.savez(fh, **out))


def frame_filename(frame):
    return f"frame_{frame:06d}.npz" if frame >= 0 else f"frame_m{-frame:06d}.npz"


class CacheWriter:
    def __init__(self, final_dir, objects: dict, domain: str, signature: str, info: dict = None):
        self.final = Path(final_dir)
        self.final.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.final.parent / f".{self.final.name}.baking-{os.getpid()}-{int(time.time() * 1000)}"
        self.tmp.mkdir()
        self.objects = objects
        self.domain = domain
        self.signature = signature
        self.info = dict(info or {})
        self.frames = {}
        self.kept = 0
        self.messages = []

    def write(self, frame, arrays):
        name = frame_filename(frame)
        write_frame(self.tmp / name, arrays)
        self.frames[int(frame)] = name
        return name

    def reuse(self, frame, prev_frame):
        self.frames[int(frame)] = self.frames[int(prev_frame)]

    def _merge_previous(self):
        try:
            old = CacheReader(self.final)
        except CacheError:
            return
        m = old.manifest
        if m.get("signature") != self.signature or m.get("domain") != self.domain \
                or m.get("objects") != self.objects:
            self.messages.append("Previous bake used other geometry or settings; its frames were discarded.")
            return
        renamed = {}
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
                if not src.is_file():
                    continue
                try:
                    os.link(src, self.tmp / dst)
                except OSError:
                    shutil.copy2(src, self.tmp / dst)
                renamed[name] = dst
            self.frames[f] = renamed[name]
            self.kept += 1

    def commit(self):
        """Merge the kept frames of the previous bake, write the manifest, swap directories."""
        self._merge_previous()
        manifest = dict(self.info, format=FORMAT, domain=self.domain, objects=self.objects,
                        signature=self.signature, frames={str(k): v for k, v in sorted(self.frames.items())})
        write_json(self.tmp / MANIFEST, manifest)
        old = None
        if self.final.exists():
            old = self.final.parent / f".{self.final.name}.old-{os.getpid()}-{int(time.time() * 1000)}"
            os.replace(self.final, old)
        os.replace(self.tmp, self.final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return manifest

    def abort(self):
        shutil.rmtree(self.tmp, ignore_errors=True)


def recover(final_dir):
    """If a crash happened between the two renames of commit(), put the old cache back."""
    final = Path(final_dir)
    if final.exists() or not final.parent.is_dir():
        return False
    olds = sorted(final.parent.glob(f".{final.name}.old-*"))
    if olds:
        os.replace(olds[-1], final)
        return True
    return False


class CacheReader:
    _files = {}   # (path, mtime) -> arrays; small LRU shared by readers

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
        if not self.frames:
            raise CacheError(f"Radiosity cache '{self.dir}' holds no frames.")
        self.manifest = m
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
        data = self._files.get(key)
        if data is None:
            try:
                with np.load(path, allow_pickle=False) as z:
                    data = {k: np.ascontiguousarray(z[k], np.float32) for k in z.files}
            except Exception as exc:
                raise CacheError(f"Corrupt radiosity cache file '{path}': {exc}") from None
            for k, a in data.items():
                want = self.objects.get(k, {}).get("count")
                if a.ndim != 2 or a.shape[1] != 4 or (want is not None and len(a) != want):
                    raise CacheError(f"Corrupt radiosity cache file '{path}': bad array for '{k}'.")
            if len(self._files) > 32:
                self._files.clear()
            self._files[key] = data
        return data
