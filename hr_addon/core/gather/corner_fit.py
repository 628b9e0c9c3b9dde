"""Vertex output that keeps each face's light: the corners' values shifted so that what a render
interpolates over a face has the mean of the light gathered over its visible part (LoopGather,
fit=True).

A render interpolates the corner values linearly over each face (its loop triangles). A corner's
value, the mean of the gathered light at samples in its region of the faces around it (LoopGather),
gives a coarse face the mean of those few points: a 24 cm strip of a cylinder sunk into a table and
under a lid, lit in its middle and dark along both, read -6.8% against Cycles on its visible part
(tests/test_cycles_clutter.py), its two samples along the strip one in the lit middle, one in the
shade of the lid. Here:

- patches cut by another solid (a corner inside it, or covered: a contact; layouts.cut_patches)
  get about EXTRA more samples spread over them (extra_points; the buried ones dropped), whose
  mean is the light's mean over the visible part, and the mean over those points of the patch's
  interpolant (its corners' weights, mean_w) stands for the visible part's;
- each such patch's shift is the light's mean less its interpolant's mean (its corners' values as
  before), and a loop adds the area-weighted mean of the shifts of the faces it averages over
  (welded faces within the smooth angle), so faces stay continuous;
- patches part open, part in a slot (layouts.slot_split: a book's side above a shorter
  neighbour, whose corners' samples lie in the slot below the lit strip) get strata samples, each
  with its part's share of the patch (weight), and the interpolant's mean over their test points
  (area): the shift as for the cut ones;
- EVERY: every other patch too, its light the mean of its corners' samples and its interpolant's
  mean over the whole patch. Off: on the Cornell box's light shapes (vertex output in total
  radiance, medium) it moved the worst surface 15.5% -> 18.8% (frame 6), and on the furnished
  sample's books the median error 12.3% -> 13.7% (docs/accuracy.md); with the cut patches alone
  both stay within 0.5 points of before.

The shift is the least change of the corners (each weighted by its share of the face's mean) that
gives a lone face the light's mean. A least-squares fit of the interpolant to the points (the mean
as a constraint) was tried first: it extrapolates the corners of a face whose visible part is
small, past 0 where the light falls off, and clipped there they lit the visible part (a 2 m strip
40% buried beside a step of light, the scene of tests/test_corner_fit.py: +24% against the exact
mean; the shift -1.2%, the corners' samples alone +4.2%). Shifts and corner values are linear in
the samples' values, so LoopGather's response sums stay sums."""

import numpy as np

from ..boxes import spans
from ..output import corner_weights

EXTRA = 8  # samples added over a patch cut by another solid (extra_points)
EVERY = False  # only the faces with extra samples (cut) shifted; True: every face


def extra_points(corners, nv, n=EXTRA):
    """(points (m, 3), patch row (m,)) about n points per patch spread over it, more of them
    along its longer sides (a 2 x 24 cm strip: 1 x 8): quads, the centres of a k_a x k_b grid of
    the bilinear map; triangles, the centroids of the upward cells of a k-subdivision (k(k+1)/2
    points, k = round(sqrt(2 n)) - 1)."""
    c = np.asarray(corners, np.float64)
    nv = np.asarray(nv)
    pts, rows = [np.zeros((0, 3))], [np.zeros(0, np.int64)]
    q = np.flatnonzero(nv == 4)
    if len(q):
        cq = c[q]
        a = 0.5 * (np.linalg.norm(cq[:, 1] - cq[:, 0], axis=1) + np.linalg.norm(cq[:, 2] - cq[:, 3], axis=1))
        b = 0.5 * (np.linalg.norm(cq[:, 3] - cq[:, 0], axis=1) + np.linalg.norm(cq[:, 2] - cq[:, 1], axis=1))
        ka = np.clip(np.round(np.sqrt(n * a / np.maximum(b, 1e-300))), 1, n).astype(np.int64)
        kb = np.clip(np.round(n / ka), 1, n).astype(np.int64)
        for x, y in set(zip(ka.tolist(), kb.tolist())):
            sel = np.flatnonzero((ka == x) & (kb == y))
            u, v = np.meshgrid((np.arange(x) + 0.5) / x, (np.arange(y) + 0.5) / y, indexing="ij")
            u, v = u.ravel(), v.ravel()
            bw = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], 1)  # (x y, 4)
            pts.append(np.einsum("sk,pkj->psj", bw, cq[sel]).reshape(-1, 3))
            rows.append(np.repeat(q[sel], len(u)))
    t = np.flatnonzero(nv == 3)
    if len(t):
        k = max(int(round(np.sqrt(2 * n))) - 1, 1)
        i, j = np.nonzero(np.add.outer(np.arange(k), np.arange(k)) <= k - 1)
        bw = np.stack([i + 1 / 3, j + 1 / 3, k - i - j - 2 / 3], 1) / k  # (m, 3) barycentric
        pts.append(np.einsum("sk,pkj->psj", bw, c[t][:, :3]).reshape(-1, 3))
        rows.append(np.repeat(t, len(bw)))
    return np.concatenate(pts), np.concatenate(rows)


def elongated(corners, nv, ratio, longest):
    """(K,) bool: patches whose longest edge is more than `ratio` x their shortest and `longest` (m)."""
    c = np.asarray(corners, np.float64)
    e = np.linalg.norm(np.roll(c, -1, 1) - c, axis=2)
    e[:, 2] = np.where(nv == 4, e[:, 2], e[:, 3])  # (a triangle's corner 3 repeats its corner 2)
    hi, lo = e.max(1), e.min(1)
    return (hi > longest) & (hi > ratio * lo)


def mean_weights(corners, nv):
    """(K, 4) the mean over each patch of its linear interpolant per unit corner value (quads as
    the triangles (0, 1, 2) and (0, 2, 3): corners 0 and 2 a third each, 1 and 3 a third of their
    triangle's share)."""
    c = np.asarray(corners, np.float64)
    a1 = np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    a2 = np.where(nv == 4, np.linalg.norm(np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 0]), axis=1), 0.0)
    f = a1 / np.maximum(a1 + a2, 1e-300)
    return np.stack([np.full(len(c), 1 / 3), f / 3, np.full(len(c), 1 / 3), (1 - f) / 3], 1)


def shift_plan(
    corners, nv, normal, patch, points, dark, n_loop, lpatch, pc_loop, pairs, weight=None, area=None
):
    """What shifted() needs, from the static layout, over the m patches some loop takes a shift
    from: (s, the samples on them with a weight in their patch's mean; sk, their patch (0..m);
    tw, that weight; mean_w (m, 4) the interpolant's mean per unit corner value over the visible
    part; pc (m, 4) the loop at each corner (0 at padding, whose mean_w is 0); (lu, inv, lp, wn):
    loop lu[inv] adds wn x patch lp's shift). The first n_loop samples are the corners' (patch
    lpatch of their loop), the rest extra_points'; dark (n,): covered; pairs (li, lj, w): loop li
    averages over loop lj's face with weight w (layouts.loop_samples); weight (n,): each extra
    sample's share of its patch's mean (None: equal; strata, layouts.slot_split); area (patches,
    (p, 4)): those patches' interpolant's mean over their visible part, known (their extra samples
    are strata, not spread evenly)."""
    K = len(nv)
    ok = ~np.asarray(dark, bool)
    extra = np.arange(len(patch)) >= n_loop
    xcnt = np.bincount(patch[extra & ok], minlength=K)
    # a patch's light: the (weighted) mean of its uncovered extra samples where it has some (the
    # corners' samples crowd near the corners), else of its corners' samples
    use = ok & (extra | (xcnt[patch] == 0))
    wt = use * (1.0 if weight is None else np.where(extra, weight, 1.0))
    cnt = np.bincount(patch[use], minlength=K)
    tw = wt / np.bincount(patch, wt, K)[patch].clip(1e-300)
    mean_w = mean_weights(corners, nv)
    x = np.flatnonzero(extra & ok)
    if len(x):
        px = patch[x]
        a = corner_weights(corners[px], nv[px], normal[px], points[x]) * tw[x, None]
        mx = np.stack([np.bincount(px, a[:, k], K) for k in range(4)], 1)
        mean_w[xcnt > 0] = mx[xcnt > 0]
    if area is not None:
        mean_w[area[0]] = area[1]
    mean_w *= (pc_loop >= 0) & (cnt > 0)[:, None]  # no light known: no shift
    if not EVERY:
        mean_w *= (xcnt > 0)[:, None]
    li, lj, w = pairs
    # the pairs on faces with a shift: a mask per face, not (pairs,) temporaries of counts (3.15 M
    # pairs at the 100k vertex bake, whose first frame peaked here; the same pairs and weights)
    shifts = (cnt > 0) & (EVERY | (xcnt > 0))
    keep = np.flatnonzero(shifts[lpatch][lj] & (w > 0))  # (per loop first: bools, not patch ids)
    li, lp, w = li[keep], lpatch[lj[keep]], w[keep]
    den = np.bincount(li, w, int(li.max()) + 1 if len(li) else 0)
    # only the patches some loop takes a shift from, their samples and the loops that take one:
    # a colour edit's correction of a few samples then costs what the cut faces hold, not the
    # room (100k room: 7 -> 18 ms an edit over every sample and loop)
    act = np.unique(lp)
    kid = np.full(K, -1, np.int64)
    kid[act] = np.arange(len(act))
    s = np.flatnonzero((tw > 0) & (kid[patch] >= 0))
    lu, inv = np.unique(li, return_inverse=True)
    pc = np.maximum(pc_loop, 0)[act]
    # shifted_at's look-ups: the (patch, corner) entries by loop, the (loop, patch) pairs by patch
    by_loop = np.argsort(pc.ravel(), kind="stable")
    by_patch = np.argsort(kid[lp], kind="stable")
    index = (pc.ravel()[by_loop], by_loop, kid[lp][by_patch], by_patch)
    return s, kid[patch[s]], tw[s], mean_w[act], pc, (lu, inv, kid[lp], w / den[li]), index


def shifted(loops, values, plan):
    """(L, C) the loop values `loops` (the corners' samples' means) plus each loop's share of its
    faces' shifts: the light's mean (of the sample values (n, C)) less the interpolant's mean."""
    s, sk, tw, mean_w, pc, (lu, inv, lp, wn) = plan[:6]
    K, out = len(mean_w), loops.copy()
    for c in range(loops.shape[1]):
        d = np.bincount(sk, tw * values[s, c], K) - np.einsum("kj,kj->k", mean_w, loops[pc, c])
        out[lu, c] += np.bincount(inv, wn * d[lp], len(lu))
    return out


def _equal_to(sorted_keys, keys):
    """Positions in sorted_keys of every entry equal to one of keys (distinct), ascending."""
    return spans(np.searchsorted(sorted_keys, keys), np.searchsorted(sorted_keys, keys, "right"))[1]


def shifted_at(loops, lv, samples, sv, plan):
    """shifted() of a sparse correction (a colour edit's few clipped samples): `loops` 0 but at
    loops (m,) (distinct, ascending) with lv (m, C), `values` 0 but at samples (k,) (distinct,
    ascending) with sv (k, C) >= 0. Returns (the loops shifted() makes or keeps non-zero,
    ascending; their values): the same values bit for bit (the terms left out are +0), at the cost
    of the faces the correction touches, not of every face with a shift (100k room: 5,052)."""
    s, sk, tw, mean_w, pc, (lu, inv, lp, wn), (pc_key, pc_at, lp_key, lp_at) = plan
    # the patches whose shift changes: a sample of theirs, or a loop at one of their corners
    i = np.searchsorted(s, samples).clip(0, max(len(s) - 1, 0))
    hit = (s[i] == samples) if len(s) else np.zeros(len(samples), bool)
    i = i[hit]
    aff = np.unique(np.r_[sk[i], pc_at[_equal_to(pc_key, loops)] // pc.shape[1]])
    t = np.sort(lp_at[_equal_to(lp_key, aff)])  # their (loop, patch) pairs, in shifted()'s order
    out_loops = np.union1d(loops, lu[inv[t]])
    at_in = np.searchsorted(out_loops, loops)
    at_pc = np.searchsorted(loops, pc[aff]).clip(0, max(len(loops) - 1, 0))
    on = (loops[at_pc] == pc[aff]) if len(loops) else np.zeros(pc[aff].shape, bool)
    out = np.zeros((len(out_loops), lv.shape[1]))
    out[at_in] = lv
    tgt = np.searchsorted(out_loops, lu[inv[t]])
    ka, kt = np.searchsorted(aff, sk[i]), np.searchsorted(aff, lp[t])
    for c in range(lv.shape[1]):
        corner = np.where(on, lv[at_pc, c], 0.0)
        d = np.bincount(ka, tw[i] * sv[hit, c], len(aff)) - np.einsum("kj,kj->k", mean_w[aff], corner)
        out[:, c] += np.bincount(tgt, wn[t] * d[kt], len(out_loops))
    return out_loops, out
