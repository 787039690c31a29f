"""Per-job result folders: checksummed manifest written last, atomic commit, validation, summary.

Protocol (what makes partial outputs impossible to mistake for complete ones):

1. the task writes into ``OUT/.tmp-<key>-<uuid>/`` (a name that is never a result);
2. the worker hashes every file and writes ``batch_result.json`` (the manifest) LAST, fsynced;
3. the folder is renamed to ``OUT/<key>`` (``rename`` is atomic on a POSIX filesystem): a result
   folder either does not exist or holds a complete manifest;
4. a result counts as done only if its manifest parses, names the same task, options and session
   content, and every listed file exists with the recorded size and SHA-256.

If two attempts of the same job race (an orphaned worker of a killed batch and its re-run), the
first rename wins and the second sees a valid result and discards its own copy, so a result is
never duplicated. A stale or corrupt result folder is moved aside and replaced.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

from vtrack.io.jsonio import write_json

RESULT_MANIFEST = "batch_result.json"
RESULT_FORMAT = "vtrack-batch-result"
RESULT_VERSION = 1
TMP_PREFIX = ".tmp-"
TRASH_PREFIX = ".trash-"


def sha256_file(path: Path, block: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def file_table(folder: Path) -> dict[str, dict[str, Any]]:
    """``{relative path: {"bytes", "sha256"}}`` of every file under ``folder`` (manifest excluded)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.name != RESULT_MANIFEST:
            out[p.relative_to(folder).as_posix()] = {"bytes": p.stat().st_size, "sha256": sha256_file(p)}
    return out


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def expected_identity(job: dict[str, Any]) -> dict[str, Any]:
    """The manifest fields that must match for a result to belong to ``job``."""
    return {
        "task": job["target"],
        "params_digest": job["params_digest"],
        "session_fingerprint": job["session_fingerprint"],
        "chunk": job["chunk"],
    }


def read_valid_result(folder: Path, job: dict[str, Any], check_hashes: bool = True) -> dict[str, Any] | None:
    """The manifest of ``folder`` if it is a complete, valid result of ``job``; else None."""
    m = folder / RESULT_MANIFEST
    try:
        man = json.loads(m.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return None
    if not isinstance(man, dict) or man.get("format") != RESULT_FORMAT:
        return None
    for k, v in expected_identity(job).items():
        if man.get(k) != v:
            return None
    files = man.get("files")
    if not isinstance(files, dict):
        return None
    for rel, info in files.items():
        p = folder / rel
        try:
            if p.stat().st_size != info["bytes"]:
                return None
            if check_hashes and sha256_file(p) != info["sha256"]:
                return None
        except (OSError, KeyError, TypeError):
            return None
    return man


def write_manifest(folder: Path, job: dict[str, Any], metrics: dict[str, Any], extra: dict[str, Any]) -> dict:
    """Hash the folder's files and write the manifest last (fsynced)."""
    man = {
        "format": RESULT_FORMAT,
        "version": RESULT_VERSION,
        **expected_identity(job),
        "key": job["key"],
        "session": job["session"],
        "params": job["params"],
        "metrics": metrics,
        "files": file_table(folder),
        **extra,
    }
    write_json(folder / RESULT_MANIFEST, man, indent=1, fsync=True)
    _fsync_dir(folder)
    return man


def commit(tmp: Path, final: Path, job: dict[str, Any]) -> str:
    """Rename a finished temp folder into place.

    Returns ``"committed"``, or ``"already_complete"`` when a valid result of the same job got
    there first (ours is discarded, so the result exists exactly once).
    """
    for _ in range(3):
        try:
            os.rename(tmp, final)
            _fsync_dir(final.parent)
            return "committed"
        except OSError:
            if not final.exists():
                raise
        if read_valid_result(final, job) is not None:
            shutil.rmtree(tmp, ignore_errors=True)
            return "already_complete"
        # Stale, foreign or corrupt folder in the way: move it aside atomically, then retry.
        trash = final.parent / f"{TRASH_PREFIX}{final.name}-{uuid.uuid4().hex[:8]}"
        try:
            os.rename(final, trash)
        except FileNotFoundError:
            pass
        shutil.rmtree(trash, ignore_errors=True)
    raise OSError(f"could not move result into place: {final}")


def clean_leftovers(out_root: Path) -> int:
    """Remove temp and trash folders of earlier (killed) runs; returns how many were removed.

    Only call this while holding the batch lock (no live worker of this output folder).
    """
    n = 0
    if not out_root.is_dir():
        return 0
    for p in out_root.iterdir():
        if p.name.startswith((TMP_PREFIX, TRASH_PREFIX)):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
            n += 1
    return n


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        elif isinstance(v, (list, tuple)):
            continue  # per-frame arrays stay in the per-session metrics, not in the table
        else:
            out[key] = v
    return out


SUMMARY_COLUMNS = ["key", "session", "chunk", "status", "attempts", "seconds", "host", "error"]


def summary_rows(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Flat table rows (scalar metrics as ``metric.<name>`` columns), one per job, in job order."""
    rows = []
    for r in records:
        ch = r.get("chunk")
        row = {
            "key": r["key"],
            "session": r["session"],
            "chunk": "" if not ch else f"{ch['frames'][0]}-{ch['frames'][1]}",
            "status": r["status"],
            "attempts": r.get("attempts", 0),
            "seconds": r.get("seconds"),
            "host": r.get("host", ""),
            "error": r.get("error", ""),
        }
        for k, v in _flatten(r.get("metrics") or {}).items():
            row[f"metric.{k}"] = v
        rows.append(row)
    return rows


def write_summary(out_root: Path, records: list[dict[str, Any]], run_info: dict[str, Any]) -> dict[str, Path]:
    """Write ``summary.csv`` and ``summary.json`` atomically; returns their paths."""
    rows = summary_rows(records)
    cols = list(SUMMARY_COLUMNS)
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    csv_path = out_root / "summary.csv"
    tmp = csv_path.with_name(f".summary.csv.{os.getpid()}.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k, "")) for k in cols})
    os.replace(tmp, csv_path)
    json_path = out_root / "summary.json"
    write_json(json_path, {"run": run_info, "results": records}, indent=1)
    return {"csv": csv_path, "json": json_path}
