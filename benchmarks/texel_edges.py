"""Issue 20's Cornell box lit by one Blender light (hr_testing.cycles_lights.solve(KIND)): the texels
whose direct light is averaged over their area (core.gather.texel_edges: a light's edge crosses
them) against Cycles' cached bakes (benchmarks/out/cycles_lights_cache/, `cycles_lights.py --cache`
makes them), with the edge texels on and off (centres only), per surface: how many texels it
changes, the root mean square and the mean of (ours - Cycles) over them relative to the surface's
mean, Cycles' own noise there (the seeds' spread / sqrt(seeds)), and the cost (the tested and edge
texels, extra shadow rays, process CPU s). SPOT also: the footprint's edge band texel by texel and
the 10-90% width of its profile, ours (edge texels averaged, and centres only) against Cycles and
an oracle (spot_band).

Run: .venv/bin/python benchmarks/texel_edges.py [KIND ...] [--spp 1024] [--seeds 1,...,8]"""

import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
CACHE = str(Path(__file__).resolve().parent / "out" / "cycles_lights_cache")


def _crossing(t, q, level):
    """The first t at which the binned profile q(t) (rising) reaches `level`, linearly between bins."""
    i = np.flatnonzero(q >= level)
    if not len(i) or i[0] == 0:
        return float("nan")
    i = i[0]
    return float(t[i - 1] + (level - q[i - 1]) * (t[i] - t[i - 1]) / (q[i] - q[i - 1]))


def spot_band(sv, refs, sub=16, bin_t=0.1):
    """The spot's footprint edge, texel by texel (SPOT only): the band = texels whose part Cycles'
    bake samples (bakepoints.texel_points, sub x sub points) reaches into the cone's blend ramp
    (0 < t < 1, t = (cos a - cos(size / 2)) / ((1 - cos(size / 2)) blend) the smoothstep's
    argument) and that no geometry shadows from the spot. Per surface with a band: its texels,
    Cycles' mean there, our mean signed error, the root mean square of (ours - Cycles) per texel
    over the band's mean and Cycles' own noise per texel (the seeds' spread / sqrt(seeds)); ours'
    direct light against the oracle (the spot's exact unshadowed light averaged over the same
    points: the edge handling alone); and the edge profile's 10-90% width in texels: the
    effective cone mask (value - our indirect light) / the spot's light without its cone, binned
    by t at the texel's centre, for ours, Cycles and the oracle."""
    from hr_addon.core import lights as lt
    from hr_addon.core.gather.bakepoints import texel_points

    rs, tg = sv.rs, sv.gather
    rec = next(r for r in sv.dyn.lights.values() if r.light.kind == "SPOT")
    L = rec.light
    ch = np.cos(L.spot_size / 2)
    span = (1 - ch) * L.spot_blend
    scale = rec.scale.mean()
    d = tg.rho * tg._light(rec)[:, None].astype(np.float64)
    d[tg.dark] = 0.0
    direct, rho = tg.outputs(d * rec.scale[None]), tg.outputs(tg.rho)
    f = (np.stack(np.meshgrid(np.arange(sub), np.arange(sub), indexing="ij"), -1).reshape(-1, 2) + 0.5) / sub
    ref_all = {n: np.array([r[n] for r in refs]) for n in rs.objects}
    out, s0 = {}, 0

    def unmasked(x, nrm):  # the spot's unit light without its cone, and t
        w = L.position - x
        r2 = (w * w).sum(-1)
        w = w / np.sqrt(r2)[..., None]
        cos = np.abs((w * nrm).sum(-1))
        return cos * lt.POINT_INTENSITY / (r2 + L.radius**2) / np.pi, (-(w @ L.direction) - ch) / span

    for n in rs.objects:
        at = rs.atlases[n]
        cen = np.flatnonzero(at.s_centre)
        m = len(cen)
        idx = at.s_texel[cen]
        tri = at.s_tri[cen]
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        c = at.s_point[cen]
        pts = texel_points(c, at.s_axes[cen], tri, np.broadcast_to(f, (m,) + f.shape))
        u, t = unmasked(pts, nrm[:, None])
        u0, t0 = unmasked(c, nrm)
        # t's change over one texel (its sides), for the width in texels
        dt = np.hypot(*(unmasked(c + at.s_axes[cen, k], nrm)[1] - t0 for k in (0, 1)))
        w = L.position - pts
        shadow = sv.system.backend.occluded(
            pts + 1e-5 * w / np.linalg.norm(w, axis=-1)[..., None], L.position
        )
        ok = ~shadow.any(1) & np.isfinite(ref_all[n]).all((0, 2))
        oracle = (u * lt.smoothstep(t)).mean(1)
        ours_d = direct[s0 : s0 + m].mean(1) / scale / np.maximum(rho[s0 : s0 + m].mean(1), 1e-12)
        ours = sv.res[n]["gather_refl"][idx].mean(1)
        ref = ref_all[n][:, idx].mean(2)  # (seeds, m)
        cyc = ref.mean(0)
        indirect = ours - direct[s0 : s0 + m].mean(1)
        s0 += m
        band = ok & (t.min(1) < 1) & (t.max(1) > 0)
        if band.sum() < 10:
            continue
        mr = cyc[band].mean()
        o = out[n] = {
            "texels": int(band.sum()),
            "mean_cycles": round(float(mr), 5),
            "bias": round(float(ours[band].mean() / mr - 1), 4),
            "rms": round(float(np.sqrt(np.mean((ours - cyc)[band] ** 2)) / mr), 4),
            "rms_cycles_noise": round(
                float(np.sqrt(np.mean(ref[:, band].var(0, ddof=1) / len(ref))) / mr), 4
            ),
            "direct_vs_oracle_rms": round(
                float(np.sqrt(np.mean((ours_d - oracle)[band] ** 2)) / oracle[band].mean()), 4
            ),
            "direct_vs_oracle_bias": round(float(ours_d[band].mean() / oracle[band].mean() - 1), 4),
        }
        # Cycles against the oracle's direct light + our indirect: what ours' direct light is not
        exact = oracle * scale * rho[s0 - m : s0].mean(1) + indirect
        o["cycles_vs_exact_direct_rms"] = round(float(np.sqrt(np.mean((exact - cyc)[band] ** 2)) / mr), 4)
        # the profile: texels around the ramp, by t at their centre
        near = ok & (t0 > -1.5) & (t0 < 2.5)
        r_rho = rho[s0 - m : s0].mean(1)
        den = u0 * scale * r_rho
        bins = np.arange(-1.5, 2.5 + bin_t, bin_t)
        k = np.digitize(t0[near], bins)
        tb = np.array([t0[near][k == i].mean() for i in np.unique(k)])
        widths = {}
        for label, v in (("ours", ours), ("cycles", cyc), ("oracle", oracle * scale * r_rho + indirect)):
            q = (v - indirect)[near] / den[near]
            qb = np.array([q[k == i].mean() for i in np.unique(k)])
            widths[label] = round(
                float((_crossing(tb, qb, 0.9) - _crossing(tb, qb, 0.1)) / np.median(dt[near])), 3
            )
        o["width_10_90_texels"] = widths
        o["profile_texels"] = int(near.sum())
    return out


def main(kind, spp, seeds):
    import hr_addon.core.gather.direct as gd
    from hr_testing import cycles_lights as CL

    on = CL.solve(kind)
    edge_direct = gd.edge_direct  # the name direct.py calls
    gd.edge_direct = lambda g, light, centre, *a, **k: np.asarray(centre, np.float64)  # centres only
    try:
        off = CL.solve(kind)
    finally:
        gd.edge_direct = edge_direct
    refs = [CL._cached_bake(on.rs, kind, spp, s, CACHE) for s in seeds]
    out = {
        "kind": kind,
        "spp": spp,
        "seeds": list(seeds),
        "tested_edge_rays": on.gather.stats.get("edge_texels"),
        "edge_cpu_s": round(on.gather.stats.get("edge_texels_cpu", 0.0), 3),
        "surfaces": {},
    }
    for n in on.rs.objects:
        a, b = on.res[n]["gather_refl"], off.res[n]["gather_refl"]
        r = np.array([x[n] for x in refs])
        ok = np.isfinite(a).all(1) & np.isfinite(b).all(1) & np.isfinite(r).all((0, 2))
        ref = r.mean(0)
        mean = ref[ok].mean()
        ch = ok & (np.abs(a - b).max(1) > 0)
        if not ch.any():
            out["surfaces"][n] = {"changed": 0}
            continue

        def err(v):
            d = (v[ch] - ref[ch]).mean(1) / mean
            return round(float(np.sqrt(np.mean(d**2))), 3), round(float(d.sum() / ok.sum()), 4)

        noise = r[:, ch].mean(2).std(0, ddof=1) / np.sqrt(len(seeds)) / mean
        out["surfaces"][n] = {
            "texels": int(ok.sum()),
            "changed": int(ch.sum()),
            "rms_centres": err(b)[0],
            "rms_areas": err(a)[0],
            "rms_cycles_noise": round(float(np.sqrt(np.mean(noise**2))), 3),
            "of_surface_centres": err(b)[1],
            "of_surface_areas": err(a)[1],
        }
    if kind == "SPOT":
        out["band"] = {"areas": spot_band(on, refs), "centres": spot_band(off, refs)}
    print("RESULT " + json.dumps(out), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a = sys.argv[1:]
    spp, seeds = 1024, tuple(range(1, 9))
    if "--spp" in a:
        i = a.index("--spp")
        spp = int(a[i + 1])
        del a[i : i + 2]
    if "--seeds" in a:
        i = a.index("--seeds")
        seeds = tuple(int(v) for v in a[i + 1].split(","))
        del a[i : i + 2]
    for kind in a or ["SPOT"]:
        main(kind, spp, seeds)
