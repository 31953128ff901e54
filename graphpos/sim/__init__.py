"""Simulated drives reproducing the papers' test set-ups.

Public API
----------
- :data:`SCENARIOS`: name -> :class:`Scenario` (name, one-line summary,
  allowed patterns, default pattern, default duration = one pass);
- :func:`simulate`: one seeded, deterministic drive of a scenario, with
  optional parameter overrides, RFID/RSU latency and injected faults
  (:mod:`graphpos.sim.faults`);
- :func:`load_config`: read a TOML parameter file for ``overrides``;
- :func:`default_params`: a scenario's full parameter dict (the papers'
  values where they give one) under a sensor profile, i.e. every key a
  config file may set.

Scenarios
---------
=====================  =====================================================
paper-straight         song2016 §6.3.2: 120 m straight tunnel, 6 m wide, 42
                       tags; 14 m / 18 m approach roads; ~2 m/s, 76 s.
paper-comprehensive    song2016 §6.3.3: 60 m straight + 60 m curve (R 50 m).
paper-imm              song2014 §5: the same shape, 7.5 m wide (two lanes).
urban-rsu-gnss         liu2016 §3: 300 m open road (GNSS), 400 m tunnel (7
                       RSUs, no GNSS), a 90 degree turn and 300 m of street
                       (multipath GNSS), 20 km/h.
long-tunnel            3 km straight tunnel at 80 km/h, 200 m approaches
                       with GNSS; tags every 6 m or in groups every 30 m.
=====================  =====================================================

The papers' DGPS was their reference, i.e. our truth; the paper-* scenarios
carry only a short DGPS-grade ``gnss`` channel on the approach before the
tunnel (5 Hz, 0.4 m, the first 5 s; parameters ``gnss_approach``), from which
the papers start every filter (song2016 §6). Channels: ``truth`` (100 Hz),
``imu`` (100 Hz), ``wheel`` (100 Hz), ``compass`` (10 Hz), and ``rfid`` (1 Hz;
tunnels with tags), ``rsu`` and ``gnss`` (1 Hz) where the scenario has them.

Sensor profiles
---------------
``simulate(..., profile=...)`` / ``graphpos simulate --profile``: ``ideal``
(the default; the sensor models above) or ``realistic`` (adds, drawn per
drive, a gyro turn-on bias, yaw-rate and wheel-speed scale errors, RFID
ranges reported 5-8 % long and gross range outliers). See
:mod:`graphpos.sim.params`.

Geometry
--------
East-north metres; the route starts at the origin heading east. Traffic keeps
right: the vehicle drives the centre of the right-hand lane
(``lane_width_m / 2`` right of the centreline); tags are on both walls,
``width_m / 2`` either side of the centreline (:mod:`graphpos.sim.infrastructure`);
the RFID reader's position is the vehicle's, in 2-D.

Windows
-------
``in_tunnel``; ``zone:<name>`` for every zone (``approach``/``tunnel``, or
``open``/``tunnel``/``street``) partitioning the drive; ``turnaround``; on
routes with a curve ``straight`` and ``curve`` (the road's shape where the
vehicle is); ``fault:<kind>`` per injected fault episode. Drives longer than
one pass go out and back (:mod:`graphpos.sim.trajectory`), so windows repeat
per pass.
"""

import importlib

__all__ = ["SCENARIOS", "Scenario", "simulate", "load_config", "default_params"]

#: Where each public name lives. They are imported on first use (PEP 562), so
#: that a command importing one light sub-module (``graphpos.sim.faults`` for
#: its names in ``--help``) does not pay for the simulator and scipy.signal.
_HOMES = {"SCENARIOS": "scenarios", "Scenario": "scenarios", "simulate": "simulate",
          "load_config": "params", "default_params": "params"}


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module 'graphpos.sim' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"graphpos.sim.{_HOMES[name]}"), name)
    globals()[name] = value
    return value
