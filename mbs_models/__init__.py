"""Models of the single-link flexible manipulator: parameters, the paper's
reduced one-mode model, model files (the Exudyn ANCF link is the built-in ``single-link``)."""

#: Every name is imported on first use: ``import mbs_models.parameters`` (the command line's
#: configuration) then imports neither scipy (the reduced model) nor Exudyn.
_LAZY = {
    "ManipulatorParameters": "mbs_models.parameters",
    "PAPER_MODE_CONSTANTS": "mbs_models.reduced",
    "FundamentalMotion": "mbs_models.reduced",
    "ModeConstants": "mbs_models.reduced",
    "ReducedModel": "mbs_models.reduced",
    "derived_mode_constants": "mbs_models.reduced",
    "mode_constants": "mbs_models.reduced",
    "exudyn_console": "mbs_models.console",
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


__all__ = sorted(_LAZY)
