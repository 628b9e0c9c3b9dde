"""Core engine against analytic oracles (tests/closed_forms.py, furnace and sphere identities). No bpy."""

import numpy as np
import pytest

import closed_forms as cf
from hr_addon.core import formfactor as ff
from hr_addon.core.geometry import InputError, MeshInput, prepare_patches
from hr_addon.core.hierarchy import Hierarchy
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_addon.core.solver import ConvergenceWarning, solve
from hr_testing import scenes

FAST = RefineParams.preset("draft")


# -- input -----------------------------------------------------------------------------------------
def test_triangulation_and_degenerates():
    v = np.array(
        [
            [0, 0, 0],
            [2, 0, 0],
            [2, 1, 0],
            [1, 1, 0],
            [1, 2, 0],
            [0, 2, 0],  # L-shaped hexagon
            [3, 0, 0],
            [4, 0, 0],
            [4, 1, 0.5],
            [3, 1, 0],  # non-planar quad
            [5, 0, 0],
            [6, 0, 0],
            [5.2, 0.2, 0],
            [5, 1, 0],  # concave quad (dart)
            [7, 0, 0],
            [8, 0, 0],
            [9, 0, 0],
        ],
        float,
    )  # collinear: degenerate
    mesh = MeshInput.from_polygons(v, [[0, 1, 2, 3, 4, 5], [6, 7, 8, 9], [10, 11, 12, 13], [14, 15, 16]], 0.5)
    p = prepare_patches(mesh)
    assert p.dropped == 1 and "Dropped 1" in p.warnings[0]
    assert np.all(p.nv == 3)
    # Area is preserved: L-shape 3, dart = triangle(10,11,12) + triangle(10,12,13)
    lshape = p.area[p.poly == 0].sum()
    dart = 0.5 * 1 * 0.2 + 0.5 * 1 * 0.2
    assert lshape == pytest.approx(3.0) and p.area[p.poly == 2].sum() == pytest.approx(dart)
    assert np.all(p.normal[p.poly != 1][:, 2] > 0.999)  # orientation kept through triangulation
    # Every patch is convex and planar: corner turns all positive about its normal.
    c = p.corners[:, :3]
    assert np.all(np.einsum("ij,ij->i", np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), p.normal) > 0)


@pytest.mark.parametrize(
    "bad, message",
    [
        (dict(verts_nan=True), "NaN or infinite vertex coordinates on polygon 1 of object 'wall'"),
        (dict(rho=1.0), "outside [0, 1)"),
        (dict(rho=np.nan), "Non-finite reflectance"),
        (dict(emission=-1.0), "Negative emission"),
    ],
)
def test_bad_input_names_the_culprit(bad, message):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    rho = np.full((2, 3), 0.5)
    em = np.zeros((2, 3))
    if bad.get("verts_nan"):
        v[4, 1] = np.nan
    if "rho" in bad:
        rho[1, 0] = bad["rho"]
    if "emission" in bad:
        em[1, 2] = bad["emission"]
    mesh = MeshInput.from_polygons(v, [[0, 1, 2, 3], [1, 4, 5, 2]], rho, em, [0, 0], ["wall"])
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        prepare_patches(mesh)


def test_empty_scene_is_an_error():
    with pytest.raises(InputError, match="no polygons"):
        prepare_patches(MeshInput.from_polygons(np.zeros((0, 3)), [], 0.5))
    with pytest.raises(InputError, match="degenerate"):
        prepare_patches(MeshInput.from_polygons(np.zeros((3, 3)), [[0, 1, 2]], 0.5))


# -- hierarchy -------------------------------------------------------------------------------------
def test_subdivision_preserves_area_orientation_and_corners():
    h = Hierarchy(prepare_patches(scenes.cornell_box()))
    for _ in range(3):
        h.subdivide(h.leaves())
    inner = np.flatnonzero(~h.is_leaf)
    kids = h.children(inner)
    assert np.allclose(h.area[kids].sum(1), h.area[inner], rtol=1e-12)
    c = h.corners[: h.n]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    assert np.all(np.einsum("ij,ij->i", n, h.normal[: h.n]) > 0)
    for k in range(4):  # child k holds its parent's corner k (output relies on it)
        has = k < h.nv[inner]
        assert np.allclose(h.corners[kids[has, k], k], h.corners[inner[has], k])


# -- form factors and links -------------------------------------------------------------------------
def test_links_reciprocal_and_bounded():
    s = RadiositySystem(scenes.cornell_box(), RefineParams.preset("medium"))
    L, h = s.links, s.h
    assert np.allclose(h.area[L.a] * L.f_ab, h.area[L.b] * L.f_ba, rtol=1e-12, atol=0)
    assert L.f_ab.max() <= 1 and L.f_ba.max() <= 1 and L.f_ab.min() >= 0
    assert 0 <= L.vis.min() and L.vis.max() <= 1
    recv, _, f = L.directed()
    assert np.all(np.diff(recv) >= 0)  # CSR: sorted by receiver
    # Every leaf's total form factor (its links, its ancestors' and the push corrections) is a
    # point's F to the rest of the box, <= 1 (its area-mean 0.837 by cosine rays: the box is open
    # at the front). Links made at ancestors once carried their own visibility (1 when all their 16
    # rays passed) to every leaf below, so a leaf beside a block kept its share of sources the block
    # hides from it: up to 1.110, 0.73% of the area above 1.01. The corrections now give each leaf
    # its own visibility, weighted by the kernel, and the link its leaves' total
    # (tests/test_refine_rowsum.py). What remains (measured 2026-12-02: at most 1.028, 0.03% of the
    # area above 1.01), traced at the worst leaf (floor, 44% exposed, touching the tall block;
    # its exact row sum 0.976 by 8 x 8 points x 24 x 24 rays per source): +0.015 from the block's
    # face (its form factor from about 6 x 6 points on the leaf's exposed part: the quadrature of
    # a kernel singular at the contact line), +0.008 from the back wall (4 segments, of which the
    # block hides fewer than it hides of the wall), the rest below 0.004 per source. The bounds:
    # 1.03 and 0.1% of the area: measured with that margin, not derived.
    op = s.operator()
    _, src, _ = L.directed()
    ex = h.view("exposure")
    fsum = op.push(np.bincount(recv, weights=f * ex[src], minlength=h.n)[None].copy())[0][op.leaves]
    a = h.area[op.leaves] * ex[op.leaves]
    assert a[fsum > 1.01].sum() < 0.001 * a.sum() and fsum.max() < 1.03
    leaf, src, dF = L.corr
    ea = h.area[leaf] * ex[leaf]
    assert len(dF) > 0 and abs(np.sum(ea * dF)) < 1e-9 * np.sum(ea * np.abs(dF))


def test_smaller_feps_never_gives_fewer_links():
    counts = [
        len(RadiositySystem(scenes.cornell_box(), RefineParams(feps=fe, veps=0, aeps=1e-3)).links)
        for fe in (0.1, 0.05, 0.02, 0.01)
    ]
    assert counts == sorted(counts) and counts[0] < counts[-1]


# -- whole-scene oracles ----------------------------------------------------------------------------
@pytest.mark.parametrize("rho", [0.3, 0.5, 0.8])
def test_furnace_box_uniform(rho):
    E = 1.0
    s = RadiositySystem(scenes.closed_box(rho=rho, emission=(E, E, E)), RefineParams.preset("medium"))
    B = s.solve()
    lf = s.h.leaves()
    rel = B[:, lf] / (E / (1 - rho)) - 1
    assert s.report.energy_error < 1e-5 and s.report.escaped < 1e-3 * s.report.emitted  # closed
    assert np.abs(rel).max() < 0.005  # everywhere, not just on average


def _absorbed_over_emitted(s):
    """(3,) the power a solved closed scene absorbs, sum A (1 - rho) H over the leaves (H = (B -
    E) / rho, the node means' irradiance), over the power it emits: 1 where no light is lost."""
    B = s.solve()
    lf = s.h.leaves()
    E = s.base_emission()[:, lf] * s.h.exposure[lf]
    a, rho = s.h.area[lf], s.patches.reflectance[:, s.h.patch[lf]]
    return (a * (1 - rho) * (B[:, lf] - E) / rho).sum(1) / (a * E).sum(1)


def test_a_closed_furnished_room_keeps_its_light_when_partly_visible_far_links_are_split():
    """The furnished 2k room (closed, a ceiling light panel) on the draft gather transport
    (RefineParams.for_gather): far (cluster) links weaker than shadow_feps are kept where their
    visibility is partial, one visibility for all their members, and the solution loses light
    (with vis_k 1 a patch link's one ray is never partial: shadow_feps splits far links only).
    What it absorbs over what it emits, measured per channel: shadow_feps 0.03 (the preset's) 0.988
    / 0.986 / 0.983; 0.01 1.002 / 0.997 / 0.993; 0.003 1.006 / 1.001 / 0.997; 0 (none split) 0.967 /
    0.965 / 0.963; the 20k room 0.930 / 0.942 / 0.950 at 0.03, 0.959 / 0.967 / 0.972 at 0.003. The
    balance is not exact at draft (parts of the 20k room alone overshoot 1 by up to 8.6% at 0.003:
    other links make light), so this asserts the balance where split finer and the direction of
    the preset's loss, not the preset's figure (a fix for it must not fail here; docs/gather.md, ind28).
    The same far links make the transport's V dark where the gather reads it (the 20k ceiling read by
    one level: -7.7% at 0.03, -2.5% at 0.01, -0.4% at 0.003 against the converged two-level gather).
    cl28: a partial end's samples on members facing away were blocked by their own solids and
    darkened its links' visibility; counted out, 0.996 / 0.993 / 0.990 at 0.03 and 1.007 / 1.002 /
    0.998 at 0.01 (the 20k room 0.945 / 0.956 / 0.964 at 0.03; its ceiling read -6.9%). cl29: samples
    on covered parts (a patch node's Gauss points under a box, a member's exposed centre under its
    cover) blocked every segment from them and dropped whole links as occluded (20k: 8% of the far
    links' exact exchange); counted out, 1.008 / 1.004 / 1.000 at 0.03 and 1.015 / 1.009 / 1.004 at
    0.01 (20k 0.964 / 0.974 / 0.980 at 0.03). Split finer the room now overshoots: the links kept
    (traced wholly visible) are the ones whose 4 or 16 segments read too high (20k: 1.00 against 0.92
    by dense sampling), the split ones the ones that read too low (docs/gather.md, cl29). far30:
    that optimism was the oracle's decision (a link kept on "wholly visible" keeps its 1, one
    split gets fresh estimates) plus centroid samples; with points spread over the members, a
    second trace for the decided links and kernel-weighted shares, every far link reads within
    0.1% of dense sampling (strong links; weak -0.04%), and the room 0.978 / 0.975 / 0.972 at
    0.03, 0.979 / 0.977 / 0.974 at 0.01 (its far links at their dense visibility: 0.990 / 0.987 /
    0.984): split finer, the balance no longer moves (main 1.008 -> 1.015). So this asserts that,
    and the draft's loss within 3% (docs/gather.md, far30)."""
    import dataclasses

    from hr_testing.furnished import furnished_room

    mesh, _ = furnished_room("2k")
    base = dataclasses.replace(RefineParams.for_gather("draft"), orient=True)
    got = {
        sf: _absorbed_over_emitted(RadiositySystem(mesh, dataclasses.replace(base, shadow_feps=sf)))
        for sf in (0.03, 0.01)
    }
    print({k: np.round(v, 4) for k, v in got.items()})
    # split finer, the balance stays (far30: 0.0012 / 0.0021 / 0.0027; main 0.007 / 0.005 / 0.004,
    # cl29's optimism of decided links growing with their number; with centroid samples only
    # replaced, 0.027)
    assert np.abs(got[0.01] - got[0.03]).max() < 0.005
    # the draft's loss (far30: 2.2 / 2.5 / 2.8%; the far links at dense visibility 1.0-1.6%)
    assert np.abs(got[0.03] - 1).max() < 0.03 and np.abs(got[0.01] - 1).max() < 0.03


def test_push_corrections_are_what_makes_the_furnace_exact():
    s = RadiositySystem(scenes.closed_box(rho=0.5), RefineParams(vcorr=0))
    lf = s.h.leaves()
    assert np.abs(s.solve()[:, lf] / 2 - 1).max() > 0.03  # plain HR push: a few % off near edges


def _sphere_irradiance_error(subdiv, rho=0.6):
    mesh = scenes.sphere(
        subdiv=subdiv, rho=rho, emission_fn=lambda c: np.where(c[:, :1] > 0.3, [[3.0, 1.0, 0.0]], 0.0)
    )
    s = RadiositySystem(mesh, RefineParams.preset("medium"))
    B = s.solve()
    lf = s.h.leaves()
    H = (B - s.base_emission())[:, lf] / rho  # gathered radiance: uniform on a sphere
    a = s.h.area[lf]
    expected = (s.base_emission()[:, lf] * a).sum(1) / a.sum() / (1 - rho)
    assert s.report.energy_error < 1e-5
    return np.abs(H[:2] / expected[:2, None] - 1).max()


def test_sphere_uniform_irradiance_for_any_emission():
    # Flat facets are not on the sphere, so the oracle holds only as the mesh is refined:
    # measured 2.8% (80 faces), 1.1% (320), 0.7% (1280, too slow for the suite).
    e1, e2 = _sphere_irradiance_error(1), _sphere_irradiance_error(2)
    assert e2 < 0.015 and e2 < 0.6 * e1


def test_black_emitter_plate_pointwise():
    mesh = scenes.parallel_plates(rho_receiver=0.5, emission=1.0, subdiv=32)
    s = RadiositySystem(mesh, RefineParams(feps=0.005, veps=0.002, aeps=2e-4))
    B = s.solve()
    h = s.h
    emitter = s.patches.object_names.index("emitter")
    on_emitter = s.patches.object_id[h.view("patch")] == emitter
    recv = np.flatnonzero(h.is_leaf & ~on_emitter)
    pts = h.centre[recv]
    # Leaves nearest to the centre and to a corner of the receiver: rho E F(leaf -> emitter), the
    # closed form averaged over 8 x 8 points of the leaf (the emitter is black: no other light).
    for target in ((0.5, 0.5, 0), (0, 0, 0)):
        i = recv[np.argmin(np.linalg.norm(pts - target, axis=1))]
        sp = ff.sample_points(h.corners[[i]], h.nv[[i]], 8)[0]
        closed = np.mean([cf.point_to_parallel_rect(x, y, 0, 1, 0, 1, 1.0) for x, y, _ in sp])
        assert B[0, i] == pytest.approx(0.5 * closed, rel=0.01)


def test_warm_start_reaches_the_cold_answer():
    s = RadiositySystem(scenes.cornell_box(), FAST)
    s.solve(warm=False)  # the solution the warm start begins from
    it_cold = s.report.iterations
    E = s.base_emission() * 1.1
    warm = s.solve(E, warm=True)
    it_warm = s.report.iterations
    again = s.solve(E, warm=False)
    assert np.abs(warm - again).max() < 1e-6 * again.max()
    assert it_warm <= it_cold


def test_cornell_box_solves_and_conserves_energy():
    s = RadiositySystem(scenes.cornell_box())
    B = s.solve()
    r = s.report
    assert r.converged and r.residual < 1e-6
    assert B.min() >= 0
    assert r.energy_error < 1e-4
    assert 0 < r.escaped < r.emitted  # the box is open at the front
    # The lamp (reflectance 0.78) reads its emission plus what it reflects; the red wall reflects
    # more red than green, the green wall the opposite.
    h = s.h
    obj = s.patches.object_id[h.view("patch")]
    lf = h.leaves()
    names = s.patches.object_names
    lamp = lf[obj[lf] == names.index("light")]
    assert np.all(B[:, lamp] >= np.array(scenes.CORNELL_LIGHT)[:, None])
    assert np.all(B[:, lamp] < 1.2 * np.array(scenes.CORNELL_LIGHT)[:, None])
    red = lf[obj[lf] == names.index("left_red")]
    green = lf[obj[lf] == names.index("right_green")]
    assert B[0, red].mean() > 3 * B[1, red].mean() and B[1, green].mean() > 1.5 * B[0, green].mean()


def test_reflectance_near_one_converges_or_stops_with_a_warning():
    s = RadiositySystem(scenes.closed_box(rho=0.999, emission=(1, 1, 1)), FAST)
    B, rep = solve(s.h, s.links, s.base_emission(), max_iter=50)  # GMRES copes
    lf = s.h.leaves()
    assert rep.converged and rep.iterations < 50
    # B = E / (1 - rho sum F): at rho = 0.999 a 5e-5 form factor deficit already costs 5%.
    assert np.allclose(B[:, lf], 1000, rtol=0.1)
    with pytest.warns(ConvergenceWarning, match="did not converge"):  # plain sweeps do not
        B, rep = solve(s.h, s.links, s.base_emission(), max_iter=50, method="jacobi")
    assert rep.iterations == 50 and not rep.converged and np.isfinite(B).all()


# -- output ----------------------------------------------------------------------------------------
def test_vertex_output_shared_vertices_agree_and_creases_stay_sharp():
    mesh = scenes.cornell_box(subdiv=4)
    s = RadiositySystem(mesh, FAST)
    s.solve()
    vals = s.loop_radiance("CORNER")
    assert vals.shape == (len(mesh.loop_verts), 3) and vals.dtype == np.float32
    loop_poly = np.repeat(np.arange(len(mesh.loop_start)), mesh.loop_total)
    normal = s.patches.normal[np.searchsorted(s.patches.poly, loop_poly)]
    # Loops at the same vertex with the same normal carry exactly one value (no cracks).
    key = np.column_stack([mesh.loop_verts, np.round(normal, 6)])
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    for g in np.unique(inv)[:200]:
        m = inv == g
        assert np.ptp(vals[m], axis=0).max() == 0
    # Floor and back wall corners differ (crease), although they share positions.
    floor = mesh.object_names.index("floor")
    back = mesh.object_names.index("back")
    oid = mesh.object_id[loop_poly]
    assert not np.allclose(vals[oid == floor].mean(0), vals[oid == back].mean(0))


def test_backends_give_the_same_solution():
    from hr_addon.core.visibility import available_backends

    if len(available_backends()) < 2:
        pytest.skip("only one ray backend available")
    res = [RadiositySystem(scenes.cornell_box(), FAST, backend=b) for b in ("numpy", "embree")]
    for s in res:
        s.solve()
    assert len(res[0].links) == len(res[1].links)
    assert np.allclose(res[0].B, res[1].B, rtol=1e-3, atol=1e-6)


def test_bf_refinement_bounds_rho_f_b_on_every_splittable_link():
    mesh = scenes.cornell_box(subdiv=2)
    base = RefineParams(feps=0.1, vcorr=1e-3)
    bfeps = 0.003
    plain = RadiositySystem(mesh, base)
    bf = RadiositySystem(mesh, RefineParams(**{**base.__dict__, "bfeps": bfeps, "bf_passes": 3}))
    thr = bfeps * max(scenes.CORNELL_LIGHT)

    def worst(s):
        B = s.solve()
        L, h = s.links, s.h
        rho = s.patches.reflectance[:, h.view("patch")]
        bfv = np.maximum(
            (rho[:, L.a] * B[:, L.b]).max(0) * L.f_ab * L.vis,
            (rho[:, L.b] * B[:, L.a]).max(0) * L.f_ba * L.vis,
        )
        splittable = np.maximum(h.area[L.a], h.area[L.b]) > base.aeps * s.patches.area.sum()
        return bfv[splittable].max()

    assert worst(plain) > 2 * thr  # the F oracle alone leaves bright links coarse
    assert worst(bf) < 2 * thr  # BF refined them (B moved a little after the last pass)
    assert len(bf.links) > len(plain.links) and bf.report.energy_error < 1e-4


def test_twisted_wall_is_lit_and_results_are_scale_invariant():
    # The Cornell red wall is not planar; subdivided, its quads are nearly planar and kept. Their
    # own occluder triangles once shadowed every ray leaving them (the wall came out black).
    res = []
    for scale in (1.0, 10.0):
        mesh = scenes.cornell_box(subdiv=4)
        mesh.verts = mesh.verts * scale
        s = RadiositySystem(mesh, FAST)
        B = s.solve()
        obj = s.patches.object_id[s.h.view("patch")]
        lf = s.h.leaves()
        red = lf[obj[lf] == s.patches.object_names.index("left_red")]
        res.append((len(s.links), B[:, red].mean(1)))
    assert res[0][1][0] > 0.05  # lit (its floor neighbour is ~0.1)
    # Every threshold is relative to the scene's size: the same links, the same light to rounding
    # (measured 2026-12-02: 13,512 links at both scales, red wall mean equal to 4e-16).
    assert res[0][0] == res[1][0] and np.allclose(res[0][1], res[1][1], rtol=1e-6)


def test_radiance_at_points_finds_leaves_and_interpolates_continuously():
    from hr_addon.core.output import locate, radiance_at

    s = RadiositySystem(scenes.cornell_box(), FAST)
    B = s.solve()
    h = s.h
    lf = h.leaves()
    # Leaf centres locate to themselves; flat values are the leaf values (of their uncovered part:
    # contacts.py; the floor under the blocks reads 0).
    assert np.array_equal(locate(h, h.patch[lf], h.centre[lf]), lf)
    shown = h.shown(B)
    expect = shown[:, lf].T.copy()
    expect[h.dark(lf, h.centre[lf])] = 0.0  # centres of partly covered leaves may be covered
    assert np.allclose(radiance_at(h, B, h.patch[lf], h.centre[lf], smooth=False), expect)
    assert (h.exposure[lf] == 0).any() and not shown[:, lf[h.exposure[lf] == 0]].any()
    # Smooth values stay within the range of the surface and vary continuously along a line
    # across the floor (no jumps bigger than the local gradient allows) except where it passes
    # under a block: covered points read 0, a true discontinuity.
    floor = s.patches.object_names.index("floor")
    root = np.flatnonzero(s.patches.object_id == floor)[0]
    c = h.corners[root]
    t = np.linspace(0.02, 0.98, 2000)
    line = c[0] + t[:, None] * (c[2] - c[0])
    v = radiance_at(h, B, np.full(len(t), root), line)
    flat = radiance_at(h, B, np.full(len(t), root), line, smooth=False)
    assert v.min() >= 0 and v.max() <= shown[:, lf].max()
    lit = ~h.dark(locate(h, np.full(len(t), root), line), line)
    both = lit[1:] & lit[:-1]
    assert (~lit).any() and both.sum() > 1000
    dv, df = np.abs(np.diff(v, axis=0))[both], np.abs(np.diff(flat, axis=0))[both]
    assert dv.max() < 0.5 * df.max()


def test_radiance_at_has_no_seams_between_input_polygons():
    from hr_addon.core.output import radiance_at

    s = RadiositySystem(scenes.cornell_box(subdiv=8), FAST)
    B = s.solve()
    pt = s.patches
    floor = np.flatnonzero(pt.object_id == pt.object_names.index("floor"))
    centre = pt.corners[floor].mean(1)
    jumps, steps = [], []
    for i, c in zip(floor, centre):
        # Points a hair either side of edge 1-2, in this patch and in the one across the edge.
        mid = (pt.corners[i, 1] + pt.corners[i, 2]) / 2
        across = floor[np.linalg.norm(centre - (2 * mid - c), axis=1) < 1e-6]
        if len(across) == 0:
            continue
        d = (c - mid) * 1e-4
        va = radiance_at(s.h, B, [i], [mid + d])
        vb = radiance_at(s.h, B, [across[0]], [mid - d])
        jumps.append(np.abs(va - vb).max())
        steps.append(np.abs(radiance_at(s.h, B, [i], [mid + 2500 * d]) - va).max())  # a quarter patch in
    assert len(jumps) > 20
    assert np.median(jumps) < 0.05 * np.median(steps) and max(jumps) < 0.02 * B[:, s.h.leaves()].max()
