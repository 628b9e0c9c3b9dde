"""Progress reports and cancellation for long core computations (the hierarchy build).

The core calls `Progress.update(done, total, what)` between bounded batches of work. The callback
given by the caller (the bake, the CLI, a test) receives a `ProgressInfo` and cancels the work by
raising `Cancelled` (or any exception): nothing the core computed so far is kept, and the
exception propagates out of the constructor that was building.
"""

import math
import time
from dataclasses import dataclass

# no numpy here: the command-line bake imports Cancelled (blender/interrupt.py) before it can
# handle Ctrl-C, and numpy's import takes a second on a loaded machine


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
        (a phase's single unit of work, as '(1/1)', says nothing and is left out). A finished
        build has no time left to tell (its countdown may still hold a few seconds)."""
        eta = "" if self.eta != self.eta or self.fraction >= 1 else f", about {_duration(self.eta)} left"
        units = f" ({self.done:,}/{self.total:,})" if self.total > 1 else ""
        return f"{self.phase} {100 * self.part:.0f}%{units}, build {100 * self.fraction:.0f}%{eta}"


class SteadyEta:
    """A time left that counts down steadily instead of following every noisy estimate.

    Between two estimates the shown value counts down by the time that passed (the countdown). A
    new raw estimate within a band around the countdown (`slack` of it, or the caller's absolute
    `band`, whichever is wider) leaves the countdown as it is; one outside moves the value by
    `gain` of its distance to the band (down when the work goes faster than shown, up only when it
    is clearly slower). So the shown value does not jump with each estimate's noise and rises only
    when the work really is slower than shown."""

    def __init__(self, gain=0.3, slack=0.1, clock=time.perf_counter):
        self.gain, self.slack, self.clock = gain, slack, clock
        self.value = float("nan")
        self.t = None

    def update(self, raw, now=None, band=0.0):
        """Feed a raw estimate (seconds left, nan: unknown); returns the value to show. band:
        seconds by which raw may differ from the countdown without moving it (e.g. the time of one
        costly step, by which an estimate counted in steps runs ahead or behind the clock)."""
        now = self.clock() if now is None else now
        if self.t is not None and self.value == self.value:
            countdown = max(self.value - (now - self.t), 0.0)
            tol = max(self.slack * countdown, band)
            if raw == raw and abs(raw - countdown) > tol:  # a step of `gain` towards the band's edge
                self.value = countdown + self.gain * (raw - countdown - math.copysign(tol, raw - countdown))
            else:
                self.value = countdown
        else:
            self.value = float(raw)
        self.t = now
        return self.value


class FrameEta:
    """Time left of a run of `total` work units (a bake's frames) from the time each one took: an
    exponential moving average of the per-unit time (the plain mean over the first units, then
    weight `alpha` for the newest), times the units left, shown through SteadyEta with the longest
    recent unit as its band. Frames that reuse the previous file take almost no time and solved
    frames seconds: counted in frames, the estimate runs ahead of the clock over cheap frames and
    behind it over a costly one, by about one costly frame; the band absorbs that."""

    def __init__(self, total, alpha=0.05, window=32, clock=time.perf_counter, **steady):
        self.total, self.alpha, self.window = int(total), alpha, int(window)
        self.n, self.mean = 0, 0.0
        self.recent = []
        self.steady = SteadyEta(clock=clock, **steady)

    def done(self, seconds, now=None):
        """One unit finished after `seconds`; returns the seconds left to show."""
        self.n += 1
        a = max(1.0 / self.n, self.alpha)
        self.mean += a * (float(seconds) - self.mean)
        self.recent = (self.recent + [float(seconds)])[-self.window :]
        left = self.total - self.n
        if left <= 0:
            self.steady.value = 0.0
            return 0.0
        return self.steady.update(self.mean * left, now, band=max(self.recent))


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
        self._eta = SteadyEta()

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
        raw = el * (1 - frac) / frac if frac > 0.02 and el > 1.0 else float("nan")
        eta = self._eta.update(raw, now) if raw == raw or self._eta.value == self._eta.value else raw
        self.callback(ProgressInfo(phase, frac, int(done), int(total), el, eta, part))

    def done(self, phase):
        self.update(phase, 1, 1, force=True)


NO_PROGRESS = Progress(None)
