"""The background bake's status file (no bpy): the worker writes it, the UI polls it.

One small JSON object, replaced atomically (write to a temporary name, os.replace) at every
progress report, so a reader sees either the previous or the next complete status. The reader
never raises on a partial, missing or foreign file: it returns None and the UI keeps the last
good status; the worker process's exit code decides what happened when the file says nothing.

Fields: version, pid, state ("running", "done", "failed", "cancelled"), stage ("start", "build",
"frame"), fraction (0..1 of the whole bake), frame, done, total, eta (seconds or null), message,
warnings (all so far), and once finished: summary, rays, error.
"""

import json
import math
import os
import time

from ..io.files import atomic_write

VERSION = 1
STATES = ("running", "done", "failed", "cancelled")


class StatusWriter:
    def __init__(self, path, **fixed):
        self.path = os.path.abspath(path)
        self.data = {
            "version": VERSION,
            "pid": os.getpid(),
            "state": "running",
            "stage": "start",
            "fraction": 0.0,
            "frame": None,
            "done": 0,
            "total": 0,
            "eta": None,
            "message": "",
            "warnings": [],
            **fixed,
        }
        self.write()

    def write(self, **changes):
        self.data.update(changes)
        self.data["updated"] = time.time()
        atomic_write(self.path, json.dumps(self.data).encode(), sync=False)  # read, not kept

    def progress(self, p):
        """A bake.BakeProgress."""
        warnings = self.data["warnings"] + [w for w in p.warnings if w not in self.data["warnings"]]
        eta = p.eta if isinstance(p.eta, (int, float)) and math.isfinite(p.eta) else None
        self.write(
            stage=p.stage,
            fraction=float(p.fraction),
            frame=p.frame if p.stage == "frame" else None,
            done=int(p.done),
            total=int(p.total),
            eta=eta,
            message=p.message,
            warnings=warnings,
        )


def read_status(path):
    """The status dict, or None when the file is missing, partial or not a status file."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("version") != VERSION or data.get("state") not in STATES:
        return None
    try:
        data["fraction"] = min(max(float(data.get("fraction") or 0.0), 0.0), 1.0)
        eta = data.get("eta")
        data["eta"] = float(eta) if eta is not None and math.isfinite(float(eta)) else None
        data["warnings"] = [str(w) for w in data.get("warnings") or []]
        data["message"] = str(data.get("message") or "")
    except (TypeError, ValueError):
        return None
    return data


def duration(seconds):
    if seconds is None:
        return ""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"
