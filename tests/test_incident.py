"""Irradiance / pi from a solution (core.texels.incident_radiance), the irradiance lightmap mode."""

import numpy as np
import pytest

from hr_testing import scenes
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
    got = solution_radiance(s, patch, pts, kind="incident")
    np.testing.assert_allclose(got, np.broadcast_to(want.T, got.shape), rtol=2e-3)
    refl = solution_radiance(s, patch, pts, kind="reflected")
    np.testing.assert_allclose(refl, got * mesh.reflectance[0], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("method", ["FE", "AUTO", "NAIVE"])
def test_incident_with_light_shapes(method):
    """With a light shape (each method's own way of adding it): reflected = rho x incident at texel
    points, no emission in the incident field, and loop_incident leaves the solution as it was."""
    from hr_testing import shapes as S
    from hr_addon.core.events import DynamicRadiosity, LightShape, surface_samples
    from hr_addon.core.texels import loop_incident

    base = RadiositySystem(
        scenes.cornell_box(), RefineParams(feps=0.1, aeps=4e-3, shadow_feps=0.02, veps=0.02)
    )
    dyn = DynamicRadiosity(base, method=method)
    window = S.window(0.2, 0.16, 0.02, centre=(0.3, 0.3), angle=0.3, shear=0.3)
    dyn.apply({"w": LightShape(S.on_plane(window, S.CORNELL_GREEN_WALL), np.array([8.0, 7.0, 5.0]), "w")})
    pts, patch = surface_samples(base.patches, 400)[:2]
    inc = solution_radiance(dyn, patch, pts, kind="incident")
    refl = solution_radiance(dyn, patch, pts, kind="reflected")
    tot = solution_radiance(dyn, patch, pts)
    rho = base.patches.reflectance[:, patch].T
    assert np.isfinite(inc).all() and (inc >= 0).all() and inc.max() > 0
    np.testing.assert_allclose(refl, rho * inc, rtol=1e-4, atol=1e-6 * inc.max())
    assert (tot >= refl - 1e-6).all() and tot.max() > refl.max()  # the window's emission is only in tot
    B = dyn.B.copy()
    loops = loop_incident(dyn, "CORNER")
    assert loops.shape == (len(base.mesh.loop_verts), 3) and np.isfinite(loops).all()
    np.testing.assert_array_equal(dyn.B, B)
    assert loop_incident(dyn, "POINT").shape == (len(base.mesh.verts), 3)
