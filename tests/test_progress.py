"""Progress reports (hr_addon/core/progress.py, no bpy): the time left is stable."""

import numpy as np
import pytest

from hr_addon.core.progress import FrameEta, Progress, SteadyEta


def _bursty(rng, n=120):
    """A light-shape animation: a frame that solves (2 s, +-30%), then 3-7 frames whose light did not
    change (they reuse the file: 0.02 s)."""
    out = []
    while len(out) < n:
        out.append(2.0 * rng.uniform(0.7, 1.3))
        out += [0.02] * int(rng.integers(3, 8))
    return np.array(out[:n])


def _uneven(rng, n=100):
    """Every frame solves, each taking 0.5-1.5 s."""
    return rng.uniform(0.5, 1.5, n)


def _reported(seconds, estimator):
    t = np.cumsum(seconds)
    return np.array([estimator(s, now) for s, now in zip(seconds, t)]), t[-1] - t


def _old_estimate(seconds):
    """The estimate before FrameEta: elapsed / frames done x frames left."""
    t = np.cumsum(seconds)
    n = len(seconds)
    return np.array([t[i] / (i + 1) * (n - i - 1) for i in range(n)])


def _largest_rise(est, start=3, rel=0.05, floor=0.5):
    """The largest rise of the reported time left from one report to the next beyond the tolerance
    max(rel x the value, floor seconds), from report `start` on (the first reports know one or two
    frames only)."""
    e = np.asarray(est)
    return float(np.max(e[start + 1 :] - e[start:-1] - np.maximum(rel * e[start:-1], floor)))


@pytest.mark.parametrize("make", [_bursty, _uneven])
@pytest.mark.parametrize("seed", range(10))
def test_time_left_counts_down_on_a_synthetic_bake(make, seed):
    seconds = make(np.random.default_rng(seed))
    eta = FrameEta(len(seconds))
    est, true = _reported(seconds, lambda s, now: eta.done(s, now))
    assert _largest_rise(est) <= 0.0, _largest_rise(est)
    assert est[-1] == 0.0 and np.all(est >= 0)
    # still an estimate of the time left: from a quarter of the frames on, off by at most a third of
    # the whole bake's time (the old estimate is off by as much on these sequences)
    k = slice(len(seconds) // 4, None)
    assert np.max(np.abs(est[k] - true[k])) <= 0.34 * true[0] + seconds[0]


def test_the_old_estimate_jumped_on_the_same_sequences():
    """The test above means something: the estimate it replaced fails it."""
    assert _largest_rise(_old_estimate(_bursty(np.random.default_rng(0)))) > 5.0
    assert _largest_rise(_old_estimate(_uneven(np.random.default_rng(0)))) > 0.0


def test_time_left_follows_a_real_slowdown():
    """Frames that become twice as slow halfway: the estimate rises, in steps, to the new pace."""
    rng = np.random.default_rng(3)
    seconds = np.r_[np.full(50, 0.5), np.full(50, 1.0)] * rng.uniform(0.95, 1.05, 100)
    eta = FrameEta(len(seconds))
    est, true = _reported(seconds, lambda s, now: eta.done(s, now))
    assert est[49] < 0.8 * true[49]  # before: the slower half is not known
    assert abs(est[85] - true[85]) < 0.25 * true[85]  # after: caught up
    assert float(np.max(np.diff(est))) < 0.15 * float(est[49])  # no single jump


def test_steady_eta_counts_down_between_estimates():
    s = SteadyEta()
    assert s.update(100.0, now=0.0) == 100.0
    assert s.update(float("nan"), now=10.0) == 90.0  # unknown: the countdown
    assert s.update(95.0, now=10.5) == pytest.approx(89.5)  # within 10%: the countdown
    assert s.update(300.0, now=11.0) == pytest.approx(89.0 + 0.3 * (300.0 - 89.0 - 8.9))


def _build_etas(monkeypatch, steady=True):
    """Time left reported by a build whose second phase takes 3x the share its weight says."""
    import hr_addon.core.progress as mod

    clock = [0.0]
    monkeypatch.setattr(mod.time, "perf_counter", lambda: clock[0])
    seen = []
    p = Progress(seen.append, {"a": 0.5, "b": 0.5}, interval=0.0)
    if not steady:
        p._eta.update = lambda raw, now=None: raw  # the raw estimate, as before SteadyEta
    for phase, steps, dt in (("a", 10, 1.0), ("b", 10, 3.0)):
        for k in range(1, steps + 1):
            clock[0] += dt
            p.update(phase, k, steps)
    return np.array([i.eta for i in seen if i.eta == i.eta])


def test_build_progress_time_left_is_steady(monkeypatch):
    """Phases weighted wrongly do not make the build's time left go up and down."""
    eta = _build_etas(monkeypatch)
    assert len(eta) >= 15 and np.all(np.diff(eta) <= 1e-9), eta
    raw = _build_etas(monkeypatch, steady=False)
    assert np.max(np.diff(raw)) > 0.5  # the raw estimate rises when the slow phase starts


def test_a_finished_build_tells_no_time_left(monkeypatch):
    """The build's last line read "push corrections 100%, build 100%, about 0 s left" (or a few
    seconds: the countdown of the last estimate) whenever the build took over a second."""
    import hr_addon.core.progress as mod

    clock = [0.0]
    monkeypatch.setattr(mod.time, "perf_counter", lambda: clock[0])
    seen = []
    p = Progress(seen.append, {"a": 0.5, "b": 0.5}, interval=0.0)
    for phase in ("a", "b"):
        for k in range(1, 5):
            clock[0] += 1.0
            p.update(phase, k, 4)
    assert "left" in seen[-2].message, seen[-2].message  # still under way: an estimate
    assert seen[-1].fraction == 1 and seen[-1].message == "b 100% (4/4), build 100%"


def test_the_cli_handles_ctrl_c_before_numpy_is_imported():
    """Ctrl-C in the command-line bake's first second killed it with a traceback: its signal
    handler's module imported numpy (through core.progress) before it could be installed."""
    import subprocess
    import sys
    from pathlib import Path

    code = "import sys, hr_addon.blender.interrupt; print(sorted(m for m in sys.modules if 'numpy' in m))"
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
