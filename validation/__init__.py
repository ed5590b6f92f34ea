"""Nonlinear checks of the linear predictions: Exudyn closed-loop runs against Floquet multipliers.

Stage of the data path after ``mbs_models`` -> ``linearize`` -> ``stability`` /
``taguchi``; imported by ``flexstab`` only.  Submodules (imported on use, Exudyn
is loaded with them):

``validation.closed_loop``
    :func:`~validation.closed_loop.validate_closed_loop`, one perturbed
    nonlinear run against the predicted multipliers.
``validation.plots``
    Figures of the nonlinear runs.
``validation.study``
    The four-Omega linear-vs-nonlinear comparison.
``validation.direct_monodromy``
    :func:`~validation.direct_monodromy.direct_monodromy`, the monodromy of any
    model file from finite differences of one-period Exudyn runs.
``validation.model_comparison``
    Reduced model, Exudyn linearisations and the direct Exudyn monodromy side by side.
"""
__all__: list = []
