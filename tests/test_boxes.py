"""boxes.points_in_boxes (a grid built once, queried by points) gives box_pairs' pairs exactly."""

import numpy as np

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
