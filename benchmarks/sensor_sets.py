"""Every estimator on simulated drives that carry only some of the sensors: failures and figures per sensor set.

A user's vehicle may lack a wheel-speed pick-up, a compass or a GNSS
receiver (an indoor UWB run has an IMU and ranges). Each sensor set is
simulated on ``paper-imm`` with the ``realistic`` profile (ranges
reported, 5-8 % long, outliers; gyro, yaw-rate and wheel errors) for the
given seeds; every estimator whose channels the drive has runs on it
without its truth (:func:`eval.execution.run_job`), and the in-tunnel RMS
and ANEES are printed, with ``FAILED`` for an estimator that raised and a
mark where the RMS exceeds 1 m or the ANEES 30::

    python benchmarks/sensor_sets.py                     # the default sets, seeds 0-1
    python benchmarks/sensor_sets.py --sets "imu,rfid;wheel,rfid" --seeds 0-4
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from eval.execution import Job, SimSource, run_job  # noqa: E402
from graphpos.registry import estimator_classes  # noqa: E402
from paper_profile import parse_seeds  # noqa: E402  (this script's folder is on the path)

DEFAULT_SETS = ("imu,rfid", "wheel,rfid", "imu,compass,rfid", "wheel,compass,rfid", "imu,wheel,rfid", "imu,wheel,compass,rfid")
#: Marked as poor beyond these (in the tunnel).
POOR_RMS_M, POOR_ANEES = 1.0, 30.0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", default=";".join(DEFAULT_SETS), help="sensor sets, ';'-separated (default: %(default)s)")
    p.add_argument("--seeds", type=parse_seeds, default=(0, 1), help="e.g. 0-4 (default 0-1)")
    p.add_argument("--profile", default="realistic")
    args = p.parse_args(argv)
    failed = poor = 0
    print(f"{'sensors':<24}{'seed':>5}  {'estimator':<26}{'rms_m':>8}{'anees':>9}")
    for sensors in args.sets.split(";"):
        for seed in args.seeds:
            overrides = json.dumps({"profile": args.profile, "sensors": sensors, "rfid": {"reports_range": True}})
            source = SimSource("paper-imm", None, seed, overrides_json=overrides)
            for name in estimator_classes():
                r = run_job(Job(source, name))
                if r.not_applicable:
                    continue
                if not r.ok:
                    failed += 1
                    print(f"{sensors:<24}{seed:>5}  {name:<26}FAILED {r.error[:150]}", flush=True)
                    continue
                w = r.metrics["windows"]["in_tunnel"]
                rms, anees = w["position"]["rms_m"], (w.get("nees") or {}).get("anees", float("nan"))
                mark = rms > POOR_RMS_M or anees > POOR_ANEES
                poor += mark
                print(f"{sensors:<24}{seed:>5}  {name:<26}{rms:>8.3f}{anees:>9.2f}{'  <- poor' if mark else ''}", flush=True)
    print(f"{failed} failed, {poor} marked poor (in-tunnel RMS > {POOR_RMS_M:g} m or ANEES > {POOR_ANEES:g})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
