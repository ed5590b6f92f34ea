"""Models of the single-link flexible manipulator: parameters, the paper's
reduced one-mode model and the Exudyn ANCF model."""
from mbs_models.parameters import ManipulatorParameters
from mbs_models.reduced import (
    PAPER_MODE_CONSTANTS,
    FundamentalMotion,
    ModeConstants,
    ReducedModel,
    derived_mode_constants,
    mode_constants,
)

#: Names provided by the Exudyn layer, imported on first use (Exudyn adds ~0.1 s).
_LAZY = {
    "ExudynLinkConfig": "mbs_models.exudyn_link",
    "ExudynLinkModel": "mbs_models.exudyn_link",
    "ExudynSolverError": "mbs_models.exudyn_link",
    "build_link_model": "mbs_models.exudyn_link",
    "exudyn_frequencies": "mbs_models.modes",
    "analytic_frequencies": "mbs_models.modes",
    "ModesResult": "mbs_models.modes",
    "Drive": "mbs_models.model_file",
    "ModelDefinition": "mbs_models.model_file",
    "ModelFileError": "mbs_models.model_file",
    "load_model_file": "mbs_models.model_file",
    "model_from_build": "mbs_models.model_file",
    "builtin_model": "mbs_models.model_file",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'mbs_models' has no attribute {name!r}")


__all__ = [
    "ManipulatorParameters",
    "ReducedModel",
    "FundamentalMotion",
    "ModeConstants",
    "PAPER_MODE_CONSTANTS",
    "derived_mode_constants",
    "mode_constants",
    *sorted(_LAZY),
]
