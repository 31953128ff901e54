"""LSSVM fit time by training-set size (issue 3: under 10 s) and the default
range model's error on simulated drives, by true-distance band.

The drives' RFID readings (RSS from :mod:`graphpos.sim.rss`, fresh tags with
their own shadowing, 2 % outliers) are converted by ``default_range_model``
(the LSSVM calibrated on simulated tunnel data) and compared with
``true_range_m``; readings of all seeds are pooled.

    python benchmarks/ranging.py [--scenario paper-straight] [--seeds 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from graphpos.drive import Channel, Drive
from graphpos.ranging import LssvmRangeModel, default_range_model
from graphpos.ranging.assess import format_range_errors, range_errors
from graphpos.sim import simulate
from graphpos.sim.rss import ENVIRONMENTS


def fit_times(sizes: tuple[int, ...] = (184, 1000, 5000, 20000)) -> None:
    env = ENVIRONMENTS["tunnel"]
    rng = np.random.default_rng(0)
    print("LSSVM fit (cross-validation + eq. 6) on tunnel RSS readings")
    for n in sizes:
        d = rng.uniform(0.2, 9.0, n)
        rss = env.sample_rss(d, rng, env.draw_tag_offsets_db(n, rng))
        start = time.perf_counter()
        model = LssvmRangeModel().fit(rss, d)
        print(f"  {n:>6} samples: {time.perf_counter() - start:6.2f} s (solved exactly on {model.support_x.size})")


def pooled(drives: list[Drive]) -> Drive:
    """One drive holding every drive's RFID readings (truth ranges kept)."""
    cols = {k: np.concatenate([d.rfid[k] for d in drives]) for k in ("tag_id", "rss", "true_range_m")}
    cols["t_s"] = np.arange(cols["rss"].size, dtype=np.float64)
    first = drives[0]
    return first.replace(channels={"rfid": Channel("rfid", cols)}, name=f"{len(drives)} drives")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper-straight")
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    fit_times()
    drives = [simulate(args.scenario, seed=s) for s in range(args.seeds)]
    model = default_range_model(drives[0])
    print(f"\n{model.kind} default range model on {args.scenario}, seeds 0-{args.seeds - 1} "
          f"({drives[0].params.get('rss_environment')}): range error (m) by true range")
    print(format_range_errors(range_errors(model, pooled(drives))))


if __name__ == "__main__":
    main()
