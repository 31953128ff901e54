"""Simulated drives reproducing the papers' test set-ups.

Public API:

- :data:`SCENARIOS`: name -> :class:`~graphpos.sim.scenarios.Scenario`
  (name, summary, allowed patterns, default pattern, default duration);
- :func:`simulate`: one seeded, deterministic drive of a scenario;
- :func:`load_config`: read a TOML parameter file for ``overrides``;
- :func:`default_params`: a scenario's full parameter dict (the papers'
  values), i.e. every key a config file may set.
"""

from graphpos.sim.params import default_params, load_config
from graphpos.sim.scenarios import SCENARIOS, Scenario
from graphpos.sim.simulate import simulate

__all__ = ["SCENARIOS", "Scenario", "simulate", "load_config", "default_params"]
