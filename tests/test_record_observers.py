"""Record observers (hook ``cab_record_observers``): selected by ``record.observers``, created in
the attempt's folder, given every event after it is written and the final result, read-only; one
that raises is logged once and detached, and the attempt and its verdict are unaffected."""
import copy
import json
import logging
import types
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

from cab_core import hookimpl
from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.records.observers import ReadOnlyDict, freeze
from cab_core.attempt.runner import attempt_spec, run_attempt
from cab_core.errors import ConfigError, PluginError
from cab_core.plugins import build_plugin_manager, distribution_versions
from cab_core.plugins import select_record_observers as select


def _plain(frozen):
    """A frozen event as JSON reads it back (tuples as lists)."""
    return json.loads(json.dumps(frozen))


def _plugin(name, observers):
    mod = types.ModuleType(name)
    mod.cab_record_observers = hookimpl(lambda: observers)
    return mod


class Recording:
    """Keeps what it is given; checks at each event that the recorder wrote it first."""

    def __init__(self, cfg):
        self.cfg = dict(cfg)
        self.dir = Path(cfg["attempt_dir"])
        self.events, self.results, self.on_disk_first = [], [], []
        (self.dir / f"{cfg['name']}.txt").write_text("created\n")

    def on_event(self, event):
        lines = (self.dir / "events.jsonl").read_text().splitlines()
        self.on_disk_first.append(json.loads(lines[-1]) == _plain(event))
        self.events.append(event)

    def on_result(self, result):
        self.results.append(result)


class Meddler(Recording):
    """Tries to change the third event it sees."""

    def on_event(self, event):
        super().on_event(event)
        if len(self.events) == 3:
            event["kind"] = "changed"


class BrokenFactory:
    def __init__(self, cfg):
        raise RuntimeError("cannot start")


@pytest.fixture
def installed(process_plugins):
    """Observers registered in the process's plugin manager, as an installed plugin's would be."""
    made: dict[str, list] = {}

    def factory(cls):
        return lambda cfg: made.setdefault(cfg["name"], []).append(cls(cfg)) or made[cfg["name"]][-1]

    plugin = _plugin("test_observers", {"keeper": factory(Recording), "meddler": factory(Meddler),
                                        "broken": BrokenFactory})
    process_plugins(plugin, "test_observers")
    return made


def _spec(out, observers):
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            ["sim=mujoco", "model=oracle", "task=click_bell", "record.video=false"]))
    spec = attempt_spec(cfg, out)
    spec.record["observers"] = observers
    return spec


def _events(d: Path):
    return [json.loads(line) for line in (d / "events.jsonl").read_text().splitlines()]


@pytest.mark.sim
def test_observers_follow_the_record_and_one_that_raises_is_detached(installed, tmp_path, caplog):
    out = tmp_path / "a"
    with caplog.at_level(logging.WARNING, logger="cab"):
        res = run_attempt(_spec(out, {"keeper": {"level": 3}, "meddler": None, "broken": {}}))
    keeper, = installed["keeper"]
    meddler, = installed["meddler"]
    assert "broken" not in installed  # its factory raised
    assert keeper.cfg == {"level": 3, "name": "keeper", "attempt_dir": str(out)}
    assert meddler.cfg == {"name": "meddler", "attempt_dir": str(out)}
    assert (out / "keeper.txt").read_text() == "created\n"

    on_disk = _events(out)
    assert [_plain(e) for e in keeper.events] == on_disk  # every event, in order, as written
    assert all(keeper.on_disk_first)  # each one after the recorder wrote it
    assert all(isinstance(e, ReadOnlyDict) for e in keeper.events)
    assert [_plain(r) for r in keeper.results] == [json.loads((out / "result.json").read_text())]

    detached = [e for e in on_disk if e["kind"] == "observer_detached"]
    assert [(e["observer"], e["stage"]) for e in detached] == [("broken", "factory"), ("meddler", "on_event")]
    assert detached[0]["error"] == "RuntimeError: cannot start"
    assert detached[1]["error"].startswith("TypeError: a recorded event is read-only")
    assert len(meddler.events) == 3 and meddler.results == []  # detached at its fault
    assert on_disk[2]["kind"] != "changed" and keeper.events[2]["kind"] == on_disk[2]["kind"]
    warnings = [r.getMessage() for r in caplog.records if "record observer" in r.getMessage()]
    assert len(warnings) == 2 and "'broken'" in warnings[0] and "'meddler'" in warnings[1]

    # versions: the core's and every installed plugin's distribution, read from the entry points
    packages = res["versions"]["packages"]
    assert {**distribution_versions(), "numpy": packages["numpy"]}.items() <= packages.items()
    assert "cab-sim-mujoco" in packages and "cab-harness-mcp" in packages

    # the same attempt with no observer: the same verdict and the same calls
    plain = run_attempt(_spec(tmp_path / "b", []))
    assert res["verdict"] == plain["verdict"] and res["verdict"]["success"] is True
    assert res["termination"] == plain["termination"]
    assert res["budget"]["tool_calls_used"] == plain["budget"]["tool_calls_used"]
    calls = lambda d: [(e["tool"], e["arguments"]) for e in _events(d) if e["kind"] == "call"]  # noqa: E731
    assert calls(out) == calls(tmp_path / "b")
    assert not any(e["kind"] == "observer_detached" for e in _events(tmp_path / "b"))


def test_an_unknown_observer_is_refused_before_anything_starts(installed, tmp_path):
    with pytest.raises(ConfigError, match=r"unknown record observer 'keeprr'; did you mean keeper\? "
                                          r"installed: .*broken, keeper, meddler"):
        run_attempt(_spec(tmp_path / "a", ["keeprr"]))
    assert not (tmp_path / "a").exists()


def test_selection():
    a = lambda cfg: None  # noqa: E731
    b = lambda cfg: None  # noqa: E731
    pm = build_plugin_manager([_plugin("p1", {"b_obs": b}), _plugin("p2", {"a_obs": a})], autoload=False)
    assert select({}, pm) == [("a_obs", a, {}), ("b_obs", b, {})]  # absent: every installed one
    assert select({"observers": None}, pm) == [("a_obs", a, {}), ("b_obs", b, {})]
    assert select({"observers": []}, pm) == []
    assert select({"observers": ["b_obs"]}, pm) == [("b_obs", b, {})]
    assert select({"observers": {"a_obs": {"x": 1}, "b_obs": None}}, pm) == [("a_obs", a, {"x": 1}), ("b_obs", b, {})]
    with pytest.raises(ConfigError, match="must be null .*, got 'a_obs'"):
        select({"observers": "a_obs"}, pm)
    with pytest.raises(ConfigError, match=r"record.observers.a_obs: an observer's config must be a mapping"):
        select({"observers": {"a_obs": 3}}, pm)
    with pytest.raises(ConfigError, match="a name must be a string"):
        select({"observers": [1]}, pm)
    with pytest.raises(ConfigError, match="installed: a_obs, b_obs"):
        select({"observers": ["zzz"]}, pm)
    twice = build_plugin_manager([_plugin("p1", {"a_obs": a}), _plugin("p2", {"a_obs": b})], autoload=False)
    with pytest.raises(PluginError, match="registered twice"):
        select({}, twice)


def test_frozen_events_are_read_only_deep_copies():
    ev = {"kind": "call", "arguments": {"xyz": [1, 2, {"a": 1}]}}
    f = freeze(ev)
    assert f == {"kind": "call", "arguments": {"xyz": (1, 2, {"a": 1})}}
    assert json.loads(json.dumps(f)) == ev
    for change in (lambda: f.__setitem__("kind", 1), lambda: f["arguments"].update(a=1), lambda: f.pop("kind"),
                   lambda: f["arguments"]["xyz"][2].clear(), lambda: f.setdefault("new", 1), lambda: f.popitem(),
                   lambda: f.__delitem__("kind")):
        with pytest.raises(TypeError):
            change()
    with pytest.raises(TypeError):
        f["arguments"]["xyz"][0] = 5  # a tuple
    mutable = copy.deepcopy(f)
    mutable["kind"] = "mine"
    assert type(mutable) is dict and f["kind"] == "call" and ev["kind"] == "call"
