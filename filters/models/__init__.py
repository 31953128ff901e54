"""Process and measurement models with analytic Jacobians, written once.

Every estimator in :mod:`filters` (and the factor graph's custom factors)
uses these functions; each returns the model value and its Jacobian.
"""
