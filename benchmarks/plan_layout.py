"""Wall time and result of ``graphpos plan-layout`` on issue 18's two cases, with the time split.

    python benchmarks/plan_layout.py            # the papers' tunnel (0.5 m) and the 3 km tunnel (1.5 m)
    python benchmarks/plan_layout.py --papers   # the papers' tunnel only

Prints per case: the chosen layout and its tag count, its bound, its simulated
error on the search's seeds and on the fresh seeds (mean and 90 % upper
limit), how many bounds and runs it took, the bound search's share of the
wall time, and the wall time (targets: 30 s and 2 minutes on 2 idle cores).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from eval.plan_layout import plan_layout
from graphpos.plan import TunnelSpec

CASES = {
    "papers' tunnel, 0.5 m RMS": (TunnelSpec(length_m=120.0, width_m=6.0, speed_mps=2.0), 0.5, 30.0),
    "3 km tunnel at 80 km/h, 1.5 m RMS": (TunnelSpec(length_m=3000.0, width_m=9.0, speed_mps=80 / 3.6), 1.5, 120.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--papers", action="store_true", help="the papers' tunnel only")
    args = ap.parse_args()
    for name, (spec, target_m, limit_s) in CASES.items():
        if args.papers and not name.startswith("papers"):
            continue
        with tempfile.TemporaryDirectory() as tmp:
            started = time.perf_counter()
            out = plan_layout(spec, Path(tmp) / "plan", target_m=target_m, progress=False)
            wall = time.perf_counter() - started
            r = json.loads((Path(tmp) / "plan" / "results.json").read_text())
        c = r["chosen"]
        print(f"{name}: {c['layout'] if c else 'none'}, {c['n_tags'] if c else '-'} tags, met={out.met}")
        if c:
            print(f"  bound {c['bound_m']:.3f} m; simulated {c['simulated_m']:.3f} m (seeds {r['seeds']}), "
                  f"fresh {c['fresh_simulated_m']:.3f} m, 90 % upper {c['fresh_upper_90_m']:.3f} m (seeds {r['fresh_seeds']})")
        print(f"  {len(r['bounds'])} bounds, bound search {r['bound_search_s']:.1f} s of {wall:.1f} s wall "
              f"(target {limit_s:.0f} s)")


if __name__ == "__main__":
    main()
