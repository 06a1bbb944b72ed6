"""The attempt record's format: its version, and how a record file is written (JSON that takes
numpy values; written atomically, so a reader never sees half a file)."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

RECORD_VERSION = "cab-record/1"


def _json_default(o: Any):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps(obj: Any, **kw) -> str:
    return json.dumps(obj, default=_json_default, **kw)


def write_json_atomic(path: Path, obj: Any) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w") as f:
        f.write(dumps(obj, indent=2, sort_keys=False))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
