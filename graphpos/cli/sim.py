"""Commands ``scenarios`` and ``simulate`` (the ``graphpos.sim`` package)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from graphpos.cli import add_output_option, one_line
from graphpos.errors import ConfigError, naming_file
from graphpos.sim.faults import FAULTS
from graphpos.sim.params import PROFILES


def register(sub) -> None:
    p = sub.add_parser("scenarios",
                       description="The simulated test set-ups (the papers' experiments and beyond), "
                                   "their motion patterns and default durations.")
    p.add_argument("--json", action="store_true", help="print a JSON list of {name, summary, patterns, default_pattern, default_duration_s}")
    p.add_argument("--params", metavar="NAME",
                   help="print a scenario's default parameters as TOML (every key a --config file may set)")
    p.add_argument("--profile", metavar="PROFILE", default=None,
                   help="with --params: the parameters under this sensor profile (" + ", ".join(PROFILES) + "; default ideal)")
    p.set_defaults(func=_scenarios)

    p = sub.add_parser("simulate",
                       description="Simulate one seeded, deterministic drive of a scenario: truth, IMU, wheel "
                                   "speed, compass, RFID/RSU/GNSS where the scenario has them, tag layouts and "
                                   "windows. Parameters default to the papers' values; --config overrides them.")
    p.add_argument("scenario", metavar="NAME", help="scenario name (see `graphpos scenarios`)")
    p.add_argument("--pattern", help="motion pattern (default: the scenario's default)")
    p.add_argument("--seed", type=int, default=0, help="random seed, >= 0 (default 0)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="drive length in seconds (default: one pass; longer drives go out and back)")
    p.add_argument("--config", type=Path, metavar="F", help="TOML file of parameter overrides")
    p.add_argument("--profile", metavar="PROFILE", default=None,
                   help="sensor profile: " + ", ".join(PROFILES) + " (default: the config file's `profile`, else ideal). "
                        "realistic adds per-drive gyro turn-on bias, yaw-rate and wheel scale errors, RFID ranges "
                        "5-8 %% long and range outliers")
    p.add_argument("--rfid-latency", metavar="S|LO:HI",
                   help="delay of RFID and RSU readings in seconds: fixed S, or uniform in LO:HI")
    p.add_argument("--fault", action="append", default=[], metavar="KIND[:KEY=VALUE...]",
                   help="inject a fault (repeatable; a kind given twice makes two episodes), e.g. "
                        "rfid_blackout:start_s=20:duration_s=30, dead_tags:fraction=0.1, "
                        "dropped_samples:channels=imu+wheel:fraction=0.05. Kinds: " + ", ".join(FAULTS)
                        + ". A [faults.KIND] table in --config does the same.")
    add_output_option(p, "FILE.mcap", "output drive file", "--output")
    p.set_defaults(func=_simulate)


def _scenarios(args: argparse.Namespace) -> int:
    from graphpos.sim import SCENARIOS, default_params
    from graphpos.sim.params import to_toml

    if args.params is not None:
        if args.params not in SCENARIOS:
            raise ConfigError(f"unknown scenario '{args.params}' (known: {', '.join(SCENARIOS)})")
        profile = "ideal" if args.profile is None else args.profile
        params = default_params(args.params, profile)
        print(f"# graphpos simulate {args.params}: default parameters (profile {profile})\n" + to_toml(params), end="")
        return 0
    if args.profile is not None:
        raise ConfigError("--profile goes with --params NAME")
    rows = [s.to_dict() for s in SCENARIOS.values()]
    if args.json:
        print(json.dumps(rows, indent=1, ensure_ascii=False))
        return 0
    for r in rows:
        print(f"{r['name']:<21} {r['default_duration_s']:7.1f} s  {r['summary']}")
        print(f"{'':<21} patterns: {', '.join(r['patterns'])} (default {r['default_pattern']})")
    return 0


def parse_latency(text: str) -> float | tuple[float, float]:
    """``"S"`` -> S, ``"LO:HI"`` -> (LO, HI); a ConfigError for anything else."""
    try:
        parts = [float(v) for v in text.split(":")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        return parts[0]
    if len(parts) == 2:
        return (parts[0], parts[1])
    raise ConfigError(f"--rfid-latency must be S or LO:HI in seconds, got '{text}'")


def parse_fault(text: str) -> tuple[str, dict[str, float | str]]:
    """``"kind:key=value:key=value"`` -> ``(kind, {key: value})`` (numbers as float)."""
    kind, *pairs = text.split(":")
    spec: dict[str, float | str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ConfigError(f"--fault {text}: expected KIND[:KEY=VALUE...], got '{pair}'")
        try:
            spec[key] = float(value)
        except ValueError:
            spec[key] = value
    return kind, spec


def _simulate(args: argparse.Namespace) -> int:
    from graphpos.io import write_drive
    from graphpos.io.outputs import check_output_file
    from graphpos.sim import SCENARIOS, load_config, simulate
    from graphpos.sim.faults import check_faults
    from graphpos.sim.params import resolve_params

    check_output_file(args.output, inputs={"config file": args.config}, kind="mcap")
    overrides = load_config(args.config) if args.config is not None else {}
    faults = overrides.pop("faults", {})
    if not isinstance(faults, dict):
        raise ConfigError(f"{args.config}: 'faults' must be a table of fault kinds")
    if args.config is not None and args.scenario in SCENARIOS:
        # The file's values are checked here, so that an error names the file.
        with naming_file(args.config):
            resolve_params(args.scenario, overrides, args.profile)
            check_faults(faults, args.duration or SCENARIOS[args.scenario].default_duration_s)
    for text in args.fault:
        kind, spec = parse_fault(text)
        before = faults.get(kind)
        faults[kind] = spec if before is None else (before if isinstance(before, list) else [before]) + [spec]
    latency = parse_latency(args.rfid_latency) if args.rfid_latency is not None else None
    drive = simulate(args.scenario, pattern=args.pattern, seed=args.seed, duration_s=args.duration,
                     overrides=overrides, rfid_latency_s=latency, faults=faults or None, profile=args.profile)
    write_drive(args.output, drive)
    counts = ", ".join(f"{name} {len(ch)}" for name, ch in drive.channels.items())
    print(f"wrote {one_line(str(args.output))}: {drive.name}, {drive.duration_s:.1f} s ({counts})")
    return 0
