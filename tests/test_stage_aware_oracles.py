"""Stage-aware reference solutions (put_bottles_dustbin, pick_diverse_bottles, dump_bin_bigbin,
place_bread_basket, place_object_basket, move_can_pot): a fork of the oracle's own attempt, at a
call where a hand is busy, is finished by the solution itself (it goes on from the hand as it is:
``keeps_hands``), never by giving up. Each case is a state the solution once could not go on from
(``cab-suite-check --forks``, catalog seed, SAPIEN)."""
from __future__ import annotations

from pathlib import Path

import pytest
from attempt_records import events
from hydra import compose, initialize_config_module

from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.records.recovery import recovery
from cab_core.attempt.runner import attempt_spec, run_attempt

CASES = {
    # the left hand open around the second bottle (taking it home knocked the bottle down)
    "put_bottles_dustbin": 14,
    # the left bottle held in front, the right hand open around its bottle
    "pick_diverse_bottles": 8,
    # the small bin held tipped over the dustbin (putting it down dropped it into the dustbin)
    "dump_bin_bigbin": 7,
    # the first bread held over the basket (putting it down and going home dragged the basket)
    "place_bread_basket": 6,
    # the object just let go in the basket, the hand still down in it
    "place_object_basket": 8,
    # the hand turned top-down over the can (taking it home knocked the can over)
    "move_can_pot": 4,
}


def run(out: Path, *overrides: str) -> dict:
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(["record.video=false", *overrides]))
    return run_attempt(attempt_spec(cfg, out))


@pytest.mark.parametrize("task", sorted(CASES))
def test_the_oracle_goes_on_from_a_busy_hand(task, tmp_path):
    parent = tmp_path / "oracle"
    assert run(parent, f"task={task}", "model=oracle")["verdict"]["success"] is True
    at = CASES[task]
    r = run(tmp_path / "fork", "model=oracle", f"fork.from='{parent}'", f"fork.at={at}")
    assert r["fork"]["exact"] is True
    assert recovery(tmp_path / "fork")["outcome"] == "recovered"
    assert not [e for e in events(tmp_path / "fork") if e["kind"] == "oracle_not_recoverable"]
