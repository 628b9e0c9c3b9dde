"""boxes.points_in_boxes (a grid built once, queried by points) gives box_pairs' pairs exactly;
box_pairs on threads gives the serial pairs."""

import numpy as np

from hr_addon.core import boxes
from hr_addon.core.boxes import box_grid, box_pairs, points_in_boxes


def test_points_in_boxes_equals_box_pairs():
    rng = np.random.default_rng(1)
    for _ in range(12):
        m, n = rng.integers(1, 2000), rng.integers(1, 3000)
        lo = rng.random((m, 3))
        hi = lo + rng.random((m, 3)) * rng.choice([0.01, 0.1, 0.5])
        lo[:, 2] = hi[:, 2] = 0.0  # the contacts' 2D boxes in a plane's frame
        g = rng.integers(0, 4, m)
        p = rng.random((n, 3)) * 1.4 - 0.2  # some outside every box
        p[:, 2] = 0.0
        p[: n // 4] = lo[rng.integers(0, m, n // 4)]  # on box corners: the closed boxes' bounds
        gp = rng.integers(0, 4, n)
        want = box_pairs(p, p, lo, hi, gp, g)
        got = points_in_boxes(box_grid(lo, hi, g), p, gp)
        assert len(want[0]) > 0
        for w, x in zip(want, got):
            np.testing.assert_array_equal(w, x)


def test_box_pairs_on_threads_equal_the_serial_and_brute_force_pairs(monkeypatch):
    """Candidate blocks of PAIR_BLOCK pairs on 1 and 2 threads (many blocks here): the same
    sorted unique pairs as the serial loop, and as comparing every pair of boxes."""
    monkeypatch.setattr(boxes, "PAIR_BLOCK", 997)
    rng = np.random.default_rng(2)
    lo = rng.random((1500, 3))
    hi = lo + rng.random((1500, 3)) * rng.choice([0.01, 0.05, 0.3], (1500, 1))
    want = box_pairs(lo - 0.01, hi + 0.01, lo, hi)
    brute = np.nonzero(np.all((lo[None] <= hi[:, None] + 0.01) & (hi[None] >= lo[:, None] - 0.01), axis=2))
    assert len(want[0]) > 10 * 997  # at least as many candidates: over ten blocks
    for threads in (1, 2):
        got = box_pairs(lo - 0.01, hi + 0.01, lo, hi, threads=threads)
        for w, x, b in zip(want, got, brute, strict=True):
            np.testing.assert_array_equal(w, x)
            np.testing.assert_array_equal(w, b)
