"""Natural frequencies of the Exudyn link: the library half of ``flexstab modes``.

:func:`natural_frequencies` computes the lowest elastic natural frequencies of the Exudyn ANCF link with
its tip mass (gravity off, hub clamped or pinned; :func:`mbs_models.modes.exudyn_frequencies`) for a
:class:`ModesOptions`, beside the Euler-Bernoulli frequency equation where it applies: the analytic list
is kept as long as the Exudyn frequencies it matches within :data:`ANALYTIC_MATCH` (only bending modes
have an Euler-Bernoulli value; the first axial mode ends the list).
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Any, Optional

logger = logging.getLogger(__name__)

__all__ = ["ModesOptions", "natural_frequencies", "check_modes_options", "matched_analytic", "DEFAULT_ELEMENTS",
           "ANALYTIC_MATCH"]

#: ANCF elements unless given (or set by a configuration).
DEFAULT_ELEMENTS = 8
#: Largest relative distance at which an Exudyn frequency is the Euler-Bernoulli bending frequency beside it.
ANALYTIC_MATCH = 0.05


@dataclass(frozen=True)
class ModesOptions:
    """What :func:`natural_frequencies` computes.

    Attributes
    ----------
    elements : int, optional
        ANCF elements (default the configuration's, else :data:`DEFAULT_ELEMENTS`).
    hub : str
        ``clamped`` (hub held) or ``pinned`` (free to rotate with the hub inertia).
    count : int
        Number of elastic frequencies (bending and axial, ascending).
    """

    elements: Optional[int] = None
    hub: str = "clamped"
    count: int = 4


def check_modes_options(opts: ModesOptions) -> None:
    """The checks of the options alone (before the configuration and Exudyn).

    Raises
    ------
    ValueError
        One line naming the option (as ``flexstab modes`` spells it) and the problem.
    """
    from mbs_models.modes import HUB_CONDITIONS

    for flag, value in (("elements", opts.elements), ("count", opts.count)):
        if value is not None and (isinstance(value, bool) or int(value) != value or value < 1):
            raise ValueError(f"--{flag} must be a positive integer, got {value!r}")
    if opts.hub not in HUB_CONDITIONS:
        raise ValueError(f"--hub must be one of {', '.join(HUB_CONDITIONS)}, got {opts.hub!r}")


def matched_analytic(frequencies_hz, analytic_hz) -> list:
    """The leading Euler-Bernoulli frequencies that match the Exudyn frequencies beside them within
    :data:`ANALYTIC_MATCH` (the list stops at the first that does not: an axial mode has no bending value)."""
    matched = []
    for f, fa in zip(frequencies_hz, analytic_hz):
        if abs(f - fa) > ANALYTIC_MATCH * fa:
            break
        matched.append(float(fa))
    return matched


def natural_frequencies(opts: ModesOptions, cfg: Any = None) -> Any:
    """Natural frequencies of the link of ``cfg`` (a :class:`~flexstab.config.StudyConfig`; ``None``: the
    paper's Table 1 link and :data:`DEFAULT_ELEMENTS` unless ``opts.elements``).

    Returns
    -------
    mbs_models.modes.ModesResult
        Its ``analytic_hz`` cut to the matched bending frequencies (:func:`matched_analytic`), so
        ``relative_errors`` compares like with like; ``to_dict()`` is the ``flexstab modes --json`` object.
    """
    check_modes_options(opts)
    from mbs_models.modes import exudyn_frequencies
    from mbs_models.parameters import ManipulatorParameters

    params = cfg.manipulator if cfg is not None else ManipulatorParameters()
    elements = opts.elements
    if elements is None:
        elements = cfg.elements if cfg is not None else DEFAULT_ELEMENTS
    logger.info("natural frequencies: %d elements, hub %s, %d frequencies", elements, opts.hub, opts.count)
    # analytic values exist for the bending modes only: ask for as many as frequencies, keep the matched ones
    res = exudyn_frequencies(params, elements=elements, hub=opts.hub, count=opts.count, analytic_count=opts.count)
    import numpy as np

    return dataclasses.replace(res, analytic_hz=np.asarray(matched_analytic(res.frequencies_hz, res.analytic_hz)))
