"""The study's two-link section: one stage function and its report blocks.

Computed in the stage (a few CPU seconds per Omega): the periodic orbit, the
linearisation and the labelled Floquet multipliers of the built-in two-link arm at
2 pi and 4 pi (``--quick``: 2 pi only), uncontrolled and at the four tuned gains, the
dominant one measured by Hill's method; figures of the poses and of the dominant
Floquet mode.

Read from the cached results of ``scripts/two_link_study.py`` (minutes of CPU: the
four-gain tunings, Nelder-Mead / differential evolution, the independent
streamed-product check, the mesh study and the robust design) in the study's own
folder (never relative to the working directory): copied into the study folder as
``two_link_cached.json`` with the SHA-256 of the source, so that every number in the
section comes from a file beside the report.  Each part of that file carries the keys
it was computed with (:func:`cache_keys`: the code hash of the packages and of the
script, the mesh, the gain ranges, rho_d, and the stage's own arguments); a part whose
keys differ from this study's is ignored, and the section says so.  Without a usable tuning the section uses
:data:`flexstab.two_link.TUNED_GAINS` and says so.
"""
from __future__ import annotations

import hashlib
import json
import math
import types
from pathlib import Path
from typing import Any, Optional

from flexstab.report import figure, table, text

__all__ = ["stage_two_link", "CACHE_NAME", "CACHE_PARTS", "find_cache", "cache_keys", "fresh_parts", "script_hash"]

#: File written by ``scripts/two_link_study.py`` into its output folder.
CACHE_NAME = "two_link.json"
#: Parts (stages) of the script's results, each with its own keys under ``keys[part]``.
CACHE_PARTS = ("tune", "mesh", "robust", "direct", "figures")


#: The script whose results the section reads (its constants -- the mesh levels, the direct stage's
#: elements -- change the numbers, and it is not one of the hashed packages).
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "two_link_study.py"


def script_hash() -> Optional[str]:
    """SHA-256 of :data:`SCRIPT`, or ``None`` when the package is installed without it."""
    return hashlib.sha256(SCRIPT.read_bytes()).hexdigest() if SCRIPT.exists() else None


def cache_keys(target: float, args: Optional[dict] = None) -> dict:
    """What the script's numbers depend on besides Omega (each part is stored per Omega): the
    SHA-256 of the packages' source (:func:`flexstab.study._code_hash`, as ``chart --model`` keys its
    stores) and of the script (:func:`script_hash`), the default mesh, the four-gain ranges and rho_d;
    with ``args``, the stage's own command-line arguments (e.g. the robust stage's ``grid``,
    ``robust_iterations``) under ``args``.  JSON-normalised (comparable with a file's)."""
    from flexstab.study import _code_hash
    from flexstab.two_link import TUNING_RANGES
    from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

    keys = {"code": _code_hash(), "script": script_hash(), "elements": DEFAULT_ELEMENTS,
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


def find_cache(out: Path) -> Optional[Path]:
    """The script's results in the study's own output folder, ``<out>/two_link/two_link.json``
    (``python3 scripts/two_link_study.py --out <out>/two_link``; its default is ``results/two_link``,
    the default study folder's).  Never a file relative to the working directory: a study must not
    report another run's numbers because of where it was started."""
    p = Path(out) / "two_link" / CACHE_NAME
    return p if p.exists() else None


def _z(z: complex) -> str:
    return f"{abs(z):.6f}"


def _mode_rows(fl: Any) -> str:
    """The Hill-refined multipliers of the drive modes / first bending mode (one of each conjugate pair)."""
    return ", ".join(f"{abs(z):.5g} ({label})" for label, z in fl.measure.refined)


def stage_two_link(cfg: Any, opts: Any) -> dict:
    """Stage function for :data:`flexstab.study.STAGES` (signature ``(cfg, opts) -> dict``)."""
    from flexstab.arm_figures import plot_floquet_mode, plot_poses
    from flexstab.plants import whole_spectrum
    from flexstab.two_link import TUNED_GAINS, two_link_floquet

    out = Path(opts.out)
    omegas = (2,) if opts.quick else (2, 4)
    cache_path = find_cache(out)
    raw = json.loads(cache_path.read_text()) if cache_path is not None else None
    doc: dict = {"omegas_over_pi": list(omegas), "cache": None, "rows": []}
    cache = None
    stale: list = []
    if raw is not None:
        expected = cache_keys(getattr(cfg, "target", 0.3))
        cache, stale = fresh_parts(raw, expected)
        doc["cache"] = {"source": str(cache_path), "sha256": hashlib.sha256(cache_path.read_bytes()).hexdigest(),
                        "keys": expected, "used": [p for p in CACHE_PARTS if p in cache], "ignored": stale}
        (out / "two_link_cached.json").write_text(json.dumps(raw, indent=2))
        if not any(p in cache for p in CACHE_PARTS):
            cache = None
    tuned_src = {}
    for k in omegas:
        g = None
        if cache is not None:
            g = ((cache.get("tune") or {}).get(f"{k}pi") or {}).get("gains")
        tuned_src[k] = ("scripts/two_link_study.py (two_link_cached.json)", g) if g else \
            ("flexstab.two_link.TUNED_GAINS", list(TUNED_GAINS[k]))
    figs = []
    rows_tab = []
    for k in omegas:
        omega = k * math.pi
        unc = two_link_floquet(omega)
        src, g = tuned_src[k]
        ctl = two_link_floquet(omega, gains=g, orbit=unc.orbit, lin=unc.linearization)
        row = {"omega": omega, "elements": unc.elements, "tuned_gains": g, "gains_source": src}
        for label, fl in (("uncontrolled", unc), ("tuned", ctl)):
            row[label] = {
                "dominant": [fl.measure.dominant.real, fl.measure.dominant.imag],
                "dominant_modulus": abs(fl.measure.dominant), "mode": fl.measure.mode,
                "hill_error_estimate": fl.measure.hill_error_estimate,
                "labelled": [{"modulus": float(abs(mu)), "mode": m["mode"], "undamped": m["undamped"]}
                             for mu, m in zip(fl.floquet.multipliers, fl.modes) if abs(mu) > 1e-6][:12],
                "cpu_seconds": fl.cpu_seconds,
            }
        whole = whole_spectrum(ctl.orbit, omega, g[0::2], g[1::2])
        row["tuned"]["whole_spectrum"] = whole
        doc["rows"].append(row)
        rows_tab.append([f"{k}π", unc.elements, f"{abs(unc.measure.dominant):.6f} ({unc.measure.mode})",
                         _mode_rows(unc), ", ".join(f"{v:.4g}" for v in g),
                         f"{abs(ctl.measure.dominant):.6f} ({ctl.measure.mode})", _mode_rows(ctl),
                         f"{whole['spectral_radius_all']:.4f} ({whole['spectral_radius_all_mode']}, "
                         f"{(whole['spectral_radius_all_frequency_hz'] or 0) / 1e3:.1f} kHz)",
                         f"{sum(unc.cpu_seconds.values()):.1f}"])
        if k == omegas[0]:
            figs.append(str(plot_poses(unc.orbit, out / f"two_link_poses_{k}pi.png").name))
        res = types.SimpleNamespace(floquet=ctl.floquet, modes=ctl.modes, orbit=ctl.orbit,
                                    linearization=ctl.linearization.with_gains(g[0::2], g[1::2]),
                                    dominant_multiplier=ctl.measure.dominant)
        # the title shows the modulus the table shows (Hill's), not the labelling product's (512 steps: 0.3023
        # against Hill's 0.300027 at 4 pi); the shape is that product's eigenvector nearest Hill's multiplier
        measured = (ctl.measure.dominant, f"Hill's method, {ctl.harmonics} harmonics, as in the table")
        row["tuned"]["mode_figure"] = {"file": f"two_link_mode_{k}pi.png", "modulus": abs(ctl.measure.dominant),
                                       "method": measured[1]}
        figs.append(str(plot_floquet_mode(res, out / f"two_link_mode_{k}pi.png", measured=measured).name))
    doc["figures"] = figs
    (out / "two_link.json").write_text(json.dumps(doc, indent=2, default=str))
    blocks = [
        text("Built-in two-link flexible arm (`--model two-link`): shoulder q1 = π/2 + (π/4) sin Ωt, "
             "elbow q2 = (π/4) sin Ωt, 2 ANCF elements per link, four PD gains (kp1, kd1, kp2, kd2). Multipliers: "
             "`magnus2` (512 steps) for all of them and their mode labels; the dominant one (drive modes / first "
             "bending mode) measured by Hill's method (`stability.hill`, 16 harmonics; its H vs H/2 estimate is in "
             "the JSON). The tuned quantity is that dominant multiplier; the last-but-one column is the spectral "
             "radius of the whole linearisation at the tuned gains (frozen-modal product, every mode) with its "
             "mode: on this mesh an axial pair of the discretisation, lightly damped through the joints, hardly "
             "moved by the gains and not converged under mesh refinement (0.557 at 2 elements per link, 0.860 at "
             "4, at the 2π gains), so it is reported, not tuned."),
        table(["Ω", "el./link", "uncontrolled: dominant |ρ|", "uncontrolled: drive / bending-1 multipliers (Hill)",
               "tuned gains kp1, kd1, kp2, kd2", "tuned: dominant |ρ| (Hill)", "tuned: drive / bending-1 multipliers",
               "tuned: whole-spectrum max|ρ| (mode)", "CPU s (orbit+lin.+Floquet)"], rows_tab),
        text("Tuned gains from " + "; ".join(f"{k}π: {tuned_src[k][0]}" for k in omegas) + "."),
    ]
    if stale:
        blocks.append(text("**Note:** results of `scripts/two_link_study.py` in `two_link/` that do not belong to this "
                           "code and these inputs were ignored (keys in `two_link.json`, cache section): "
                           + "; ".join(stale) + ". Re-run `python3 scripts/two_link_study.py --out <study out>/two_link`."))
    if cache is not None:
        blocks += _cached_blocks(cache)
    else:
        blocks.append(text("No usable results of `scripts/two_link_study.py` in this study's folder (`two_link/`): the "
                           "tuning, method comparison, independent check, mesh study and robust design are not in this "
                           "report (run `python3 scripts/two_link_study.py --out <study out>/two_link` first)."))
    for f in figs:
        k = f.split("_")[-1].replace(".png", "").replace("pi", "π")
        cap = (f"The arm over one period on its periodic orbit, Ω = {k}" if "poses" in f else
               f"Floquet mode of the dominant multiplier at the tuned gains, Ω = {k}: deformation along one "
               "period (red) on the orbit pose (grey)")
        blocks.append(figure(f, cap))
    return {"json": "two_link.json", "title": "Two-link flexible arm", "blocks": blocks,
            "files": ["two_link.json"] + (["two_link_cached.json"] if raw is not None else []) + figs}


def _cached_blocks(c: dict) -> list:
    blocks = []
    tune = c.get("tune") or {}
    if tune:
        rows = []
        for key, t in tune.items():
            chk = t.get("check") or {}
            rows.append([key.replace("pi", "π"), ", ".join(f"{v:.5g}" for v in t["gains"]),
                         f"{t['rho']:.6f}", f"{chk.get('streamed_moduli', {}).get('32768', float('nan')):.6f}",
                         f"{chk.get('difference', float('nan')):.1e}",
                         f"{abs(t['rho'] - c.get('target', 0.3)) / c.get('target', 0.3):.1e}",
                         t["evaluations"], f"{t['cpu_s']:.1f}"])
        blocks += [
            text("Four-gain Taguchi (L9, iterated) to ρ_d, response = dominant multiplier by Hill's method; checked "
                 "by an independent method: the streamed exponential-midpoint product (`stability.floquet` with a fixed step count, streamed in chunks) at "
                 "32768 steps (no Hill code; its own 16384 → 32768 change is in the cached JSON)."),
            table(["Ω", "tuned gains", "|ρ| Hill (loop)", "|ρ| magnus2 32768 steps", "|Hill − magnus2|",
                   "|ρ − ρ_d| / ρ_d", "evaluations", "CPU s"], rows),
        ]
    comp = [(k, t) for k, t in tune.items() if t.get("direct")]
    if comp:
        rows = []
        for key, t in comp:
            rows.append([key.replace("pi", "π"), "Taguchi", t["evaluations"], f"{t['cpu_s']:.1f}", f"{t['rho']:.6f}"])
            for d in t["direct"]:
                rows.append([key.replace("pi", "π"), d["method"], d["evaluations"], f"{d.get('cpu_s', d['elapsed']):.1f}",
                             f"{d['spectral_radius']:.6f}"])
        src = ", ".join(sorted({str(t.get("direct_source", "this run")) for _, t in comp}))
        blocks += [text("Same objective (Hill response), same tolerance (1e-3 ρ_d), each method stops at its first "
                        "hit. CPU seconds: Taguchi on 2 worker processes (summed), Nelder–Mead and differential "
                        f"evolution serial (measured by the benchmark: {src})."),
                   table(["Ω", "method", "evaluations", "CPU s", "|ρ| reached"], rows)]
    mesh = c.get("mesh") or {}
    if mesh:
        rows = []
        for key, rs in mesh.items():
            for r in rs:
                rows.append([key.replace("pi", "π"), r["elements"], r["size"],
                             f"{r['uncontrolled']['modulus']:.7f} ({r['uncontrolled']['mode']})",
                             f"{r['uncontrolled']['hill_error_estimate']:.0e}",
                             f"{r['tuned']['modulus']:.8f} ({r['tuned']['mode']})",
                             f"{r['tuned']['hill_error_estimate']:.0e}"])
        blocks += [text("Mesh convergence of the dominant multipliers (Hill's method; its H vs H/2 estimate beside)."),
                   table(["Ω", "elements per link", "coordinates", "uncontrolled |ρ|", "est.", "tuned |ρ|", "est."],
                         rows)]
    rob = c.get("robust") or {}
    if rob:
        rows = []
        for key, r in rob.items():
            for label, w in (("nominal", r["nominal"]), ("robust", r["robust"]["check"])):
                rows.append([key.replace("pi", "π"), label, ", ".join(f"{v:.4g}" for v in w["gains"]),
                             f"{w['nominal']:.5f}", f"{w['worst']:.5f}",
                             ", ".join(f"{a} {b:.3g}" for a, b in w["worst_noise"].items())])
            rows.append([key.replace("pi", "π"), "change", "", f"{r['nominal_cost']:+.4f} (|ρ − ρ_d|)",
                         f"{-r['worst_case_improvement']:+.5f} ({-r['worst_case_improvement_percent']:+.2f} %)",
                         f"grid {r['grid_size']} points"])
        blocks += [text("Robust design: inner L9 array of the four gains × outer L9 array of the noise factors "
                        "(payload 0.05–0.2 kg, Ω ± 10 %, E ± 5 %), S/N = −10 log10 mean (|ρ| − ρ_d)² over the outer "
                        "runs; both gain sets judged by the worst |ρ| over a full grid of the noise box."),
                   table(["Ω", "gains", "kp1, kd1, kp2, kd2", "|ρ| at nominal", "worst |ρ| on grid", "worst at"],
                         rows)]
    return blocks
