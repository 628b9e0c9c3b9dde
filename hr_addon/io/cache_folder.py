"""A radiosity cache folder's ownership and life cycle (no bpy): which files a bake wrote, whether
a bake may write a folder, the temporary folders beside it, and the swap's clean-up.

Safety: a bake writes into a sibling temporary directory (.<name>.baking-<host>-<pid>-<ms>) and
only replaces the cache at the end (cache.CacheWriter.commit), every file is written to a temporary
name and os.replace()d (files.atomic_write), so a cancelled or failed bake leaves the previous cache
untouched. Temporary directories left by killed processes of this machine are removed by the next
bake of that cache (remove_stale_temp); a crash between the swap's two renames is undone by
recover().

Ownership: a bake only ever deletes or replaces what a bake of this extension wrote. Every cache
folder carries the marker file MARKER and its manifest lists the files the bake wrote ("files").
A bake into an existing folder without the marker (and without a readable manifest of ours: caches
of earlier versions) that is not empty, or onto a plain file, is refused (folder_problem). Files of
anyone else found in a cache folder are moved into the new cache at the swap, never deleted
(_retire).

Farms (docs/farm.md): several processes may bake frame ranges into one cache folder at once. Every
change of the folder's top level (the commit's merge and swap, recover(), the precompute's file and
build lock) happens under the folder's lock (folder_lock), a file beside the folder that the swap
does not move. The precompute and its kept host-visibility segments (CARRIED) stay in the folder
across bakes: the swap moves them into the new folder.
"""

import contextlib
import json
import os
import re
import shutil
import socket
import threading
import time
import uuid
from pathlib import Path

from .files import atomic_write

MANIFEST = "manifest.json"
MARKER = ".hr_radiosity"  # "this folder is a radiosity cache": written first, into every cache folder
_MARKER_TEXT = b"Written by HR Radiosity bakes. A bake replaces only the files its manifest.json lists.\n"
# names our bakes write (frames, texture sequences, atomic_write temporaries): ours in a marked folder
_OWN_NAME = re.compile(r"^(frame_m?\d{6}(_\d+)?\.npz|\..+\.\d+\.tmp|precompute\.(hrpc|hrhv|lock))$")
# written by io.precompute, not by one bake: they outlive the bake's swap (swap_in moves them along)
CARRIED = ("precompute.hrpc", "precompute.hrhv", "precompute.lock")
_OWN_TEXTURE = re.compile(r"^.+_-?\d{5,}\.(exr|png)$")
TEX_DIR = "textures"


def _own_name(rel_dir, name):
    """Whether `name` in the sub-folder `rel_dir` (posix, "." for the top) is named as bakes name
    their files."""
    if rel_dir == ".":
        return name in (MANIFEST, MARKER) or bool(_OWN_NAME.match(name))
    return rel_dir == TEX_DIR and bool(_OWN_TEXTURE.match(name) or _OWN_NAME.match(name))


class CacheError(RuntimeError):
    """Missing, corrupt or mismatched cache; the message says which and what to do."""


HOST = re.sub(r"[^A-Za-z0-9_.]", "_", socket.gethostname() or "host")
_TEMP = re.compile(
    r"^\.(?P<name>.+)\.(?P<kind>baking|old)-(?:(?P<host>[A-Za-z0-9_.]+)-)?"
    r"(?P<pid>\d+)-(?P<ms>\d+)$"
)


def _beside(final, kind):
    """The path of a temporary folder of `kind` beside the cache folder `final`, named for this
    process (temp_dirs reads the name back)."""
    return final.parent / f".{final.name}.{kind}-{HOST}-{os.getpid()}-{int(time.time() * 1000)}"


def mark(folder):
    """Create `folder` if needed and mark it as a radiosity cache folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / MARKER).is_file():
        atomic_write(folder / MARKER, _MARKER_TEXT, sync=False)
    return folder


def new_temp_dir(final_dir):
    """Create the marked folder a bake of the cache `final_dir` writes into (swap_in puts it in
    place)."""
    tmp = _beside(Path(final_dir), "baking")
    tmp.mkdir()
    return mark(tmp)


def swap_in(tmp, final_dir):
    """Replace the cache `final_dir` by the finished folder `tmp` (call under folder_lock); the
    precompute moves into the new folder; then delete what the previous bake wrote and give every
    other file back to the cache folder. Returns the paths that could not be given back (_retire)."""
    final = Path(final_dir)
    old = None
    if final.exists():
        old = _beside(final, "old")
        os.replace(final, old)
    os.replace(tmp, final)
    if old is None:
        return []
    for name in CARRIED:  # the same files (a lock keeps its holder's token and heartbeat)
        if (old / name).is_file() and not (final / name).exists():
            os.replace(old / name, final / name)
    return _retire(old, final)


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


def refuse_problem(folder, error=CacheError):
    """Raise error(why), naming the folder, unless a bake may write `folder` (folder_problem)."""
    why = folder_problem(folder)
    if why:
        raise error(why)


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
            with folder_lock(final):
                if not final.exists() or not p.exists():
                    continue  # recover() puts it back; or another process retired it
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
    refuse_problem(final)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        probe = _beside(final, "probe")
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


def recover(final_dir):
    """If a crash happened between the two renames of commit(), put the old cache back. Under the
    folder lock: a swap in progress on another node holds it, and is waited for, not undone."""
    final = Path(final_dir)
    if final.exists() or not final.parent.is_dir():
        return False
    try:
        with folder_lock(final):
            olds = sorted((ms, str(p)) for p, kind, _, _, ms in temp_dirs(final) if kind == "old")
            if final.exists() or not olds:
                return False
            os.replace(olds[-1][1], final)
            return True
    except OSError:  # a read-only parent folder: nobody can be swapping there
        return False


# -- the folder lock ---------------------------------------------------------------------------------

STALE = 30.0  # seconds without a heartbeat after which another host's lock counts as dead
_local = {}  # lock path -> [threading.RLock, depth]: re-entrant within a process


def lock_path(final_dir):
    """The folder lock's file: beside the cache folder, so that the swap does not move it."""
    final = Path(final_dir)
    return final.parent / f".{final.name}.lock"


def holder(path):
    """The content of a lock file (a dict), or None if absent or unreadable."""
    try:
        h = json.loads(Path(path).read_text())
        return h if isinstance(h, dict) else None
    except (OSError, ValueError):
        return None


def _remove_dead(path, stale):
    """Delete the lock file `path` if its holder is dead: same host and its pid gone, or no
    heartbeat (mtime) for `stale` seconds (a node that lost power). Only that lock: it is renamed
    aside and compared, and put back if another process's fresh lock was taken by mistake."""
    h = holder(path)
    try:
        age = time.time() - path.stat().st_mtime
    except FileNotFoundError:
        return
    local_dead = h is not None and h.get("host") == HOST and not pid_alive(int(h.get("pid", -1)))
    if not (local_dead or age > stale):
        return
    aside = path.with_name(f"{path.name}.{uuid.uuid4().hex}.stale")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return
    if holder(aside) != h:  # replaced in between: a live holder's, give it back
        with contextlib.suppress(OSError):
            os.link(aside, path)
    aside.unlink(missing_ok=True)


def _beat(path, stop, beat):
    while not stop.wait(beat):
        with contextlib.suppress(OSError):
            os.utime(path)


@contextlib.contextmanager
def folder_lock(final_dir, stale=STALE, poll=0.05, beat=2.0):
    """Hold the lock of the cache folder `final_dir` (waiting for it; re-entrant in a process).
    The file holds {pid, host, token}; its mtime is a heartbeat refreshed every `beat` seconds."""
    path = lock_path(final_dir)
    entry = _local.setdefault(str(path), [threading.RLock(), 0])
    with entry[0]:
        if entry[1]:
            entry[1] += 1
            try:
                yield
            finally:
                entry[1] -= 1
            return
        token = uuid.uuid4().hex
        data = json.dumps({"pid": os.getpid(), "host": HOST, "token": token}).encode()
        while True:
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
                break
            except FileExistsError:
                _remove_dead(path, stale)
                time.sleep(poll)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        stop = threading.Event()
        beating = threading.Thread(target=_beat, args=(path, stop, beat), daemon=True)
        beating.start()
        entry[1] = 1
        try:
            yield
        finally:
            entry[1] = 0
            stop.set()
            beating.join()
            if (holder(path) or {}).get("token") == token:
                path.unlink(missing_ok=True)
