"""Gather sample layouts: the input mesh's corners (LoopGather) and texel centres (texel_gather)."""

import numpy as np

from ..boxes import csr_rows
from ..geometry import insideness, isolated_objects, prepare_patches
from ..parallel import batch_map, ranges, release_free_memory
from ..slots import pairs_of
from ..output import corner_weights, equal_key_pairs, in_domain, loop_welds
from . import corner_fit
from .bakepoints import has_area, texel_points
from .final import OPEN_EDGE, FinalGather
from .sampling import cosine_directions, hash_uniform, position_keys
from .texel_edges import texel_area

SUB = 4  # sub-samples per side of a texel whose area straddles a coverage boundary
# sub-samples per side of a texel wholly in a slot (every point and corner covered, in a slot) near
# a mouth: there the light varies with the depth only, and smoothly; 16 of them per texel were 65%
# of the furnished 20k room's samples at 2 cm texels (its books' sides) and most of the gather's
# memory (docs/gather.md, "Texel samples' memory"). SUB: as before session 20
SLOT_SUB = 2
CORNERS = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])  # a texel's, in its offsets
TEST_BATCH = 1 << 14  # candidate texels per batch of texel_samples' test (each its own: any size)
# loop_samples' inset (how far from its corner towards its patch's centre a corner's sample lies):
# INSET on the system's own mesh (the user's corners: Vertex Spacing 0, or a spacing that
# subdivides nothing, as before bit for bit), OUTPUT_INSET on an output layout's finer corners
# (Vertex Spacing). Interpolated over a face, the corner values show about the mean of its corners'
# samples; at 0.5 (the centres of a quad's corner quarters) a light that falls off steeply and
# convexly across a face (a book's top into the shelf, under the board above) reads low, samples
# nearer the corners read nearer its mean (Gauss' two points per side: 0.42). The furnished
# sample from the camera at 0.25 m, within 5% (wide / close): 0.5 80 / 74%, 0.42 82 / 75%, 0.36
# 85 / 76%, 0.30 82 / 78%, 0.25 83 / 79% (docs/accuracy.md, session 24, vx27).
INSET = 0.5
OUTPUT_INSET = 0.36
# LoopGather on an output layout: faces ELONGATED x longer than wide and longer than ELONGATED_MIN
# (m), which the spacing left whole (a bottle's 24 cm side 1.6 cm wide), get corner_fit's extra
# samples along them and keep their light's mean (a shadow's edge across a third of one read -20%
# with its two corner rows; docs/accuracy.md, session 33). 0: off
ELONGATED = 4.0
ELONGATED_MIN = 0.1
FIT = True  # LoopGather's default: the cut faces' corners shifted to keep their light (corner_fit)
SPLIT = True  # with FIT: faces part open, part in a slot too (slot_split); False: before 2026-12-05


class OwnLayout:
    """The output on the transport's own mesh (LoopGather's default): its patches are the output's."""

    def __init__(self, system):
        self.mesh, self.patches = system.mesh, system.patches

    def transport(self, patch, points):
        return patch

    def has_transport(self):
        return np.ones(len(self.patches.nv), bool)


class OutputLayout:
    """LoopGather's output on a finer mesh than the transport's (Vertex Spacing: the user's mesh
    linearly subdivided): `mesh` (MeshInput) whose every polygon lies on polygon poly[i] of the
    transport system's mesh. Its polygons are laid out as patches of their own (prepare_patches:
    the corners' regions, the cut faces, the slots' strata are the finer faces'), and every sample
    point on one is located on the transport patch under it (transport(): a user quad is one patch
    or two triangles, an n-gon several; by the point). The hierarchy, its links and contacts, the
    second-level samples stay the transport's."""

    def __init__(self, system, mesh, poly):
        self.mesh = mesh
        self.poly = np.asarray(poly, np.int64)
        if len(self.poly) != len(mesh.loop_start):
            raise ValueError("OutputLayout: one transport polygon per output polygon")
        self.patches = prepare_patches(mesh)
        tp = system.patches
        self._tp = tp
        # the transport patches of each transport polygon (CSR by polygon)
        self.under = np.argsort(tp.poly, kind="stable")
        self.under_start = np.searchsorted(tp.poly[self.under], np.arange(len(system.mesh.loop_start) + 1))

    def has_transport(self):
        """(K,) bool: output patches whose transport polygon has patches (not dropped as degenerate)."""
        u = self.poly[self.patches.poly]
        return self.under_start[u + 1] > self.under_start[u]

    def transport(self, patch, points):
        """(n,) the transport patch under each point (n, 3) of output patch `patch` (n,): its
        polygon's patch that holds it (the nearest, by insideness, if none does: a point on an
        edge); -1 where the polygon has none."""
        tp = self._tp
        patch = np.asarray(patch, np.int64)
        points = np.asarray(points, np.float64).reshape(-1, 3)
        u = self.poly[self.patches.poly[patch]]
        a = self.under_start[u]
        cnt = self.under_start[u + 1] - a
        out = np.where(cnt > 0, self.under[np.minimum(a, max(len(self.under) - 1, 0))], -1)
        m = np.flatnonzero(cnt > 1)
        if len(m):
            best = np.full(len(m), -np.inf)
            for r in range(int(cnt[m].max())):
                i = np.flatnonzero(cnt[m] > r)
                k = self.under[a[m[i]] + r]
                d = insideness(tp.corners[k][:, None], tp.normal[k][:, None], points[m[i]])[:, 0]
                better = d > best[i]
                best[i[better]] = d[better]
                out[m[i[better]]] = k[better]
        return out


def default_inset(layout=None):
    """loop_samples' inset when none is given: INSET on the system's own mesh, OUTPUT_INSET on an
    output layout's finer corners (Vertex Spacing)."""
    return INSET if layout is None or isinstance(layout, OwnLayout) else OUTPUT_INSET


def loop_samples(system, smooth_angle=30.0, inset=None, nudge=1e-3, layout=None):
    """Gather samples for the input mesh's corners, the layout of core.output.loop_radiance.

    inset > 0 (default; None: default_inset(layout)): one sample per loop, inside the corner's own
    region of its patch: `inset` of the way from the corner to the patch's centre (0.5: the centre
    of a quad's corner quarter).
    A corner's value is then the area-weighted mean over the loops at the same position of the same
    object whose polygons lie within smooth_angle (uncovered samples only), like output.loop_plan's
    leaves: interpolated over a face, the corner values give the face's mean even on coarse meshes,
    where values at the corners themselves would stand for the corners only (contacts, concave
    corners).
    inset = 0: samples at the corners themselves, one per welded vertex and smooth normal (the area
    mean of the polygons' normals within smooth_angle) and material, moved `nudge` of the way
    towards the patch's centre.
    Returns (points (S, 3), normals (S, 3), patch ids (S,), loop -> sample index (L,), -1 for loops
    of polygons dropped as degenerate, and (li, lj, w, lpatch, pc_loop): loop li (int32) averages sample
    loop_index[lj] (int32) with weight w, lpatch (L,) the patch of each loop, pc_loop (K, 4) the loop at
    each patch corner, -1 at padding (None for inset = 0)).
    layout: OutputLayout (the corners of a finer mesh; the patches returned are its own, the
    transport's under the points are layout.transport's) or None (the system's own mesh)."""
    inset = default_inset(layout) if inset is None else inset
    layout = OwnLayout(system) if layout is None else layout
    mesh, pt = layout.mesh, layout.patches
    P = len(mesh.loop_start)
    loop_poly, weld = loop_welds(mesh)
    # the patch of each loop: the patch of its polygon holding its vertex
    jj, kk = np.nonzero(pt.vert_index >= 0)
    key_p = pt.poly[jj].astype(np.int64) * (len(mesh.verts) + 1) + pt.vert_index[jj, kk]
    order = np.argsort(key_p, kind="stable")
    key_l = loop_poly.astype(np.int64) * (len(mesh.verts) + 1) + np.asarray(mesh.loop_verts, np.int64)
    pos = np.minimum(np.searchsorted(key_p[order], key_l), len(order) - 1)
    found = key_p[order][pos] == key_l
    lpatch = np.where(found, jj[order][pos], -1)
    if not isinstance(layout, OwnLayout):  # (a finer polygon on a transport polygon dropped: none)
        lpatch[lpatch >= 0] = np.where(layout.has_transport()[lpatch[lpatch >= 0]], lpatch[lpatch >= 0], -1)
    # polygon normal and area (from their patches)
    pn = np.zeros((P, 3))
    np.add.at(pn, pt.poly, pt.normal * pt.area[:, None])
    parea = np.linalg.norm(pn, axis=1)
    pn = pn / np.maximum(parea, 1e-300)[:, None]
    # pairs of loops at the same weld whose polygons lie within smooth_angle
    L = len(weld)
    li, lj = equal_key_pairs(weld, weld)
    # by steps of pairs: their polygons' normals, (pairs, 3) each, held whole were 0.34 GB at the
    # 100k vertex bake's 7.1 M pairs (each pair's own product: the same flags)
    ok, cos_min = np.empty(len(li), bool), np.cos(np.radians(smooth_angle))
    # a flat-shaded polygon (MeshInput.flat) shows its own light, as a render shades it: averaged
    # only with polygons in its plane (a flat 16-sided cup's lit side read 4-12% dark, each face
    # averaged with its less lit neighbours 22.5 degrees round; docs/accuracy.md, session 33)
    flat = None if mesh.flat is None else mesh.flats()
    cos_flat = np.cos(np.radians(FLAT_ANGLE))
    for s0 in range(0, len(li), PAIR_STEP):
        a, b = loop_poly[li[s0 : s0 + PAIR_STEP]], loop_poly[lj[s0 : s0 + PAIR_STEP]]
        lim = cos_min if flat is None else np.where(flat[a] | flat[b], max(cos_flat, cos_min), cos_min)
        ok[s0 : s0 + PAIR_STEP] = np.einsum("ij,ij->i", pn[a], pn[b]) >= lim
    valid = lpatch >= 0
    vl = np.flatnonzero(valid)
    p = np.asarray(mesh.verts, float)[np.asarray(mesh.loop_verts)]
    if inset > 0:
        keep = ok & valid[lj]  # (the pairs averaged, before the samples' rules: 7.1 -> 3.15 M at 100k)
        li, lj = li[keep].astype(np.int32), lj[keep].astype(np.int32)  # (held with the gather: loops)
        del ok, keep
        loop_index = np.full(L, -1, np.int64)
        loop_index[vl] = np.arange(len(vl))
        patch = lpatch[vl]
        c = pt.corners[patch]
        centre = np.where((pt.nv[patch] == 4)[:, None], c.mean(1), c[:, :3].mean(1))
        corner = p[vl]  # (once; the patches' corners not held under the rules below: 0.1 GB at 100k)
        del c, p
        pts = corner + inset * (centre - corner)
        del centre
        _uncover(system, pts, corner, patch, inset, layout)
        if not isinstance(layout, OwnLayout) and (OUTPUT_MOUTH > 0 or OUTPUT_OPEN > 0):
            # both rules start from each sample's transport patch and contacts' covered test: made
            # once, and again only for the samples _toward_mouths moved
            tp, cov = _transport_covered(system, pts, patch, layout)
            if OUTPUT_MOUTH > 0:
                moved = _toward_mouths(system, pts, corner, patch, layout, tp, cov)
                tp[moved], cov[moved] = _transport_covered(system, pts[moved], patch[moved], layout)
            if OUTPUT_OPEN > 0:
                _toward_openings(system, pts, corner, patch, layout, tp, cov)
            del tp, cov
        del corner
        lpj = lpatch[lj]
        w = pt.area[lpj] / pt.nv[lpj]  # the corner's share of its patch
        lorder = np.argsort(key_l, kind="stable")  # the loop at each patch corner
        at = lorder[np.minimum(np.searchsorted(key_l[lorder], key_p), L - 1)]
        pc_loop = np.full(pt.vert_index.shape, -1, np.int64)
        pc_loop[jj, kk] = np.where(key_l[at] == key_p, at, -1)
        return pts, pt.normal[patch], patch, loop_index, (li, lj, w, lpatch, pc_loop)
    b = loop_poly[lj]
    sn = np.zeros((L, 3))
    for c in range(3):
        sn[:, c] = np.bincount(li, weights=ok * pn[b, c] * parea[b], minlength=L)
    nl = np.linalg.norm(sn, axis=1)
    sn = np.where(nl[:, None] > 0, sn / np.maximum(nl, 1e-300)[:, None], pn[loop_poly])
    mat = np.column_stack(
        [pt.reflectance[:, np.maximum(lpatch, 0)].T, pt.emission[:, np.maximum(lpatch, 0)].T]
    )
    key = np.column_stack([weld, np.round(sn * 1e4).astype(np.int64), np.round(mat * 1e6).astype(np.int64)])
    _, first, inv = np.unique(key[valid], axis=0, return_index=True, return_inverse=True)
    rep = vl[first]
    loop_index = np.full(L, -1, np.int64)
    loop_index[vl] = inv.ravel()
    patch = lpatch[rep]
    q = p[rep]
    towards = pt.corners[patch].mean(1) - q  # the patch's centre (padded triangles: close enough)
    dist = np.linalg.norm(towards, axis=1)
    f = np.minimum(nudge, 50 * system.refiner.eps / np.maximum(dist, 1e-300))
    pts = q + f[:, None] * towards
    nrm = sn[rep]
    side = system.patches.normal[layout.transport(patch, pts)]  # (the transport's: the gather's side)
    flip = np.einsum("ij,ij->i", nrm, side) <= 0  # turned to the patch's side
    nrm[flip] = side[flip]
    return pts, nrm, patch, loop_index, None


FLAT_ANGLE = 1.0  # loop_samples: flat-shaded polygons' corners averaged with polygons this close in angle
PAIR_STEP = 1 << 20  # loop_samples: pairs of loops whose polygons' normals are compared at a time

# _uncover: where a corner's sample may move, as fractions of the way from the corner to its
# patch's centre, nearest the default inset (0.5) first
UNCOVER = (0.25, 0.75, 0.125, 0.875, 0.0625, 0.95)
PROBE_RAYS = 8  # _buried: rays per sample; buried when at least 3/4 of them hit a back face
# (and none escapes, or one of those faces is one the sample's patch crosses)
# _buried: or under a plane (a box's side below a floor plane it is sunk into): at least
# PROBE_UNDER rays hit back faces whose plane the sample's patch crosses and at most PROBE_FRONT a
# front face, the rest escaping (below the plane, outside the room); a sample by an open window or
# the open side of a box has no back faces, one on a floor under a one-sided canopy or table top
# (in the open: rays escape around it) back faces of a plane its patch lies wholly behind
PROBE_UNDER = 2
PROBE_FRONT = 0
PROBE_BATCH = 1 << 13  # _buried: samples per batch on threads (fixed: values never depend on threads)


def probe_reach(system):
    """_buried's probe rays' length: 4 x the size of the main group of objects."""
    return 4.0 * float(np.sqrt(isolated_objects(system.mesh).main_area))


def _buried(system, pts, patch, reach):
    """Samples inside another solid or under a face touching theirs: covered as final.py decides
    it (the contacts' test, open edges of gaps OPEN_EDGE, a slot lit through its mouths not), or
    most of PROBE_RAYS rays hitting back faces, none escaping or one of those faces crossed by the
    sample's patch (inside a closed solid whose crossing the contacts do not see: a lid's side sunk
    into a box), or some hitting back faces its patch crosses and none a front face (under a plane:
    a box's side below the floor it is sunk into). A back face whose plane the patch lies wholly
    behind hides nothing of it when rays escape around: a floor under a one-sided canopy or table
    top in the open (tests/test_corner_fit.py; before, its samples were moved and its faces taken as
    cut, the canopy's shadow read 5% bright). reach: the rays' length (_uncover's)."""
    pt = system.patches
    out = np.zeros(len(pts), bool)
    con = system.h.contacts
    # the covered test and the rays by batches of samples on the system's threads (every sample's
    # answer and rays are its own: the same values for any thread count)
    threads = system.backend.threads
    if con is not None:
        out = con.covered(pts, patch, open_edge=OPEN_EDGE, threads=0 if threads is None else threads)
        c = np.flatnonzero(out)
        if len(c):
            con.close_mouths(system.backend.occluded)  # as final.py does (once per Contacts)
            out[c[con.slots(pts[c], patch[c])[1] > 0]] = False
    eps = float(system.refiner.eps)
    # the rays traced first: a sample none of whose first rays hits a back face cannot reach 3/4
    # (any split gives the same answers: it only sets how many rays are traced)
    first = PROBE_RAYS + 1 - -(-3 * PROBE_RAYS // 4)

    def back_faces(i, j):  # samples i..j: most of their rays hit a back face
        # each ray's answer is its own: a sample already covered traces none, and the rest only
        # while 3/4 of PROBE_RAYS can still be reached (the same answers as all the rays')
        nrm = pt.normal[patch[i:j]]
        dirs = cosine_directions(nrm, np.arange(i, j), PROBE_RAYS, seed=7)
        org = pts[i:j] + eps * nrm
        backs = np.zeros(j - i, np.int64)
        unders = np.zeros(j - i, np.int64)  # back faces the patch crosses
        misses = np.zeros(j - i, np.int64)  # rays that escape
        fronts = np.zeros(j - i, np.int64)
        todo = np.flatnonzero(~out[i:j])
        for r0, r1 in ((0, first), (first, PROBE_RAYS)):
            if not len(todo):
                break
            k = r1 - r0
            d = dirs[todo, r0:r1].reshape(-1, 3)
            prim, _ = system.backend.first_hit(org[todo], d, reach, per=k)
            hit = prim >= 0
            back = np.zeros(len(prim), bool)
            hp = pt.triangle_patch[prim[hit]]
            back[hit] = np.einsum("ij,ij->i", d[hit], pt.normal[hp]) > 0
            # a back face whose plane the sample's own patch crosses (some corner of it in front:
            # the patch is sunk through that face); a plane wholly in front of the patch (a
            # one-sided canopy or table top above a floor) hides nothing of it
            cross = np.zeros(len(prim), bool)
            own = np.repeat(patch[i:j][todo], k)[hit]
            ahead = np.einsum("mcj,mj->mc", pt.corners[own] - pt.corners[hp][:, :1], pt.normal[hp])
            cross[hit] = ahead.max(1) > eps
            backs[todo] += back.reshape(-1, k).sum(1)
            unders[todo] += (back & cross).reshape(-1, k).sum(1)
            fronts[todo] += (hit & ~back).reshape(-1, k).sum(1)
            misses[todo] += (~hit).reshape(-1, k).sum(1)
            rest = PROBE_RAYS - r1
            todo = todo[
                (backs[todo] * 4 + rest * 4 >= 3 * PROBE_RAYS)  # can still reach either rule
                | ((fronts[todo] <= PROBE_FRONT) & (unders[todo] + rest >= PROBE_UNDER))
            ]
        inside = (backs * 4 >= 3 * PROBE_RAYS) & ((misses == 0) | (unders > 0))
        return inside | ((fronts <= PROBE_FRONT) & (unders >= PROBE_UNDER))

    parts = batch_map(back_faces, ranges(len(pts), PROBE_BATCH), threads)
    return out | (np.concatenate(parts) if parts else np.zeros(0, bool))


def _uncover(system, pts, corner, patch, inset, layout=None):
    """Move buried samples (_buried; in place) along the line from their corner to their patch's
    centre (UNCOVER) to the first place not buried, so the corner takes the light of its region's
    visible part. Before, they read 0 and so did their corner (a loop with no uncovered sample):
    interpolated, the visible part went dark. The clutter room (tests/test_cycles_clutter.py): a
    table top's corner sample inside the footprint of a box standing on it (the top's visible part
    -14% against Cycles), a lid's side whose lower corners are sunk into a box (-30%). patch: the
    layout's (loop_samples'), tested on the transport patch under each point."""
    if not len(pts):
        return
    at = (lambda k, q: k) if layout is None else layout.transport
    reach = probe_reach(system)  # (the same for every pass: computed once)
    todo = np.flatnonzero(_buried(system, pts, at(patch, pts), reach))
    for f in UNCOVER:
        if not len(todo):
            return
        q = corner[todo] + (f / inset) * (pts[todo] - corner[todo])
        cov = _buried(system, q, at(patch[todo], q), reach)
        pts[todo[~cov]] = q[~cov]
        todo = todo[cov]


OUTPUT_MOUTH = 1.0  # _toward_mouths: a slot corner's sample no deeper than this many gap widths
MOUTH_NUDGE = 0.02  # _toward_mouths: the corner's own depth, probed this far towards its sample


def _transport_covered(system, pts, patch, layout):
    """((n,) the transport patch under each sample (layout.transport; -1: none), (n,) bool: covered
    there (contacts' test; False where there is no patch or no contacts)): what _toward_mouths and
    _toward_openings start from."""
    tp = layout.transport(patch, pts)
    cov = np.zeros(len(pts), bool)
    con = system.h.contacts
    if con is not None and len(pts):
        th = system.backend.threads
        ok = np.flatnonzero(tp >= 0)
        cov[ok] = con.covered(pts[ok], tp[ok], threads=0 if th is None else th)
    return tp, cov


def _toward_mouths(system, pts, corner, patch, layout, tp, covered):
    """On an output layout: corner samples in a slot (contacts: under a parallel face a gap h in
    front, lit through its open edges) whose corner lies nearer the slot's mouths than they do
    move (in place) straight towards their nearest mouth, to OUTPUT_MOUTH x h from it (or to their
    corner's depth if that is deeper), keeping their place along it. A camera sees of such a face
    only a strip of a few gap widths along its mouths (a book's side 2 mm from its neighbour's,
    from the front); at the default inset the sample lies 3-5 cm deep, where the slot is dark, and
    the strip read that dark. tp, covered: _transport_covered(pts). Returns the samples moved."""
    con = system.h.contacts
    none = np.zeros(0, np.int64)
    if con is None or not len(pts):
        return none
    cov = np.flatnonzero(covered)
    if not len(cov):
        return none
    con.close_mouths(system.backend.occluded)
    x, h, foot = con.slots(pts[cov], tp[cov])[:3]
    far = (h > 0) & (x > OUTPUT_MOUTH * h)
    c, x, h, foot = cov[far], x[far], h[far], foot[far]
    if not len(c):
        return none
    q0 = corner[c] + MOUTH_NUDGE * (pts[c] - corner[c])
    t0, cov0 = _transport_covered(system, q0, patch[c], layout)
    x0 = np.full(len(c), np.inf)  # covered at its corner but in no slot: left where it is
    ok = np.flatnonzero(t0 >= 0)
    open_ = ~cov0[ok]
    x0[ok[open_]] = 0.0  # open at its corner (a mouth's own edge)
    ok = ok[~open_]
    x0[ok] = con.slots(q0[ok], t0[ok])[0]
    move = x0 < x
    c, x, h, foot, x0 = c[move], x[move], h[move], foot[move], x0[move]
    f = np.maximum(OUTPUT_MOUTH * h, x0) / x
    pts[c] = foot + f[:, None] * (pts[c] - foot)
    return c


OUTPUT_OPEN = 1.0  # _toward_openings: a sample no farther from its corner than this x its clearance
OPEN_FAR = 4.0  # _toward_openings: a probe ray escapes when it goes this x the clearance or farther
OPEN_RAYS = 32  # _toward_openings: probe rays from a sample and from near its corner


def _toward_openings(system, pts, corner, patch, layout, tp, covered):
    """On an output layout: corner samples under a face parallel in front of them wider than a
    slot (a book's side 3 cm from the bookcase's side: not a contact) whose clearance c (along
    their normal) is less than their distance to their corner, where the corner sees out more
    (of OPEN_RAYS rays from near it, more going OPEN_FAR x c or farther than from the sample),
    move (in place) towards their corner to OUTPUT_OPEN x c from it. tp, covered:
    _transport_covered(pts) (covered samples, in a slot: _toward_mouths')."""
    if not len(pts):
        return
    pt = system.patches
    eps = float(system.refiner.eps)
    ok = np.flatnonzero((tp >= 0) & ~covered)
    reach = probe_reach(system)
    nrm = pt.normal[tp[ok]]
    prim, dist = system.backend.first_hit(pts[ok] + eps * nrm, nrm, reach)
    dist = np.where(prim >= 0, dist, np.inf)
    gap = np.linalg.norm(pts[ok] - corner[ok], axis=1)
    c = ok[dist < gap]
    clear = dist[dist < gap]
    if not len(c):
        return
    q0 = corner[c] + MOUTH_NUDGE * (pts[c] - corner[c])

    def escaping(q, keys):  # (each sample's rays keyed by its own index: its own answer)
        n = pt.normal[tp[c]]
        d = cosine_directions(n, keys, OPEN_RAYS, seed=11)
        hp, hd = system.backend.first_hit(q + eps * n, d.reshape(-1, 3), reach, per=OPEN_RAYS)
        far = (hp < 0) | (hd >= OPEN_FAR * np.repeat(clear, OPEN_RAYS))
        return far.reshape(-1, OPEN_RAYS).sum(1)

    at_corner, at_sample = escaping(q0, c), escaping(pts[c], c + len(pts))
    move = at_corner > at_sample
    c, clear = c[move], clear[move]
    f = np.minimum(OUTPUT_OPEN * clear / np.linalg.norm(pts[c] - corner[c], axis=1), 1.0)
    pts[c] = corner[c] + f[:, None] * (pts[c] - corner[c])


def cut_patches(system, nudge=0.05, reach=None, layout=None):
    """(K,) bool: patches with a corner inside another solid or covered (_buried, probed `nudge`
    of the way from the corner to the patch's centre): cut by another object, the light of their
    visible part ends in a dark band along the cut (corner_fit's extra samples). layout: an
    OutputLayout's patches (K of them), tested on the transport's under the points."""
    layout = OwnLayout(system) if layout is None else layout
    pt = layout.patches
    jj, kk = np.nonzero(pt.vert_index >= 0)
    c = pt.corners[jj, kk]
    centre = pt.corners[jj, :3].mean(1)
    centre[pt.nv[jj] == 4] = pt.corners[jj[pt.nv[jj] == 4]].mean(1)
    out = np.zeros(len(pt.nv), bool)
    reach = probe_reach(system) if reach is None else reach
    q = c + nudge * (centre - c)
    tr = layout.transport(jj, q)
    ok = tr >= 0  # (an output patch on a transport polygon dropped as degenerate: never cut)
    out[jj[ok][_buried(system, q[ok], tr[ok], reach)]] = True
    return out


SLOT_GRID = 256  # slot_split: test points per patch with a contact (a square: 16 x 16)
SLOT_AREA = 64  # slot_split: points a slot part's transfer is averaged over
SLOT_WHOLE = False  # slot_split: patches wholly in a slot too (depths > 2x apart; measured, left off)
# slot_split on an output layout's patches (Vertex Spacing): the slot part's weight in a split
# patch's mean. 0: the open part's mean alone, what a camera sees (the slot part, 2 mm behind a
# neighbour, shows only through the gap), and no slot samples gathered; the system's own corners
# keep 1 (each part by its area, as before). Furnished camera at 0.25 m: within 5% wide / close
# 85.0 / 76.4% -> 95.6 / 85.9% (docs/accuracy.md, vx28)
OUTPUT_SLOT_SEEN = 0.0
SPLIT_BATCH = 256  # slot_split: patches per batch on threads (fixed, never by the thread count)


def slot_split(system, skip=None, grid=SLOT_GRID, n=None, layout=None):
    """Samples for the patches with a contact that lie part open, part in a slot (of their `grid`
    test points, corner_fit.extra_points, some covered by nothing and some in a slot: a book's side
    above a shorter neighbour, lit as the room's walls on a strip and through a 2 mm gap below it):
    n // 2 (corner_fit.EXTRA) spread over the open part, and one in the slot whose transfer is the
    mean over SLOT_AREA of the part's test points (FinalGather's slot_area: the light falls off
    steeply from the mouths, which a few samples would catch or miss); each part weighted by its
    share of the patch's visible area (test points covered without a gap left out). A stratified
    mean of the light over the patch, whose corners' samples (a quarter of the way in) all lie in
    the slot's shade when the open strip is narrower than a quarter of the patch. skip (K,) bool:
    patches left out (cut_patches'). On an output layout's patches the slot part weighs
    OUTPUT_SLOT_SEEN (0: the open part alone, no slot sample). Returns (points (m, 3), patch (m,),
    weight (m,), slot_area (rows of the slot samples (r,), their points (r, SLOT_AREA, 3), the slot
    chain slots() found at each of those points (r, SLOT_AREA) on its transport patch (r,
    SLOT_AREA): FinalGather._slots reuses them), (the split patches (p,), their interpolant's mean
    per unit corner value over the visible test points (p, 4)). Computed by
    batches of SPLIT_BATCH patches on the system's threads. layout: an OutputLayout (its patches
    are split, each point tested on the transport patch under it) or None (the system's)."""
    con = system.h.contacts
    own = layout is None
    layout = OwnLayout(system) if own else layout
    n = corner_fit.EXTRA if n is None else n
    none = (
        np.zeros((0, 3)),
        np.zeros(0, np.int64),
        np.zeros(0),
        (
            np.zeros(0, np.int64),
            np.zeros((0, SLOT_AREA, 3)),
            np.zeros((0, SLOT_AREA), np.int64),
            np.zeros((0, SLOT_AREA), np.int64),
        ),
        (np.zeros(0, np.int64), np.zeros((0, 4))),
    )
    cand = np.zeros(0, np.int64) if con is None else np.asarray(con.receivers, np.int64)
    if own:
        if skip is not None:
            cand = cand[~skip[cand]]
        if len(cand):
            con.close_mouths(system.backend.occluded)  # (and the mouths built: once, before the batches)
            cand = cand[con.may_slot(cand)]  # the others have no point in a slot: never split
    elif len(cand):  # the output patches on a transport polygon with such a patch, by their own box
        con.close_mouths(system.backend.occluded)
        cand = cand[con.may_slot(cand)]
        hit = np.zeros(len(layout.under_start) - 1, bool)
        hit[system.patches.poly[cand]] = True
        lp = layout.patches
        cand = np.flatnonzero(hit[layout.poly[lp.poly]])
        if skip is not None:
            cand = cand[~skip[cand]]
        if len(cand):  # each tested on the transport patch under its centre
            home = layout.transport(
                cand,
                np.where((lp.nv[cand] == 4)[:, None], lp.corners[cand].mean(1), lp.corners[cand, :3].mean(1)),
            )
            ok = con.may_slot(home, lp.corners[cand])
            cand, home = cand[ok], home[ok]
    # the candidates' chains by part of their boxes, once for every batch: their test points search
    # those, not the grid's cells (Contacts.patch_boxes: the same pairs)
    boxes = None
    if len(cand):
        lp = layout.patches
        home, faces = (cand, None) if own else (home, (lp.corners[cand], lp.nv[cand]))
        boxes = (home, con.patch_boxes(home, faces))
    threads = system.backend.threads
    parts = batch_map(
        lambda i, j: _split_part(system, cand[i:j], grid, n, layout, boxes and (i, *boxes)),
        ranges(len(cand), SPLIT_BATCH),
        0 if threads is None else threads,
    )
    parts = [p for p in parts if p is not None]
    if not parts:
        return none
    sel, psel, w, deep, pdeep, ws, area, achain, apatch, mixed, mean_w = (
        np.concatenate(x) for x in zip(*parts)
    )
    return (
        np.r_[sel, deep],
        np.r_[psel, pdeep],
        np.r_[w, ws],
        (len(sel) + np.arange(len(deep)), area, achain, apatch),
        (mixed, mean_w),
    )


def _split_part(system, cand, grid, n, layout, boxes=None):
    """slot_split for patches `cand` (each patch's samples its own: a batch of them): (open samples'
    points, their patches, weights, slot samples' points, their patches, weights, their area's
    points, their chains and transport patches, the split patches, their interpolants' mean) or None
    if none is split. boxes: (cand[0]'s row, the table's patches, Contacts.patch_boxes' table)."""
    pt, con = layout.patches, system.h.contacts
    if not len(cand):
        return None
    gp, row = corner_fit.extra_points(pt.corners[cand], pt.nv[cand], grid)
    order = np.argsort(row, kind="stable")  # by patch, each in its grid's order
    gp, row = gp[order], row[order]
    tr = layout.transport(cand[row], gp)  # the transport patch under each test point
    cls = np.zeros(len(gp), np.int64)  # 0 open, 1 in a slot, 2 covered without a gap
    depth, mouth, chain = np.zeros(len(gp)), np.full(len(gp), -1, np.int64), np.full(len(gp), -1, np.int64)
    K = len(cand)
    if boxes is not None:  # a point on its row's plane and piece searches that row's chains
        r = boxes[0] + row
        bp = boxes[1][r]
        r[(con.plane[tr] != con.plane[bp]) | (con.piece[tr] != con.piece[bp])] = -1
        boxes = (r, boxes[2])
    cov, pairs = con.covered_pairs(gp, tr, boxes=boxes)  # (inline: this is a batch; its pairs for slots())
    cls[cov] = 2
    # which covered points lie in a slot: on the patches with an open point only (the others are
    # never split)
    c = np.flatnonzero(cov & (SLOT_WHOLE | (np.bincount(row, ~cov, K) > 0)[row]))
    if len(c):
        x, h, _, ch, mo = con.slots(gp[c], tr[c], pairs=pairs_of(pairs, c, len(gp)))
        cls[c], depth[c], mouth[c], chain[c] = np.where(h > 0, 1, 2), x, mo, ch
    cnt = np.stack([np.bincount(row, cls == k, K) for k in (0, 1)], 1)  # (K, 2) open, slot
    mixed = (cnt > 0).all(1)
    if SLOT_WHOLE:  # patches wholly in a slot, their light falling off over depths more than 2x apart
        d = np.where(cls == 1, depth, np.nan)
        start = np.searchsorted(row, np.arange(K))
        mixed |= (cnt[:, 1] > 0) & (np.fmax.reduceat(d, start) > 2 * np.fmin.reduceat(d, start))
    mixed = np.flatnonzero(mixed)
    if not len(mixed):
        return None
    sw = 1.0 if isinstance(layout, OwnLayout) else OUTPUT_SLOT_SEEN
    seen = cnt[mixed] * np.array([1.0, sw])  # the parts' weights (the slot part's: sw)
    share = seen / seen.sum(1, keepdims=True)
    # the open part: n // 2 of its test points, nearest the centres of a k_a x k_b grid over the
    # part's extent along the patch's sides (a strip 4 cm x 20 cm: 1 x 4, along its middle); all
    # mixed patches at once over (centre, open point of its patch) pairs
    q = np.flatnonzero(np.isin(row, mixed) & (cls == 0))  # by patch (gp is sorted by row)
    op, j = np.unique(row[q], return_inverse=True)  # the patches with open points
    cq = pt.corners[cand[op]]
    last = np.where((pt.nv[cand[op]] == 4)[:, None], cq[:, 3], cq[:, 2])
    e = np.stack([cq[:, 1] - cq[:, 0], last - cq[:, 0]], 1)
    ee = np.einsum("pij,pij->pi", e, e)
    uv = np.einsum("qj,qij->qi", gp[q] - cq[j, 0], e[j]) / ee[j]  # in units of the sides
    first = np.searchsorted(j, np.arange(len(op)))
    lo, hi = np.minimum.reduceat(uv, first), np.maximum.reduceat(uv, first)
    ext = hi - lo + 1e-9
    size = ext * np.sqrt(ee)
    ka = np.clip(np.round(np.sqrt(n / 2 * size[:, 0] / size[:, 1])), 1, n // 2).astype(np.int64)
    kb = np.maximum(n // 2 // ka, 1)
    tc = ka * kb
    tp = np.repeat(np.arange(len(op)), tc)  # each centre's patch
    ti = np.arange(len(tp)) - np.repeat(np.cumsum(tc) - tc, tc)  # its index in its patch's grid
    t = np.stack([(ti // kb[tp] + 0.5) / ka[tp], (ti % kb[tp] + 0.5) / kb[tp]], 1)
    t = lo[tp] + t * (hi - lo)[tp]
    pc, pq = csr_rows(np.r_[first, len(q)], tp)  # (centre, open point of its patch) pairs
    dist = np.linalg.norm((t[pc] - uv[pq]) * size[tp[pc]] / ext[tp[pc]], axis=1)
    o = np.lexsort((pq, dist, pc))  # per centre its nearest open point (the first of ties)
    o = o[np.r_[True, pc[o][1:] != pc[o][:-1]]]
    sel = q[np.unique(pq[o])]
    r = row[sel]
    w = share[np.searchsorted(mixed, r), 0] / np.bincount(r, minlength=K)[r]
    # the slot part: one sample per mouth its test points are nearest (the light outside differs
    # by mouth: a book's top and front), at the deepest of them (its gather reads that mouth), the
    # transfer averaged over SLOT_AREA of them (none when the slot part has no weight: sw 0)
    if sw > 0:
        sl = np.flatnonzero(np.isin(row, mixed) & (cls == 1))
        _, grp = np.unique(np.column_stack([row[sl], mouth[sl]]), axis=0, return_inverse=True)
        grp = grp.ravel()
        o = np.lexsort((-depth[sl], grp))  # by group, deepest first
        sl, grp = sl[o], grp[o]
        first = np.searchsorted(grp, np.arange(grp.max() + 1))
        ms = np.bincount(grp)
        deep = sl[first]
        at = sl[first[:, None] + (np.arange(SLOT_AREA)[None] * ms[:, None]) // SLOT_AREA]
        area = gp[at]
        achain, apatch = chain[at], tr[at]
        ws = share[np.searchsorted(mixed, row[deep]), 1] * ms / np.bincount(row[sl], minlength=K)[row[deep]]
    else:
        deep, area, ws = np.zeros(0, np.int64), np.zeros((0, SLOT_AREA, 3)), np.zeros(0)
        achain = apatch = np.zeros((0, SLOT_AREA), np.int64)
    # the interpolant's mean over the visible part (the strata are not spread evenly): over the
    # open and slot test points
    vis = np.flatnonzero(np.isin(row, mixed) & (cls < 2))
    kv = cand[row[vis]]
    a = corner_weights(pt.corners[kv], pt.nv[kv], pt.normal[kv], gp[vis])
    ri = np.searchsorted(mixed, row[vis])
    a *= np.where(cls[vis] == 1, sw, 1.0)[:, None]
    mean_w = np.stack([np.bincount(ri, a[:, j], len(mixed)) for j in range(4)], 1) / seen.sum(1)[:, None]
    return gp[sel], cand[r], w, gp[deep], cand[row[deep]], ws, area, achain, apatch, cand[mixed], mean_w


# LoopGather: the samples averaged into one corner share its hemisphere rays, each tracing rays / k
# (k the fewest samples of a corner it is averaged into, at most SHARE; 1: every sample all rays)
SHARE = 4


def shared_rays(average, loop_index, n, rays, share=SHARE):
    """(n,) hemisphere rays per corner sample (loop_samples' inset layout: average (li, lj, ...)):
    rays // k, k the fewest samples any corner that reads the sample averages (at most `share`).
    Such a corner's value is the mean of its k samples (the loops at one welded vertex within the
    smooth angle: 4 to 6 per vertex of a fine smooth mesh, a few mm apart at 100k), so their rays
    between them give it as many directions as one sample with all of them had; each sample's own
    value stays unbiased (its own rotated pattern), only its noise grows. Samples read alone (a box's
    sharp corners) keep all rays."""
    li, lj = average[:2]
    k = np.minimum(np.bincount(li, minlength=len(loop_index)), share)
    m = np.full(n, max(int(share), 1), np.int64)
    np.minimum.at(m, loop_index[lj], k[li])
    return np.maximum(int(rays) // m, 1)


# LoopGather: the extra samples of one face (corner_fit's over a cut face or along an elongated
# one, slot_split's over a split face's open part) stand only for their face's mean
# (corner_fit.shift_plan), so they share EXTRA_FACE x rays between them, each the power of two at
# most its share (at most rays; a face's 8 samples 64 rays each, 4 or fewer all). 0: each traces
# all rays (before session 34). The 100k bake's top-level rays 45.1 -> 40.0 M; per object within
# the seed floor (FE add median 0.591% against main's 0.586%, its four realisations
# 0.569-0.594%); 2 (32 rays each of 8, 64 of 4: 35.1 M) at the floor's edge, 0.596%
# (docs/scale.md, session 34, bakepre)
EXTRA_FACE = 4


def extra_rays(patch, rays, face=None):
    """(m,) hemisphere rays per extra sample on patches `patch` (m,) (the samples of one face are
    those with its patch): rays, or with face > 0 (None: EXTRA_FACE) the power of two at most
    face x rays / (the face's samples), within 1..rays (powers of two: the rows keep hit counts)."""
    face = EXTRA_FACE if face is None else face
    patch = np.asarray(patch, np.int64)
    if face <= 0 or not len(patch):
        return np.full(len(patch), int(rays), np.int64)
    _, inv, cnt = np.unique(patch, return_inverse=True, return_counts=True)
    share = np.maximum(face * int(rays) / cnt[inv.ravel()], 1.0)
    return np.minimum(2 ** np.floor(np.log2(share)).astype(np.int64), int(rays))


class LoopGather(FinalGather):
    """FinalGather for the input mesh's corners: loop_radiance() in the layout of
    DynamicRadiosity.loop_radiance (CORNER: (L, 3) per loop; POINT: (V, 3) per vertex), float32.
    inset: see loop_samples (0.5: samples in the corners' regions, averaged; 0: at the corners;
    None: default_inset(output), INSET or OUTPUT_INSET).
    fit (inset > 0; None: FIT): extra samples over the faces cut by another solid, and their
    corners' values shifted so each keeps the mean of the light gathered over its visible part
    (corner_fit); False: the corners' samples averaged alone.
    output: an OutputLayout (a finer mesh over the system's: Vertex Spacing), whose corners the
    samples are laid out on and loop_radiance's layout is; None: the system's own mesh."""

    output = None  # (class defaults: a gather stored before output layouts restores without them)
    out_patch = None  # (n,) with an output layout: each sample's patch of it (self.patch: the transport's)

    def __init__(self, system, smooth_angle=30.0, inset=None, fit=None, output=None, **kw):
        s = system.system
        lay = OwnLayout(s) if output is None else output
        inset = default_inset(output) if inset is None else inset
        pts, nrm, patch, self.loop_index, self.average = loop_samples(s, smooth_angle, inset, layout=output)
        self.smooth_angle = smooth_angle
        self.fit = bool(FIT if fit is None else fit) and self.average is not None
        self.n_loop = len(pts)  # the corners' samples; corner_fit's extra samples follow
        if self.average is not None and SHARE > 1:
            rays = int(kw.get("rays", 128))  # (FinalGather's default)
            kw["sample_rays"] = shared_rays(self.average, self.loop_index, len(pts), rays)
        if self.fit:
            pt = lay.patches
            reach = probe_reach(s)
            skip = cut_patches(s, reach=reach, layout=output)
            sp, spatch, sw, (rows, *area), self.split_mean = slot_split(
                s, skip if SPLIT else np.ones_like(skip), layout=output
            )
            cut = skip.copy()
            if output is not None and ELONGATED > 0:
                # the faces left whole (their transport polygon's only one), not the slots' split
                # patches (strata of their own)
                whole = np.bincount(output.poly)[output.poly] == 1
                cut |= corner_fit.elongated(pt.corners, pt.nv, ELONGATED, ELONGATED_MIN) & whole[pt.poly]
                cut[spatch] = skip[spatch]
            cut = np.flatnonzero(cut)
            xp, row = corner_fit.extra_points(pt.corners[cut], pt.nv[cut])
            seen = ~_buried(s, xp, lay.transport(cut[row], xp), reach)  # the cut patches' visible part only
            xp, xpatch = xp[seen], cut[row[seen]]
            self.extra_weight = np.r_[np.ones(len(pts) + len(xp)), sw]
            if len(rows):
                kw["slot_area"] = (len(pts) + len(xp) + rows, *area)
            xp, xpatch = np.r_[xp, sp], np.r_[xpatch, spatch]
            pts, nrm, patch = np.r_[pts, xp], np.r_[nrm, pt.normal[xpatch]], np.r_[patch, xpatch]
            if "sample_rays" in kw:  # a face's extra samples share its rays (EXTRA_FACE); a slot's all
                n_open = len(xpatch) - len(rows)  # (corner_fit's, then slot_split's open ones)
                own = extra_rays(xpatch[:n_open], rays)
                kw["sample_rays"] = np.r_[kw["sample_rays"], own, np.full(len(rows), rays, np.int64)]
        if output is not None:  # gathered on the transport patch under each point, to its side
            self.output, self.out_patch = output, patch
            patch = output.transport(patch, pts)
            if inset > 0:
                nrm = s.patches.normal[patch]
        release_free_memory()  # the layout's freed temporaries: not resident under the rays'
        super().__init__(system, pts, nrm, patch, **kw)

    def loop_radiance(self, dyn, domain="CORNER", kind="radiance", rows=None, out=None):
        """rows (CORNER): only these loops' values, in this order (a caller's layout, e.g.
        scene_in.FlatExtract's): with the cached responses only they are summed, no (L, 3) array
        of every loop (the same values as loop_radiance(dyn)[rows]). out: the float32
        (len(rows), 3) array (a view may be) they are written into."""
        if rows is not None and domain != "CORNER":
            raise ValueError("loop_radiance: rows index loops (CORNER)")
        res = self._radiance_by_response(dyn, rows) if kind == "radiance" else None
        if res is None:
            res = self.loop_values(self.evaluate(dyn, kind), domain)
            res = res if rows is None else res[rows]
        elif rows is None:
            res = in_domain(res, self.out_mesh, domain)
        if out is None:
            return res.astype(np.float32, copy=False)
        out[...] = res  # (float64 -> float32: in_domain's rounding)
        return out

    def _loop_map(self):
        """(li, sj, wn, start): loop li takes wn x sample value sj, sorted by sj, start (n + 1,)
        the entries of each sample: loop_values as one constant linear map (the mean over the
        uncovered samples of the corner's loops; a loop with none reads 0). Built on first use;
        the loops and samples int32 (their counts are), each temporary let go once used (the 100k
        vertex bake's first frame peaks here: 3.15 M pairs; docs/scale.md, session 32)."""
        got = self.__dict__.get("_loop_weights")
        if got is None:
            L = len(self.loop_index)
            if self.average is not None:
                li, lj, w = self.average[:3]
                sj = self.loop_index[lj]
                wn = w * ~self.dark[sj]
                den = np.bincount(li, wn, L)
                wn /= np.where(den > 0, den, 1.0)[li]  # (in place: the same quotients)
                del den
            else:
                li = np.flatnonzero(self.loop_index >= 0)
                sj, wn = self.loop_index[li], np.ones(len(li))
            keep = np.flatnonzero(wn > 0)
            keep = keep[np.argsort(sj[keep], kind="stable")]  # the kept entries by sample, in order
            sj = np.take(sj, keep).astype(np.int32)
            li, wn = np.take(li, keep).astype(np.int32), np.take(wn, keep)
            del keep
            got = self._loop_weights = (li, sj, wn, np.searchsorted(sj, np.arange(self.n + 1)))
        return got

    def _shift_plan(self):
        """corner_fit.shift_plan of this layout (built on first use, like _loop_map)."""
        got = self.__dict__.get("_shift")
        if got is None:
            pt, (li, lj, w, lpatch, pc_loop) = self._layout_patches(), self.average
            got = self._shift = corner_fit.shift_plan(
                pt.corners,
                pt.nv,
                pt.normal,
                self.patch if self.out_patch is None else self.out_patch,
                self.points,
                self.dark,
                self.n_loop,
                lpatch,
                pc_loop,
                (li, lj, w),
                self.extra_weight,
                self.split_mean,
            )
        return got

    def _layout_patches(self):
        return self.system.patches if self.output is None else self.output.patches

    @property
    def out_mesh(self):
        """The mesh whose loops loop_radiance's values are for (the output layout's, or the system's)."""
        return self.system.mesh if self.output is None else self.output.mesh

    def loop_values(self, v, domain="CORNER"):
        """Sample values (n, 3) (evaluate's, or core.lights.indirect_incident's) in the loop_radiance
        layout (>= 0: a face's shift may take a corner below)."""
        return in_domain(np.maximum(self._loops(v), 0.0), self.out_mesh, domain)

    def _loops(self, v):
        """(L, 3) float64 per loop of sample values v (n, 3) (_loop_map)."""
        li, sj, wn, _ = self._loop_map()
        L = len(self.loop_index)
        out = np.empty((L, v.shape[1]))

        def channel(c):  # (by channel on threads: each its own column, the same sums)
            out[:, c] = np.bincount(li, wn * v[sj, c], L)

        batch_map(channel, [(c,) for c in range(v.shape[1])], self.threads)
        return corner_fit.shifted(out, v, self._shift_plan()) if getattr(self, "fit", False) else out

    def _radiance_by_response(self, dyn, rows=None):
        """(L, 3) loop_radiance (CORNER, float64) as a weighted sum of the response parts' own
        loop values (FinalGather._response_parts): the output is linear in them but where the
        incident light sum dips below 0 (clipped to 0: the slopes' read), so each part's loop
        values are kept with the samples where it is negative, and the sum is corrected at the
        samples where the total is. A colour or strength edit is then one sum of (L, 3) arrays.
        rows (distinct loops): the parts are kept, and summed, at those only ((len(rows), 3)).
        None where the responses do not apply (evaluate's path)."""
        parts = self._response_parts(dyn) if self.group is None else None
        if parts is None:
            return None
        self.forget_shapes(dyn)
        cache = self.__dict__.setdefault("_loop_parts", {})
        if self.__dict__.setdefault("_loop_rows", (rows, None))[0] is not rows:  # (in another layout)
            cache.clear()
            self._loop_rows = (rows, None)
        if rows is not None and self._loop_rows[1] is None:  # each loop's row (-1: none)
            at = np.full(len(self.loop_index), -1, np.int64)
            at[rows] = np.arange(len(rows))
            self._loop_rows = (rows, at)
        ok = ~self.dark

        def gain(i):  # rho x the slot samples' transfer at samples i (at the clipped ones: not all)
            return self.rho[i] if self.gain is None else self.rho[i] * self.gain[i]

        out, neg = None, []
        for key, wt, part, rec in parts:
            got = cache.get(key)
            if got is None or got[0] is not part:
                # the output of this part alone: what it adds to E + rho gain (D + I) where uncovered
                x = gain(slice(None)) * part
                if rec is None and wt is None:
                    x += self.E_static
                elif rec is not None:
                    own = self._shape if rec.preview is None else self._preview_shape
                    x[own(dyn, rec)[1]] += 1.0  # the shape's own emission, per unit
                x[self.dark] = 0.0
                idx = np.flatnonzero((part < 0).any(1) & ok)
                Q = self._loops(x).astype(np.float32)
                got = cache[key] = (part, Q if rows is None else Q[rows], idx)
                del x, Q
                release_free_memory()  # (a new part's loop values' temporaries: not under the next's)
            Q, idx = got[1], got[2]
            if wt is None:
                out = Q.astype(np.float64)
            else:
                out += wt * Q
            neg.append(idx)
        live = {p[0] for p in parts}
        for k in [k for k in cache if k not in live][:-8]:
            del cache[k]
        idx = np.unique(np.concatenate(neg))
        if len(idx):
            # the clipped samples: the same total as _incident_by_response there, its part below 0 out
            tot = parts[0][2][idx].copy()
            for _, wt, part, _ in parts[1:]:
                tot += wt[None] * part[idx]
            d = np.where(tot < 0, -gain(idx) * tot, 0.0)
            j = np.flatnonzero(d.any(1))
            if len(j):
                li, _, wn, start = self._loop_map()
                pr, e = csr_rows(start, idx[j])  # the map's entries of the corrected samples
                row = j[pr]
                touched, tl = np.unique(li[e], return_inverse=True)
                add = np.stack([np.bincount(tl, wn[e] * d[row, c], len(touched)) for c in range(3)], 1)
                if getattr(self, "fit", False):  # (_loops of the correction: the shifts take in
                    # every sample of a face; only the faces it touches)
                    touched, add = corner_fit.shifted_at(touched, add, idx[j], d[j], self._shift_plan())
                # added at the loops it may reach only (a few): elsewhere it is 0, and x + 0 is x as
                # the sum holds no -0.0 (its first term, the base's loop values, is bincount sums,
                # which start at +0.0)
                at = touched if rows is None else self._loop_rows[1][touched]
                out[at[at >= 0]] += add[at >= 0]
        # a sum of terms >= 0, where only the parts' rounding dips below; with the faces' shifts
        # (fit) a corner may (loop_values' clip)
        return np.maximum(out, 0.0, out=out)


def texel_samples(
    system, patch, points, axes, sub=SUB, seed=0, open_edge=OPEN_EDGE, tris=None, slot_sub=SLOT_SUB
):
    """Gather samples of texels: the centre, or sub x sub stratified points over the texel's area
    where the light changes inside it at a contact: some of those points covered and some not (a
    block's footprint on a floor), or in a slot (between two books) some within open_edge gap
    widths of its mouth or at depths more than 2x apart (the light falls off as 1 / depth^2). A
    renderer's bake averages over part of the texel (Cycles: its middle half, the part inside the
    centre's triangle); a centre reads one point, 0 or lit. axes (n, 2, 3): the texel's sides on
    the surface (world vectors of one texel step in u and in v), None: centres only. tris (n, 3,
    3): the triangle each centre lies in, in the mesh's loop-triangle order: the points are placed
    as Cycles' bake places them, over the middle half of the texel inside that triangle
    (bake_points); None: over the texel's parallelogram. The jitter is keyed by the texel centre's
    position.
    Texels wholly in a slot whose points lie at depths more than 2x apart gather at their centre,
    with the slot's transfer averaged over their points (FinalGather's slot_area); the other texels
    wholly in a slot that are sampled over their area take slot_sub x slot_sub points.
    Returns (points (S, 3), patch (S,), group (S,) texel of each sample, non-decreasing,
    slot_area: None or (sample rows (r,), their texels' points (r, sub^2, 3)))."""
    s = system.system
    con = s.h.contacts
    points, patch = np.asarray(points, np.float64).reshape(-1, 3), np.asarray(patch, np.int64)
    n = len(points)
    cand = np.zeros(0, np.int64)
    if axes is not None and sub > 1 and con is not None and n:
        cand = np.flatnonzero(np.isin(patch, con.receivers))  # texels on patches with a contact
    if tris is not None and len(cand):
        cand = cand[has_area(np.asarray(tris, np.float64).reshape(-1, 3, 3)[cand])]
    if not len(cand):
        return points, patch, np.arange(n), None
    k2 = sub * sub
    size = float(np.sqrt(isolated_objects(s.mesh).main_area))
    keys = position_keys(points[cand], 2.0 ** (np.floor(np.log2(size)) - 12))
    gx, gy = np.meshgrid(np.arange(sub), np.arange(sub), indexing="ij")
    grid = np.stack([gx.ravel(), gy.ravel()], 1)
    axes = np.asarray(axes, np.float64).reshape(-1, 2, 3)

    def test(a, b):  # candidates a..b, each its own: by rows (20 points each and their temporaries)
        f = (grid[None] + hash_uniform(seed, keys[a:b], 2000, 2 * k2).reshape(-1, k2, 2)) / sub
        # tested at the sub-points and the texel's corners (a boundary between jittered points)
        f = np.concatenate([f, np.broadcast_to(CORNERS, (b - a, 4, 2))], 1)
        c_ = cand[a:b]
        pts = texel_points(points[c_], axes[c_], tris, f, c_)
        m = pts.shape[1]
        flat, fp = pts.reshape(-1, 3), np.repeat(patch[c_], m)
        cov, pairs = con.covered_pairs(flat, fp)
        cov = cov.reshape(-1, m)
        mixed = cov.any(1) & ~cov.all(1)
        spread, whole = np.zeros(b - a, bool), np.zeros(b - a, bool)
        if open_edge > 0 and cov.any():
            # in a slot the light falls off as its mouth's view factor, about (h / 2x)^2 at depth x:
            # a texel near a mouth, or across depths whose light differs by more than 4x, is sampled
            # over its area
            con.close_mouths(s.backend.occluded)
            c = np.flatnonzero(cov.ravel())
            x, hg = np.full(cov.size, np.inf), np.zeros(cov.size)
            x[c], hg[c] = con.slots(flat[c], fp[c], pairs=pairs_of(pairs, c, cov.size))[:2]
            x, slot = x.reshape(-1, m), (hg > 0).reshape(-1, m)
            mixed |= (slot & (x < open_edge * hg.reshape(-1, m))).any(1)
            band = con.covered(flat[c], fp[c], open_edge=open_edge)  # gathered where they lie (FinalGather)
            mixed |= np.bincount(c[~band] // m, minlength=b - a) > 0
            spread = ~mixed & slot.all(1) & (x.max(1) > 2 * x.min(1))
            if slot_sub != sub:
                whole = mixed & slot.all(1)
        keep = mixed | spread  # (the others' points are not used)
        return np.flatnonzero(keep) + a, pts[keep, :k2], mixed, spread, whole

    parts = [test(a, b) for a, b in ranges(len(cand), TEST_BATCH)]
    kept, sp, mixed, spread, whole = (np.concatenate(p) for p in zip(*parts))
    del parts
    at = np.full(len(cand), -1)  # each candidate's row of sp (the kept ones')
    at[kept] = np.arange(len(kept))
    ks = slot_sub * slot_sub
    cnt = np.ones(n, np.int64)
    cnt[cand[mixed]] = np.where(whole[mixed], ks, k2)
    group = np.repeat(np.arange(n), cnt)
    pts = points[group]
    first = np.cumsum(cnt) - cnt
    full = mixed & ~whole
    rows = (first[cand[full]][:, None] + np.arange(k2)).ravel()
    pts[rows] = sp[at[full]].reshape(-1, 3)
    if whole.any():  # their own stratified jitter, slot_sub x slot_sub
        gx, gy = np.meshgrid(np.arange(slot_sub), np.arange(slot_sub), indexing="ij")
        g2 = np.stack([gx.ravel(), gy.ravel()], 1)
        f2 = (g2[None] + hash_uniform(seed, keys[whole], 2001, 2 * ks).reshape(-1, ks, 2)) / slot_sub
        c = cand[whole]
        p2 = texel_points(points[c], axes[c], tris, f2, c)
        pts[(first[c][:, None] + np.arange(ks)).ravel()] = p2.reshape(-1, 3)
    if open_edge > 0 and spread.any():
        # deep in a slot, across depths whose light differs by more than 4x: the centre gathers the
        # mouth's light for the whole texel, its transfer is the mean over the texel's points
        return pts, patch[group], group, (first[cand[spread]], sp[at[spread]])
    return pts, patch[group], group, None


def texel_gather(system, patch, points, axes=None, sub=SUB, tris=None, slot_sub=SLOT_SUB, **kw):
    """FinalGather at texels (lightmap.plan's points on input patches), normals from the patches:
    evaluate(solution, kind) replaces core.texels.solution_radiance(solution, patch, points,
    kind=kind) (same kinds; float64, cast as needed). axes (n, 2, 3): the texels' sides on the
    surface; texels straddling a contact's edge then gather over their area (texel_samples) and
    output the mean (gather.n: samples, gather.n_out: texels). tris (n, 3, 3): each centre's
    triangle in loop-triangle order, the area inside it as Cycles' bake takes it."""
    s = system.system
    pts, pp, group, area = texel_samples(
        system, patch, points, axes, sub, kw.get("seed", 0), kw.get("open_edge", OPEN_EDGE), tris, slot_sub
    )
    if kw.get("rho") is not None and np.ndim(kw["rho"]) == 2:  # per texel: per sample
        kw["rho"] = np.asarray(kw["rho"])[group]
    sub_rays = None
    if len(group) > len(points):  # sub-samples: a quarter of the rays each, 4x the texel's in all
        cnt = np.bincount(group)[group]
        sub_rays = np.where(cnt > 1, max(kw.get("rays", 128) // 4, 16), kw.get("rays", 128))
    g = FinalGather(
        system,
        pts,
        s.patches.normal[pp],
        pp,
        groups=None if axes is None else group,
        sample_rays=sub_rays,
        slot_area=area,
        **kw,
    )
    if axes is not None and len(group):
        # texels gathered at their centre: a Blender light's edge across one is averaged over its
        # area (texel_edges.edge_direct)
        one = np.flatnonzero(np.bincount(group)[group] == 1)
        g.texel_area = texel_area(
            np.asarray(points, np.float64).reshape(-1, 3)[group[one]],
            np.asarray(axes, np.float64).reshape(-1, 2, 3)[group[one]],
            None if tris is None else np.asarray(tris, np.float64).reshape(-1, 3, 3)[group[one]],
            one,
        )
    return g
