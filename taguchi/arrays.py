"""Taguchi orthogonal arrays, taken from :mod:`pydoe` and checked on load.

The tables are not typed here: every array comes from
``pydoe.get_orthogonal_array`` and is verified (balance and pairwise
orthogonality, i.e. strength 2) before it is offered.  Arrays that fail the
check are left out of the catalogue (logged at INFO); with pydoe 1.6.0 that
is ``'L64(2^31)'``, whose columns are neither balanced nor orthogonal.

Naming
------
Each array has a *canonical* name derived from its actual content, in
Taguchi's notation ``L<runs>(<levels>^<columns> ...)`` with the column groups
in column order, e.g. ``'L9(3^4)'``, ``'L18(6^1 3^6)'``, ``'L36(2^11 3^12)'``.
:func:`get_array` also accepts

* the short name ``'L<runs>'`` (``'L9'``, ``'L25'``, ``'L27'``, ``'L81'``, ...).
  Where pydoe offers two arrays with the same number of runs, the short name
  follows Taguchi's standard tables (Phadke 1989, Ch. 7 and appendix; Ross 1996, appendix):
  ``'L16'`` is the two-level ``L16(2^15)`` and ``'L32'`` is ``L32(2^31)``; the
  four-level "modified" arrays are reached by their full names
  ``'L16(4^5)'`` and ``'L32(2^1 4^9)'``.  ``'L64'`` is ``L64(4^21)``, the only
  64-run array that passes the check;
* pydoe's own labels, which for two arrays do not match the content
  (pydoe 1.6.0 labels the three-level ``L27(3^13)`` as ``'L27(2^1 3^12)'`` and
  the mixed ``L36(2^11 3^12)`` as ``'L36(3^23)'``);
* Minitab's spelling ``'L16(4**5)'``.

Names are matched case-insensitively and without regard to spaces.

References
----------
.. [1] G. Taguchi, *System of Experimental Design*, UNIPUB/Kraus, 1987.
.. [2] M. S. Phadke, *Quality Engineering Using Robust Design*,
   Prentice Hall, 1989, Ch. 3 and Ch. 7 (orthogonal arrays, standard tables).
.. [3] P. J. Ross, *Taguchi Techniques for Quality Engineering*, 2nd ed.,
   McGraw-Hill, 1996 (orthogonal arrays and their appendix tables).
.. [4] A. S. Hedayat, N. J. A. Sloane, J. Stufken, *Orthogonal Arrays:
   Theory and Applications*, Springer, 1999, Def. 1.1 (strength).
"""

from __future__ import annotations

import functools
import itertools
import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

__all__ = [
    "SHORT_NAMES",
    "OrthogonalArray",
    "array_for",
    "available_arrays",
    "check_orthogonal_array",
    "get_array",
    "is_balanced",
    "is_pairwise_orthogonal",
    "level_counts",
    "to_design",
]

logger = logging.getLogger(__name__)

#: Short names ``L<runs>`` for run counts where pydoe offers more than one
#: array: Taguchi's standard (two-level) table wins, as in Phadke (1989),
#: Ch. 7.  Unambiguous run counts get their short name automatically.
SHORT_NAMES: Mapping[str, str] = MappingProxyType(
    {
        "L16": "L16(2^15)",
        "L32": "L32(2^31)",
    }
)


def _as_level_matrix(matrix: npt.ArrayLike) -> np.ndarray:
    """Return ``matrix`` as a 2-D integer array of 0-based levels, or raise."""
    a = np.asarray(matrix)
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(
            f"an orthogonal array must be a non-empty 2-D matrix, got shape {a.shape}"
        )
    if not np.issubdtype(a.dtype, np.integer):
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise ValueError("orthogonal-array entries must be integer levels")
        a = a.astype(np.int64)
    if a.min() < 0:
        raise ValueError("orthogonal-array levels must be 0-based (no negative entries)")
    return a


def level_counts(matrix: npt.ArrayLike) -> tuple[int, ...]:
    """Number of levels of each column (``max + 1`` of the 0-based levels).

    Parameters
    ----------
    matrix : array_like of int, shape (runs, columns)
        Levels coded 0, 1, ..., s-1.

    Returns
    -------
    tuple of int
        ``s`` for every column.
    """
    a = _as_level_matrix(matrix)
    return tuple(int(v) + 1 for v in a.max(axis=0))


def is_balanced(matrix: npt.ArrayLike) -> bool:
    """Whether every column contains each of its levels equally often.

    Parameters
    ----------
    matrix : array_like of int, shape (runs, columns)
        0-based levels; column ``j`` is taken to have ``max(column j) + 1``
        levels, so a level that never appears makes the column unbalanced.

    Returns
    -------
    bool

    Maths
    -----
    Column ``j`` with ``s_j`` levels in ``N`` runs is balanced when each level
    appears exactly ``N / s_j`` times (strength 1).

    References
    ----------
    Phadke (1989), Ch. 3; Hedayat, Sloane & Stufken (1999), Def. 1.1.
    """
    a = _as_level_matrix(matrix)
    n_runs = a.shape[0]
    for j, s in enumerate(level_counts(a)):
        if n_runs % s:
            return False
        counts = np.bincount(a[:, j], minlength=s)
        if np.any(counts != n_runs // s):
            return False
    return True


def is_pairwise_orthogonal(matrix: npt.ArrayLike) -> bool:
    """Whether every pair of columns contains every level pair equally often.

    Parameters
    ----------
    matrix : array_like of int, shape (runs, columns)
        0-based levels.

    Returns
    -------
    bool
        True for a strength-2 orthogonal array (a single column is trivially
        orthogonal).

    Maths
    -----
    Columns ``i`` and ``j`` with ``s_i`` and ``s_j`` levels are orthogonal when
    each of the ``s_i s_j`` combinations ``(a, b)`` occurs ``N / (s_i s_j)``
    times in the ``N`` runs.

    References
    ----------
    Phadke (1989), Ch. 3 (balancing property); Ross (1996);
    Hedayat, Sloane & Stufken (1999), Def. 1.1.
    """
    a = _as_level_matrix(matrix)
    n_runs = a.shape[0]
    levels = level_counts(a)
    for i, j in itertools.combinations(range(a.shape[1]), 2):
        cells = levels[i] * levels[j]
        if n_runs % cells:
            return False
        counts = np.bincount(a[:, i] * levels[j] + a[:, j], minlength=cells)
        if np.any(counts != n_runs // cells):
            return False
    return True


def _canonical_name(n_runs: int, levels: Sequence[int]) -> str:
    groups = [f"{s}^{len(list(g))}" for s, g in itertools.groupby(levels)]
    return f"L{n_runs}({' '.join(groups)})"


def _normalise(name: str) -> str:
    return re.sub(r"\s+", "", name).replace("**", "^").upper()


@dataclass(frozen=True, eq=False)
class OrthogonalArray:
    """A strength-2 orthogonal array with 0-based levels.

    Parameters
    ----------
    name : str
        Canonical name, e.g. ``'L9(3^4)'``.
    matrix : numpy.ndarray of int, shape (runs, columns)
        Levels coded 0, ..., s-1; stored read-only.
    levels : tuple of int
        Number of levels of each column.
    columns : tuple of int
        Which columns of the catalogue array ``name`` this array holds (all of
        them unless made by :meth:`subset`).
    source : str
        Where the table came from (library, version and label).

    Notes
    -----
    Construction checks shape, levels, balance and pairwise orthogonality and
    raises ``ValueError`` if any fails.
    """

    name: str
    matrix: np.ndarray
    levels: tuple[int, ...]
    columns: tuple[int, ...] = ()
    source: str = ""

    def __post_init__(self) -> None:
        a = _as_level_matrix(self.matrix).copy()
        a.setflags(write=False)
        object.__setattr__(self, "matrix", a)
        levels = tuple(int(s) for s in self.levels)
        object.__setattr__(self, "levels", levels)
        if len(levels) != a.shape[1]:
            raise ValueError(
                f"{self.name}: {len(levels)} level counts for {a.shape[1]} columns"
            )
        if any(s < 2 for s in levels):
            raise ValueError(f"{self.name}: every column needs at least 2 levels")
        if np.any(a.max(axis=0) >= np.asarray(levels)):
            raise ValueError(f"{self.name}: a level index exceeds its column's level count")
        cols = tuple(int(c) for c in self.columns) or tuple(range(a.shape[1]))
        if len(cols) != a.shape[1]:
            raise ValueError(f"{self.name}: {len(cols)} column indices for {a.shape[1]} columns")
        object.__setattr__(self, "columns", cols)
        if level_counts(a) != levels or not is_balanced(a):
            raise ValueError(f"{self.name}: columns are not balanced")
        if not is_pairwise_orthogonal(a):
            raise ValueError(f"{self.name}: columns are not pairwise orthogonal")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, OrthogonalArray):
            return NotImplemented
        return (
            self.name == other.name
            and self.columns == other.columns
            and self.levels == other.levels
            and np.array_equal(self.matrix, other.matrix)
        )

    def __hash__(self) -> int:
        return hash((self.name, self.columns, self.matrix.tobytes()))

    @property
    def n_runs(self) -> int:
        """Number of runs (rows)."""
        return int(self.matrix.shape[0])

    @property
    def n_columns(self) -> int:
        """Number of columns (factors it can hold)."""
        return int(self.matrix.shape[1])

    def columns_with_levels(self, n_levels: int) -> tuple[int, ...]:
        """Indices (into this array) of the columns that have ``n_levels`` levels."""
        return tuple(j for j, s in enumerate(self.levels) if s == n_levels)

    def subset(self, columns: Sequence[int]) -> OrthogonalArray:
        """The array restricted to some of its columns (still strength 2).

        Parameters
        ----------
        columns : sequence of int
            Distinct column indices into this array, in the order wanted.
        """
        cols = [int(c) for c in columns]
        if not cols:
            raise ValueError("subset needs at least one column")
        if len(set(cols)) != len(cols):
            raise ValueError(f"duplicate columns in {cols}")
        bad = [c for c in cols if not 0 <= c < self.n_columns]
        if bad:
            raise ValueError(f"{self.name} has columns 0..{self.n_columns - 1}; got {bad}")
        return OrthogonalArray(
            name=self.name,
            matrix=self.matrix[:, cols],
            levels=tuple(self.levels[c] for c in cols),
            columns=tuple(self.columns[c] for c in cols),
            source=self.source,
        )


@functools.lru_cache(maxsize=1)
def _catalogue() -> tuple[Mapping[str, OrthogonalArray], Mapping[str, str]]:
    """Load and verify pydoe's arrays once; return (arrays, alias → canonical)."""
    import pydoe

    version = getattr(pydoe, "__version__", "unknown")
    arrays: dict[str, OrthogonalArray] = {}
    aliases: dict[str, str] = {}
    for label in pydoe.list_orthogonal_arrays():
        raw = np.asarray(pydoe.get_orthogonal_array(label))
        try:
            a = _as_level_matrix(raw)
            levels = level_counts(a)
            name = _canonical_name(a.shape[0], levels)
            oa = OrthogonalArray(
                name=name, matrix=a, levels=levels, source=f"pydoe {version} {label!r}"
            )
        except ValueError as exc:
            logger.info("pydoe array %r left out: %s", label, exc)
            continue
        if name != label:
            logger.debug("pydoe labels %r but its content is %r", label, name)
        arrays[name] = oa
        aliases[_normalise(name)] = name
        aliases.setdefault(_normalise(label), name)
    by_runs: dict[int, list[str]] = {}
    for name, oa in arrays.items():
        by_runs.setdefault(oa.n_runs, []).append(name)
    for runs, names in by_runs.items():
        if len(names) == 1:
            aliases.setdefault(f"L{runs}", names[0])
    for short, full in SHORT_NAMES.items():
        if full in arrays:
            aliases[_normalise(short)] = full
    return MappingProxyType(arrays), MappingProxyType(aliases)


def available_arrays() -> tuple[str, ...]:
    """Canonical names of the verified arrays, smallest first.

    Returns
    -------
    tuple of str
        e.g. ``('L4(2^3)', 'L8(2^7)', 'L9(3^4)', ...)``.
    """
    arrays, _ = _catalogue()
    return tuple(sorted(arrays, key=lambda n: (arrays[n].n_runs, n)))


def _short_names() -> dict[str, str]:
    _, aliases = _catalogue()
    return {k: v for k, v in aliases.items() if "(" not in k}


def get_array(name: str) -> OrthogonalArray:
    """Look up an orthogonal array by name.

    Parameters
    ----------
    name : str
        Short name (``'L9'``), canonical name (``'L9(3^4)'``), pydoe label or
        Minitab spelling (``'L9(3**4)'``); case and spaces are ignored.

    Returns
    -------
    OrthogonalArray

    Raises
    ------
    ValueError
        If the name is unknown; the message lists the available names.
    """
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"array name must be a non-empty string, got {name!r}")
    arrays, aliases = _catalogue()
    key = _normalise(name)
    if key not in aliases:
        shorts = ", ".join(sorted(_short_names(), key=lambda k: int(k[1:])))
        raise ValueError(
            f"unknown orthogonal array {name!r}; available: {', '.join(available_arrays())}"
            f" (short names: {shorts})"
        )
    return arrays[aliases[key]]


def array_for(n_factors: int, n_levels: int) -> OrthogonalArray:
    """The smallest array holding ``n_factors`` factors with ``n_levels`` levels each.

    Parameters
    ----------
    n_factors : int
        Number of factors (>= 1).
    n_levels : int
        Levels per factor (>= 2).

    Returns
    -------
    OrthogonalArray
        The array with the fewest runs that has at least ``n_factors`` columns
        of ``n_levels`` levels, restricted (:meth:`OrthogonalArray.subset`) to
        the first ``n_factors`` such columns, so ``matrix`` has exactly one
        column per factor.  Ties in run count go to the array with fewer
        columns.

    Raises
    ------
    ValueError
        If no available array fits.

    Examples
    --------
    >>> array_for(2, 3).name
    'L9(3^4)'
    >>> array_for(2, 5).matrix.shape
    (25, 2)
    """
    if isinstance(n_factors, bool) or not isinstance(n_factors, (int, np.integer)) or n_factors < 1:
        raise ValueError(f"n_factors must be a positive integer, got {n_factors!r}")
    if isinstance(n_levels, bool) or not isinstance(n_levels, (int, np.integer)) or n_levels < 2:
        raise ValueError(f"n_levels must be an integer >= 2, got {n_levels!r}")
    arrays, _ = _catalogue()
    fits = [
        oa for oa in arrays.values() if len(oa.columns_with_levels(int(n_levels))) >= n_factors
    ]
    if not fits:
        raise ValueError(
            f"no available orthogonal array holds {n_factors} factors at {n_levels} levels; "
            f"available: {', '.join(available_arrays())}"
        )
    best = min(fits, key=lambda oa: (oa.n_runs, oa.n_columns, oa.name))
    return best.subset(best.columns_with_levels(int(n_levels))[:n_factors])


def check_orthogonal_array(matrix: npt.ArrayLike | OrthogonalArray) -> None:
    """Raise ``ValueError`` unless ``matrix`` is balanced and pairwise orthogonal.

    Parameters
    ----------
    matrix : array_like of int or OrthogonalArray
        0-based levels, shape (runs, columns).
    """
    a = matrix.matrix if isinstance(matrix, OrthogonalArray) else matrix
    if not is_balanced(a):
        raise ValueError("matrix is not balanced (some column has unequal level counts)")
    if not is_pairwise_orthogonal(a):
        raise ValueError("matrix is not pairwise orthogonal")


def to_design(
    oa: OrthogonalArray | npt.ArrayLike, values: Sequence[Sequence[float]]
) -> np.ndarray:
    """Map 0-based levels to factor values, run by run.

    Parameters
    ----------
    oa : OrthogonalArray or array_like of int, shape (runs, columns)
        One column per factor (use :meth:`OrthogonalArray.subset` or
        :func:`array_for` to drop unused columns).
    values : sequence of sequences of float
        ``values[j][k]`` is the value of factor ``j`` at level ``k``; one entry
        per column, each with as many values as that column has levels.

    Returns
    -------
    numpy.ndarray of float, shape (runs, columns)
        ``design[i, j] = values[j][oa[i, j]]``.

    Examples
    --------
    >>> to_design(array_for(2, 3), [[0.0, 5.0, 10.0], [1.0, 2.0, 3.0]])[:3]
    array([[0., 1.],
           [0., 2.],
           [0., 3.]])
    """
    a = oa.matrix if isinstance(oa, OrthogonalArray) else _as_level_matrix(oa)
    levels = oa.levels if isinstance(oa, OrthogonalArray) else level_counts(a)
    if len(values) != a.shape[1]:
        raise ValueError(f"{len(values)} factor value lists for {a.shape[1]} columns")
    design = np.empty(a.shape, dtype=float)
    for j, (vals, s) in enumerate(zip(values, levels)):
        v = np.asarray(vals, dtype=float)
        if v.shape != (s,):
            raise ValueError(f"factor {j}: expected {s} level values, got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"factor {j}: level values must be finite")
        design[:, j] = v[a[:, j]]
    return design
