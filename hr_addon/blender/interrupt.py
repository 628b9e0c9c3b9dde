"""Ctrl-C (SIGINT) and SIGTERM for the command-line bake (no bpy).

The handler only records the signal, except inside `raising()` regions (the core's computations:
pure Python and numpy, no Blender callbacks), where it raises Cancelled at once. Everywhere else
the bake checks `check()` between bounded steps (between batches of the hierarchy build, between
frames), so the cancel comes within a second or two in any phase and never inside Blender code
that would swallow the exception and print a traceback, nor inside the cache's commit. The bake's
cleanup (removing its temporary folder) then runs as for any other error.
"""

import signal
from contextlib import contextmanager

from ..core.progress import Cancelled

SIGNALS = tuple(
    s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None)) if s is not None
)


class Interrupts:
    def __init__(self):
        self.signum = 0  # the first signal received (0: none)
        self._raising = 0
        self._old = {}

    @property
    def requested(self):
        return bool(self.signum)

    @property
    def name(self):
        try:
            return signal.Signals(self.signum).name
        except ValueError:
            return str(self.signum)

    def install(self):
        """Handle SIGINT and SIGTERM (main thread only; elsewhere a no-op). Idempotent."""
        for s in SIGNALS:
            if s in self._old:
                continue
            try:
                self._old[s] = signal.signal(s, self._handler)
            except (ValueError, OSError):  # not the main thread
                pass
        return self

    def restore(self):
        for s, old in self._old.items():
            try:
                signal.signal(s, old if old is not None else signal.SIG_DFL)
            except (ValueError, OSError, TypeError):
                pass
        self._old.clear()

    def _handler(self, signum, frame):
        if not self.signum:
            self.signum = signum
        if self._raising > 0:
            self._raising = 0  # once: the cleanup that follows must not be interrupted
            raise Cancelled(f"cancelled ({self.name})")

    def check(self):
        """Raise Cancelled if a signal came."""
        if self.signum:
            raise Cancelled(f"cancelled ({self.name})")

    @contextmanager
    def raising(self):
        """A region where the signal raises at once (no Blender callbacks may run inside)."""
        self.check()
        self._raising += 1
        depth = self._raising
        try:
            yield
        finally:
            self._raising = max(0, min(self._raising, depth) - 1)


INTERRUPTS = Interrupts()
