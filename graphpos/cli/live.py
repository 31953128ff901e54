"""Commands ``live`` (online estimators on measurements as they arrive) and ``replay`` (send a drive as a live feed).

``graphpos live --site SITE.mcap -e graph-isam2 [-e NAME ...] [--listen udp://HOST:PORT ...] [--mapping M.toml]
[--foxglove HOST:PORT | --no-foxglove] [--udp-out udp://HOST:PORT] -o REC.mcap`` listens (default
``udp://127.0.0.1:7400``), runs each estimator in its own thread, publishes
every estimate on a Foxglove WebSocket server (default ``127.0.0.1:8765``,
:mod:`graphpos.live.foxglove_out`) and records inputs and outputs into
REC.mcap (:mod:`graphpos.live.recording`; written in place, so that it
reads after any stop, ``kill -9`` included). It runs until the
end-of-drive message, SIGINT (Ctrl-C) or SIGTERM, then finishes the
estimators, closes the recording and prints the counts.

With ``--mapping``, messages are rosbridge operations read through that
import mapping (:mod:`graphpos.live.rosbridge`) and ``{"op": "graphpos_end"}``
ends the drive.

The *site* is a drive of the same vehicle and place (a recording imported
with ``graphpos import``, or a simulated drive): live takes its tag and
RSU maps, origin, and the sensors the vehicle has; never its measurements
or truth. Estimators take the options of ``run`` (``--layout``,
``--range-model``, ``--initial-pose``, ``--profile``, ``--set``). Only
online estimators run live (graph-batch smooths a whole drive: run it on
the recording afterwards).

``graphpos replay DRIVE.mcap --to udp://HOST:PORT [--speed 1.0] [--loss P] [--duplicate P] [--reorder P]
[--malformed P] [--seed N]`` sends the drive at its recorded arrival times
(:mod:`graphpos.live.replay`); ``--speed 0`` sends as fast as the link
takes them (use TCP for that: a UDP receiver's buffer overflows).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path

from graphpos.cli import error_line, one_line
from graphpos.errors import ConfigError

DEFAULT_LISTEN = "udp://127.0.0.1:7400"
DEFAULT_FOXGLOVE = "127.0.0.1:8765"
LIVE_SWITCH_INTERVAL_S = 0.0005


def register(sub) -> None:
    from graphpos.cli import add_output_option
    from graphpos.cli.calibrate import add_profile_option
    from graphpos.cli.estimators import add_initial_pose_option, add_settings_options

    p = sub.add_parser("live",
                       description="Listen for measurements (one JSON message per UDP datagram or TCP line, in the drive's "
                                   "channel schemas, or rosbridge messages through an import mapping), run online "
                                   "estimators on them as they arrive, publish each estimate on a Foxglove WebSocket "
                                   "server and record inputs and outputs into an MCAP file that reads after any stop.")
    p.add_argument("--site", type=Path, required=True, metavar="SITE.mcap",
                   help="a drive of this vehicle and place: its tag/RSU maps, origin and sensor set are used (never its "
                        "measurements or truth)")
    p.add_argument("-e", "--estimator", dest="estimators", action="append", required=True, metavar="NAME",
                   help="online estimator (repeat for several): graph-isam2, graph-fixed-lag or any filter")
    p.add_argument("--listen", action="append", default=None, metavar="ADDRESS",
                   help=f"udp://HOST:PORT or tcp://HOST:PORT to receive on (repeat for several; port 0: any free one); "
                        f"default {DEFAULT_LISTEN}")
    p.add_argument("--mapping", type=Path, metavar="M.toml",
                   help="take rosbridge JSON messages ({\"op\": \"publish\", \"topic\": ...}) and read them through this "
                        "import mapping (`graphpos import rosbag`'s)")
    p.add_argument("--foxglove", default=DEFAULT_FOXGLOVE, metavar="HOST:PORT",
                   help=f"Foxglove WebSocket server address (default {DEFAULT_FOXGLOVE}; port 0: any free one)")
    p.add_argument("--no-foxglove", action="store_true", help="no Foxglove server")
    p.add_argument("--udp-out", metavar="udp://HOST:PORT", help="also send each estimate as a JSON datagram there")
    p.add_argument("--layout", metavar="L", help="use only the tags of this named layout")
    p.add_argument("--range-model", type=Path, metavar="F", help="range model JSON (from `graphpos ranging fit`)")
    p.add_argument("--status-every", type=float, default=1.0, metavar="S", help="seconds between status lines (default 1)")
    p.add_argument("--quiet", action="store_true", help="no status lines (the start and the summary are still printed)")
    add_output_option(p, "REC.mcap", "recording of the session (an MCAP drive with the estimates; written as it goes)")
    add_settings_options(p)
    add_initial_pose_option(p)
    add_profile_option(p)
    p.set_defaults(func=_live)

    p = sub.add_parser("replay",
                       description="Send a drive's measurements (never its truth) at their recorded arrival times, one "
                                   "JSON message each, to a `graphpos live`; optionally lose, garble, duplicate and "
                                   "reorder messages as a real network does.")
    p.add_argument("drive", type=Path, metavar="DRIVE.mcap")
    p.add_argument("--to", required=True, metavar="ADDRESS", help="udp://HOST:PORT or tcp://HOST:PORT")
    p.add_argument("--speed", type=float, default=1.0, help="time factor: 1 real time (default), 10 ten times faster, 0 no pacing")
    for name, what in (("loss", "lost"), ("duplicate", "sent twice"), ("reorder", "held back behind the next 1-3"),
                       ("malformed", "garbled")):
        p.add_argument(f"--{name}", type=float, default=0.0, metavar="P", help=f"probability that a message is {what} (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the damage (default 0)")
    p.add_argument("--json", action="store_true", help="print the counts of what was sent and done as JSON")
    p.set_defaults(func=_replay)


def _estimators(args, site):
    from graphpos.cli.calibrate import profile as profile_of
    from graphpos.cli.estimators import estimator_settings, initial_pose
    from graphpos.live.feed import LiveFeed
    from graphpos.ranging import load_range_model
    from graphpos.registry import make_estimator, require_known

    names = list(dict.fromkeys(args.estimators))
    if args.final:
        raise ConfigError("--final is graph-isam2's smoothed trajectory once a drive has ended; live publishes the causal "
                          "one (run `graphpos run REC.mcap -e graph-isam2 --final` on the recording)")
    offline = [n for n, cls in require_known(names).items() if cls.merge_by != "arrival"]
    if offline:
        raise ConfigError(f"{', '.join(offline)} smooths a whole drive and gives no output until it ends; run it on the "
                          f"recording afterwards (`graphpos run REC.mcap -e {offline[0]}`)")
    settings = estimator_settings(args, names)
    range_model = load_range_model(args.range_model) if args.range_model else None
    if args.layout:
        site.tags.layout(args.layout)  # a clear error for an unknown layout
    made = [make_estimator(n, settings=settings.get(n), layout=args.layout, range_model=range_model,
                           initial_pose=initial_pose(args), profile=profile_of(args)) for n in names]
    return [LiveFeed(est, site) for est in made], settings


def _status_line(status: dict) -> str:
    t = status["t_s"]
    parts = [f"t {t:8.2f} s" if t is not None else "t      -  ",
             f"{status['received']} msgs (lost {status['lost']}, dup {status['duplicates']}, reord {status['reordered']}, "
             f"bad {status['malformed_total']})"]
    for name, e in status["estimators"].items():
        p95 = e["latency_ms"]["p95"]
        lag = f"lag {e['lag_s']:.2f} s, queue {e['queue']}" if e["lag_s"] > 0.5 or e["queue"] > 100 else "keeping up"
        parts.append(f"{name}: {e['status'] if e['status'] != 'running' else lag}, p95 {p95:.2f} ms" if p95 is not None
                     else f"{name}: {e['status']}")
    return " | ".join(parts)


def _live(args: argparse.Namespace) -> int:
    from graphpos.io import read_drive
    from graphpos.io.outputs import check_output_file
    from graphpos.live.recording import LiveRecording
    from graphpos.live.session import LiveSession
    from graphpos.live.sources import Address, Listener

    if not args.status_every > 0:
        raise ConfigError(f"--status-every must be a positive number of seconds, got {args.status_every}")
    addresses = [Address.parse(a) for a in (args.listen or [DEFAULT_LISTEN])]
    udp_out = Address.parse(args.udp_out, ("udp",)) if args.udp_out else None
    foxglove_at = None if args.no_foxglove else _host_port(args.foxglove)
    check_output_file(args.output, inputs={"site": args.site, "mapping file": args.mapping}, kind="mcap")
    site = read_drive(args.site)
    translator = None
    if args.mapping:
        from graphpos.live.rosbridge import RosbridgeTranslator

        translator = RosbridgeTranslator(args.mapping)
        for what, theirs, ours in (("tag", translator.tags, site.tags), ("RSU", translator.rsus, site.rsus)):
            if len(theirs) and theirs != ours:
                raise ConfigError(f"the {what} map of {args.mapping} is not the one of the site {args.site}; the readings "
                                  f"would be placed against the wrong map")
    feeds, settings = _estimators(args, site)

    def log(line: str) -> None:
        print(one_line(f"graphpos live: {line}"), file=sys.stderr, flush=True)

    outputs = []
    if foxglove_at is not None:
        from graphpos.live.foxglove_out import FoxgloveOutput

        outputs.append(FoxgloveOutput(site, [f.name for f in feeds], *foxglove_at))
    if udp_out is not None:
        from graphpos.live.udp_out import UdpOutput

        outputs.append(UdpOutput(site, udp_out))
    live_info = {"started_unix_s": time.time(), "site": str(args.site), "estimators": [f.name for f in feeds], "settings": settings,
                 "listen": [str(a) for a in addresses]}
    recording = LiveRecording(args.output, site, live_info)
    outputs.append(recording)
    session = LiveSession(site, feeds, outputs, recording, translator, log=log)
    # hand the interpreter between the listener and the estimators every 0.5 ms instead of 5 ms: the
    # latency of a measurement that arrives while an estimator runs Python code
    sys.setswitchinterval(LIVE_SWITCH_INTERVAL_S)
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    listeners = []
    try:
        listeners = [Listener(a, session.receive) for a in addresses]
        log("listening on " + ", ".join(str(li.address) for li in listeners))
        if foxglove_at is not None:
            log(f"Foxglove: open connection ws://{foxglove_at[0]}:{outputs[0].port}")
        log(f"recording to {args.output}")
        on_status = None if args.quiet else (lambda s: log(_status_line(s)))
        final = session.run(stop, args.status_every, on_status)
    finally:
        for li in listeners:
            li.close()
        recording.close()
        for out in outputs[:-1]:
            out.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    why = "the drive ended" if session.ended else "stopped"
    log(f"{why}: {_status_line(final)}")
    print(json.dumps(final, indent=1, default=float))
    failed = [n for n, e in final["estimators"].items() if e["status"] == "failed"]
    for name in failed:
        print(error_line("live", f"{name} failed: {final['estimators'][name]['error']}"), file=sys.stderr)
    return 1 if failed else 0


def _host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"--foxglove {text!r}: expected HOST:PORT")
    return host.strip("[]"), int(port)


def _replay(args: argparse.Namespace) -> int:
    from graphpos.io import read_drive
    from graphpos.live.replay import Damage, replay
    from graphpos.live.sources import Address, sender

    address = Address.parse(args.to)
    damage = Damage(args.loss, args.duplicate, args.reorder, args.malformed, args.seed)
    drive = read_drive(args.drive)
    send = sender(address)
    refused = []

    def send_quietly(payload: bytes) -> None:
        try:
            send(payload)
        except ConnectionRefusedError:  # UDP: nobody listening yet; the datagram is lost as on a real link
            if not refused:
                print(error_line("replay", f"nobody listens on {address} (datagrams are lost until something does)"),
                      file=sys.stderr)
            refused.append(1)

    def log(line: str) -> None:
        print(f"graphpos {line}", file=sys.stderr, flush=True)

    damaged = damage if any((args.loss, args.duplicate, args.reorder, args.malformed)) else None
    try:
        counts = replay(drive, send_quietly, args.speed, damaged, log)
    except (BrokenPipeError, ConnectionResetError) as exc:
        raise ConfigError(f"{address} closed the connection ({exc.strerror or exc})") from None
    summary = {**counts.to_dict(), "refused": len(refused)}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"sent {counts.sent} messages of {counts.messages} to {address}"
              + (f" (lost {counts.lost}, duplicated {counts.duplicated}, reordered {counts.reordered}, garbled "
                 f"{sum(counts.malformed.values())})" if damaged else ""))
    return 0
