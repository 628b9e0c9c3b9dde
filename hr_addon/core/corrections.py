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


def push_corrections(h: Hierarchy, links: Links, vcorr=1e-3, budget=3_000_000, centres=None, exposed=None):
    """Correct HR's push-down, which hands a link's average form factor to every leaf below the
    receiver. For links whose form factor varies across the receiver by more than ~vcorr, each
    leaf below gets F_link x (F(leaf centre -> source) / area-mean of those values) - F_link: the
    shape of the form factor across the receiver, normalised so the link's total transfer (and
    with it reciprocity and energy balance) is unchanged. Budget bounds the (leaf, link) pairs.
    centres(nodes): where each leaf's value is taken (Refiner.centres: off covered parts);
    exposed(leaf, src) -> (F, mask): near a source, a partly covered leaf's value averaged over
    its exposed part (Refiner.leaf_form_factors) where mask.
    Returns the Links with corrections attached."""
    links = Links(links.a, links.b, links.f_ab, links.f_ba, links.vis, far=links.far)
    recv, src, f = links.directed()
    cand = np.flatnonzero(h.child0[recv] >= 0)
    if vcorr <= 0 or len(cand) == 0:
        return links
    r, s_, fl = recv[cand].astype(np.int64), src[cand].astype(np.int64), f[cand]
    d = np.linalg.norm(h.centre[r] - h.centre[s_], axis=1)
    # Relative change of a point form factor across a receiver of size sqrt(A) at distance d is
    # about 3 sqrt(A) / d (inverse square law plus the two cosines).
    v_est = fl * np.minimum(3 * np.sqrt(h.area[r]) / np.maximum(d, 1e-300), 2.0)
    order, lo, hi = _leaf_ranges(h)
    count = hi[r] - lo[r]
    pick = np.argsort(-v_est, kind="stable")
    pick = pick[v_est[pick] > vcorr]
    pick = pick[np.cumsum(count[pick]) <= budget]
    if len(pick) == 0:
        return links
    r, s_, fl, count = r[pick], s_[pick], fl[pick], count[pick]
    li = np.repeat(np.arange(len(r)), count)
    leaf = order[np.repeat(lo[r], count) + np.arange(len(li)) - np.repeat(np.cumsum(count) - count, count)]
    # Only the shape across the receiver matters (it is normalised below): far links use the
    # differential kernel cos cos / r^2, near ones the exact contour integral.
    far = (d[pick] > 2 * (np.sqrt(h.area[r]) + np.sqrt(h.area[s_])))[li]
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
    # normalised over the exposed area (contacts.py), where the link's light lands
    ea = h.area[leaf] * h.exposure[leaf]
    mean = np.bincount(li, weights=fc * ea, minlength=len(r)) / np.maximum(
        np.bincount(li, weights=ea, minlength=len(r)), 1e-300
    )
    ok = mean[li] > 0
    dF = np.where(ok, fl[li] * (fc / np.where(ok, mean[li], 1.0) - 1.0), 0.0)
    links.corr = (leaf, src_of, dF)
    links._csr = None
    return links
