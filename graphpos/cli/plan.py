"""Command ``plan-layout``: the cheapest tag layout for a tunnel (:mod:`eval.plan_layout`, issue 18)."""

from __future__ import annotations

import time

from graphpos.cli import OUTPUT_FOLDER_HELP, add_output_option, one_line


def register(sub) -> None:
    p = sub.add_parser("plan-layout",
                       description="Search tag layout families (pairs, staggered, one wall, groups) for a tunnel by "
                                   "the position bound, then confirm the cheapest by simulation. Writes report.md/html, "
                                   "results.json, plan.png and layout.toml (for graphpos simulate --config).")
    p.add_argument("--length-m", type=float, required=True, help="tunnel length, metres")
    p.add_argument("--width-m", type=float, default=6.0, help="tunnel width wall to wall (default 6 m)")
    p.add_argument("--speed-kmh", type=float, default=7.2, help="driving speed (default 7.2 km/h = the papers' 2 m/s)")
    p.add_argument("--curve-radius-m", type=float, default=None, help="radius of a left curve inside the tunnel (default: straight)")
    p.add_argument("--curve-length-m", type=float, default=0.0, help="arc length of the curve")
    p.add_argument("--curve-start-m", type=float, default=0.0, help="where the curve starts, from the entry portal")
    p.add_argument("--profile", choices=("ideal", "paper"), default="ideal",
                   help="simulator sensor profile of the drives (default ideal: the papers' sensors, white noise)")
    p.add_argument("--sensors", default=None,
                   help="sensors the vehicle carries, comma-separated, among imu, wheel, compass, rfid, rsu, gnss "
                        "(default: the papers', imu,wheel,compass,rfid,gnss; gnss is the DGPS fixes on the approach)")
    p.add_argument("--reader-range-m", type=float, default=None, help="RFID reader range, at most 9 m (default: the papers' reader, 9 m)")
    p.add_argument("--pattern", default=None,
                   help="speed profile of the drives: a motion pattern of paper-comprehensive (default constant; "
                        "`graphpos scenarios` lists them)")
    goal = p.add_mutually_exclusive_group()  # neither: plan_layout says so in one line
    goal.add_argument("--target-m", type=float, help="target position error in the tunnel, metres")
    goal.add_argument("--budget", type=int, help="tag budget: the best layout with at most this many tags")
    p.add_argument("--metric", choices=("rms", "max"), default="rms", help="target metric: RMS (default) or worst case")
    p.add_argument("-e", "--estimator", default="graph-batch",
                   help="estimator the target is for (default graph-batch; a causal one is held to the filtering bound)")
    p.add_argument("--seeds", type=int, default=2, help="simulated drives per layout in the search (seeds 0.., default 2)")
    p.add_argument("--fresh-seeds", type=int, default=6,
                   help="fresh drives (seeds 100..) the chosen layout must meet the target on too (default 6)")
    add_output_option(p, "DIR", OUTPUT_FOLDER_HELP)
    p.add_argument("--workers", type=int, default=None, help="local worker processes for the simulations (default: all cores)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.set_defaults(func=_plan_layout)


def _plan_layout(args) -> int:
    from eval.plan_layout import plan_layout
    from graphpos.io.outputs import check_output_folder
    from graphpos.plan import TunnelSpec

    started = time.perf_counter()
    check_output_folder(args.output)
    given = {"sensors": args.sensors, "reader_range_m": args.reader_range_m, "pattern": args.pattern}
    spec = TunnelSpec(args.length_m, args.width_m, args.speed_kmh / 3.6, args.curve_radius_m, args.curve_length_m,
                      args.curve_start_m, args.profile, **{k: v for k, v in given.items() if v is not None})
    outcome = plan_layout(spec, args.output, target_m=args.target_m, budget=args.budget, metric=args.metric,
                          estimator=args.estimator, seeds=args.seeds, fresh_seeds=args.fresh_seeds, workers=args.workers, progress=not args.no_progress)
    took = time.perf_counter() - started
    print(f"plan-layout: wrote {one_line(str(outcome.folder))}/report.md, report.html, results.json, plan.png"
          f"{', layout.toml' if outcome.chosen is not None else ''} in {took:.1f} s")
    if outcome.chosen is None or not outcome.met:
        print("plan-layout: no layout met the target; see the report", flush=True)
        return 1
    return 0
