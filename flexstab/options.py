"""Parsing helpers shared by the command-line sub-commands."""
from __future__ import annotations

import argparse
import math
import re
from pathlib import Path

__all__ = ["dump_json", "resolve_omega", "parse_omega", "omega_type", "add_model_options", "non_negative_float",
           "positive_float", "gain_list", "is_model_file", "resolve_model_definition", "ensure_out_dir", "gain_pairs",
           "check_range_arg", "check_model_arg", "result_output", "gains_as_lists", "GAIN_FIELDS",
           "add_damping_option", "resolve_damping", "EXUDYN_ALIAS", "model_route"]

_PI_FORM = re.compile(r"^\s*([-+]?[0-9]*\.?[0-9]*(?:[eE][-+]?[0-9]+)?)\s*\*?\s*pi\s*$", re.IGNORECASE)


def parse_omega(text: str) -> float:
    """Parse an angular frequency: rad/s (``"6.283"``) or a multiple of pi (``"2pi"``, ``"0.5pi"``, ``"pi"``).

    Raises
    ------
    ValueError
        If the text is not a number or a multiple of pi, or the value is not finite and > 0.
    """
    s = str(text).strip()
    m = _PI_FORM.match(s)
    try:
        if m:
            sign = -1.0 if m.group(1).startswith("-") else 1.0
            digits = m.group(1).lstrip("+-")
            factor = sign * (float(digits) if digits not in ("", ".") else 1.0)
            value = factor * math.pi
        else:
            value = float(s)
    except ValueError:
        raise ValueError(f"omega must be rad/s or a multiple of pi like '2pi', got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"omega must be finite, got {text!r}")
    if value <= 0:
        raise ValueError(f"omega must be positive, got {text!r}")
    return value


def omega_type(text: str) -> float:
    """``argparse`` type for :func:`parse_omega`."""
    try:
        return parse_omega(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _float_type(lower: float, strict: bool, what: str):
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value) or (value <= lower if strict else value < lower):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return value

    return convert


non_negative_float = _float_type(0.0, False, "finite and >= 0")


def gain_list(text: str) -> tuple:
    """``argparse`` type: one gain or a comma-separated list (one per drive), each finite and >= 0."""
    parts = [p for p in str(text).split(",")]
    if not parts or any(not p.strip() for p in parts):
        raise argparse.ArgumentTypeError(f"expected a number or a comma-separated list like 10,2, got {text!r}")
    return tuple(non_negative_float(p.strip()) for p in parts)


#: ``--model exudyn`` is the paper's Exudyn ANCF link: the built-in model file ``single-link`` with the
#: configured manipulator (default the paper's Table 1), on the generic model-file path.
EXUDYN_ALIAS = "single-link"


def model_route(model: str) -> str:
    """The model a ``--model`` name is computed with: ``exudyn`` -> :data:`EXUDYN_ALIAS`, else itself."""
    return EXUDYN_ALIAS if model == "exudyn" else model


def is_model_file(model: str) -> bool:
    """Whether ``--model`` names a model file (a ``.py`` path) rather than a built-in model."""
    return str(model).endswith(".py")


def check_model_arg(model) -> None:
    """The check of ``--model`` before any import: a model file ``PATH.py`` must exist.

    Raises
    ------
    ValueError
        The model file is missing (the message of :func:`mbs_models.model_file.load_model_file`).
    """
    if model is not None and is_model_file(model) and not Path(model).is_file():
        raise ValueError(f"model file {str(model)!r} not found")


def check_range_arg(rng, flag: str) -> None:
    """The check of a ``--kp-range LO HI`` style option before any import: finite, ``0 <= LO < HI``.

    Raises
    ------
    ValueError
        Naming the option and its values.
    """
    if rng is None:
        return
    lo, hi = rng
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{flag} must be finite, got {lo:g} {hi:g}")
    if lo < 0:
        raise ValueError(f"{flag}: gains must be >= 0, got LO = {lo:g}")
    if not lo < hi:
        raise ValueError(f"{flag} is empty or inverted: LO = {lo:g}, HI = {hi:g}")


def resolve_model_definition(model: str, cfg, elements=None, **builtin_options):
    """The one ``--model`` rule of every command for model files: ``(definition, build options)``.

    * ``exudyn``: :data:`EXUDYN_ALIAS` (``single-link``, below);
    * a model file ``PATH.py``: its own defaults; ``--elements`` and the ``builtin_options``
      that are set (non-zero damping, ...) are rejected, they apply to built-in models only;
    * ``single-link``: the configured link (``cfg.manipulator``) with ``--elements`` or the
      configuration's ``elements``;
    * any other built-in (``two-link``): its own default mesh unless ``--elements`` is given
      (the configuration's ``elements`` describes the single link).

    ``builtin_options`` (e.g. ``bending_damping``) are passed to a built-in's ``build`` when set.

    Raises
    ------
    ValueError
        Unknown model name, or options that do not apply to a model file.
    """
    from mbs_models.model_file import BUILTIN_MODELS, builtin_model, load_model_file

    model = model_route(model)
    given = {k: v for k, v in builtin_options.items() if v}
    if is_model_file(model):
        material = given.pop("material_damping", None)
        if elements is not None or given:
            flags = (["--elements"] if elements is not None else []) + ["--" + k.replace("_", "-") for k in given]
            raise ValueError(f"{', '.join(flags)} applies to built-in models only, not to a model file")
        definition = load_model_file(model)
        if material:
            # the model-file contract: a build that accepts material_damping receives --damping's beta
            import inspect

            params = inspect.signature(definition.build).parameters
            if "material_damping" not in params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
                raise ValueError(f"--damping: the model file {model} takes no material damping (its build has no "
                                 f"material_damping keyword; see docs/verdicts.md)")
            return definition, {"material_damping": material}
        return definition, {}
    if model not in BUILTIN_MODELS:
        raise ValueError(f"unknown model {model!r}: use reduced, exudyn, {', '.join(sorted(BUILTIN_MODELS))} "
                         f"or a model file PATH.py")
    options = dict(given)
    if model == "single-link":
        options.update(elements=elements if elements is not None else cfg.elements, params=cfg.manipulator)
    elif elements is not None:
        options["elements"] = elements
    return builtin_model(model), options


positive_float = _float_type(0.0, True, "finite and > 0")


def add_damping_option(parser: argparse.ArgumentParser) -> None:
    """``--damping``: structural damping of the beams (:mod:`mbs_models.damping`)."""
    parser.add_argument("--damping", default=None, metavar="SPEC",
                        help="structural damping of the beam elements: BETA, the Kelvin-Voigt loss time in s "
                             "(bendingDamping = BETA EI, axialDamping = BETA EA; e.g. 1e-5), or "
                             "beta=B,bending=X,axial=Y (Exudyn's values added); default [study] damping, else none")


def resolve_damping(args: argparse.Namespace, cfg):
    """The one damping rule: ``--damping`` if given, else ``[study] damping``; the raw
    ``--bending-damping`` / ``--axial-damping`` values (where a command has them) are added.

    Returns
    -------
    mbs_models.damping.DampingSpec
    """
    import dataclasses

    from mbs_models.damping import parse_damping

    text = getattr(args, "damping", None)
    spec = parse_damping(text) if text is not None else getattr(cfg, "damping", None) or parse_damping(None)
    extra_b = float(getattr(args, "bending_damping", 0.0) or 0.0)
    extra_a = float(getattr(args, "axial_damping", 0.0) or 0.0)
    if extra_b or extra_a:
        spec = dataclasses.replace(spec, bending=spec.bending + extra_b, axial=spec.axial + extra_a)
    return spec


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """Options shared by the commands that build a manipulator model."""
    parser.add_argument("--config", metavar="FILE", help="TOML file describing the manipulator (see README)")
    parser.add_argument(
        "--constants",
        choices=["auto", "paper", "derived"],
        default="auto",
        help="mode constants of the reduced model: paper (as printed, for the 0.9 m link), derived "
             "(from the clamped-free mode of the configured link), auto (default: paper for the paper's "
             "link length, derived otherwise)",
    )
    parser.add_argument(
        "--omega",
        type=omega_type,
        default=None,
        metavar="W",
        help="frequency of the fundamental motion, rad/s or like '2pi' (default: [study] omega of --config, else 2pi)",
    )


def resolve_omega(args: argparse.Namespace, cfg) -> float:
    """The one Omega rule of every command: ``--omega`` if given, else ``[study] omega`` of the config (2pi)."""
    omega = getattr(args, "omega", None)
    return float(omega) if omega is not None else float(cfg.omega)


def result_output(args: argparse.Namespace):
    """Context in which a command prints its result: to the real standard output.

    :func:`flexstab.cli.main` sends everything else written to ``sys.stdout`` while a command runs
    (Exudyn's solver banners and warnings, any library's console output) to stderr, so that stdout holds
    the table or the ``--json`` object only; it keeps the real stream as ``args.result_stdout``.
    Without it (a command's ``run`` called directly) the current ``sys.stdout``.
    """
    import contextlib
    import sys

    return contextlib.redirect_stdout(getattr(args, "result_stdout", None) or sys.stdout)


#: Fields holding gains: in every command's JSON each is an array with one number per drive, in the
#: order of the model's drives (the single link: one element), whatever the model (docs/running.md).
GAIN_FIELDS = ("kp", "kd")


def gains_as_lists(d: dict) -> dict:
    """Apply the JSON typing rule of :data:`GAIN_FIELDS` to ``d`` (in place; returned): a number
    becomes a one-element list, a tuple a list; ``None`` stays ``None``."""
    for key in GAIN_FIELDS:
        v = d.get(key)
        if v is None:
            continue
        d[key] = [float(x) for x in v] if isinstance(v, (list, tuple)) else [float(v)]
    return d


def dump_json(obj, fp) -> None:
    """Write ``obj`` as strict JSON (numpy types converted, NaN/inf as ``null``) and a newline."""
    import json

    from stability.serialization import json_ready

    fp.write(json.dumps(json_ready(obj), allow_nan=False, default=str))
    fp.write("\n")


def ensure_out_dir(path) -> Path:
    """Create the output folder ``path`` (and its parents) if missing; return it as a Path.

    Raises
    ------
    ValueError
        The folder cannot be created (one line naming it and the reason).
    """
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create output folder {str(out)!r}: {exc.strerror or exc}") from None
    return out


def gain_pairs(gains, n_drives: int):
    """``(kp, kd)`` of interleaved gains ``(kp1, kd1, kp2, kd2, ...)`` of ``n_drives`` drives: scalars for one
    drive, lists otherwise (:class:`stability.gains.Gains`)."""
    from stability.gains import Gains

    g = Gains.from_interleaved(gains)
    if g.drives != n_drives:
        raise ValueError(f"gains: {n_drives} (kp, kd) pairs expected, got {g.drives}")
    return (g.kp[0], g.kd[0]) if n_drives == 1 else (list(g.kp), list(g.kd))
