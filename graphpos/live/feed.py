"""One estimator fed live: what ``Estimator.run`` does to a whole drive, done one measurement at a time.

``run`` prepares the drive (the sensor profile's corrections, the layout's
tags) and then feeds its rows to ``process``. Live there is no drive, only
the *site*: a drive of the same vehicle and place (its tag and RSU maps,
origin, and which sensors the vehicle has at which rates), which the
estimator starts on (:meth:`graphpos.estimator.Estimator.start` reads maps
and the sensor set, never channel data). Each received measurement then
gets what ``prepare`` would have done to its row, so that a drive sent
live gives the output ``run`` gives offline (tested to 1e-9 m).
"""

from __future__ import annotations

from graphpos.drive import Drive, Measurement
from graphpos.estimate import Estimate, OutputRow
from graphpos.estimator import Estimator


class LiveFeed:
    """An estimator started on a site and fed measurements as they arrive.

    Parameters
    ----------
    estimator : Estimator
        Built as for ``run`` (config, layout, range model, start pose, profile).
    site : Drive
        The site (maps, origin, sensor set); its truth is never shown to the estimator.

    Raises
    ------
    MissingChannelError
        The site lacks a channel the estimator needs.
    """

    def __init__(self, estimator: Estimator, site: Drive):
        self.estimator = estimator
        self.name = estimator.name
        site = estimator.prepare(site.without_truth())
        self._layout_tags = {int(t) for t in site.tags.layout(estimator.layout)} if estimator.layout else None
        self._profile = estimator.profile
        self._channels = frozenset(estimator.channels_used(site))
        estimator.start(site)

    def process(self, m: Measurement) -> list[OutputRow]:
        """The outputs the measurement completes (none for a channel the estimator does not use)."""
        if m.channel not in self._channels:
            return []
        if self._layout_tags is not None and m.channel == "rfid" and int(m.values["tag_id"]) not in self._layout_tags:
            return []
        if self._profile is not None:
            m = m._replace(values=self._profile.corrected_values(m.channel, m.values), t_s=self._profile.corrected_time(m.channel, m.t_s))
        return self.estimator.process(m)

    def finish(self) -> Estimate:
        """The whole estimate (the estimator's ``finish``)."""
        return self.estimator.finish()
