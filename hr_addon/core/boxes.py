"""Box and segment helpers shared by contacts.py and slots.py: sorted lookups, CSR row expansion,
pairs of overlapping axis-aligned boxes through a uniform grid, 2D ray exits."""

import numpy as np

from .parallel import batch_map, ranges

# candidate pairs per batch of box_pairs on threads (core.parallel): fixed, never by the thread
# count (the pairs come out sorted and unique whatever the blocks)
PAIR_BLOCK = 1 << 20
# candidate pairs per step within a block: its int64 temporaries (1 MB) come from the heap and stay
# in the cache, where a whole block's (8 MB, madvised huge pages) were faulted in fresh and unmapped
# each time: a third of box_pairs' CPU was system time at 100k (issue 23, docs/threads.md, session
# 36); the keys are each step's unique ones merged (merge_unique): the same
PAIR_STEP = 1 << 17


def sorted_index(table, keys):
    """Index of each key in the sorted array table, -1 where it is absent."""
    keys = np.asarray(keys)
    if not len(table):
        return np.full(keys.shape, -1, np.int64)
    i = np.minimum(np.searchsorted(table, keys), len(table) - 1)
    return np.where(table[i] == keys, i, -1)


def row_groups(rows):
    """(inverse, counts) of np.unique(rows, axis=0, return_inverse=True, return_counts=True): the
    same groups, numbered in the same (lexicographic) order, from one lexsort of the columns
    instead of a sort of the rows as structured records (4-5x faster on the build's keys)."""
    rows = np.asarray(rows)
    n = len(rows)
    order = np.lexsort(rows.T[::-1])
    s = rows[order]
    new = np.ones(n, bool)
    new[1:] = (s[1:] != s[:-1]).any(1)
    inv = np.empty(n, np.int64)
    inv[order] = np.cumsum(new) - 1
    return inv, np.diff(np.r_[np.flatnonzero(new), n])


def spans(start, end):
    """(owner, index) of the concatenated ranges [start_i, end_i): every index, range by range in
    order, and which range it lies in."""
    start = np.asarray(start)
    n = np.asarray(end) - start
    owner = np.repeat(np.arange(len(n)), n)
    return owner, np.repeat(start - (np.cumsum(n) - n), n) + np.arange(len(owner))


def csr_rows(start, rows):
    """Every element of the CSR rows `rows` (offsets `start`): (position in `rows` of each, its
    index), row by row in order."""
    return spans(start[rows], start[rows + 1])


def grid_cells(lo, hi, origin, size, dims, group):
    """(box index, cell key) for every grid cell each box overlaps; boxes of different groups
    never share a cell."""
    c0 = np.floor((lo - origin) / size).astype(np.int64)
    c1 = np.floor((hi - origin) / size).astype(np.int64)
    span = c1 - c0 + 1
    cnt = span.prod(1)
    box = np.repeat(np.arange(len(lo)), cnt)
    k = np.arange(len(box)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    key = np.zeros(len(box), np.int64) if group is None else np.asarray(group, np.int64)[box]
    for ax in range(3):
        key = key * dims[ax] + c0[box, ax] + k % span[box, ax]
        k //= span[box, ax]
    return box, key


def box_pairs(lo_a, hi_a, lo_b, hi_b, group_a=None, group_b=None, max_refs=4_000_000, threads=None, key=None):
    """Index pairs (i, j) whose axis-aligned boxes overlap (and whose groups are equal, if
    given), through a uniform grid: cells about the median box size, coarsened until the cell
    lists fit, so the cost follows the overlaps rather than all pairs. threads: the candidate
    pairs' blocks (PAIR_BLOCK) as a batch map on that many threads; None: a plain loop over
    blocks of max_refs. key: a function (i, j) -> int64 keys of (some of) the overlapping pairs
    (a filter and a key in one); then the sorted unique keys are returned instead of the pairs
    (each block's own, merged: the same as the keys of all pairs, without the pairs' unique)."""
    if not len(lo_a) or not len(lo_b):
        if key is not None:
            return np.zeros(0, np.int64)
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    origin = np.minimum(lo_a.min(0), lo_b.min(0))
    ext = np.maximum(hi_a.max(0), hi_b.max(0)) - origin
    span = float(ext.max()) or 1.0
    size = max(float(np.median(np.concatenate([hi_a - lo_a, hi_b - lo_b]).max(1))), 1e-3 * span)
    while True:
        n = sum(
            int(np.prod(np.floor((top - origin) / size) - np.floor((bot - origin) / size) + 1, axis=1).sum())
            for bot, top in ((lo_a, hi_a), (lo_b, hi_b))
        )
        if n <= max_refs or size >= span:
            break
        size *= 2
    dims = (np.floor(ext / size) + 1).astype(np.int64)
    ba, ka = grid_cells(lo_a, hi_a, origin, size, dims, group_a)
    bb, kb = grid_cells(lo_b, hi_b, origin, size, dims, group_b)
    order = np.argsort(kb, kind="stable")
    kb, bb = kb[order], bb[order]
    first = np.searchsorted(kb, ka, "left")
    cnt = np.searchsorted(kb, ka, "right") - first
    # candidate pairs in blocks of about `block`: their temporaries stay bounded
    ends = np.cumsum(cnt)
    block = max_refs if threads is None else PAIR_BLOCK
    cuts = np.searchsorted(ends, np.arange(block, int(ends[-1]) if len(ends) else 0, block))

    cm = [np.ascontiguousarray(x.T) for x in (lo_a, hi_a, lo_b, hi_b)]  # per axis: 1-D gathers

    def step(s, e):
        c = cnt[s:e]
        i = np.repeat(ba[s:e], c)
        j = bb[np.repeat(first[s:e], c) + np.arange(len(i)) - np.repeat(np.cumsum(c) - c, c)]
        ok = _overlap(cm, i, j)
        if key is not None:
            return np.unique(key(i[ok], j[ok]))
        return np.unique(i[ok] * len(lo_b) + j[ok])

    def pairs(s, e):  # a block by steps of about PAIR_STEP candidate pairs (rows s..e of a)
        if e - s <= 1:
            return step(s, e)
        at = np.cumsum(cnt[s:e])
        cut = s + np.searchsorted(at, np.arange(PAIR_STEP, int(at[-1]), PAIR_STEP))
        parts = [step(i, j) for i, j in zip(np.r_[s, cut], np.r_[cut, e]) if j > i]
        return parts[0] if len(parts) == 1 else merge_unique(parts)

    blocks = list(zip(np.r_[0, cuts], np.r_[cuts, len(ka)]))
    keys = [pairs(s, e) for s, e in blocks] if threads is None else batch_map(pairs, blocks, threads)
    if key is not None:
        return merge_unique(keys)
    keys = merge_unique(keys)
    return keys // len(lo_b), keys % len(lo_b)


def unique_ints(x, threads=None, block=PAIR_BLOCK):
    """np.unique(x) of an integer array: its blocks' np.unique as a batch map on threads (fixed
    blocks), then merged (merge_unique); the same array. threads None: np.unique."""
    if threads is None:
        return np.unique(x)
    return merge_unique(batch_map(lambda i, j: np.unique(x[i:j]), ranges(len(x), block), threads))


def merge_unique(parts):
    """np.unique(np.concatenate(parts)) of sorted unique integer arrays: the stable sort (timsort)
    merges the sorted runs, 5x faster than np.unique's sort from scratch; the same array."""
    if not parts:
        return np.zeros(0, np.int64)
    s = np.sort(np.concatenate(parts), kind="stable")
    keep = np.ones(len(s), bool)
    keep[1:] = s[1:] != s[:-1]
    return s[keep]


def _overlap(cm, i, j):
    """Boxes i of a and j of b overlap (cm: lo_a, hi_a, lo_b, hi_b component major), axis by axis
    on the pairs still in (a third of the gathers of (P, 3) rows)."""
    lo_a, hi_a, lo_b, hi_b = cm
    keep = np.arange(len(i))
    for ax in range(lo_a.shape[0]):
        ii, jj = i[keep], j[keep]
        keep = keep[(lo_b[ax][jj] <= hi_a[ax][ii]) & (hi_b[ax][jj] >= lo_a[ax][ii])]
    ok = np.zeros(len(i), bool)
    ok[keep] = True
    return ok


def box_grid(lo, hi, group=None, max_refs=4_000_000):
    """A uniform grid over the boxes (lo, hi) (M, 3) for repeated point queries (points_in_boxes):
    built once, where box_pairs would rebuild it (and size it by the query points too) per call.
    Cells about the small boxes' size (the 10th percentile), coarsened until there are at most 32
    cell entries per box: a point then meets few boxes whose own box misses it (on the furnished
    room's contact chains 8x faster queries than at the median box size, for 14 entries per box)."""
    origin = lo.min(0)
    ext = hi.max(0) - origin
    span = float(ext.max()) or 1.0
    size = max(float(np.percentile((hi - lo).max(1), 10)), 1e-3 * span)
    while True:
        n = int(np.prod(np.floor((hi - origin) / size) - np.floor((lo - origin) / size) + 1, axis=1).sum())
        if n <= min(max_refs, 32 * len(lo)) or size >= span:
            break
        size *= 2
    dims = (np.floor(ext / size) + 1).astype(np.int64)
    box, key = grid_cells(lo, hi, origin, size, dims, group)
    order = np.argsort(key, kind="stable")
    # the occupied cells once each (one search per query point, in a shorter array), their first
    # entry; the boxes component major (the queries' overlap test runs axis by axis)
    cells, first = np.unique(key[order], return_index=True)
    cm = (np.ascontiguousarray(lo.T), np.ascontiguousarray(hi.T))
    # axes on which every box is the one value (the contact chains' boxes in their planes: z = 0)
    same = ((lo == lo[:1]) & (hi == lo[:1])).all(0) if len(lo) else np.zeros(lo.shape[1], bool)
    flat = [float(lo[0, ax]) if same[ax] else None for ax in range(lo.shape[1])]
    return cells, np.r_[first, len(key)], box[order], origin, size, dims, cm, flat


def points_in_boxes(grid, p, group=None):
    """Index pairs (i, j), sorted by i then j, of the points p (N, 3) lying in box j of grid
    (box_grid) whose group equals the point's: box_pairs(p, p, lo, hi, group, groups)'s pairs."""
    cells, start, box, origin, size, dims, (lo, hi), flat = grid
    # the cells by columns (an (N, 3) array's ops broadcast over rows of 3 loop per row: 3x the
    # time of three contiguous passes; the same values)
    inside, cs = np.ones(len(p), bool), []
    for ax in range(3):
        c = np.floor((p[:, ax] - origin[ax]) / size).astype(np.int64)
        inside &= (c >= 0) & (c < dims[ax])
        cs.append(c)
    idx = np.flatnonzero(inside)
    key = np.zeros(len(idx), np.int64) if group is None else np.asarray(group, np.int64)[idx]
    for ax in range(3):
        key = key * dims[ax] + cs[ax][idx]
    at = np.searchsorted(cells, key)
    found = at < len(cells)
    found[found] = cells[at[found]] == key[found]
    idx, at = idx[found], at[found]
    first = start[at]
    cnt = start[at + 1] - first
    i = np.repeat(idx, cnt)
    j = box[np.repeat(first, cnt) + np.arange(len(i)) - np.repeat(np.cumsum(cnt) - cnt, cnt)]
    # the overlap test axis by axis on the pairs still in (the point's coordinate against the
    # box's bounds), on the axes where it can fail: not one where every box and point has the
    # same value (the contacts' 2D points, z = 0: a third of the test's gathers)
    keep = np.arange(len(i))
    for ax in range(3):
        q = p[:, ax]
        if flat[ax] is not None and (q == flat[ax]).all():
            continue
        ii, jj = i[keep], j[keep]
        q = q[ii]
        keep = keep[(lo[ax][jj] <= q) & (hi[ax][jj] >= q)]
    return i[keep], j[keep]


def ray_exit(f, u, a, b):
    """(M,) how far rays from 2D points f (M, 2) along unit u (M, 2) go before they cross the
    segments a, b (M, 2) (0: they do not)."""
    d = b - a
    den = u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0]
    safe = np.where(den == 0, 1.0, den)
    w = a - f
    t = (w[:, 0] * d[:, 1] - w[:, 1] * d[:, 0]) / safe
    s = (w[:, 0] * u[:, 1] - w[:, 1] * u[:, 0]) / safe
    return np.where((den != 0) & (s >= 0) & (s <= 1) & (t > 0), t, 0.0)
