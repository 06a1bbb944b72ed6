"""The ``tcp_csv`` record observer: one CSV row per tool call with both arms' TCP
positions after it, written next to the attempt's other records (``tcp_positions.csv``)."""
from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import Any

COLUMNS = ("seq", "tool", "status", "physics_step_end", "left_x", "left_y", "left_z", "right_x", "right_y", "right_z")


def _tcp(result: Mapping[str, Any], arm: str) -> list[float | str]:
    """The arm's TCP position as a tool result reports it ("" when the result does not say)."""
    for key in ("observed_after", "observed_before"):
        obs = (result.get(key) or {}).get(arm) or {}
        pose = obs.get("tcp_pose")
        if pose:
            return [round(float(v), 5) for v in pose[:3]]
    return ["", "", ""]


class TcpCsv:
    def __init__(self, cfg: Mapping[str, Any]):
        self.path = Path(cfg["attempt_dir"]) / "tcp_positions.csv"
        self._rows: list[list] = []

    def on_event(self, event: Mapping[str, Any]) -> None:
        if event.get("kind") != "call":
            return
        result = event.get("result") or {}
        self._rows.append([event.get("seq"), event.get("tool"), event.get("status") or "",
                           event.get("physics_step_end", ""), *_tcp(result, "left"), *_tcp(result, "right")])

    def on_result(self, result: Mapping[str, Any]) -> None:
        with self.path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(COLUMNS)
            w.writerows(self._rows)
