"""``flexstab study``: the whole study on the built-in (or a configured) manipulator."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from flexstab.options import add_damping_option, omega_type

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser(
        "study",
        help="run the whole study and write report.md / report.html",
        description="Tables 2 and 3, charts, transients, the Exudyn model and nonlinear validation, "
        "written as one report with every number traceable to a JSON file beside it.",
    )
    p.add_argument("--config", metavar="FILE", help="TOML file describing the manipulator")
    p.add_argument("--out", default="results", help="output folder (default results/)")
    p.add_argument("--quick", action="store_true", help="one case, coarse grids (about a minute)")
    p.add_argument("--stages", default=None, help="comma-separated subset of the stages")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="Dask scheduler for the sweeps")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="processes: 2 (default) runs the Exudyn stages beside the others; 1 runs all in one")
    p.add_argument("--no-resume", action="store_true",
                   help="recompute every stage (default: reuse finished stages whose inputs are unchanged)")
    p.add_argument("--model", default=None, metavar="MODEL",
                   help="study a model file PATH.py (or a built-in model file: single-link, two-link, laval-rotor, slider-crank) instead of "
                        "the paper's study: orbit, labelled multipliers, Taguchi-tuned gains of every drive, charts, "
                        "nonlinear validation (target and gain ranges from --config)")
    p.add_argument("--omega", type=omega_type, default=None, metavar="W",
                   help="--model: frequency of the periodic motion, rad/s or like '2pi' (default: [study] omega of "
                        "--config, else 2pi)")
    p.add_argument("--samples", type=int, default=None, help="--model: collocation samples per period (default 32)")
    p.add_argument("--elements", type=int, default=None,
                   help="--model: ANCF elements of a built-in model (default: its own; single-link: --config's)")
    add_damping_option(p)
    p.set_defaults(func=run)


def run_model(args: argparse.Namespace, cfg) -> int:
    """``flexstab study --model PATH.py``: :func:`flexstab.model_study.run_model_study`."""
    from flexstab.model_study import ModelStudyOptions, run_model_study
    from flexstab.progress import progress_bars
    from flexstab.options import resolve_omega
    from linearize.periodic_orbit import DEFAULT_SAMPLES

    for flag, bad in (("--stages", args.stages is not None), ("--scheduler", args.scheduler is not None),
                      ("--jobs", args.jobs != 2)):
        if bad:
            raise ValueError(f"{flag} applies to the paper's study, not to --model (a model study runs its "
                             "stages in this process, in order)")
    samples = args.samples if args.samples is not None else DEFAULT_SAMPLES
    if samples < 4 or samples % 2:
        raise ValueError(f"--samples must be an even integer >= 4, got {samples}")
    opts = ModelStudyOptions(out=Path(args.out), omega=resolve_omega(args, cfg), target=cfg.target,
                             kp_range=tuple(cfg.kp_range), kd_range=tuple(cfg.kd_range), samples=samples,
                             elements=args.elements,
                             quick=args.quick, progress=progress_bars(), log=_progress_log(),
                             resume=not args.no_resume)
    return _report_exit_code(run_model_study(args.model, cfg, opts), getattr(args, "result_stdout", None))


def _progress_log():
    """The project's progress rule: tqdm bars on a terminal stderr (``progress=isatty()``), else one line
    per stage event (this function, ``None`` on a terminal)."""
    if sys.stderr.isatty():
        return None
    return lambda line: print(line, file=sys.stderr, flush=True)


def _report_exit_code(res, stdout=None) -> int:
    """Print where the report is and one line per stage that failed or whose check failed; the exit code
    (1 if any, else 0)."""
    bad = [k for k, v in res.stages.items() if v.get("status") in ("failed", "check failed")]
    print(f"report: {res.report_md} and {res.report_html} ({res.elapsed:.1f} s)", file=stdout or sys.stdout)
    for k in bad:
        print(f"stage {k} {res.stages[k]['status']}: {res.stages[k].get('error', '')}", file=sys.stderr)
    return 1 if bad else 0


def run(args: argparse.Namespace) -> int:
    if args.model is None:  # the checks of the arguments alone, before any numerical import
        for flag in ("omega", "samples", "elements"):
            if getattr(args, flag) is not None:
                raise ValueError(f"--{flag} applies to --model (the paper's study takes [study] omega from --config)")
        if args.stages is not None and not args.stages.strip():
            raise ValueError("--stages is empty; name one or more of: table2, table3, charts, transients, exudyn, "
                             "validation, two_link, sensitivity")
        if args.jobs < 1:
            raise ValueError(f"--jobs must be >= 1, got {args.jobs}")
    else:
        from flexstab.options import check_model_arg

        if args.samples is not None and (args.samples < 4 or args.samples % 2):
            raise ValueError(f"--samples must be an even integer >= 4, got {args.samples}")
        check_model_arg(args.model)
    if args.scheduler:
        from flexstab.executor import validate_scheduler_address

        validate_scheduler_address(args.scheduler)  # fail before hours of work, not after
    from flexstab.config import load_config

    import dataclasses

    from flexstab.options import resolve_damping

    cfg = load_config(args.config)
    cfg = dataclasses.replace(cfg, damping=resolve_damping(args, cfg))  # --damping over [study] damping
    if args.model is not None:
        return run_model(args, cfg)
    from flexstab.study import StudyOptions, run_study

    stages = tuple(s.strip() for s in args.stages.split(",") if s.strip()) if args.stages else ()
    res = run_study(cfg, StudyOptions(out=Path(args.out), quick=args.quick, stages=stages,
                                      progress=sys.stderr.isatty(), scheduler=args.scheduler, log=_progress_log(),
                                      resume=not args.no_resume, jobs=args.jobs))
    return _report_exit_code(res, getattr(args, "result_stdout", None))
