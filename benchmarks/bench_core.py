"""Core engine benchmark on the Cornell box: build and solve cost per quality setting, and error
against a converged reference. Prints a table, writes benchmarks/out/core.json and
benchmarks/core_speed_accuracy.png. Usage: python benchmarks/bench_core.py [--quick]
"""

import argparse
import json
import os
import sys
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hr_testing import scenes  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "out")
# The reference: the high preset pushed further (finer Aeps and Feps, more shadow refinement).
REFERENCE = RefineParams(
    feps=0.004, veps=0.003, aeps=1.5e-5, shadow_feps=2e-4, vis_k=3, vcorr=1e-5, corr_budget=8_000_000
)


def run(name, params, mesh, backend="auto", repeat_solve=3):
    tracemalloc.start()
    t0 = time.process_time()  # CPU seconds: the two cores are shared
    s = RadiositySystem(mesh, params, backend=backend)
    t_build = time.process_time() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    times = []
    for _ in range(repeat_solve):
        c0 = time.process_time()
        s.solve(warm=False)
        times.append(time.process_time() - c0)
    rep = s.report
    st = s.build.refine
    op = s.operator()
    # Bare gather on the same links (the memory-bound limit): one bincount per channel.
    B = s.B
    t1 = time.perf_counter()
    # With clusters the links gather in an extended index space (far-link intermediates, cluster
    # slots, then the nodes: solver.Operator); the bare gather runs over the same terms.
    n_ext = op.nT + op.off + op.n
    for _ in range(10):
        for c in range(3):
            Z = np.zeros(n_ext)
            Z[n_ext - op.n :] = B[c]
            if op.tree is not None:
                X = Z[op.nT :]
                Z[: op.nT] = np.bincount(op.t_slot, weights=op.t_w * X[op.t_src], minlength=op.nT)
            np.bincount(op.recv, weights=op.f * Z[op.src], minlength=op.off + op.n)
    t_bare = (time.perf_counter() - t1) / 10
    t1 = time.perf_counter()
    for _ in range(10):
        op.apply(B, s.base_emission())
    t_iter = (time.perf_counter() - t1) / 10
    return s, dict(
        name=name,
        backend=s.build.backend,
        polygons=len(mesh.loop_start),
        patches=s.build.patches,
        nodes=s.h.n,
        links=len(s.links),
        directed_links=len(op.recv),
        corrections=s.links.n_corrections,
        memory_mb=(s.h.n * s.h.node_bytes() + len(op.recv) * 16) / 1e6,
        peak_build_mb=peak / 1e6,
        t_build=t_build,
        t_refine=st.get("t_refine", 0),
        t_ff=st.get("t_ff", 0),
        t_vis=st.get("t_vis", 0),
        t_corr=st.get("t_corr", 0),
        rays=st.get("rays", 0),
        rays_per_s=st.get("rays", 0) / max(st.get("t_vis", 1e-9), 1e-9),
        t_solve=min(times),
        iterations=rep.iterations,
        residual=rep.residual,
        energy_error=rep.energy_error,
        links_per_s=len(op.recv) * rep.iterations / min(times),
        t_gather_bare=t_bare,
        t_iteration=t_iter,
        iteration_over_bare_gather=t_iter / t_bare,
    )


def errors(s, ref, mesh):
    """Vertex radiance RMSE / max / mean relative against the reference, on the same fine mesh."""
    a = s.loop_radiance("CORNER").astype(float)
    b = ref.loop_radiance("CORNER").astype(float)
    lamp = mesh.object_id[
        np.repeat(np.arange(len(mesh.loop_start)), mesh.loop_total)
    ] == mesh.object_names.index("light")
    a, b = a[~lamp], b[~lamp]
    d = a - b
    return dict(
        rmse=float(np.sqrt(np.mean(d**2))),
        max_abs=float(np.abs(d).max()),
        mean_rel=float(np.abs(d).sum() / np.abs(b).sum()),
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="skip the high preset and use a coarser reference")
    ap.add_argument("--table", action="store_true", help="print the markdown table of core.json and stop")
    args = ap.parse_args()
    if args.table:
        with open(os.path.join(OUT, "core.json")) as f:
            print(table(json.load(f)))
        return
    os.makedirs(OUT, exist_ok=True)
    mesh = scenes.cornell_box(subdiv=8)  # the output mesh: errors are measured at its vertices
    settings = [("draft", RefineParams.preset("draft")), ("medium", RefineParams.preset("medium"))]
    if not args.quick:
        settings.append(("high", RefineParams.preset("high")))
    settings += [
        ("medium, no push corrections", RefineParams(vcorr=0)),
        ("medium, numpy rays", RefineParams.preset("medium")),
    ]
    ref_params = RefineParams.preset("high") if args.quick else REFERENCE
    print("building the reference ...", flush=True)
    ref, ref_row = run("reference", ref_params, mesh, repeat_solve=1)
    rows = []
    for name, prm in settings:
        s, row = run(name, prm, mesh, backend="numpy" if "numpy" in name else "auto")
        row.update(errors(s, ref, mesh))
        rows.append(row)
    ref_row.update(rmse=0.0, max_abs=0.0, mean_rel=0.0)
    rows.append(ref_row)
    cols = [
        "name",
        "backend",
        "polygons",
        "nodes",
        "links",
        "corrections",
        "memory_mb",
        "t_build",
        "t_refine",
        "t_ff",
        "t_vis",
        "t_corr",
        "rays_per_s",
        "t_solve",
        "iterations",
        "links_per_s",
        "iteration_over_bare_gather",
        "energy_error",
        "rmse",
        "mean_rel",
    ]
    print(" | ".join(cols))
    for r in rows:
        print(" | ".join(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in cols), flush=True)
    with open(os.path.join(OUT, "core.json"), "w") as f:
        json.dump(rows, f, indent=1)
    plot(rows, time.strftime("%Y-%m-%d", time.gmtime()))


def table(rows):
    """The README's markdown table from core.json."""
    L = [
        "| setting | nodes | links (+ push corrections) | memory | build CPU | solve CPU (iterations) | "
        "mean rel. error | RMSE |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        L.append(
            f"| {r['name']} | {r['nodes']:,} | {r['links']:,} (+{r['corrections']:,}) | "
            f"{r['memory_mb']:.0f} MB | "
            f"{r['t_build']:.2f} s | {r['t_solve']:.2f} s ({r['iterations']}) | "
            f"{100 * r['mean_rel']:.1f}% | {r['rmse']:.4f} |"
        )
    return "\n".join(L)


def plot(rows, date=""):
    import matplotlib
    from matplotlib.ticker import FuncFormatter

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.plot_events import label_log_axis

    fig, ax = plt.subplots(figsize=(7.2, 4.6))
    offsets = {"medium, no push corrections": (6, -12), "medium, numpy rays": (-8, 8)}
    for r in rows:
        if r["name"] == "reference":
            continue
        t = r["t_build"] + r["t_solve"]
        ax.loglog(t, r["mean_rel"], "o", ms=7, mec="k")
        dx, dy = offsets.get(r["name"], (6, 4))
        ax.annotate(
            r["name"],
            (t, r["mean_rel"]),
            textcoords="offset points",
            xytext=(dx, dy),
            fontsize=8,
            ha="right" if dx < 0 else "left",
        )
    ax.margins(x=0.25, y=0.15)
    label_log_axis(ax.xaxis)
    label_log_axis(ax.yaxis)
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{100 * v:g}%"))
    ax.set_xlabel("build + solve, CPU seconds")
    ax.set_ylabel("mean relative error at the vertices")
    when = f", measured {date}" if date else ""
    ax.set_title(
        f"Cornell box, 8 x 8 output mesh per wall: error vs a converged reference\n"
        f"(clusters and contacts on{when})",
        fontsize=9,
    )
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(os.path.dirname(OUT), "core_speed_accuracy.png"), dpi=120)


if __name__ == "__main__":
    main()
