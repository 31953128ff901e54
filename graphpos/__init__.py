"""graphpos: vehicle positioning where GNSS is denied.

Core types: :class:`~graphpos.drive.Drive`, :class:`~graphpos.estimate.Estimate`
and the :class:`~graphpos.estimator.Estimator` contract.
"""

__version__ = "0.1.0"
