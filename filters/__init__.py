"""The papers' Kalman-filter estimators, by name.

Each paper module defines ``ESTIMATORS`` (name -> Estimator class); they are
merged here for :mod:`graphpos.registry`.
"""

from graphpos.estimator import Estimator

from filters.song2016 import ESTIMATORS as _SONG2016
from filters.lms import ESTIMATORS as _LMS
from filters.song2014 import ESTIMATORS as _SONG2014
from filters.liu2016 import ESTIMATORS as _LIU2016

ESTIMATORS: dict[str, type[Estimator]] = {}
ESTIMATORS.update(_SONG2016)
ESTIMATORS.update(_LMS)
ESTIMATORS.update(_SONG2014)
ESTIMATORS.update(_LIU2016)
