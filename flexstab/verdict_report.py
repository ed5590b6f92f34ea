"""The verdict block at the top of the study report and of ``study.json``.

Three lines a reader needs first -- *uncontrolled*, *tuned*, *nonlinear check* -- in words and
numbers, each from the JSON file of the stage that computed it (``table2.json``, ``exudyn.json``,
``validation.json``, ``sensitivity.json``, and the two-link arm's ``two_link.json``) and each consistent with the verdict rule of
:mod:`stability.verdict` (asymptotically stable only if every multiplier of the whole closed loop
decays by ``e`` within 1000 periods, beyond its own error estimate).  A stage that did not run
(or failed) gives "not computed" instead of a guess.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional

__all__ = ["verdict_summary", "verdict_blocks"]


def _rows(out: Path, name: str) -> Optional[list]:
    p = Path(out) / name
    if not p.exists():
        return None
    try:
        return json.loads(p.read_text()).get("rows")
    except (OSError, ValueError):
        return None


def _study_row(rows: Optional[list], omega: float) -> Optional[dict]:
    for r in rows or []:
        if abs(float(r.get("omega", math.nan)) - omega) <= 1e-9 * omega:
            return r
    return None


def verdict_summary(out: Path, omega: float, computed: Optional[set] = None) -> dict:
    """The verdict block as data (the ``verdict`` key of ``study.json``).

    ``computed``: names of the stages whose results belong to this run (a file of a stage that failed
    or was not asked for is ignored).

    Returns
    -------
    dict
        ``uncontrolled``, ``tuned``, ``nonlinear_check`` and ``sensitivity``, each with ``verdict`` (or
        ``None``), the numbers and ``words``.
    """
    def ok(stage: str) -> bool:
        return computed is None or stage in computed

    summary: dict[str, Any] = {}
    ex = (_rows(out, "exudyn.json") or [None])[0] if ok("exudyn") else None
    t2 = _study_row(_rows(out, "table2.json"), omega) if ok("table2") else None
    # uncontrolled
    unc: dict[str, Any] = {"verdict": None, "words": "not computed (stages table2 / exudyn did not run)"}
    if ex and ex.get("verdict_uncontrolled"):
        v = ex["verdict_uncontrolled"]
        unc = {"verdict": v["verdict"], "model": f"Exudyn ANCF link, {ex['elements']} elements",
               "spectral_radius": v["spectral_radius"], "spectral_radius_mode": v["spectral_radius_mode"],
               "words": v["message"]}
        if t2:
            rho = float(t2["moduli"][0])
            unc["reduced_model_spectral_radius"] = rho
            unc["words"] += f"; the reduced model (hub and bending 1): ρ = {rho:.4g}"
    elif t2:
        rho = float(t2["moduli"][0])
        unc = {"verdict": "unstable" if rho > 1 else None, "model": "reduced model", "spectral_radius": rho,
               "words": f"reduced model: ρ = {rho:.4g}"}
    summary["uncontrolled"] = unc
    # tuned
    tuned: dict[str, Any] = {"verdict": None, "words": "not computed (stage exudyn did not run)"}
    if ex and ex.get("verdict_tuned"):
        v = ex["verdict_tuned"]
        resp = float(ex["tuned_dominant"])
        words = (f"gains kp = {ex['tuned_kp']:.4g}, kd = {ex['tuned_kd']:.4g} (Taguchi on the Exudyn model): the tuned "
                 f"response (hub and bending 1) is ρ = {resp:.4g} (target {ex['target']:g}); whole loop: "
                 f"{v['message']}")
        if v["spectral_radius"] > resp * (1 + 1e-9):
            words += (f". The tuned modes decay at {resp:.3g} per period, but {v['spectral_radius_mode']} does not "
                      "decay that fast: its multiplier is set by the mesh and by structural damping the model "
                      "does not have (see the sensitivity table and --damping)")
        tuned = {"verdict": v["verdict"], "tuned_response": resp, "tuned_response_modes": "hub, bending 1",
                 "spectral_radius": v["spectral_radius"], "spectral_radius_mode": v["spectral_radius_mode"],
                 "spectral_radius_error": v["spectral_radius_error"], "undamped_count": v["undamped_count"],
                 "kp": ex["tuned_kp"], "kd": ex["tuned_kd"], "words": words}
    summary["tuned"] = tuned
    # the two-link arm (its own stage): the tuned drive-mode response beside the whole loop's spectral radius
    two = (_rows(out, "two_link.json") or [None])[0] if ok("two_link") else None
    whole = ((two or {}).get("tuned") or {}).get("whole_spectrum") or {}
    if whole.get("verdict_detail"):
        from flexstab.plants import MODEL_RESPONSE_MODES, response_note

        v = whole["verdict_detail"]
        resp = float(two["tuned"]["dominant_modulus"])
        note = response_note(resp, MODEL_RESPONSE_MODES, v)
        summary["two_link_tuned"] = {
            "verdict": v["verdict"], "elements_per_link": two.get("elements"), "tuned_response": resp,
            "tuned_response_modes": MODEL_RESPONSE_MODES, "spectral_radius": v["spectral_radius"],
            "spectral_radius_mode": v["spectral_radius_mode"],
            "spectral_radius_frequency_hz": v["spectral_radius_frequency_hz"],
            "spectral_radius_error": v["spectral_radius_error"], "gains": two.get("tuned_gains"),
            "words": (f"{two.get('elements')} elements per link, gains "
                      + ", ".join(f"{g:.5g}" for g in two.get("tuned_gains") or []) + f": {v['message']}"
                      + (f". In words: {note}, set by the mesh and by structural damping the model does not have"
                         if note else ""))}
    # nonlinear check
    chk: dict[str, Any] = {"verdict": None, "words": "not computed (stage validation did not run)"}
    val = (_rows(out, "validation.json") or [None])[0] if ok("validation") else None
    if val:
        if val.get("diverged"):
            chk = {"verdict": "diverged", "words": f"the nonlinear closed loop diverged: {val.get('reason')}"}
        else:
            agrees = bool(val.get("agrees"))
            n = len(val.get("multipliers") or [])
            chk = {"verdict": "confirmed" if agrees else "check failed", "agrees": agrees,
                   "words": (f"the multipliers measured from nonlinear Exudyn runs "
                             f"{'agree' if agrees else 'do NOT agree'} with the linearisation within their error "
                             f"bars ({n} compared, the projected measurement on the predicted modes)")}
    summary["nonlinear_check"] = chk
    sens = _rows(out, "sensitivity.json") if ok("sensitivity") else None
    if sens:
        summary["sensitivity"] = [{k: r.get(k) for k in ("elements", "damping", "verdict", "spectral_radius",
                                                          "spectral_radius_mode", "undamped_count", "margin")}
                                  for r in sens]
    return summary


def verdict_blocks(summary: dict) -> list:
    """Report blocks (``flexstab.report``) of :func:`verdict_summary`'s data."""
    from flexstab.report import table, text

    def line(key: str, title: str) -> list:
        d = summary.get(key) or {}
        v = d.get("verdict") or "not computed"
        return [f"**{title}**", v, d.get("words", "")]

    rows = [line("uncontrolled", "uncontrolled"), line("tuned", "tuned")]
    if summary.get("two_link_tuned"):
        rows.append(line("two_link_tuned", "tuned (two-link arm)"))
    rows.append(line("nonlinear_check", "nonlinear check"))
    blocks = [
        text("Verdict rule: asymptotically stable only if every Floquet multiplier of the whole closed loop "
             "(every mode of the model, not only the tuned ones) decays by a factor e within 1000 periods, beyond "
             "its own error estimate; unstable if one is certified outside the unit circle; critical otherwise, "
             "with the practically undamped modes counted."),
        table(["", "verdict", "in numbers"], rows),
    ]
    sens = summary.get("sensitivity")
    if sens:
        blocks.append(text("Sensitivity of the verdict to the mesh and to structural damping (reference gains):"))
        blocks.append(table(["elements", "damping", "verdict", "spectral radius (mode)", "undamped multipliers"],
                            [[r["elements"], r["damping"], r["verdict"],
                              f"{r['spectral_radius']:.10g} ({r['spectral_radius_mode']})", r["undamped_count"]]
                             for r in sens]))
    return blocks
