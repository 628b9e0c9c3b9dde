"""boxes.points_in_boxes (a grid built once, queried by points) gives box_pairs' pairs exactly;
box_pairs on threads gives the serial pairs."""

import numpy as np

from hr_addon.core import boxes
from hr_addon.core.boxes import box_grid, box_pairs, points_in_boxes


def test_points_in_boxes_equals_box_pairs():
    """2D boxes and points (the test skips their flat axis) and 3D ones."""
    rng = np.random.default_rng(1)
    for k in range(12):
        m, n = rng.integers(1, 2000), rng.integers(1, 3000)
        lo = rng.random((m, 3))
        hi = lo + rng.random((m, 3)) * rng.choice([0.01, 0.1, 0.5])
        g = rng.integers(0, 4, m)
        p = rng.random((n, 3)) * 1.4 - 0.2  # some outside every box
        if k % 3:
            lo[:, 2] = hi[:, 2] = 0.0  # the contacts' 2D boxes in a plane's frame
            p[:, 2] = 0.0 if k % 3 == 1 else p[:, 2] * (rng.random(n) < 0.5)  # (all or half in it)
        p[: n // 4] = lo[rng.integers(0, m, n // 4)]  # on box corners: the closed boxes' bounds
        gp = rng.integers(0, 4, n)
        want = box_pairs(p, p, lo, hi, gp, g)
        got = points_in_boxes(box_grid(lo, hi, g), p, gp)
        assert len(want[0]) > 0
        for w, x in zip(want, got):
            np.testing.assert_array_equal(w, x)


def test_box_pairs_on_threads_equal_the_serial_and_brute_force_pairs(monkeypatch):
    """Candidate blocks of PAIR_BLOCK pairs on 1 and 2 threads (many blocks here, each in steps
    of PAIR_STEP pairs, merged): the same sorted unique pairs as the serial loop, and as comparing
    every pair of boxes."""
    monkeypatch.setattr(boxes, "PAIR_BLOCK", 997)
    monkeypatch.setattr(boxes, "PAIR_STEP", 101)
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


def test_row_groups_and_unique_helpers_equal_numpys_unique():
    """row_groups: np.unique(axis=0)'s inverse and counts (integer rows, and float rows where -0.0
    and 0.0 are one value); merge_unique and unique_ints (1 and 2 threads, many blocks): np.unique."""
    rng = np.random.default_rng(4)
    for rows in (
        rng.integers(-3, 4, (5000, 5)),
        rng.integers(-(10**12), 10**12, (300, 2))[rng.integers(0, 300, 3000)],
        rng.integers(0, 50, (4000, 1)),
        np.round(rng.standard_normal((4000, 4)) * 2) * rng.choice([-1.0, 1.0], (4000, 4)),
    ):
        _, inv, cnt = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
        got_inv, got_cnt = boxes.row_groups(rows)
        np.testing.assert_array_equal(got_inv, inv.ravel())
        np.testing.assert_array_equal(got_cnt, cnt)
        assert cnt.max() > 1
    x = rng.integers(0, 20000, 50_000)
    parts = [np.unique(x[i : i + 7000]) for i in range(0, len(x), 7000)]
    np.testing.assert_array_equal(boxes.merge_unique(parts), np.unique(x))
    assert len(boxes.merge_unique([])) == 0
    for threads in (None, 1, 2):
        np.testing.assert_array_equal(boxes.unique_ints(x, threads, block=4096), np.unique(x))


def test_norm3_is_linalg_norm_bit_for_bit():
    from hr_addon.core.formfactor import norm3

    rng = np.random.default_rng(5)
    v = rng.standard_normal((20000, 5, 3)) * rng.uniform(1e-6, 1e6, (20000, 5, 1))
    assert np.array_equal(norm3(v), np.linalg.norm(v, axis=-1))
    assert np.array_equal(norm3(v[:, 0]), np.linalg.norm(v[:, 0], axis=1))


def test_box_pairs_keyed_inside_the_blocks_equal_the_pairs_keys(monkeypatch):
    """box_pairs(key=...) (Contacts' (plane, occluder) keys made inside each block, session 22):
    the sorted unique keys of all the pairs it would return, serially and on 1 and 2 threads (each
    block in steps of PAIR_STEP pairs)."""
    monkeypatch.setattr(boxes, "PAIR_BLOCK", 997)
    monkeypatch.setattr(boxes, "PAIR_STEP", 101)
    rng = np.random.default_rng(6)
    lo = rng.random((1500, 3))
    hi = lo + rng.random((1500, 3)) * rng.choice([0.01, 0.05, 0.3], (1500, 1))
    plane = rng.integers(0, 40, 1500)

    def key(i, j):
        keep = (i != j) & (plane[i] != plane[j])
        return plane[i[keep]] * 1500 + j[keep]

    i, j = box_pairs(lo - 0.01, hi + 0.01, lo, hi)
    want = np.unique(key(i, j))
    assert len(want) > 1000
    for threads in (None, 1, 2):
        np.testing.assert_array_equal(box_pairs(lo - 0.01, hi + 0.01, lo, hi, threads=threads, key=key), want)
    assert len(box_pairs(lo[:0], hi[:0], lo, hi, key=key)) == 0
