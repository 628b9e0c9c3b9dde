"""Peak RSS and CPU of reading a stored precompute and writing it again (issue 19, docs/scale.md
"The stored precompute: memory and the first frame").

    python benchmarks/bench_precompute_io.py STORE.hrpc OUT_DIR [--json out.json] [--step read|write]

--step read: only pc.read; write: pc.read then pc.write into OUT_DIR (each step its own process,
so that ru_maxrss is that step's peak)."""

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("store")
    ap.add_argument("out_dir")
    ap.add_argument("--step", choices=("read", "write"), default="write")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from hr_addon.io import precompute as pc

    rss = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # GB (Linux: kB)
    out = {"store": args.store, "rss_before_gb": rss()}
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


if __name__ == "__main__":
    main()
