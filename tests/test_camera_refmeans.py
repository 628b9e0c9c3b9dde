"""benchmarks/camera_refmeans.py: our renders against the per-object Cycles means a camera_compare
JSON keeps (session 36, branch two36)."""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))


def test_a_render_against_kept_means_gives_camera_compares_metrics_per_lit_object():
    from camera_refmeans import against_means

    # three objects of 60 / 60 / 40 px (index 1, 2, 3); the third below MIN_PIXELS (50): left out
    ob = np.zeros((10, 16), np.int64)
    ob[:, :6], ob[:, 6:12], ob[:, 12:] = 1, 2, 3
    rgb = np.zeros((10, 16, 3))
    rgb[ob == 1] = [0.50, 0.40, 0.30]
    rgb[ob == 2] = [0.10, 0.10, 0.10]
    rgb[ob == 3] = [1.0, 1.0, 1.0]
    kept = {
        "lit": ["a", "b", "c"],
        "objects": {
            "a": {"mean_ref": [0.50, 0.40, 0.30]},  # exact
            "b": {"mean_ref": [0.11, 0.10, 0.09]},  # red -9.1%, green 0, blue +11.1%
            "c": {"mean_ref": [1.0, 1.0, 1.0]},
        },
    }
    r = against_means(rgb, ob, ["a", "b", "c"], kept)
    assert r["lit"] == ["a", "b"]
    a, b = r["objects"]["a"]["vertex"], r["objects"]["b"]["vertex"]
    assert a["mre"] < 1e-12 and abs(a["bias"]) < 1e-12 and a["texels"] == 60
    assert np.isclose(b["mre"], np.mean([0.01 / 0.11, 0.0, 0.01 / 0.09]))
    assert np.isclose(b["bias"], np.mean([-0.01 / 0.11, 0.0, 0.01 / 0.09]))
    st = r["summary"]["vertex|all"]
    assert st["objects"] == 2 and st["within_5"] == 0.5
    # pooled: pixel-weighted grey means, ours over the references'
    assert np.isclose(st["pooled_bias"], (0.4 + 0.1) / (0.4 + 0.1) - 1)
