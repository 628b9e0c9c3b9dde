"""Peak RSS and CPU of reading a stored precompute and writing it again (issue 19, docs/scale.md
"The stored precompute: memory and the first frame").

    python benchmarks/bench_precompute_io.py STORE.hrpc OUT_DIR [--json out.json] [--step read|write|terms]

--step read: only pc.read; write: pc.read then pc.write into OUT_DIR (each step its own process,
so that ru_maxrss is that step's peak); terms: load and restore (bench_gather_events.load_store),
then the solver's far-link terms (Links.extended: stored since branch pcio), and the restored
terms against those made again from the restored hierarchy."""

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("store")
    ap.add_argument("out_dir")
    ap.add_argument("--step", choices=("read", "write", "terms"), default="write")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from hr_addon.io import precompute as pc

    rss = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # GB (Linux: kB)
    out = {"store": args.store, "rss_before_gb": rss()}
    if args.step == "terms":
        out.update(_terms(args.store))
        args.step = None
    if args.step is None:
        print(json.dumps(out))
        if args.json:
            Path(args.json).write_text(json.dumps(out, indent=1))
        return
    c0 = time.process_time()
    arrays, header = pc.read(args.store)
    out["read_cpu_s"] = time.process_time() - c0
    out["read_peak_gb"] = rss()
    out["arrays_gb"] = sum(a.nbytes for a in arrays.values()) / 1e9
    if args.step == "write":
        want = {k: header[k] for k in ("format_version", "extension", "code", "settings", "objects")}
        c0 = time.process_time()
        pc.write(args.out_dir, arrays, header["graph"], want, header.get("info"))
        out["write_cpu_s"] = time.process_time() - c0
        out["write_peak_gb"] = rss()
        out["file_bytes"] = (Path(args.out_dir) / pc.FILENAME).stat().st_size
    print(json.dumps(out))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


def _terms(store):
    import numpy as np

    from bench_gather_events import load_store

    out, cpu = {}, time.process_time
    c0 = cpu()
    s, _, _ = load_store(store)
    out["load_cpu_s"] = cpu() - c0
    out["restored_terms"] = s.links._ext is not None
    c0 = cpu()
    ext = s.links.extended(s.h)
    out["terms_after_load_cpu_s"] = cpu() - c0
    out["links"], out["far_links"] = len(s.links), s.links.n_far
    out["terms_mb"] = sum(x.nbytes for part in ext for x in part) / 1e6
    out["peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # before the check
    s.links._ext = None
    fresh = s.links.extended(s.h)
    pairs = [(x, y) for a, b in zip(ext, fresh) for x, y in zip(a, b)]
    out["terms_equal_fresh"] = all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in pairs)
    return out


if __name__ == "__main__":
    main()
