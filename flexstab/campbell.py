"""Campbell diagram of a model: one Floquet analysis per rotation speed, modes tracked, figure and tables.

Per speed ``Omega`` (:class:`CampbellPointTask`, picklable, so the points can run through
:func:`flexstab.executor.make_executor`'s executors): the model's periodic orbit, its linearisation and
the monodromy matrix (:func:`linearize.analysis.analyze`), then the modes of the point
(:func:`stability.campbell.floquet_modes`): the principal frequency of each mode by the harmonic content of
its Floquet solution read in the linearisation's independent displacement coordinates ``z`` (which co-rotate
with the bodies, as the package's mode labels do), of its harmonics' aliases the one nearest plus or minus
the frozen-time modal frequency of the mode (so that a structural mode far above ``Omega`` is not aliased), propagated in a
frozen-modal frame of the linearisation (where the stiff part is nearly constant); the mode shape for
tracking are the displacements ``dq = N(0) z`` at ``t = 0`` in Exudyn's coordinates.  The modes are then tracked across the speeds by MAC
and an optimal assignment (:func:`stability.campbell.campbell`).
"""
from __future__ import annotations

import csv
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

__all__ = ["CampbellPointTask", "point_modes", "plot_campbell", "campbell_tables", "PRINCIPAL_RULE",
           "MIN_RELIABLE_DIGITS", "CampbellOptions", "campbell_diagram", "check_campbell_options", "MAX_POINTS"]

logger = logging.getLogger(__name__)

#: The frequency rule, as the JSON output states it.
PRINCIPAL_RULE = ("principal frequency: Im(log(rho)/T) + k* Omega, k* the harmonic of Omega carrying the largest "
                  "share of the Floquet solution's periodic part, read in the linearisation's independent "
                  "displacement coordinates (co-rotating with the bodies) at 64 samples, of k*'s aliases k* + 64 m the "
                  "one nearest +-(the frozen-time modal frequency of the mode's label); "
                  "one mode per conjugate pair (the member with positive frequency); damping ratio "
                  "-Re(lambda)/|lambda| of that representative; 'harmonics' maps k - k* to its share")


#: Propagator steps of a speed at which the adaptive solve (``--steps`` not given) cannot meet its
#: tolerance (a ``FloquetError``): the fixed-step frozen-modal solve of :func:`linearize.analysis.analyze`
#: with 4096 steps, Richardson-extrapolated, its error estimate in the point's JSON (measured on the slider-crank
#: at 80 rad/s, where the adaptive solve stopped at 1.7e-9 > 1e-9: estimate 7e-9, 1.0 s CPU; 256 steps: 1e-1).
FALLBACK_STEPS = 4096
#: Modes whose multiplier the Floquet engine resolves to fewer digits (``reliable_digits``: a multiplier below
#: the product's rounding floor, e.g. a strongly PD-damped mode) are left out of the diagram: their
#: exponents, hence frequency and damping, are rounding noise.  The count is stated per speed.
MIN_RELIABLE_DIGITS = 1.0


@dataclass(frozen=True)
class CampbellPointTask:
    """Picklable task: ``omega -> dict`` (JSON-ready) of one Campbell point of a model.

    Attributes
    ----------
    name : str
        Model name (built-in name or file stem).
    source : str or None
        Model file path (re-loaded in the worker); ``None``: ``name`` is a built-in.
    options : dict
        Keyword options of the model's ``build``.
    kp, kd : tuple of float
        PD gains per drive (empty: zero gains / no drives).
    samples : int
        Orbit collocation samples.
    n_steps : int or None
        Frozen-modal propagator steps of :func:`linearize.analysis.analyze` (``None``: adaptive).
    """

    name: str
    source: Optional[str]
    options: dict = field(default_factory=dict)
    kp: tuple = ()
    kd: tuple = ()
    samples: int = 32
    n_steps: Optional[int] = None

    def definition(self) -> Any:
        from mbs_models.model_file import ModelDefinition, builtin_model, load_model_file

        base = builtin_model(self.name) if self.source is None else load_model_file(self.source)
        return ModelDefinition(name=self.name, build=base.build, source=base.source, options=dict(self.options))

    def __call__(self, omega: float) -> dict:
        from linearize.analysis import analyze

        from stability.floquet import FloquetError

        t0, c0 = time.perf_counter(), time.process_time()
        kp = self.kp if self.kp else 0.0
        kd = self.kd if self.kd else 0.0
        definition = self.definition()
        fallback = None
        try:
            res = analyze(definition, float(omega), kp=kp, kd=kd, samples=self.samples, n_steps=self.n_steps)
        except FloquetError as exc:
            if self.n_steps is not None:
                raise
            # the adaptive solve could not meet its rtol: the fixed-step solve, its estimate stated
            fallback = f"adaptive solve failed ({exc}); {FALLBACK_STEPS} steps, extrapolated"
            logger.warning("Omega = %.6g: %s", omega, fallback)
            res = analyze(definition, float(omega), kp=kp, kd=kd, samples=self.samples, n_steps=FALLBACK_STEPS)
        modes = point_modes(res)
        out = {
            "omega": float(omega),
            "fallback": fallback,
            "modes": modes,
            "unresolved_modes": _pairs(res.floquet.multipliers) - len(modes),
            "orbit_residual": float(res.orbit.residual),
            "shooting_residual": float(res.orbit.shooting_residual),
            "spectral_radius": float(res.floquet.spectral_radius),
            "error_estimate": float(res.floquet.error_estimate),
            "propagator_steps": int(res.floquet.n_steps),
            "frame": res.frame,
            "wall_seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0,
            "stage_cpu_seconds": dict(res.cpu_timings),
        }
        return out


def _pairs(multipliers) -> int:
    """Modes of a spectrum: one per conjugate pair, one per real multiplier."""
    from stability.campbell import REAL_MULTIPLIER_TOLERANCE

    mu = np.asarray(multipliers)
    real = np.abs(mu.imag) <= REAL_MULTIPLIER_TOLERANCE * np.abs(mu)
    return int(np.sum(real) + np.sum(~real & (mu.imag > 0)))


def point_modes(res: Any) -> list:
    """The modes of one :class:`~linearize.analysis.ModelFloquetResult` as JSON-ready dicts (see the module notes).

    Each: ``frequency`` (rad/s), ``frequency_hz``, ``damping_ratio``, ``multiplier`` ``[re, im]``, ``modulus``,
    ``exponent`` ``[re, im]`` (the principal one), ``harmonics`` (``{k - k*: share}``), ``closure``,
    ``label`` (frozen-mode label of the nearest multiplier), ``shape`` (``[[re, im], ...]``: ``N(0) z``).
    """
    from linearize.fourier import trig_interpolate
    from stability.campbell import floquet_modes
    from stability.modal import FrozenModalSystem, ModalBasisError

    lin = res.linearization
    r = lin.size
    n_q = lin.basis.shape[1] if lin.basis is not None else r
    T = lin.period

    def displacements(times: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(times)
        Nt = trig_interpolate(lin.basis, T, t) if lin.basis is not None else np.broadcast_to(np.eye(r), (t.size, r, r))
        out = np.zeros((t.size, n_q, 2 * r))
        out[:, :, :r] = Nt
        return out

    propagate: Any = lin
    basis = None
    try:
        frame = FrozenModalSystem(lin)
        propagate = frame
        basis = lambda t: frame.scale[None, :, None] * frame.basis(t)  # noqa: E731 - x = D V(t) w
    except ModalBasisError as exc:
        logger.info("Campbell harmonics in the model's coordinates (no frozen-modal frame: %s)", exc)
    Phi = np.asarray(res.floquet.monodromy)
    mu_eig = np.linalg.eigvals(Phi)
    mults = np.asarray(res.floquet.multipliers)
    labels, centres = [], []
    for m in mu_eig:  # label and frozen-mode frequency of the analysed multiplier nearest each eigenvalue
        j = int(np.argmin(np.abs(mults - m)))
        labels.append(res.modes[j].mode if j < len(res.modes) else "")
        centres.append(2 * math.pi * res.modes[j].frequency_hz if j < len(res.modes) else 0.0)
    z_rows = np.eye(2 * r)[:r]
    fm = floquet_modes(propagate, Phi, period=T, shape_map=displacements(np.zeros(1))[0], labels=labels,
                       centres=centres, basis=basis,
                       output=lambda t: np.broadcast_to(z_rows, (np.size(t), r, 2 * r)))
    out = []
    digits = np.asarray(res.floquet.reliable_digits, dtype=float)
    for j in range(len(fm)):
        lam = fm.exponents[j]
        mu = fm.multipliers[j]
        near = int(np.argmin(np.abs(mults - mu)))
        if not digits[near] >= MIN_RELIABLE_DIGITS:
            continue  # below the rounding floor of the product: its exponent (frequency, damping) is noise
        out.append({
            "frequency": float(fm.frequencies[j]),
            "frequency_hz": float(fm.frequencies[j] / (2 * math.pi)),
            "damping_ratio": float(fm.damping_ratios[j]),
            "multiplier": [float(mu.real), float(mu.imag)],
            "modulus": float(abs(mu)),
            "exponent": [float(lam.real), float(lam.imag)],
            "harmonics": {str(k): float(s) for k, s in fm.harmonics[j].items()},
            "closure": float(fm.closure[j]),
            "label": fm.labels[j],
            "shape": [[float(v.real), float(v.imag)] for v in fm.shapes[j]],
        })
    return out


def modes_from_points(points: Sequence[dict]) -> list:
    """:class:`stability.campbell.FloquetModes` rebuilt from :class:`CampbellPointTask` results."""
    from stability.campbell import FloquetModes

    out = []
    for p in points:
        ms = p["modes"]
        out.append(FloquetModes(
            period=2 * math.pi / p["omega"],
            multipliers=np.array([complex(*m["multiplier"]) for m in ms], dtype=complex),
            exponents=np.array([complex(*m["exponent"]) for m in ms], dtype=complex),
            frequencies=np.array([m["frequency"] for m in ms], dtype=float),
            damping_ratios=np.array([m["damping_ratio"] for m in ms], dtype=float),
            shapes=np.array([[complex(*v) for v in m["shape"]] for m in ms], dtype=complex).reshape(len(ms), -1),
            harmonics=tuple({int(k): s for k, s in m["harmonics"].items()} for m in ms),
            closure=np.array([m["closure"] for m in ms], dtype=float),
            labels=tuple(m["label"] for m in ms)))
    return out


def branch_table(result: Any) -> list:
    """Per branch: ``branch``, ``label``, ``frequency_hz``, ``damping_ratio``, ``modulus``, ``mac`` lists (``None``
    where the branch is absent), ordered by the branch's median frequency."""
    rows = []
    for b in range(result.tracking.n_branches):
        d = result.branch(b)
        med = float(np.nanmedian(d["frequency"]))
        rows.append((med, b, d))
    rows.sort(key=lambda x: (x[0], x[1]))

    def clean(a: np.ndarray) -> list:
        return [None if not math.isfinite(v) else float(v) for v in a]

    return [{"branch": b, "label": d["label"], "median_frequency_hz": med / (2 * math.pi),
             "frequency_hz": clean(d["frequency"] / (2 * math.pi)), "damping_ratio": clean(d["damping_ratio"]),
             "modulus": clean(d["modulus"]), "mac": clean(d["mac"])} for med, b, d in rows]


def campbell_tables(result: Any, points: Sequence[dict], csv_path: Path) -> None:
    """Write the CSV: one row per (speed, mode) with its branch."""
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["omega_rad_s", "omega_hz", "branch", "label", "frequency_hz", "damping_ratio", "modulus",
                    "mac_with_previous", "principal_share", "harmonics"])
        for i, p in enumerate(points):
            for j, m in enumerate(p["modes"]):
                b = int(result.tracking.branches[i][j])
                mac = result.tracking.macs[i][j]
                share = m["harmonics"].get("0", 0.0)
                harm = " ".join(f"{k}:{v:.3f}" for k, v in m["harmonics"].items())
                w.writerow([f"{p['omega']:.10g}", f"{p['omega'] / (2 * math.pi):.10g}", b, m["label"],
                            f"{m['frequency_hz']:.10g}", f"{m['damping_ratio']:.8g}", f"{m['modulus']:.12g}",
                            "" if not math.isfinite(mac) else f"{mac:.4f}", f"{share:.4f}", harm])


def plot_campbell(result: Any, branches: list, path: Path, *, title: str, max_branches: int = 10,
                  harmonic_share: float = 0.1, orders: int = 4) -> Path:
    """Frequency and damping ratio of the tracked branches against the rotation frequency, with the 1P, 2P, ... lines.

    Non-principal harmonics of a mode with at least ``harmonic_share`` of its power are drawn as small open
    markers at ``|f + k Omega|`` in the branch's colour.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = result.omegas / (2 * math.pi)
    shown = branches[:max_branches]
    fmax = max((max((v for v in b["frequency_hz"] if v is not None), default=0.0) for b in shown), default=1.0)
    fmax = max(fmax, 1e-12) * 1.25
    fig, (ax, az) = plt.subplots(2, 1, figsize=(10.5, 7.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    xs = np.array([x.min(), x.max()])
    placed: list = []
    for k in range(1, orders + 1):
        ax.plot(xs, k * xs, color="0.6", lw=0.8, ls="--", zorder=1)
        xe = min(x.max(), fmax / k)
        ye = k * xe
        # the label where the line leaves the axes (top or right edge), inside them; lines that leave
        # close together (a frequency range far above the rotation) share the lowest one's label
        span = max(float(x.max() - x.min()), 1e-300)
        if xe > x.min() and all(math.hypot((xe - a) / span, (ye - b) / fmax) > 0.04 for a, b in placed):
            ax.annotate(f"{k}P", (xe, ye), textcoords="offset points", xytext=(-16, -12 if ye > 0.1 * fmax else 2),
                        fontsize=8, color="0.4")
            placed.append((xe, ye))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for n, b in enumerate(shown):
        col = colors[n % len(colors)]
        f = np.array([np.nan if v is None else v for v in b["frequency_hz"]])
        z = np.array([np.nan if v is None else v for v in b["damping_ratio"]])
        name = f"{b['label'] or 'mode'} (branch {b['branch']})"
        ax.plot(x, f, "-o", color=col, ms=3.5, lw=1.4, label=name, zorder=3)
        az.plot(x, 100 * z, "-o", color=col, ms=3.5, lw=1.4, zorder=3)
        # the other harmonics of this branch's modes
        for i, p in enumerate(result.points):
            j = result.tracking.index(i, b["branch"])
            if j is None:
                continue
            for k, s in p.harmonics[j].items():
                if k != 0 and s >= harmonic_share:
                    fk = abs(p.frequencies[j] + k * p.omega) / (2 * math.pi)
                    if fk <= fmax:
                        ax.plot(x[i], fk, "o", mfc="none", mec=col, ms=3 + 5 * s, alpha=0.7, zorder=2)
    az.axhline(0.0, color="red", lw=1, ls="--")
    # speeds at which some mode has negative damping (unstable), shaded in both panels
    unstable = np.array([bool(np.any(p.damping_ratios < 0)) for p in result.points])
    for i in np.flatnonzero(unstable):
        lo = x[i] - 0.5 * (x[i] - x[i - 1]) if i > 0 else x[i]
        hi = x[i] + 0.5 * (x[i + 1] - x[i]) if i + 1 < x.size else x[i]
        for a in (ax, az):
            a.axvspan(lo, hi, color="red", alpha=0.08, lw=0, zorder=0)
    ax.set_ylim(0.0, fmax)
    ax.set_xlim(x.min(), x.max())
    ax.set_ylabel("Floquet frequency (Hz)")
    az.set_ylabel("damping ratio ζ (%)")
    az.set_xlabel("rotation frequency Ω/2π (Hz)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    az.grid(True, alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    from matplotlib.lines import Line2D

    handles += [Line2D([], [], color="0.6", ls="--", lw=0.8),
                Line2D([], [], ls="none", marker="o", mfc="none", mec="0.3")]
    labels += ["kP: f = k Ω/2π", f"other harmonics (share ≥ {harmonic_share:g})"]
    if unstable.any():
        from matplotlib.patches import Patch

        handles.append(Patch(color="red", alpha=0.15))
        labels.append("a mode unstable (ζ < 0)")
    # beside the axes, never over the curves
    ax.legend(handles, labels, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- the whole diagram (flexstab campbell)
#: Most speeds of one diagram (each is an orbit, a linearisation and a Floquet analysis).
MAX_POINTS = 1001


@dataclass(frozen=True)
class CampbellOptions:
    """What :func:`campbell_diagram` computes.

    Attributes
    ----------
    model : str
        A model file ``PATH.py`` or a built-in model file name (not ``reduced`` or ``exudyn``).
    omega_range : (float, float)
        Lowest and highest speed (rad/s).
    points : int
        Speeds, evenly spaced (2 .. :data:`MAX_POINTS`).
    kp, kd : tuple of float
        Gains, one per drive (or one for every drive); empty: uncontrolled.
    samples, steps : int, optional
        Collocation samples per period; frozen-modal propagator steps per point (default adaptive).
    elements : int, optional
        ANCF elements of a built-in model.
    modes : int
        Branches drawn, lowest median frequency first.
    min_mac : float, optional
        Smallest MAC that continues a branch (default :data:`stability.campbell.MIN_MAC`).
    workers : int, optional
        Worker processes for the speeds.
    out : Path
        Output folder (created).
    """

    model: str
    omega_range: tuple
    points: int
    kp: tuple = ()
    kd: tuple = ()
    samples: Optional[int] = None
    steps: Optional[int] = None
    elements: Optional[int] = None
    modes: int = 10
    min_mac: Optional[float] = None
    workers: Optional[int] = None
    out: Path = Path("results")


def check_campbell_options(opts: "CampbellOptions") -> None:
    """The checks of the options alone (before any model is loaded).

    Raises
    ------
    ValueError
        One line naming the option (as ``flexstab campbell`` spells it) and the problem.
    """
    if isinstance(opts.points, bool) or not 2 <= opts.points <= MAX_POINTS:
        raise ValueError(f"--points must be an integer in 2..{MAX_POINTS}, got {opts.points}")
    if opts.samples is not None and (opts.samples < 4 or opts.samples % 2):
        raise ValueError(f"--samples must be an even integer >= 4, got {opts.samples}")
    if opts.steps is not None and opts.steps < 4:
        raise ValueError(f"--steps must be >= 4, got {opts.steps}")
    if opts.modes < 1:
        raise ValueError(f"--modes must be >= 1, got {opts.modes}")
    if opts.min_mac is not None and not (0.0 <= opts.min_mac <= 1.0):
        raise ValueError(f"--min-mac must lie in [0, 1], got {opts.min_mac}")
    if opts.workers is not None and opts.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {opts.workers}")
    if opts.model == "reduced":
        raise ValueError("--model reduced: the Campbell diagram needs a model file or a built-in model file "
                         "(e.g. single-link or exudyn)")


def campbell_diagram(opts: "CampbellOptions", cfg: Any, progress: bool = True) -> dict:
    """Compute the diagram of ``opts`` (``cfg``: the configuration, which decides the built-in single link);
    write PNG, JSON and CSV into ``opts.out``; return the JSON-ready summary."""
    import concurrent.futures as cf
    import hashlib
    import json

    from flexstab.executor import SerialExecutor, make_executor
    from flexstab.progress import make_bar, progress_bars
    from flexstab.options import ensure_out_dir, is_model_file, resolve_model_definition
    from linearize.periodic_orbit import DEFAULT_SAMPLES
    from stability.campbell import MIN_MAC, campbell

    check_campbell_options(opts)
    definition, options = resolve_model_definition(opts.model, cfg, opts.elements)
    lo, hi = opts.omega_range
    omegas = np.linspace(lo, hi, int(opts.points))
    samples = opts.samples if opts.samples is not None else DEFAULT_SAMPLES
    min_mac = MIN_MAC if opts.min_mac is None else float(opts.min_mac)
    kp = tuple(opts.kp) if opts.kp else ()
    kd = tuple(opts.kd) if opts.kd else ()
    task = CampbellPointTask(name=definition.name, source=definition.source if is_model_file(opts.model) else None,
                             options=options, kp=kp, kd=kd, samples=samples, n_steps=opts.steps)
    out_dir = ensure_out_dir(opts.out)
    t0, c0 = time.perf_counter(), time.process_time()
    # the command line's progress rule (flexstab.progress): tqdm on a terminal, lines on a pipe
    bar = make_bar(progress_bars() if progress else False, total=omegas.size, desc="campbell", unit="speed")

    def step(i: int, point: dict) -> None:
        bar.set_postfix_str(f"Ω = {point['omega']:.6g} rad/s, {len(point['modes'])} modes, "
                            f"{point['cpu_seconds']:.2f} s CPU")
        bar.update(1)

    close = bar.close
    points: list = [None] * omegas.size
    with make_executor("auto", max_workers=opts.workers, n_tasks=omegas.size) as ex:
        try:
            if isinstance(ex, SerialExecutor):
                for i, w in enumerate(omegas):
                    points[i] = task(float(w))
                    step(i, points[i])
            else:
                futures = {ex.submit(task, float(w)): i for i, w in enumerate(omegas)}
                for f in cf.as_completed(futures):
                    i = futures[f]
                    points[i] = f.result()
                    step(i, points[i])
        finally:
            close()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    result = campbell(omegas, modes_from_points(points), min_mac=min_mac)
    branches = branch_table(result)
    tag = hashlib.sha1(json.dumps([definition.name, definition.source, repr(sorted(options.items())), lo, hi,
                                   int(opts.points), kp, kd, samples, opts.steps, min_mac]).encode()).hexdigest()[:8]
    stem = out_dir / f"campbell_{definition.name}_{tag}"
    png = plot_campbell(result, branches, stem.with_suffix(".png"), max_branches=opts.modes,
                        title=f"Campbell diagram of {definition.name} ({omegas.size} speeds, "
                              f"Ω = {lo:.4g} .. {hi:.4g} rad/s; modes tracked by MAC)")
    csv_path = stem.with_suffix(".csv")
    campbell_tables(result, points, csv_path)
    point_cpu = [p["cpu_seconds"] for p in points]
    summary = {
        "model": opts.model,
        "omegas": omegas.tolist(),
        "kp": list(kp), "kd": list(kd),
        "rule": PRINCIPAL_RULE,
        "tracking": "MAC of the displacement shapes at t = 0 with each branch's last shape, one-to-one by "
                    "scipy.optimize.linear_sum_assignment on 1 - MAC; below min_mac a new branch",
        "min_mac": min_mac,
        "branches": branches,
        "points": [{k: v for k, v in p.items() if k != "modes"} | {"modes": [
            {k: v for k, v in m.items() if k != "shape"} | {"branch": int(result.tracking.branches[i][j])}
            for j, m in enumerate(p["modes"])]} for i, p in enumerate(points)],
        "timing": {"wall_seconds": wall, "cpu_seconds_this_process": cpu,
                   "cpu_seconds_per_point": point_cpu,
                   "cpu_seconds_per_point_mean": float(np.mean(point_cpu))},
        "figures": [str(png)],
        "csv": str(csv_path),
        "json": str(stem.with_suffix(".json")),
    }
    from stability.serialization import json_ready

    stem.with_suffix(".json").write_text(json.dumps(json_ready(summary)))
    return summary
