"""Push corrections: the shape of a link's form factor across the leaves below its receiver (HR's
push-down hands every leaf the link's average)."""

import numpy as np

from . import formfactor as ff
from .hierarchy import Hierarchy
from .links import Links


def _leaf_ranges(h):
    """Leaves in depth-first order and, per node, the [lo, hi) range of its leaf descendants in it."""
    n = h.n
    lv = h.view("level").astype(np.int64)
    depth = int(lv.max()) if n else 0
    if depth > 26:
        raise ValueError("hierarchy deeper than 26 levels")
    digit = np.zeros(n, np.int64)
    inner = h.view("parent") >= 0
    digit[inner] = np.arange(n)[inner] - h.child0[h.parent[:n][inner]]
    # Path key: root id, then one base-4 digit per level (levels processed shallow to deep).
    key = np.zeros(n, np.int64)
    for ids in h.levels():
        par = h.parent[ids]
        root = par < 0
        key[ids[root]] = ids[root].astype(np.int64) << (2 * depth)
        key[ids[~root]] = key[par[~root]] | (digit[ids[~root]] << (2 * (depth - lv[ids[~root]])))
    leaves = h.leaves()
    order = leaves[np.argsort(key[leaves], kind="stable")]
    ks = key[order]
    lo = np.searchsorted(ks, key, "left")
    hi = np.searchsorted(ks, key + (np.int64(1) << (2 * (depth - lv))), "left")
    return order, lo, hi


def push_corrections(
    h: Hierarchy, links: Links, vcorr=1e-3, budget=3_000_000, centres=None, exposed=None, visibility=None
):
    """Correct HR's push-down, which hands a link's average form factor to every leaf below the
    receiver. For links whose form factor varies across the receiver by more than ~vcorr, each
    leaf below gets F_link x (F(leaf centre -> source) / area-mean of those values) - F_link: the
    shape of the form factor across the receiver, normalised so the link's total transfer (and
    with it reciprocity and energy balance) is unchanged. Budget bounds the (leaf, link) pairs.
    centres(nodes): where each leaf's value is taken (Refiner.centres: off covered parts);
    exposed(leaf, src) -> (F, mask): near a source, a partly covered leaf's value averaged over
    its exposed part (Refiner.leaf_form_factors) where mask.
    visibility(leaf, src) -> each leaf's visibility of src (Refiner.leaf_visibility): then each
    leaf gets its unoccluded share x its own visibility, and the link's visibility (one number
    for its whole receiver, from a few rays) becomes the form-factor-weighted mean of its leaves'
    (the same number both ways: reciprocity and energy balance hold), so a leaf that a block
    hides from a source under a link that saw it no longer counts the source (row sums <= 1).
    Returns the Links with corrections attached."""
    vis = links.vis.copy()
    n = len(links.a)
    lk = np.concatenate([np.arange(n), np.arange(n)])
    recv, src = np.concatenate([links.a, links.b]), np.concatenate([links.b, links.a])
    fu = np.concatenate([links.f_ab, links.f_ba])  # unoccluded form factor of each direction
    fl = fu * vis[lk]
    cand = np.flatnonzero((fl > 0) & (h.child0[recv] >= 0))
    if vcorr <= 0 or len(cand) == 0:
        return Links(links.a, links.b, links.f_ab, links.f_ba, vis, far=links.far)
    r, s_, fl, fu, lk = (x[cand] for x in (recv.astype(np.int64), src.astype(np.int64), fl, fu, lk))
    d = np.linalg.norm(h.centre[r] - h.centre[s_], axis=1)
    # Relative change of a point form factor across a receiver of size sqrt(A) at distance d is
    # about 3 sqrt(A) / d (inverse square law plus the two cosines).
    v_est = fl * np.minimum(3 * np.sqrt(h.area[r]) / np.maximum(d, 1e-300), 2.0)
    if visibility is not None:
        # a partly occluded link's F x V can fall to 0 across its receiver: its whole transfer
        v_est = np.where(vis[lk] < 1, np.maximum(v_est, fl), v_est)
    order, lo, hi = _leaf_ranges(h)
    count = hi[r] - lo[r]
    pick = np.argsort(-v_est, kind="stable")
    pick = pick[v_est[pick] > vcorr]
    pick = pick[np.cumsum(count[pick]) <= budget]
    if len(pick) == 0:
        return Links(links.a, links.b, links.f_ab, links.f_ba, vis, far=links.far)
    r, s_, fl, fu, lk, count = r[pick], s_[pick], fl[pick], fu[pick], lk[pick], count[pick]
    li = np.repeat(np.arange(len(r)), count)
    leaf = order[np.repeat(lo[r], count) + np.arange(len(li)) - np.repeat(np.cumsum(count) - count, count)]
    # Only the shape across the receiver matters (it is normalised below): far links use the
    # differential kernel cos cos / r^2, near ones the exact contour integral.
    far_t = d[pick] > 2 * (np.sqrt(h.area[r]) + np.sqrt(h.area[s_]))
    far = far_t[li]
    src_of = s_[li]
    at = h.centre[leaf] if centres is None else centres(leaf)
    fc = np.zeros(len(li))
    m = np.flatnonzero(far)
    w = h.centre[src_of[m]] - at[m]
    r2 = np.einsum("ij,ij->i", w, w)
    fc[m] = (
        np.maximum(np.einsum("ij,ij->i", w, h.normal[leaf[m]]), 0)
        * np.maximum(-np.einsum("ij,ij->i", w, h.normal[src_of[m]]), 0)
        / (r2 * r2)
    )
    m = np.flatnonzero(~far)
    for a in range(0, len(m), 1_000_000):
        mm = m[a : a + 1_000_000]
        fc[mm] = ff.point_to_polygon(at[mm], h.normal[leaf[mm]], h.corners[src_of[mm]], h.nv[src_of[mm]])
    if exposed is not None and len(m):
        fe, has = exposed(leaf[m], src_of[m])
        fc[m[has]] = fe[has]
    # sums over the exposed area (contacts.py), where the link's light lands
    ea = h.area[leaf] * h.exposure[leaf]
    mean = np.bincount(li, weights=fc * ea, minlength=len(r)) / np.maximum(
        np.bincount(li, weights=ea, minlength=len(r)), 1e-300
    )
    ok = mean > 0
    shape = np.where(ok[li], fc / np.where(ok, mean, 1.0)[li], 1.0)  # area-mean 1 over each receiver
    f_ab, f_ba = links.f_ab.copy(), links.f_ba.copy()
    if visibility is not None:
        V = visibility(leaf, src_of)
        tot = np.bincount(li, weights=ea, minlength=len(r))
        wv = np.bincount(li, weights=shape * V * ea, minlength=len(r))
        # The link's form factor and visibility from its leaves. A partly covered receiver's F
        # came from about 6 x 6 points on its whole exposed part, its leaves' from their own: the
        # finer sum replaces it (traced: a partly covered node beside a block read 1.66 x its
        # leaves' sum). Elsewhere the link's F stays: 3 x 3 Gauss points against the exact
        # contour beat the leaves' centre values (which put a closed box's mean row sum at
        # 1.0005), and far links' fc is a kernel's shape. Both ends corrected: their estimates
        # of A x F (one number both ways) averaged, weighted by their leaf counts.
        Fu = np.where(far_t | ~ok | (h.exposure[r] >= 1), fu, mean)
        Fv = Fu * np.where(tot > 0, wv / np.maximum(tot, 1e-300), vis[lk])
        A = h.area[r]
        wsum = np.maximum(np.bincount(lk, weights=count, minlength=n), 1)
        Gu = np.bincount(lk, weights=count * A * Fu, minlength=n) / wsum
        Gv = np.bincount(lk, weights=count * A * Fv, minlength=n) / wsum
        done = np.flatnonzero(np.bincount(lk, minlength=n) > 0)
        # neither end's form factor above 1 (the smaller end's, from the larger's leaves)
        Gu[done] = np.minimum(Gu[done], np.minimum(h.area[links.a[done]], h.area[links.b[done]]))
        Gv[done] = np.minimum(Gv[done], Gu[done])
        f_ab[done], f_ba[done] = Gu[done] / h.area[links.a[done]], Gu[done] / h.area[links.b[done]]
        vis[done] = np.where(Gu[done] > 0, Gv[done] / np.maximum(Gu[done], 1e-300), 0.0)
        # each leaf: its unoccluded share x its own visibility, normalised to the link's new total
        seen = wv > 0
        shape = np.where(seen[li], shape * V * (tot / np.where(seen, wv, 1.0))[li], shape)
        fu = np.where(r == links.a[lk], f_ab[lk], f_ba[lk])
    fl = fu * vis[lk]
    dF = fl[li] * (shape - 1.0)
    out = Links(links.a, links.b, f_ab, f_ba, vis, far=links.far)
    out.corr = (leaf, src_of, dF)
    return out
