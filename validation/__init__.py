"""Nonlinear checks of the linear predictions: Exudyn closed-loop runs against Floquet multipliers.

Stage of the data path after ``mbs_models`` -> ``linearize`` -> ``stability`` /
``taguchi``; imported by ``flexstab`` only.  Submodules (imported on use, Exudyn
is loaded with them):

``validation.multipliers``
    :func:`~validation.multipliers.validate_model_multipliers`, the one-period map of
    the nonlinear closed loop measured against the predicted multipliers.
``validation.full_map``
    The whole one-period map from random constraint-consistent perturbations.
``validation.plots``
    Figures of the nonlinear runs.
``validation.direct_monodromy``
    :func:`~validation.direct_monodromy.direct_monodromy`, the monodromy of any
    model file from finite differences of one-period Exudyn runs.
"""
__all__: list = []
