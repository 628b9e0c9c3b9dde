"""Files that are complete or absent (no bpy).

Every file of a bake is written under a temporary name beside its final one and os.replace()d
into place, so a reader, a crash or a cancelled bake sees the old file or the new one, never part
of one. Frames whose content repeats are hard links of the first file (copies where the file
system has no hard links).
"""

import os
import shutil


def atomic_write(path, data, sync=True):
    """Write `data` (bytes, or a function taking the open binary file) to `path` atomically.
    sync: fsync before the rename, so a power cut after the cache swap cannot leave an empty file
    under the final name (the job status file, rewritten at every progress report, skips it)."""
    path = os.fspath(path)
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            if callable(data):
                data(fh)
            else:
                fh.write(data)
            if sync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def link_or_copy(src, dst):
    """Hard link src as dst (replacing dst), or copy it where hard links are not supported."""
    if os.path.lexists(dst):
        os.unlink(dst)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)
