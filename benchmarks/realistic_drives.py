"""Graph estimators on long realistic-profile drives: RMS, ANEES and the sensor corrections they found.

A ``realistic`` drive (:mod:`graphpos.sim.params`) has the errors real
sensor sets show: a yaw rate up to 30 % off, a wheel up to 10 % off,
ranges 5-8 % long, gross range outliers. Over 300 s of ``paper-straight``
(laps of the tunnel with a U-turn outside each portal, where no tag is in
range) the self-calibration has to find them, and how well it did decides
the error in the U-turns. Each estimator runs without the drive's truth;
the truth and the simulated errors are read afterwards, to score::

    python benchmarks/realistic_drives.py                      # graph-batch, seeds 0-3
    python benchmarks/realistic_drives.py -e graph-isam2 --seeds 4-11
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from eval.metrics import evaluate_estimate  # noqa: E402
from graphpos.registry import make_estimator  # noqa: E402
from graphpos.sim import simulate  # noqa: E402
from paper_profile import parse_seeds  # noqa: E402  (this script's folder is on the path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-e", "--estimator", action="append", help="estimator (repeatable; default: graph-batch)")
    p.add_argument("--seeds", type=parse_seeds, default=(0, 1, 2, 3), help="e.g. 4-11 (default 0-3)")
    p.add_argument("--scenario", default="paper-straight")
    p.add_argument("--duration", type=float, default=300.0, metavar="S")
    args = p.parse_args(argv)
    names = args.estimator or ["graph-batch"]
    rms = {name: [] for name in names}
    print(f"{'seed':>4}  {'estimator':<14}{'rms_m':>8}{'anees':>8}  {'yaw-rate scale found/simulated':>31}  {'wheel scale found/simulated':>28}")
    for seed in args.seeds:
        drive = simulate(args.scenario, seed=seed, profile="realistic", duration_s=args.duration)
        realised = drive.params["realised"]
        for name in names:
            est = make_estimator(name).run(drive.without_truth())
            window = evaluate_estimate(drive, est)["windows"]["whole"]
            position = window["position"]
            found = est.diagnostics.get("profile") or {}
            rms[name].append(position["rms_m"])
            print(f"{seed:>4}  {name:<14}{position['rms_m']:>8.3f}{(window.get('nees') or {}).get('anees', math.nan):>8.2f}"
                  f"  {found.get('yaw_rate_scale', math.nan):>15.3f} / {1 + realised['yaw_rate_scale_error']:<13.3f}"
                  f"  {found.get('wheel_scale', math.nan):>12.3f} / {1 + realised['wheel_scale_error']:<13.3f}", flush=True)
    for name, values in rms.items():
        print(f"mean {name}: {np.mean(values):.3f} m RMS (max {np.max(values):.3f}) over seeds {','.join(map(str, args.seeds))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
