"""``flexstab modes``: natural frequencies of the Exudyn link beside Euler-Bernoulli theory."""
from __future__ import annotations

import argparse
import contextlib
import sys

from flexstab.options import dump_json, result_output

__all__ = ["register", "run", "modes_report"]


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def register(sub) -> None:
    """Add the ``modes`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    p = sub.add_parser(
        "modes",
        help="natural frequencies of the Exudyn ANCF link (hub clamped or pinned)",
        description=(
            "Natural frequencies of the Exudyn ANCF link with tip mass (gravity off), "
            "beside the Euler-Bernoulli frequency equation where it applies."
        ),
    )
    p.add_argument("--config", metavar="FILE", help="TOML file describing the manipulator (see README)")
    p.add_argument("--elements", type=_positive_int, default=None, help="ANCF elements (default 8)")
    p.add_argument("--hub", choices=["clamped", "pinned"], default="clamped", help="hub boundary condition")
    p.add_argument("--count", type=_positive_int, default=4, help="number of frequencies (default 4)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def modes_report(args: argparse.Namespace) -> dict:
    """Compute the frequencies requested by ``args``; return the JSON-ready dict."""
    from mbs_models.modes import exudyn_frequencies
    from mbs_models.parameters import ManipulatorParameters

    params = ManipulatorParameters()
    elements = args.elements
    if getattr(args, "config", None):
        from flexstab.config import load_config

        cfg = load_config(args.config)
        params = cfg.manipulator
        if elements is None:
            elements = cfg.elements
    elements = 8 if elements is None else elements
    # analytic values exist for the bending modes; give as many as asked for
    # Exudyn prints its warnings (e.g. "more than 1000 coordinates, consider a sparse solver") through
    # Python's stdout: send them to stderr so that stdout holds only the table or the JSON object
    from mbs_models.console import exudyn_console  # Exudyn is imported only by the commands that use it

    with contextlib.redirect_stdout(sys.stderr), exudyn_console(quiet=bool(getattr(args, "json", False))):
        res = exudyn_frequencies(params, elements=elements, hub=args.hub, count=args.count,
                                 analytic_count=args.count)
    out = res.to_dict()
    # only bending modes have an Euler-Bernoulli value: keep the analytic list
    # as long as the Exudyn frequencies it matches (within 5 %)
    matched = []
    for f, fa in zip(out["frequencies_hz"], out["analytic_hz"]):
        if abs(f - fa) > 0.05 * fa:
            break
        matched.append(fa)
    out["analytic_hz"] = matched
    out["relative_errors"] = out["relative_errors"][: len(matched)]
    return out


def run(args: argparse.Namespace) -> int:
    """Run ``flexstab modes``; return the exit code."""
    out = modes_report(args)
    with result_output(args):
        return _print_modes(args, out)


def _print_modes(args: argparse.Namespace, out: dict) -> int:
    if args.json:
        dump_json(out, sys.stdout)
        return 0
    lines = [
        f"Exudyn ANCF link, {out['elements']} elements, hub {out['hub']}"
        + (f" ({out['rigid_modes']} rigid-body mode at 0 Hz not listed)" if out["rigid_modes"] else ""),
        "",
        f"{'#':>3}  {'Exudyn (Hz)':>14}  {'Euler-Bernoulli (Hz)':>20}  {'rel. error':>11}",
    ]
    for i, f in enumerate(out["frequencies_hz"]):
        if i < len(out["analytic_hz"]):
            fa, e = out["analytic_hz"][i], out["relative_errors"][i]
            lines.append(f"{i + 1:>3}  {f:>14.6f}  {fa:>20.6f}  {e:>11.3e}")
        else:
            lines.append(f"{i + 1:>3}  {f:>14.6f}  {'-':>20}  {'-':>11}")
    sys.stdout.write("\n".join(lines) + "\n")
    return 0
