"""Whether the books' -x / +x asymmetry (docs/gather.md, "The books' -x faces") follows the face's
orientation or the row's build order: the furnished room (furnished_room("20k"), no window light
shape) as built, or mirrored in x (every face's loop reversed: normals stay outward, a book's face
towards the book made before it becomes a +x face). Cycles bakes the books only (one seed); ours is
the bake's draft texel gather. Prints ours / Cycles over the sides above a shorter neighbour, by
the face's side and by whether it looks at the previous or the next book of its row.

    .venv/bin/python benchmarks/books_mirror.py MIRROR(0/1) SPP
"""

import dataclasses
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import books_common as BC  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402
from hr_testing.blend import mesh_scene  # noqa: E402
from hr_testing.furnished import W, furnished_room  # noqa: E402

TEXEL = 0.0553  # the furnished sample's texel (texel_rel 1 / 150)


def main():
    mirror, spp = int(sys.argv[1]), int(sys.argv[2])
    mi, _ = furnished_room("20k")
    if mirror:
        v = mi.verts.copy()
        v[:, 0] = W - v[:, 0]
        lv = mi.loop_verts.copy()
        for s, n in zip(mi.loop_start, mi.loop_total):
            lv[s : s + n] = lv[s : s + n][::-1]
        mi = dataclasses.replace(mi, verts=v, loop_verts=lv, tri_loops=None)
    scene = mesh_scene(mi)
    rs = C.prepare(scene, texel=TEXEL, only=[n for n in mi.object_names if "_book" in n])
    t0 = time.process_time()
    ref, _, mask = C.bake(rs, spp, 1)
    print(f"Cycles bake: {time.process_time() - t0:.0f} s CPU", flush=True)
    t0 = time.process_time()
    s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
    dyn = DynamicRadiosity(s, method="FE")
    dyn.apply(C.shape_proxies(rs, 1))
    res, _ = C.gather_results(rs, C.Ours(rs, s, dyn), dyn, vertex=False, **BC.BASE)
    print(f"ours: {time.process_time() - t0:.0f} s CPU", flush=True)
    box = BC.book_boxes(rs)
    acc = np.zeros((2, 2, 3))  # [face -x / +x, looks at the previous book], (ours, Cycles, texels)
    for n in box:
        x = BC.texel_centres(rs.atlases[n])
        o = res[n]["gather_refl"].mean(1)
        r = np.where(mask[n], ref[n].mean(1), np.nan)
        for side in (0, 1):
            prev = int(side == mirror)  # the previous book lies at -x as built, at +x mirrored
            nb = BC.neighbour(box, n, 1 - prev)  # neighbour's side 1 is the next book
            if nb is None:
                continue
            m = BC.side_above(x, *box[n], side, nb) & np.isfinite(o) & np.isfinite(r)
            acc[side, prev] += (o[m].sum(), r[m].sum(), m.sum())
    for side in (0, 1):
        for prev in (0, 1):
            a = acc[side, prev]
            if a[2]:
                print(
                    f"mirror {mirror}: {'-+'[side]}x faces looking at the {'previous' if prev else 'next'} "
                    f"book: ours / Cycles {a[0] / a[1]:.3f} ({int(a[2])} texels, Cycles {a[1] / a[2]:.5f})"
                )


if __name__ == "__main__":
    main()
