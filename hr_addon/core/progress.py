"""Progress reports and cancellation for long core computations (the hierarchy build).

The core calls `Progress.update(done, total, what)` between bounded batches of work. The callback
given by the caller (the bake, the CLI, a test) receives a `ProgressInfo` and cancels the work by
raising `Cancelled` (or any exception): nothing the core computed so far is kept, and the
exception propagates out of the constructor that was building.
"""

import time
from dataclasses import dataclass


class Cancelled(Exception):
    """Raised by a progress callback (or the core on its behalf) to stop a computation."""


@dataclass
class ProgressInfo:
    phase: str  # e.g. "linking", "visibility", "push corrections"
    fraction: float  # 0..1 of the whole build (estimated)
    done: int  # work units finished in this phase
    total: int  # work units known so far in this phase (may grow while refining)
    elapsed: float  # seconds since the build started
    eta: float  # estimated seconds left (nan while unknown)
    part: float = 0.0  # 0..1 of this phase

    @property
    def message(self):
        """'linking 40% (1,200/3,000), build 66%': the phase's own share done, then the build's
        (a phase's single unit of work, as '(1/1)', says nothing and is left out)."""
        eta = "" if self.eta != self.eta else f", about {_duration(self.eta)} left"
        units = f" ({self.done:,}/{self.total:,})" if self.total > 1 else ""
        return f"{self.phase} {100 * self.part:.0f}%{units}, build {100 * self.fraction:.0f}%{eta}"


def _duration(s):
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.1f} min"


class Progress:
    """Maps per-phase progress onto one fraction of a whole computation and estimates time left.

    phases: {name: weight}, the expected share of the total time of each phase (normalised).
    callback(ProgressInfo) is called at most every `interval` seconds (and at every phase end)."""

    def __init__(self, callback=None, phases=None, interval=0.25):
        self.callback = callback
        w = dict(phases or {"build": 1.0})
        s = sum(w.values()) or 1.0
        self._start, acc = {}, 0.0
        for k, v in w.items():
            self._start[k] = acc
            acc += v / s
        self._weight = {k: v / s for k, v in w.items()}
        self.t0 = time.perf_counter()
        self._last = -1e9
        self.interval = interval

    def update(self, phase, done, total, force=False):
        if self.callback is None:
            return
        now = time.perf_counter()
        if not force and now - self._last < self.interval:
            return
        self._last = now
        part = min(max(done / total, 0.0), 1.0) if total > 0 else 0.0
        frac = self._start.get(phase, 0.0) + self._weight.get(phase, 0.0) * part
        el = now - self.t0
        eta = el * (1 - frac) / frac if frac > 0.02 and el > 1.0 else float("nan")
        self.callback(ProgressInfo(phase, frac, int(done), int(total), el, eta, part))

    def done(self, phase):
        self.update(phase, 1, 1, force=True)


NO_PROGRESS = Progress(None)
