"""Floquet multipliers of a model about its periodic motion: the library half of ``flexstab floquet``.

:func:`floquet_analysis` computes the multipliers of the reduced model, the Exudyn link or a model file
(:func:`linearize.analysis.analyze`) at the gains of a :class:`FloquetOptions`, certified to its ``rtol``
(:mod:`stability.floquet`), with the whole loop's verdict; it returns the JSON-ready dict of
``flexstab floquet --json``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

from flexstab.options import check_model_arg, resolve_damping

__all__ = ["FloquetOptions", "floquet_analysis", "check_floquet_options"]


@dataclass(frozen=True)
class FloquetOptions:
    """What :func:`floquet_analysis` computes (``None``: the configuration's value or the default).

    Attributes
    ----------
    model : str
        ``reduced``, ``exudyn``, a built-in model file name or a model file ``PATH.py``.
    omega : float, optional
        Frequency of the periodic motion (rad/s).
    kp, kd : tuple of float
        Gains: one value, or one per drive of a model file.
    constants : str
        The reduced model's mode constants.
    samples : int, optional
        Collocation samples per period of a model file's orbit.
    method : str, optional
        Floquet method (default magnus6 for the reduced model, else magnus2).
    elements : int, optional
        ANCF elements.
    damping : str, optional
        Structural damping of the beams (:func:`mbs_models.damping.parse_damping`; default the configuration's).
    bending_damping, axial_damping : float
        Added to ``damping``: Exudyn's bendingDamping and axialDamping.
    small_multipliers : str
        ``flag`` or ``qr`` (multipliers below the rounding floor).
    rtol : float, optional
        The accuracy contract (default the configuration's).
    """

    model: str = "reduced"
    omega: Optional[float] = None
    kp: tuple = (0.0,)
    kd: tuple = (0.0,)
    constants: str = "auto"
    samples: Optional[int] = None
    method: Optional[str] = None
    elements: Optional[int] = None
    damping: Optional[str] = None
    bending_damping: float = 0.0
    axial_damping: float = 0.0
    small_multipliers: str = "flag"
    rtol: Optional[float] = None


def check_floquet_options(opts: FloquetOptions) -> None:
    """The checks of the options alone (before the configuration and any numerical import).

    Raises
    ------
    ValueError
        One line naming the option (as ``flexstab floquet`` spells it) and the problem.
    """
    if opts.model == "reduced":
        if len(opts.kp) != 1 or len(opts.kd) != 1:
            raise ValueError(f"--model {opts.model} has one drive (the hub): give one --kp and one --kd value")
        if opts.samples is not None:
            raise ValueError("--samples applies to model files only")
    else:
        if opts.samples is not None and (opts.samples < 4 or opts.samples % 2):
            raise ValueError(f"--samples must be an even integer >= 4, got {opts.samples}")
        check_model_arg(opts.model)


def floquet_analysis(opts: FloquetOptions, cfg: Any) -> dict:
    """The Floquet analysis of ``opts`` for the configuration ``cfg``: the JSON-ready dict of
    ``flexstab floquet --json``."""
    check_floquet_options(opts)
    builtin = opts.model == "reduced"
    from stability import DEFAULT_METHOD, METHODS, floquet

    from stability.floquet import DEFAULT_RTOL, recertify

    omega = opts.omega if opts.omega is not None else cfg.omega
    rtol = opts.rtol if opts.rtol is not None else cfg.rtol
    method = opts.method or (DEFAULT_METHOD if opts.model == "reduced" else "magnus2")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(sorted(METHODS))}")
    if not builtin:
        return _model_file_analysis(opts, cfg, omega, method, rtol)
    kp, kd = opts.kp[0], opts.kd[0]
    out: dict = {"model": opts.model}
    damping = resolve_damping(opts, cfg)
    exudyn_only = [flag for flag, given in (("--elements", opts.elements is not None),
                                            ("--damping", damping.given)) if given]
    if exudyn_only:
        raise ValueError(f"{', '.join(exudyn_only)} applies to --model exudyn only and to model files "
                         "(built-in or PATH.py), not to --model reduced")
    from mbs_models.reduced import ReducedModel

    model = ReducedModel(omega=omega, kp=kp, kd=kd, params=cfg.manipulator, constants=opts.constants)
    # the engine refines to min(its default, rtol); certified against rtol
    res = floquet(model, method=method, small_multipliers=opts.small_multipliers, rtol=min(DEFAULT_RTOL, rtol))
    out["constants"] = opts.constants
    out.update(
        {
            "omega": omega,
            "period": 2 * math.pi / omega,
            "kp": kp,
            "kd": kd,
        }
    )
    res = recertify(res, rtol)
    out.update(res.to_dict())
    if "verdict_detail" not in out:  # the reduced model: no mode labels
        from stability.verdict import judge_floquet

        out["verdict_detail"] = judge_floquet(res).to_dict()
    return out


def _model_file_analysis(opts: FloquetOptions, cfg: Any, omega: float, method: str, rtol: float) -> dict:
    """Floquet analysis of a model file (``--model PATH.py`` or a built-in model file)."""
    from linearize.analysis import analyze
    from linearize.periodic_orbit import DEFAULT_SAMPLES
    from flexstab.options import resolve_model_definition

    damping = resolve_damping(opts, cfg)
    model, options = resolve_model_definition(opts.model, cfg, opts.elements, **damping.build_options())
    samples = opts.samples if opts.samples is not None else DEFAULT_SAMPLES
    res = analyze(model, omega, kp=opts.kp, kd=opts.kd, samples=samples, method=method,
                  small_multipliers=opts.small_multipliers, rtol=rtol, **options)
    out = {"model": opts.model}
    out.update(res.summary())
    out["model"] = opts.model
    out.update({"omega": omega, "period": 2 * math.pi / omega, "kp": list(res.kp), "kd": list(res.kd)})
    out["damping"] = damping.to_dict()
    if opts.model == "exudyn":  # the keys of the paper's link (besides the model file's)
        from mbs_models.damping import material_damping_values

        p = cfg.manipulator
        bending, axial = material_damping_values(damping.material, p.bending_stiffness, p.axial_stiffness,
                                                 damping.bending, damping.axial)
        out.update({"elements": options["elements"], "reference": "periodic", "dominant_mode": res.dominant_mode,
                    "undamped_multipliers": res.undamped_count, "bending_damping": bending,
                    "axial_damping": axial})
    out.update(res.floquet.to_dict())
    # the verdict of the labelled rule (the same rule; an autonomous orbit's structural multiplier left out)
    out["verdict"] = out["verdict_detail"]["verdict"]
    return out
