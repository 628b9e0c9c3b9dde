"""The books' -x / +x strips against Cycles' sampling pattern (docs/gather.md, "The books' -x / +x
gap is the reference's shared random numbers"). `bake`: a books-only Cycles bake of the furnished
sample .blend (`sample`, saved with Cycles' default pattern AUTOMATIC = blue noise) or of the
builder's room (`built`, hr_testing.blend.mesh_scene of furnished_room("20k"), whose new scene
defaults to TABULATED_SOBOL), with the pattern given (or the scene's own: `scene`), all books
with one seed or (`per_object`) book i alone with its own seed (cycles_ref.bake seed_per_object);
saves the texels (unbaked: nan).
`report`: ours (a saved furnished_vs_cycles run) over each bake on the sides above a shorter
neighbour by face side, and how much of each bake's error is shared by the texels at one atlas
position (x, y) of different books: Cycles seeds a texel's samples by its pixel (x, y) in the
image it bakes, and every book is baked into its own small image.

    .venv/bin/python benchmarks/books_pattern_ref.py bake sample|built SPP SEED PATTERN|scene [per_object]
    .venv/bin/python benchmarks/books_pattern_ref.py report OURS_NPZ BAKE.npz [BAKE.npz ...]
"""

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import books_common as BC  # noqa: E402
import cycles_compare as CC  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402

OUT = os.path.join(HERE, "out")


def scene(which):
    """(the prepared RefScene of the books, for a books-only bake)."""
    if which == "sample":
        sc, texel = CC.open_scene("furnished"), dict(texel_rel=1 / 150)
    else:
        from hr_testing.blend import mesh_scene
        from hr_testing.furnished import furnished_room

        sc, texel = mesh_scene(furnished_room("20k")[0]), dict(texel=0.0553)
    return C.prepare(sc, only=[o.name for o in sc.objects if "_book" in o.name], **texel)


def bake(which, spp, seed, pattern, per_object=False):
    rs = scene(which)
    if pattern != "scene":
        rs.scene.cycles.sampling_pattern = pattern
    pattern = rs.scene.cycles.sampling_pattern
    t0 = time.process_time()
    ref, _, mask = C.bake(rs, spp, seed, seed_per_object=per_object)
    tag = f"{which}_{pattern}_s{spp}_seed{seed}{'_per_object' if per_object else ''}"
    print(f"{tag}: bake {time.process_time() - t0:.0f} s CPU", flush=True)
    path = os.path.join(OUT, f"books_ref_{tag}.npz")
    np.savez_compressed(path, **{n: np.where(mask[n][:, None], ref[n], np.nan) for n in rs.objects})
    print("wrote", path)


def strips(rs):
    """{book: [(texel indices, side)]} of the sides above a shorter neighbour."""
    box = BC.book_boxes(rs)
    out = {}
    for n in box:
        x = BC.texel_centres(rs.atlases[n])
        for side in (0, 1):
            nb = BC.neighbour(box, n, side)
            if nb is not None:
                out.setdefault(n, []).append((np.flatnonzero(BC.side_above(x, *box[n], side, nb)), side))
    return out


def report(ours_path, bakes):
    import books_daylight as BD

    rs = scene("sample")
    ours = BD.load_ours(ours_path, "gather_refl")
    refs = {os.path.basename(p): np.load(p) for p in bakes}
    st = strips(rs)
    for name, z in refs.items():
        acc = np.zeros((2, 3))
        pos = {}  # (side, x, y) -> [ours / Cycles of that texel in each book]
        for n, lst in st.items():
            at = rs.atlases[n]
            o, r = ours[n].mean(1), z[n].mean(1)
            for idx, side in lst:
                m = idx[np.isfinite(o[idx]) & np.isfinite(r[idx]) & (r[idx] > 0)]
                acc[side] += (o[m].sum(), r[m].sum(), len(m))
                for t in m:
                    pos.setdefault((side, at.tx[t], at.ty[t]), []).append(o[t] / r[t])
        print(
            f"{name}: ours / C  -x {acc[0, 0] / acc[0, 1]:.3f} ({int(acc[0, 2])} texels)"
            f"  +x {acc[1, 0] / acc[1, 1]:.3f} ({int(acc[1, 2])} texels)"
        )
        for side in (0, 1):
            g = [np.array(v) for k, v in pos.items() if k[0] == side and len(v) >= 5]
            means = np.array([v.mean() for v in g])
            # a position mean's noise if the books were independent
            within = np.mean([v.var(ddof=1) / len(v) for v in g])
            print(
                f"   {'-+'[side]}x: {len(g)} atlas positions with >= 5 texels ({sum(map(len, g))} texels):"
                f" spread of their means {means.std(ddof=1):.3f}, expected from the books' scatter"
                f" {np.sqrt(within):.3f}; position means {np.round(np.sort(means), 3).tolist()}"
            )


if __name__ == "__main__":
    if sys.argv[1] == "bake":
        bake(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], "per_object" in sys.argv[6:])
    else:
        report(sys.argv[2], sys.argv[3:])
