#!/usr/bin/env python3
"""Reproduce Figs. 2-9 of the paper: transient response of the linearised manipulator.

Thin wrapper of :func:`flexstab.transients.make_transients` (see its module
docstring for what the figures show and how the envelope is drawn).
Options: ``--out DIR`` (default ``results/``), ``--with-forcing``,
``--figures N [N ...]`` (subset of 2..9), ``--quick`` (figures 5 and 9 only,
fewer periods and samples; for the tests), ``--measure-periods``.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Optional, Sequence

from flexstab.transients import FULL, QUICK, Settings, make_transients


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="results", help="output folder (default results/)")
    ap.add_argument("--with-forcing", action="store_true",
                    help="include h_L (Eq. 24) in the plotted response; the homogeneous one is drawn in grey")
    ap.add_argument("--quick", action="store_true",
                    help="figures 5 and 9 only, fewer periods and samples (for tests)")
    ap.add_argument("--figures", type=int, nargs="+", choices=range(2, 10), metavar="N",
                    help="paper figure numbers to make (2..9; default all, or 5 9 with --quick)")
    ap.add_argument("--measure-periods", type=int, default=None,
                    help="periods integrated for the growth measurement of the uncontrolled cases (default 8)")
    args = ap.parse_args(argv)
    settings = QUICK if args.quick else FULL
    if args.measure_periods is not None:
        if args.measure_periods < 2:
            ap.error("--measure-periods must be >= 2")
        settings = Settings(**{**settings.__dict__, "measure_uncontrolled": args.measure_periods})
    doc = make_transients(Path(args.out), quick=args.quick, with_forcing=args.with_forcing,
                          figures=args.figures, settings=settings)
    for s in doc["cases"]:
        print(
            f"{s['figure_file']}: rho1={s['spectral_radius']:.6g}  last ratio={s['last_ratio']:.6g} "
            f"({s['last_ratio_relative_error']:+.2%})  fit={s['fitted_ratio']:.6g}  "
            f"[{s['integrator']}, {s['nfev']} fev]"
        )
    print(f"wrote {len(doc['cases'])} figures to {args.out}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
