"""RSS -> distance (LSSVM, propagation model) and range calibration behind one RangeModel interface.

Every estimator gets distances and 1-sigmas through a
:class:`~graphpos.ranging.model.RangeModel`: :func:`default_range_model` for a
drive, or a model saved by ``graphpos ranging fit`` and read with
:func:`load_range_model`.
"""

from graphpos.ranging.drive_models import calibrated_model, default_range_model, fit_from_drive, ranges_by_field, reading_models, true_ranges_m
from graphpos.ranging.lssvm import LssvmRangeModel
from graphpos.ranging.model import LinearCalibration, RangeModel, load_range_model
from graphpos.ranging.propagation import PropagationRangeModel

__all__ = [
    "RangeModel",
    "LinearCalibration",
    "LssvmRangeModel",
    "PropagationRangeModel",
    "load_range_model",
    "default_range_model",
    "reading_models",
    "ranges_by_field",
    "calibrated_model",
    "fit_from_drive",
    "true_ranges_m",
]
