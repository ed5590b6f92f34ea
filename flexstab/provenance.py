"""Provenance of a study's files: hashes of code and inputs, stage records and the manifest.

A study writes, into its output folder, one *stage record* ``<stage>.stage.json`` per finished
stage and one ``manifest.json`` naming the run.  A record holds the hash of the stage's inputs
(:func:`inputs_hash`: the configuration, the options and :func:`code_hash`), the stage's report
blocks and the SHA-256 of every file it wrote (:func:`file_sha`); a record is *valid* for given
inputs when its inputs hash matches and every file it names is still the one it wrote
(:func:`record_valid`).  The stage runner (:mod:`flexstab.stages`) reuses exactly the stages whose
records are valid.

Both studies (:mod:`flexstab.study`, :mod:`flexstab.model_study`) and the charts' resumable stores
(:mod:`flexstab.chart_runs`) key their files through this module.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import importlib.util
import json
from pathlib import Path
from typing import Any, Mapping, Optional

__all__ = ["CODE_PACKAGES", "canonical", "short_hash", "code_hash", "file_sha", "inputs_hash", "record_path",
           "load_record", "write_record", "record_valid", "stage_files", "stamp_json", "read_manifest",
           "write_manifest", "now", "MANIFEST"]

#: Packages whose source code decides the numbers (hashed into every stage's inputs).
CODE_PACKAGES = ("mbs_models", "linearize", "stability", "taguchi", "validation", "flexstab")
#: The manifest of a study's output folder.
MANIFEST = "manifest.json"


def canonical(obj: Any) -> str:
    """``obj`` as canonical JSON (sorted keys, no spaces; anything else by ``str``): what is hashed."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def short_hash(text: str, n: int = 16) -> str:
    """The first ``n`` hex digits of the SHA-256 of ``text``."""
    return hashlib.sha256(text.encode()).hexdigest()[:n]


def code_hash(packages: tuple[str, ...] = CODE_PACKAGES) -> str:
    """SHA-256 (16 hex digits) of the source files of ``packages`` (a code change invalidates stages).

    Each file contributes its path relative to its package and its bytes, in sorted order.
    """
    h = hashlib.sha256()
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            continue
        for root in spec.submodule_search_locations:
            for f in sorted(Path(root).rglob("*.py")):
                h.update(str(f.relative_to(root)).encode())
                h.update(f.read_bytes())
    return h.hexdigest()[:16]


def file_sha(path: Path) -> str:
    """SHA-256 (16 hex digits) of the file ``path``."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def inputs_hash(inputs: Mapping[str, Any]) -> str:
    """Hash (16 hex digits) of a stage's inputs (a JSON-ready mapping; see :func:`canonical`)."""
    return short_hash(canonical(dict(inputs)))


def record_path(out: Path, name: str) -> Path:
    """``out/<name>.stage.json``: the record of stage ``name``."""
    return Path(out) / f"{name}.stage.json"


def _read_json(path: Path) -> Optional[dict]:
    """The JSON in ``path``, or ``None`` when the file is missing or unreadable."""
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def load_record(out: Path, name: str) -> Optional[dict]:
    """The record of stage ``name`` in ``out``, or ``None`` when it is missing or unreadable."""
    return _read_json(record_path(out, name))


def write_record(out: Path, record: Mapping[str, Any]) -> Path:
    """Write ``record`` (with a ``"stage"`` key) as ``out/<stage>.stage.json``; return its path."""
    p = record_path(out, record["stage"])
    p.write_text(json.dumps(dict(record), indent=2, default=str))
    return p


def stage_files(json_name: Optional[str], files=(), blocks=()) -> list[str]:
    """Every file a stage wrote: ``files``, the figures of its report ``blocks`` and its JSON (sorted)."""
    names = list(files or ())
    names += [b["file"] for b in blocks or () if b["kind"] == "figure"]
    if json_name:
        names.append(json_name)
    return sorted(set(names))


def record_valid(out: Path, rec: Optional[Mapping[str, Any]], ihash: str) -> bool:
    """Whether ``rec`` is for inputs ``ihash`` and every file it names is still the one it wrote."""
    if rec is None or rec.get("inputs_hash") != ihash or "error" in rec:
        return False
    for f, sha in rec.get("files", {}).items():
        p = Path(out) / f
        if not p.exists() or file_sha(p) != sha:
            return False
    return True


def stamp_json(path: Path, stamp: Mapping[str, Any]) -> None:
    """Add ``"study": stamp`` (configuration and inputs hashes) to a stage's data JSON (a JSON object)."""
    doc = json.loads(Path(path).read_text())
    if isinstance(doc, dict):
        doc["study"] = dict(stamp)
        Path(path).write_text(json.dumps(doc, indent=2, default=str))


def read_manifest(out: Path) -> Optional[dict]:
    """``out/manifest.json``, or ``None`` when it is missing or unreadable."""
    return _read_json(Path(out) / MANIFEST)


def write_manifest(out: Path, manifest: Mapping[str, Any]) -> None:
    """Write ``out/manifest.json``."""
    (Path(out) / MANIFEST).write_text(json.dumps(dict(manifest), indent=2, default=str))


def now() -> str:
    """The current UTC time as the records write it (``2026-01-31 12:00:00 UTC``)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
