"""Irradiance / pi from a solution (core.texels.incident_radiance), the irradiance lightmap mode."""

import numpy as np

from benchmarks import scenes
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_addon.core.texels import incident_radiance, solution_radiance


def test_furnace_incident_equals_radiance_and_zero_reflectance_is_gathered():
    """Closed box, uniform emission E, reflectance rho per channel (one channel 0): every point sees
    the whole box, so H / pi = B = E / (1 - rho), also in the black channel (gathered, not divided)."""
    mesh = scenes.closed_box(rho=0.5, emission=(1.0, 2.0, 0.5), subdiv=2)
    mesh.reflectance[:] = (0.5, 0.0, 0.8)
    s = RadiositySystem(mesh, RefineParams.preset("draft"))
    s.solve()
    h = s.h
    inc = incident_radiance(h, s.B, s.base_emission(), s.links)
    lf = h.leaves()
    want = np.array([1.0 / 0.5, 2.0, 0.5 / 0.2])[:, None]
    np.testing.assert_allclose(inc[:, lf], np.broadcast_to(want, (3, len(lf))), rtol=2e-3)
    pts = s.patches.corners[:, :3].mean(1)
    patch = np.arange(len(pts))
    got = solution_radiance(None, s, patch, pts, kind="incident")
    np.testing.assert_allclose(got, np.broadcast_to(want.T, got.shape), rtol=2e-3)
    refl = solution_radiance(None, s, patch, pts, kind="reflected")
    np.testing.assert_allclose(refl, got * mesh.reflectance[0], rtol=1e-5, atol=1e-6)
