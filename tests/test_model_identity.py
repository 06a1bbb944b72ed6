"""Issue 28, model identity: a configuration is named by what varies among the attempts reported
together; a model is given ad hoc (a generic provider option plus ``model.model_id=``); keys under
``model.`` are checked against what the model's harness and provider declare.

The two-model sweep is real: ``cab -m model=qwen_local model.model_id=modelA,modelB`` on MuJoCo
against a fake Chat Completions server (:class:`fake_json_api.FakeServer`, the real ``openai`` SDK
on the wire) that answers ``done`` at once; cab-report and cab-export then read its records."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from cab_core.analysis.configurations import NOT_IDENTITY, configuration_labels, identity

BIN = os.path.dirname(sys.executable)
DONE = {"report": "nothing done", "success_claim": False}
KEY_VARS = ("OPENAI_API_KEY", "OPENAI_BASE_URL", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy",
            "https_proxy", "all_proxy")


def _env():
    env = {k: v for k, v in os.environ.items() if k not in KEY_VARS}
    env["NO_PROXY"] = env["no_proxy"] = "127.0.0.1,localhost"
    return env


def _cab(args, cwd, exe="cab", timeout=300):
    return subprocess.run([os.path.join(BIN, exe), *args], cwd=cwd, env=_env(), capture_output=True, text=True,
                          timeout=timeout)


# --- the rule ---------------------------------------------------------------------------------


def _cfg(model="qwen_local", sim="mujoco", **model_cfg):
    return {"model": model, "harness": "reference", "sim": sim, "model_cfg": {"name": model, **model_cfg}}


def test_settings_that_differ_name_the_configurations_and_the_same_ones_do_not():
    labels = configuration_labels([_cfg(model_id="modelA", base_url="u", max_output_tokens=8),
                                   _cfg(model_id="modelB", base_url="u", max_output_tokens=8),
                                   _cfg(model_id="modelA", base_url="u", max_output_tokens=8)])
    assert labels == ["qwen_local[model_id=modelA] (reference, mujoco)",
                      "qwen_local[model_id=modelB] (reference, mujoco)",
                      "qwen_local[model_id=modelA] (reference, mujoco)"]


def test_a_configuration_alone_keeps_the_papers_name():
    assert configuration_labels([_cfg(model_id="m"), _cfg(model_id="m", sim="sapien")]) == \
        ["qwen_local (reference, mujoco)", "qwen_local (reference, sapien)"]


def test_nested_and_missing_settings_are_named_by_their_dotted_key():
    labels = configuration_labels([_cfg(extra_body={"enable_thinking": True}),
                                   _cfg(extra_body={"enable_thinking": False}),
                                   _cfg(reasoning_effort="high")])
    assert labels == [
        "qwen_local[extra_body.enable_thinking=true,reasoning_effort=unset] (reference, mujoco)",
        "qwen_local[extra_body.enable_thinking=false,reasoning_effort=unset] (reference, mujoco)",
        "qwen_local[extra_body.enable_thinking=unset,reasoning_effort=high] (reference, mujoco)"]


@pytest.mark.parametrize("key", sorted(NOT_IDENTITY - {"name"}))
def test_settings_that_are_not_the_models_identity_never_split_a_configuration(key):
    labels = configuration_labels([_cfg(model_id="m", **{key: 1}), _cfg(model_id="m", **{key: 2})])
    assert labels == ["qwen_local (reference, mujoco)"] * 2
    assert key not in identity({key: 1, "model_id": "m"})


def test_a_setting_that_follows_the_task_does_not_split_a_configuration():
    per_task = [dict(_cfg("scripted", script=f"{t}.json"), task=t) for t in ("lift_pot", "click_bell")]
    assert configuration_labels(per_task) == ["scripted (reference, mujoco)"] * 2
    two_per_task = per_task + [dict(_cfg("scripted", script="other.json"), task="lift_pot")]
    assert configuration_labels(two_per_task) == ["scripted[script=lift_pot.json] (reference, mujoco)",
                                                  "scripted[script=click_bell.json] (reference, mujoco)",
                                                  "scripted[script=other.json] (reference, mujoco)"]


def test_model_name_names_the_configuration_whatever_its_settings():
    labels = configuration_labels([_cfg("a", model_id="x"), _cfg("b", model_id="y")])
    assert labels == ["a (reference, mujoco)", "b (reference, mujoco)"]


def test_a_record_without_its_resolved_configuration_keeps_its_base_label():
    old = {"model": "qwen_local", "harness": "reference", "sim": "mujoco"}
    labels = configuration_labels([old, _cfg(model_id="a"), _cfg(model_id="b")])
    assert labels[0] == "qwen_local (reference, mujoco)"
    assert labels[1:] == ["qwen_local[model_id=a] (reference, mujoco)", "qwen_local[model_id=b] (reference, mujoco)"]


# --- two model ids, one sweep: two configurations in cab-report and the parquet export ---------


@pytest.fixture(scope="module")
def two_model_sweep(tmp_path_factory):
    pytest.importorskip("mujoco")
    pytest.importorskip("openai")
    from fake_json_api import FakeServer
    from test_provider_openai_compatible import completion, tc

    tmp = tmp_path_factory.mktemp("identity")
    out = tmp / "sweep"
    with FakeServer([(200, completion({"content": None, "tool_calls": [tc("call_1", "done", DONE)]}))]) as srv:
        r = _cab(["-m", "model=qwen_local", "model.model_id=modelA,modelB", f"model.base_url={srv.url}", "++model.probe=false",
                  "task=click_bell", "sim=mujoco", "record.video=false", f"hydra.sweep.dir={out}"], tmp)
        models = sorted(body.get("model") for path, body, _ in srv.requests)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert models == ["modelA", "modelB"]
    return out


A = "qwen_local[model_id=modelA] (reference, mujoco)"
B = "qwen_local[model_id=modelB] (reference, mujoco)"


@pytest.mark.sim
def test_two_model_ids_are_two_configurations_in_cab_report(two_model_sweep, tmp_path):
    r = _cab([str(two_model_sweep), "--out", str(tmp_path), "--no-views", "--no-figure-files"], tmp_path,
             exe="cab-report", timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert sorted(c["config"] for c in report["configs"]) == [A, B]
    assert sorted(row["config"] for row in report["attempt_rows"]) == [A, B]


@pytest.mark.sim
def test_two_model_ids_are_two_configurations_in_the_parquet_export(two_model_sweep, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    r = _cab(["parquet", str(two_model_sweep), "--out", str(tmp_path / "x")], tmp_path, exe="cab-export", timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    (table,) = [pq.read_table(p) for p in (tmp_path / "x").rglob("attempts.parquet")]
    assert sorted(table.column("config").to_pylist()) == [A, B]


# --- a model given ad hoc: a generic provider option plus model.model_id ------------------------


@pytest.mark.sim
def test_an_ad_hoc_model_runs_and_names_its_folder_and_configuration_by_its_id(tmp_path):
    pytest.importorskip("mujoco")
    pytest.importorskip("openai")
    from fake_json_api import FakeServer
    from test_provider_openai_compatible import completion, tc

    with FakeServer([(200, completion({"content": None, "tool_calls": [tc("call_1", "done", DONE)]}))]) as srv:
        r = _cab(["model=openai_compatible", "model.model_id=org/vl:8b", f"model.base_url={srv.url}", "++model.probe=false",
                  "task=click_bell", "sim=mujoco", "record.video=false"], tmp_path)
        (request,) = [body for _, body, _ in srv.requests]
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert request["model"] == "org/vl:8b"  # the id as given goes to the server
    (result,) = (tmp_path / "outputs" / "click_bell" / "org_vl_8b" / "mujoco").glob("*/result.json")
    assert json.loads(result.read_text())["model"] == "org_vl_8b"


@pytest.mark.parametrize("value, name", [("Qwen/Qwen3-VL-8B-Instruct", "Qwen_Qwen3-VL-8B-Instruct"),
                                         ("qwen3-vl:8b", "qwen3-vl_8b"), ("gpt-5.6", "gpt-5.6"),
                                         ("../x y", "x_y")])
def test_a_model_id_becomes_one_safe_folder_name(value, name):
    from cab_core.sweep.layout import folder_safe

    assert folder_safe(value) == name


@pytest.mark.parametrize("option", ["openai_compatible", "openai", "anthropic", "google"])
def test_a_generic_option_without_a_model_id_is_refused_in_one_line(option):
    from cab_core.apps.cmdline import check_command_line
    from cab_core.errors import ConfigError

    with pytest.raises(ConfigError) as e:
        check_command_line([f"model={option}", "task=click_bell"])
    assert str(e.value) == f"model={option} names no model: give model.model_id=<the id the provider serves>"
    check_command_line([f"model={option}", "model.model_id=some/model", "task=click_bell"])  # accepted


# --- keys under model. are checked ------------------------------------------------------------


def _refusal(argv):
    from cab_core.apps.cmdline import check_command_line
    from cab_core.errors import ConfigError

    with pytest.raises(ConfigError) as e:
        check_command_line(argv)
    return str(e.value)


@pytest.mark.parametrize("key", ["model.base_ur", "+model.base_ur", "++model.base_ur"])
def test_a_misspelt_model_key_is_refused_with_the_closest_valid_one(key):
    msg = _refusal(["model=qwen_local", f"{key}=http://x", "task=click_bell"])
    assert msg.startswith("unknown key 'model.base_ur'; did you mean model.base_url? "
                          "valid keys under model (model=qwen_local): name, agent, harness, ")
    assert "max_tokens_param" in msg and "limits" in msg and "paper_usage" in msg and "\n" not in msg


def test_every_model_option_of_a_sweep_is_checked():
    # model_id is every provider's; max_tokens_param is only the Chat Completions provider's
    msg = _refusal(["-m", "model=qwen_local,opus5", "model.max_tokens_param=max_tokens", "task=click_bell"])
    assert msg.startswith("unknown key 'model.max_tokens_param'; did you mean model.max_output_tokens? "
                          "valid keys under model (model=opus5): ")


def test_the_model_free_agents_take_their_own_keys():
    assert _refusal(["model=scripted", "model.scrip=x.jsonl", "task=click_bell"]).startswith(
        "unknown key 'model.scrip'; did you mean model.script? valid keys under model (model=scripted): "
        "name, agent, harness, script")
    assert _refusal(["model=idle", "+model.script=x.jsonl", "task=click_bell"]) == (
        "unknown key 'model.script'; valid keys under model (model=idle): name, agent, harness")


@pytest.mark.parametrize("argv", [
    ["model=qwen_local", "model.base_url=http://h/v1", "model.retry.max_attempts=5"],
    ["model=opus5", "model.effort=low", "+model.limits={requests_per_minute: 50}"],
    ["model=mcp_client", "model.name=my-agent"],
    ["model=scripted", "model.script=calls.jsonl"],
])
def test_keys_the_plugins_declare_are_accepted(argv):
    from cab_core.apps.cmdline import check_command_line

    check_command_line([*argv, "task=click_bell"])


def test_every_shipped_model_option_carries_only_declared_keys():
    from cab_core.apps.cmdline import check_command_line
    from cab_core.config import Compositions

    with Compositions.of_command(None, None, None, []) as c:
        options = c.options("model")
    assert {"qwen_local", "opus5", "openai_compatible", "mcp_client", "scripted"} <= set(options)
    for option in options:
        if option != "human":  # played from cab-studio only
            check_command_line([f"model={option}", "model.model_id=m", "task=click_bell"]
                               if option in ("openai_compatible", "openai", "anthropic", "google", "inspect") else
                               [f"model={option}", "task=click_bell"])


def test_a_misspelt_model_key_exits_2_before_any_folder_is_written(tmp_path):
    r = _cab(["model=qwen_local", "+model.base_ur=http://127.0.0.1:9/v1", "task=click_bell", "sim=mujoco"], tmp_path)
    assert r.returncode == 2
    assert r.stderr.startswith("cab: unknown key 'model.base_ur'; did you mean model.base_url? ")
    assert len(r.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.sim
def test_two_model_ids_are_two_configurations_in_the_studios_progress(two_model_sweep):
    from cab_core.apps.studio.tree import groups

    (g,) = groups(two_model_sweep)
    assert sorted(a["config"] for a in g.as_dict()["attempts"]) == [A, B]
    assert all("identity" not in a for a in g.as_dict()["attempts"])  # the page shows the label only
