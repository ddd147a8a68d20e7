"""Result records: one small JSON file per benchmark run under ``benchmarks/results/``.

The scoreboard of ``docs/results.md`` is generated from these files (``benchmarks/scoreboard.py``),
so a figure quoted there always comes with the command that printed it, the machine and the load
it ran under, the date and the code.

Schema (``"schema": 1``), every key required:

``benchmark``
    the script or make target that measured it (``"fidelity"``, ``"extract"``, ``"demo"`` ...).
``name``
    the record's file stem, unique in the folder (``"demo-bunny"``, ``"fidelity-dense-bunny-seed0"``).
``title``
    one line for the scoreboard's heading.
``command``
    the exact command line, runnable from the repository root.
``machine``
    ``{"cpu": model name, "cores": int, "gpu": card name or None, "torch": version or None}``.
``load``
    ``{"loadavg": [1, 5, 15 min] at the start, or None, "note": free text ("" when none)}``.
``date``
    ISO date (UTC) the figures were measured.
``commit``
    the git commit measured (12 hex digits, ``+dirty.<digest>`` when ``shsas_core/`` had
    uncommitted changes), or None when it was not recorded; ``commit_note`` says more.
``transcribed``
    None for a record written by the benchmark itself; for one copied by hand from an older
    document, ``{"from": where, "note": why}`` so that nobody takes it for a fresh run.
``columns``
    ``[[key, label, format], ...]``: the figures' keys in table order, their labels and a
    ``str.format`` spec (``"{:.3f}"``). The first column is the row's label (no format).
``rows``
    ``[{key: value, ...}, ...]``: one dict per table row; a missing or None value prints "–".
``notes``
    free text printed under the table ("" when none).

Optional: ``commit_note``, ``scene``, ``regime``, ``seed``, ``protocol``.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from shsas_core.common.machine import cpu_model

ROOT = Path(__file__).resolve().parents[1]
RESULTS_DIR = ROOT / "benchmarks" / "results"
#: The meshes of ``../shared`` beside the repository (read in place, never copied in).
SHARED_MESHES = ROOT.parent / "shared" / "data" / "meshes"
SCHEMA = 1
REQUIRED = ("schema", "benchmark", "name", "title", "command", "machine", "load", "date", "commit",
            "transcribed", "columns", "rows", "notes")
MACHINE_KEYS = ("cpu", "cores", "gpu", "torch")


def machine(gpu: str | None = None) -> dict[str, Any]:
    """The record's ``machine``: CPU model, cores, the GPU that ran it (None: none), torch version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        torch = version("torch")
    except PackageNotFoundError:
        torch = None
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "gpu": gpu, "torch": torch}


def load(note: str = "") -> dict[str, Any]:
    """The record's ``load``: the load averages now (call it at the start of the run)."""
    return {"loadavg": [round(x, 2) for x in os.getloadavg()], "note": note}


def commit() -> str | None:
    """The git commit of the tree, with a digest of uncommitted ``shsas_core/`` changes; None without git."""
    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    try:
        head = git("rev-parse", "HEAD").strip()[:12]
        changes = git("status", "--porcelain", "--", "shsas_core") + git("diff", "HEAD", "--", "shsas_core")
    except (OSError, subprocess.CalledProcessError):
        return None
    if not changes.strip():
        return head
    return f"{head}+dirty.{hashlib.sha256(changes.encode()).hexdigest()[:8]}"


def today() -> str:
    """Today's date, UTC, ISO."""
    return datetime.datetime.now(datetime.UTC).date().isoformat()


def override_suffix(overrides: Mapping[str, Any]) -> str:
    """The part of a record's name that says which spec fields a run changed (``-sparsity-0.3``):
    a run away from the defaults is its own record, so it never overwrites the scoreboard's row."""
    return "".join(f"-{k.replace('_', '-')}-{v}" for k, v in overrides.items())


def make_record(benchmark: str, name: str, title: str, command: str,
                columns: Sequence[Sequence[str]], rows: Iterable[Mapping[str, Any]], *,
                machine_info: Mapping[str, Any], load_info: Mapping[str, Any], notes: str = "",
                **extra: Any) -> dict[str, Any]:
    """A record of a run made now, by this tree (``date`` and ``commit`` filled in)."""
    record: dict[str, Any] = {
        "schema": SCHEMA, "benchmark": benchmark, "name": name, "title": title, "command": command,
        "machine": dict(machine_info), "load": dict(load_info), "date": today(), "commit": commit(),
        "transcribed": None, "columns": [list(c) for c in columns], "rows": [dict(r) for r in rows],
        "notes": notes, **extra}
    problems = validate(record)
    if problems:
        raise ValueError(f"record {name!r}: " + "; ".join(problems))
    return record


def validate(record: Mapping[str, Any]) -> list[str]:
    """What is wrong with ``record`` against the schema (empty when nothing)."""
    problems = [f"missing {k!r}" for k in REQUIRED if k not in record]
    if problems:
        return problems
    if record["schema"] != SCHEMA:
        problems.append(f"schema {record['schema']!r}, expected {SCHEMA}")
    for k in ("benchmark", "name", "title", "command", "date"):
        if not isinstance(record[k], str) or not record[k]:
            problems.append(f"{k!r} must be a non-empty string")
    m = record["machine"]
    if not isinstance(m, Mapping) or any(k not in m for k in MACHINE_KEYS):
        problems.append(f"'machine' must hold {', '.join(MACHINE_KEYS)}")
    ld = record["load"]
    if not isinstance(ld, Mapping) or "loadavg" not in ld or "note" not in ld:
        problems.append("'load' must hold 'loadavg' and 'note'")
    elif ld["loadavg"] is None and not ld["note"]:
        problems.append("'load' without a load average needs a note saying what is known")
    t = record["transcribed"]
    if t is not None and (not isinstance(t, Mapping) or not t.get("from")):
        problems.append("'transcribed' must be None or {'from': ..., 'note': ...}")
    cols = record["columns"]
    if not isinstance(cols, list) or not cols or any(not isinstance(c, list) or len(c) != 3 for c in cols):
        problems.append("'columns' must be a non-empty list of [key, label, format]")
    rows = record["rows"]
    if not isinstance(rows, list) or not rows or any(not isinstance(r, Mapping) for r in rows):
        problems.append("'rows' must be a non-empty list of objects")
    return problems


def write_record(record: Mapping[str, Any], folder: Path = RESULTS_DIR) -> Path:
    """Write ``record`` as ``folder/<name>.json`` (replacing an older run of the same name)."""
    problems = validate(record)
    if problems:
        raise ValueError(f"record {record.get('name')!r}: " + "; ".join(problems))
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{record['name']}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
    os.replace(tmp, path)
    return path


def read_records(folder: Path = RESULTS_DIR) -> tuple[list[dict[str, Any]], list[str]]:
    """The records in ``folder`` (sorted by name) and the names of JSON files there in a format of
    their own (no ``"schema"`` key, e.g. ``bench_gpu.py``'s); a malformed record raises ValueError."""
    records, others = [], []
    for path in sorted(folder.glob("*.json")):
        try:
            record = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{path.name}: not JSON ({e})") from None
        if not isinstance(record, dict):
            raise ValueError(f"{path.name}: not a JSON object")
        if "schema" not in record:
            others.append(path.name)
            continue
        problems = validate(record)
        if problems:
            raise ValueError(f"{path.name}: " + "; ".join(problems))
        if record["name"] != path.stem:
            raise ValueError(f"{path.name}: its name is {record['name']!r}, not the file's stem")
        records.append(record)
    return records, others
