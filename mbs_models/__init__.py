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

__all__ = [
    "ManipulatorParameters",
    "ReducedModel",
    "FundamentalMotion",
    "ModeConstants",
    "PAPER_MODE_CONSTANTS",
    "derived_mode_constants",
    "mode_constants",
]
