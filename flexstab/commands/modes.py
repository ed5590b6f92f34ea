"""``flexstab modes``: natural frequencies of the Exudyn link beside Euler-Bernoulli theory (the command line
of :func:`flexstab.mode_runs.natural_frequencies`)."""
from __future__ import annotations

import argparse
import contextlib
import sys

from flexstab.options import dump_json, result_output

__all__ = ["register", "run", "modes_options", "modes_report"]


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


def modes_options(args: argparse.Namespace) -> "ModesOptions":
    """The :class:`~flexstab.mode_runs.ModesOptions` of the parsed command line."""
    from flexstab.mode_runs import ModesOptions

    return ModesOptions(elements=args.elements, hub=args.hub, count=args.count)


def modes_report(args: argparse.Namespace) -> dict:
    """``flexstab modes``: :func:`flexstab.mode_runs.natural_frequencies` of the command line (``--config``'s
    link if given); return the JSON-ready dict."""
    from flexstab.mode_runs import check_modes_options, natural_frequencies

    opts = modes_options(args)
    check_modes_options(opts)
    cfg = None
    if getattr(args, "config", None):
        from flexstab.config import load_config

        cfg = load_config(args.config)
    # Exudyn prints its warnings (e.g. "more than 1000 coordinates, consider a sparse solver") through
    # Python's stdout: send them to stderr so that stdout holds only the table or the JSON object
    from mbs_models.console import exudyn_console  # Exudyn is imported only by the commands that use it

    with contextlib.redirect_stdout(sys.stderr), exudyn_console(quiet=bool(getattr(args, "json", False))):
        return natural_frequencies(opts, cfg).to_dict()


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
