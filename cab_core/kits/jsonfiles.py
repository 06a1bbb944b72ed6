"""Reading an attempt's files as a plugin does (a record exporter, a harness reading its parent's
records): one JSON object, and an append-only JSON-lines log whose last line may be torn."""
from __future__ import annotations

import json
from pathlib import Path

from cab_core.errors import RecordError


def read_json_object(path: Path) -> dict:
    """One JSON object from ``path``; a missing or unparsable file is a RecordError."""
    path = Path(path)
    try:
        obj = json.loads(path.read_text())
    except FileNotFoundError as e:
        raise RecordError(f"{path.name} is missing") from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RecordError(f"{path.name} is not valid JSON: {e}") from e
    if not isinstance(obj, dict):
        raise RecordError(f"{path.name} does not hold a JSON object")
    return obj


def read_jsonl(path: Path) -> list[dict]:
    """Every line of an append-only log. A torn last line (a process killed mid-write) is
    dropped; a bad line anywhere else is a RecordError."""
    try:
        lines = Path(path).read_text().splitlines()
    except FileNotFoundError as e:
        raise RecordError(f"{Path(path).name} is missing") from e
    out = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError as e:
            if i == len(lines) - 1:
                break
            raise RecordError(f"{Path(path).name} line {i + 1} is not valid JSON: {e}") from e
    return out
