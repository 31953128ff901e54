"""Command ``fault-study``: every estimator through every injected fault (:mod:`eval.faults`)."""

from __future__ import annotations

import sys
import time

from graphpos.cli import OUTPUT_FOLDER_HELP, add_output_option


def register(sub) -> None:
    p = sub.add_parser("fault-study",
                       description="Run every estimator on seeded drives of SCENARIO, fault-free and with each fault "
                                   "of the simulator injected in turn; report max/RMS error during the fault, the "
                                   "recovery time after it, output rate, covariance health and exceptions.")
    p.add_argument("scenario", nargs="?", default=None,
                   help="simulation scenario (default paper-comprehensive; long-tunnel adds GNSS faults)")
    p.add_argument("-e", "--estimator", dest="estimators", action="append", default=None, metavar="NAME",
                   help="estimator (repeat or comma-separate; default: every estimator)")
    p.add_argument("--seeds", type=int, default=None, help="seeded drives (default 3, quick 1)")
    p.add_argument("--quick", action="store_true", help="one seed")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="drive length (default: one pass)")
    add_output_option(p, "DIR", OUTPUT_FOLDER_HELP, "--output")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_fault_study)


def _fault_study(args) -> int:
    from eval.faults import DEFAULT_SCENARIO, fault_study, write_study
    from graphpos.cli import one_line
    from graphpos.errors import ConfigError
    from graphpos.io.outputs import check_output_folder

    started = time.perf_counter()
    check_output_folder(args.output, parents=False)
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration must be positive, got {args.duration}")
    names = [n.strip() for v in args.estimators or [] for n in v.split(",") if n.strip()] or None
    seeds = args.seeds if args.seeds is not None else (1 if args.quick else 3)
    study = fault_study(args.scenario or DEFAULT_SCENARIO, names, seeds=seeds, duration_s=args.duration,
                        workers=args.workers, progress=not args.no_progress)
    folder = write_study(study, args.output)
    print(f"fault-study: wrote {one_line(str(folder))}/report.md, report.html, results.json, fault_errors.png "
          f"in {time.perf_counter() - started:.1f} s")
    if study.failures:
        print(f"fault-study: {len(study.failures)} runs raised:", file=sys.stderr)
        for fault, est, error in study.failures:
            print(one_line(f"  {est} with {fault}: {error}"), file=sys.stderr)
        return 1
    return 0
