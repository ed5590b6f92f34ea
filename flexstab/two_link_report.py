"""The study's two-link section: one stage function and its report blocks.

Everything the section shows is computed by the stage, at the study Omega (~20-40 s
CPU, most of it the tuning): the periodic orbit and linearisation of the built-in
two-link arm, its labelled Floquet multipliers uncontrolled (the dominant one measured
by Hill's method), the four-gain Taguchi tuning to rho_d, the multipliers at the tuned
gains, an independent check of the tuned value (the frozen-modal product, no Hill
code) and figures of the poses and of the dominant Floquet mode.

The longer studies of the arm (mesh convergence, robust design, direct optimisers,
the streamed-product check at 32768 steps) are ``scripts/two_link_study.py``'s; its
stage files carry the keys they were computed with (:func:`cache_keys`: the code hash
of the packages and of the script, the mesh, the gain ranges, rho_d and the stage's
own arguments), and :func:`fresh_parts` keeps the parts computed with given keys.
"""
from __future__ import annotations

import hashlib
import json
import math
import time
import types
from pathlib import Path
from typing import Any, Optional, Sequence

from flexstab.report import figure, table, text
from flexstab.stages import StageOutput
from stability.gains import Gains

__all__ = ["stage_two_link", "CHECK_MODAL_STEPS", "CACHE_NAME", "CACHE_PARTS", "cache_keys", "fresh_parts",
           "script_hash"]

#: File written by ``scripts/two_link_study.py`` into its output folder.
CACHE_NAME = "two_link.json"
#: Parts (stages) of the script's results, each with its own keys under ``keys[part]``.
CACHE_PARTS = ("tune", "mesh", "robust", "direct", "figures")


#: The script whose stage files :func:`cache_keys` keys (its constants -- the mesh levels, the direct stage's
#: elements -- change the numbers, and it is not one of the hashed packages).
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "two_link_study.py"


def script_hash() -> Optional[str]:
    """SHA-256 of :data:`SCRIPT`, or ``None`` when the package is installed without it."""
    return hashlib.sha256(SCRIPT.read_bytes()).hexdigest() if SCRIPT.exists() else None


def cache_keys(target: float, args: Optional[dict] = None) -> dict:
    """What the script's numbers depend on besides Omega (each part is stored per Omega): the
    SHA-256 of the packages' source (:func:`flexstab.provenance.code_hash`, as ``chart --model`` keys its
    stores) and of the script (:func:`script_hash`), the default mesh, the four-gain ranges and rho_d;
    with ``args``, the stage's own command-line arguments (e.g. the robust stage's ``grid``,
    ``robust_iterations``) under ``args``.  JSON-normalised (comparable with a file's)."""
    from flexstab.provenance import code_hash
    from flexstab.two_link import TUNING_RANGES
    from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

    keys = {"code": code_hash(), "script": script_hash(), "elements": DEFAULT_ELEMENTS,
            "ranges": [list(r) for r in TUNING_RANGES], "target": float(target)}
    if args is not None:
        keys["args"] = dict(args)
    return json.loads(json.dumps(keys))


def fresh_parts(cache: dict, expected: dict) -> tuple[dict, list]:
    """The parts of ``cache`` (the script's merged JSON) computed with the ``expected`` keys, and one
    note per part ignored (keys missing or different, naming the keys that differ).

    Only the keys in ``expected`` are compared: a part's stage arguments (``args``, e.g. the robust
    grid) are the script run's choice, recorded with it, not something the study can expect."""
    keys = cache.get("keys") or {}
    fresh: dict = {}
    notes = []
    for part in CACHE_PARTS:
        if part not in cache:
            continue
        k = keys.get(part)
        if k and all(n in k and k[n] == v for n, v in expected.items()):
            fresh[part] = cache[part]
            continue
        diff = sorted(n for n in expected if (k or {}).get(n, ...) != expected[n])
        notes.append(f"`{part}` ignored: " + ("computed without keys (an older script)" if not k else
                                               "computed with other " + ", ".join(diff)))
    if fresh and "target" in cache:
        fresh["target"] = cache["target"]
    return fresh, notes


def _mode_rows(fl: Any) -> str:
    """The Hill-refined multipliers of the drive modes / first bending mode (one of each conjugate pair)."""
    return ", ".join(f"{abs(z):.5g} ({label})" for label, z in fl.measure.refined)


#: Steps of the independent check of the tuned value: the exponential midpoint in frozen-modal
#: coordinates (:func:`stability.modal.modal_floquet`), Richardson-extrapolated from these and half as
#: many (fourth order, with its own error estimate; no Hill code).  Measured at the 2 pi gains:
#: estimate 2e-5 against the tuning tolerance 3e-4, 0.4 s CPU.
CHECK_MODAL_STEPS = 512


def _check_tuned(lin: Any, gains: Sequence[float], near: complex) -> dict:
    """The tuned dominant multiplier by the frozen-modal product (independent of the loop's Hill response)."""
    import numpy as np

    from stability.engines import floquet

    g = Gains.from_interleaved(gains)
    r = floquet(lin.with_gains(g.kp, g.kd), method="modal", order=2, n_steps=CHECK_MODAL_STEPS, extrapolate=True)
    w = np.asarray(r.multipliers)
    z = complex(w[int(np.argmin(np.abs(w - near)))])
    return {"method": f"frozen-modal magnus2, {CHECK_MODAL_STEPS}/{CHECK_MODAL_STEPS // 2} steps extrapolated",
            "multiplier": [z.real, z.imag], "modulus": abs(z), "error_estimate": float(r.error_estimate)}


def _cpu() -> float:
    """CPU seconds of this process and of its finished child processes (the tuning's pool)."""
    import resource

    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def stage_two_link(cfg: Any, opts: Any) -> StageOutput:
    """Stage function for :data:`flexstab.study.STAGES` (signature ``(cfg, opts) -> StageOutput``).

    At the study Omega: the orbit and linearisation of the built-in two-link arm, its labelled
    multipliers uncontrolled, the four-gain Taguchi tuning to the study's rho_d (Hill response,
    :func:`flexstab.two_link.tune_four_gains`, ranges :data:`flexstab.two_link.TUNING_RANGES`),
    the labelled multipliers at the tuned gains, an independent check of the tuned value
    (:func:`_check_tuned`) and the pose and mode figures.  Everything the section shows is
    computed here.
    """
    from flexstab.arm_figures import plot_floquet_mode, plot_poses
    from flexstab.plants import whole_spectrum
    from flexstab.report import pi_multiple as _pi
    from flexstab.two_link import TUNING_RANGES, tune_four_gains, two_link_floquet

    out = Path(opts.out)
    omega = float(cfg.omega)
    target = float(getattr(cfg, "target", 0.3))
    k = omega / math.pi
    tag = f"{k:.4g}pi".replace(".", "p")
    unc = two_link_floquet(omega)
    from flexstab.executor import make_executor

    # the tuning is most of the stage: the 9 runs of each experiment on 2 processes, so that the section's
    # process is not the study's longest chain (CPU: this process + the pool's, RUSAGE_CHILDREN)
    c0 = _cpu()
    with make_executor("process", max_workers=2) as ex:
        tuned = tune_four_gains(unc.linearization, target, orbit=unc.orbit, executor=ex)
    tune_cpu = _cpu() - c0
    g = list(tuned.gains)
    ctl = two_link_floquet(omega, gains=g, orbit=unc.orbit, lin=unc.linearization)
    check = _check_tuned(unc.linearization, g, ctl.measure.dominant)
    tol = tuned.tolerance
    confirmed = bool(abs(check["modulus"] - target) <= tol + check["error_estimate"])
    row: dict = {"omega": omega, "omega_over_pi": k, "elements": unc.elements, "target": target,
                 "tuning": {"gains": g, "names": list(tuned.names), "ranges": [list(r) for r in TUNING_RANGES],
                            "status": tuned.status, "message": tuned.message, "converged": tuned.converged,
                            "response": tuned.spectral_radius, "tolerance": tol,
                            "evaluations": tuned.evaluations, "iterations": len(tuned.iterations),
                            "cpu_seconds": tune_cpu},
                 "tuned_gains": g, "gains_source": "Taguchi tuning in this stage (tuning)",
                 "check": dict(check, confirmed=confirmed)}
    for label, fl in (("uncontrolled", unc), ("tuned", ctl)):
        row[label] = {
            "dominant": [fl.measure.dominant.real, fl.measure.dominant.imag],
            "dominant_modulus": abs(fl.measure.dominant), "mode": fl.measure.mode,
            "hill_error_estimate": fl.measure.hill_error_estimate,
            "labelled": [{"modulus": float(abs(mu)), "mode": m.mode, "undamped": m.undamped}
                         for mu, m in zip(fl.floquet.multipliers, fl.modes) if abs(mu) > 1e-6][:12],
            "cpu_seconds": fl.cpu_seconds,
        }
    tuned_gains = Gains.from_interleaved(g)
    whole = whole_spectrum(ctl.orbit, omega, tuned_gains.kp, tuned_gains.kd)
    row["tuned"]["whole_spectrum"] = whole
    poses = plot_poses(unc.orbit, out / f"two_link_poses_{tag}.png",
                       title=f"Two-link arm on its periodic orbit, Ω = {_pi(omega)} rad/s").name
    res = types.SimpleNamespace(floquet=ctl.floquet, modes=ctl.modes, orbit=ctl.orbit,
                                linearization=ctl.linearization.with_gains(tuned_gains.kp, tuned_gains.kd),
                                dominant_multiplier=ctl.measure.dominant)
    # the title shows the modulus the table shows (Hill's), not the labelling product's; the shape is that
    # product's eigenvector nearest Hill's multiplier
    measured = (ctl.measure.dominant, f"Hill's method, {ctl.harmonics} harmonics")
    mode_png = f"two_link_mode_{tag}.png"
    mode_fig = plot_floquet_mode(res, out / mode_png, measured=measured)
    row["tuned"]["mode_figure"] = {"file": mode_png, "modulus": abs(ctl.measure.dominant), "method": measured[1],
                                   "deformation_scale_m": mode_fig.scale_m}
    # "cache" stays for readers of earlier files: the stage reads no cached results (always null)
    doc = {"omegas_over_pi": [k], "cache": None, "rows": [row], "figures": [poses, mode_png]}
    (out / "two_link.json").write_text(json.dumps(doc, indent=2, default=str))
    t = row["tuning"]
    names = ", ".join(tuned.names)
    rows_tab = [[f"{_pi(omega)}", unc.elements, f"{abs(unc.measure.dominant):.6f} ({unc.measure.mode})",
                 _mode_rows(unc), ", ".join(f"{v:.4g}" for v in g),
                 f"{abs(ctl.measure.dominant):.6f} ({ctl.measure.mode})",
                 f"{check['modulus']:.6f} ± {check['error_estimate']:.0e}",
                 f"{abs(abs(ctl.measure.dominant) - target) / target:.1e}",
                 f"{whole['spectral_radius_all']:.4f} ({whole['spectral_radius_all_mode']}, "
                 f"{(whole['spectral_radius_all_frequency_hz'] or 0) / 1e3:.1f} kHz)",
                 t["evaluations"], f"{tune_cpu:.1f}"]]
    ranges = "; ".join(f"{s} {lo:g}–{hi:g}" for s, (lo, hi) in zip(tuned.names, TUNING_RANGES))
    blocks = [
        text("Built-in two-link flexible arm (`--model two-link`): shoulder q1 = π/2 + (π/4) sin Ωt, elbow "
             f"q2 = (π/4) sin Ωt, {unc.elements} ANCF elements per link, four PD gains ({names}). Multipliers: "
             "`magnus2` (512 steps) for all of them and their mode labels; the dominant one (drive modes / first "
             "bending mode) measured by Hill's method (`stability.hill`; its H vs H/2 estimate is in the JSON)."),
        text(f"Four-gain Taguchi tuning (L9, iterated) to ρ_d = {target:g} in this stage, response = that dominant "
             f"multiplier by Hill's method, from the ranges {ranges} (N·m/rad, N·m·s/rad): {t['status']} after "
             f"{t['evaluations']} evaluations in {t['iterations']} iterations ({tune_cpu:.1f} s CPU). Checked by an "
             f"independent method without Hill code: {check['method']} (its own error estimate beside the value): "
             + ("confirmed" if confirmed else "**not confirmed**") + f" within ρ_d ± {tol:.1e}."),
        table(["Ω (rad/s)", "el./link", "uncontrolled: dominant |ρ|",
               "uncontrolled: drive / bending-1 multipliers (Hill)", f"tuned gains {names}",
               "tuned: dominant |ρ| (Hill)", "independent check |ρ|", "|ρ − ρ_d| / ρ_d",
               "tuned: whole-spectrum max|ρ| (mode)", "evaluations", "tuning CPU s"], rows_tab),
        text("The whole-spectrum column is the spectral radius of the whole linearisation at the tuned gains "
             "(frozen-modal product, every mode) with its mode: on this mesh an axial pair of the discretisation, "
             "lightly damped through the joints, hardly moved by the gains and not converged under mesh "
             "refinement, so it is reported, not tuned. Mesh convergence, the robust design and the comparison "
             "with direct optimisers are not part of the study (`scripts/two_link_study.py`, minutes of CPU)."),
        figure(poses, f"The two-link arm at 12 instants of one period on its periodic orbit (Ω = {_pi(omega)} "
                      "rad/s), coloured by time; dotted: the tip path. Poses half a period apart coincide when the "
                      "motion is symmetric."),
        figure(mode_png, f"Floquet mode of the dominant multiplier at the tuned gains (|ρ| = "
                         f"{abs(ctl.measure.dominant):.6f}, {ctl.measure.mode}; Hill's method, {ctl.harmonics} "
                         f"harmonics, as in the table) at 8 instants of the period: grey the orbit pose, red the pose "
                         f"plus the T-periodic mode. A mode has no amplitude of its own: it is drawn with its largest "
                         f"displacement equal to {mode_fig.scale_m:.3g} m (8 % of the arm's reach); the shape is the "
                         "512-step labelling product's eigenvector nearest Hill's multiplier."),
    ]
    if not tuned.converged:
        blocks.insert(2, text(f"**Tuning did not reach ρ_d:** {tuned.message}."))
    return StageOutput(json="two_link.json", title=f"Two-link flexible arm at Ω = {_pi(omega)} rad/s", blocks=blocks,
                       files=("two_link.json", poses, mode_png))
