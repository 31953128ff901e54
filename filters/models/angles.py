"""Angle handling in one place: wrapping, residuals, circular means.

Yaw is measured from east, counter-clockwise, in radians. Filters keep yaw
wrapped to ``[-pi, pi)`` and every yaw innovation goes through
:func:`angle_residual`, so a compass reading of ``+179 deg`` against an
estimate of ``-179 deg`` is a 2-degree innovation, not 358 degrees.
"""

from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi
# The same constants as 0-d arrays: numpy combines them with an array faster than Python floats.
_PI_ARRAY, _TWO_PI_ARRAY = np.array(math.pi), np.array(_TWO_PI)


def wrap_angle(angle_rad):
    """Wrap to ``[-pi, pi)`` (float or array)."""
    if isinstance(angle_rad, float):
        return (angle_rad + math.pi) % _TWO_PI - math.pi
    return (np.asarray(angle_rad) + _PI_ARRAY) % _TWO_PI_ARRAY - _PI_ARRAY


def angle_residual(a_rad, b_rad):
    """``a - b`` wrapped to ``[-pi, pi)``: the innovation of an angle."""
    return wrap_angle(a_rad - b_rad)


def circular_mean(angles_rad: np.ndarray, weights: np.ndarray, axis: int = 0) -> np.ndarray:
    """Weighted mean of angles on the circle, ``atan2(sum w sin, sum w cos)``.

    Used for the yaw component of an unscented transform, where the sigma
    points may straddle ``+-pi`` (weights may be negative, as the scaled
    transform's centre weight often is).
    """
    if axis == 0 and np.ndim(angles_rad) == 1:
        return np.arctan2(weights.dot(np.sin(angles_rad)), weights.dot(np.cos(angles_rad)))
    s = np.tensordot(weights, np.sin(angles_rad), axes=(0, axis))
    c = np.tensordot(weights, np.cos(angles_rad), axes=(0, axis))
    return np.arctan2(s, c)
