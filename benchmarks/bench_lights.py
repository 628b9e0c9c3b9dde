"""Cost of Blender-light events against light-shape events on the same scene, same run (issue 20's
speed target): the Cornell box (hr_testing/scenes.py, its ceiling emitter kept), FE, the final
gather at the corners (LoopGather, two levels + 4 iterations); a spot aimed at the back wall
with a footprint about the size of a 0.2 x 0.2 m light shape on that wall. Each event: apply()
plus the gather's evaluation, CPU seconds, median of 3 moves.

Run: .venv/bin/python benchmarks/bench_lights.py [quality]   (prints one JSON line)"""

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hr_testing import scenes  # noqa: E402
from hr_testing import shapes as S  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, LightShape  # noqa: E402
from hr_addon.core.gather import LoopGather  # noqa: E402
from hr_addon.core.lights import Light  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402


def main(quality="medium"):
    mesh = scenes.cornell_box(subdiv=1)
    t0 = time.process_time()
    system = RadiositySystem(mesh, RefineParams.preset(quality))
    dyn = DynamicRadiosity(system, method="FE")
    g = LoopGather(dyn, rays=128, shadow_rays=32, levels=2, iterations=4)
    out = {"quality": quality, "build_and_gather_cpu_s": round(time.process_time() - t0, 2)}

    def timed(fn):
        c = time.process_time()
        fn()
        g.loop_radiance(dyn)
        return time.process_time() - c

    def spot(x, strength=10.0):
        pos = np.array([0.28, 0.25, 0.30])
        aim = np.array([x, 0.5592, 0.30]) - pos
        # footprint radius ~0.1 m on the back wall 0.31 m away: half angle atan(0.1 / 0.31)
        return Light(
            "SPOT",
            (1, 1, 1),
            strength,
            position=pos,
            direction=aim,
            spot_size=2 * math.atan(0.1 / 0.31),
            spot_blend=0.1,
            name="spot",
        )

    def shape(x):
        ring = S.on_plane(S.rect(0.2, 0.2, centre=(x, 0.30)), S.CORNELL_BACK_WALL)
        return LightShape(ring, np.full(3, 5.0), "patch")

    dyn.apply({}, {"s": spot(0.20)})
    g.loop_radiance(dyn)
    out["spot_move_s"] = sorted(timed(lambda x=x: dyn.apply({}, {"s": spot(x)})) for x in (0.25, 0.30, 0.35))[
        1
    ]
    out["spot_strength_s"] = sorted(
        timed(lambda k=k: dyn.apply({}, {"s": spot(0.35, 10.0 * k)})) for k in (2, 3, 4)
    )[1]
    out["spot_unchanged_s"] = timed(lambda: dyn.apply({}, {"s": spot(0.35, 40.0)}))
    dyn.apply({}, {})
    dyn.apply({"p": shape(0.20)}, {})
    g.loop_radiance(dyn)
    out["shape_move_s"] = sorted(
        timed(lambda x=x: dyn.apply({"p": shape(x)}, {})) for x in (0.25, 0.30, 0.35)
    )[1]
    print("RESULT " + json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}))


if __name__ == "__main__":
    main(*(sys.argv[1:] or ["medium"]))
