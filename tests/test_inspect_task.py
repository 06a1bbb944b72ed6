"""``inspect eval cab/codeaction`` (issue 29): real attempts on the MuJoCo simulator, each served by
``cab +harness=mcp`` in its own process to the Inspect agent, Inspect's ``mockllm`` as the model.

The machine is offline: Inspect's ``mockllm`` counts the tokens of what it is sent with tiktoken's
``o200k_base``, a file tiktoken downloads on first use. Where it is not in tiktoken's cache, the
tests count a token per four characters instead (:func:`offline_tokens`); nothing else of Inspect
is replaced."""
from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("inspect_ai")
pytest.importorskip("mujoco")

from inspect_ai import eval as inspect_eval  # noqa: E402
from inspect_ai._util.content import ContentImage, ContentText  # noqa: E402
from inspect_ai.log import read_eval_log, resolve_sample_attachments  # noqa: E402
from inspect_ai.model import (  # noqa: E402
    ChatMessageTool,
    ChatMessageUser,
    ModelOutput,
    ModelUsage,
    get_model,
)
from inspect_ai.tool import ToolError  # noqa: E402
from inspect_cab.attempt import AttemptFailed, Outcome, ServedAttempt, read_result  # noqa: E402
from inspect_cab.tools import inline_refs, tool_def  # noqa: E402

from cab_harness_mcp.script_client import calls_from_events  # noqa: E402

pytestmark = [pytest.mark.sim, pytest.mark.slow]

TASK = "click_bell"
CAB = shutil.which("cab") or "cab"

# `inspect` with tiktoken's token count replaced where its encoding cannot be fetched (module doc)
INSPECT = [sys.executable, "-c", """
import sys
try:
    import tiktoken
    tiktoken.get_encoding("o200k_base")
except Exception:
    import inspect_ai.model._model as m, inspect_ai.model._tokens as t
    t.count_text_tokens = m.count_text_tokens = lambda text: max(1, len(text) // 4)
from inspect_ai._cli.main import main
sys.argv = ["inspect", *sys.argv[1:]]
main()
"""]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def offline_tokens(monkeypatch) -> None:
    try:
        import tiktoken

        tiktoken.get_encoding("o200k_base")
    except Exception:
        import inspect_ai.model._model as m
        import inspect_ai.model._tokens as t

        for mod in (m, t):
            monkeypatch.setattr(mod, "count_text_tokens", lambda text: max(1, len(text) // 4))


def one_log(log_dir: Path):
    [path] = list(log_dir.glob("*.eval"))
    return read_eval_log(str(path))


@pytest.fixture(scope="module")
def oracle_calls(tmp_path_factory) -> list[dict]:
    """The oracle's calls on click_bell (MuJoCo, the catalog seed), recorded by a direct attempt."""
    out = tmp_path_factory.mktemp("oracle") / "attempt"
    subprocess.run([CAB, "+model=oracle", f"task={TASK}", "sim=mujoco", "record.video=false", f"hydra.run.dir={out}"],
                   check=True, capture_output=True, timeout=600)
    assert json.loads((out / "result.json").read_text())["verdict"]["success"] is True
    calls = calls_from_events(out / "events.jsonl")
    assert calls[-1]["tool"] == "done" and len(calls) > 2
    return calls


@pytest.fixture(scope="module")
def acceptance_run(tmp_path_factory) -> Path:
    """The issue's command, no key, run once: its working directory (the log in logs/)."""
    cwd = tmp_path_factory.mktemp("acceptance")
    r = subprocess.run([*INSPECT, "eval", "cab/codeaction", "-T", f"tasks={TASK}", "-T", "sim=mujoco",
                        "--model", "mockllm/model", "--limit", "1", "--log-dir", str(cwd / "logs"), "--display", "none"],
                       capture_output=True, text=True, timeout=600, cwd=cwd)
    assert r.returncode == 0, r.stderr[-3000:]
    return cwd


def test_acceptance_command_writes_a_scored_failure_with_cab_verdict(acceptance_run):
    """The default mockllm never calls a tool; each epoch's attempt is a failure scored by cab's
    verifier, its record in the sweep layout beside the log."""
    tmp_path = acceptance_run
    logs = tmp_path / "logs"
    log = one_log(logs)
    assert log.status == "success" and log.eval.task == "cab/codeaction"
    assert [(s.id, s.epoch) for s in log.samples] == [(f"{TASK}/seed-0", e) for e in (1, 2, 3)]  # 3 attempts: epochs
    root = next(logs.glob("*.cab"))
    for s in log.samples:
        score = s.scores["verdict"]
        assert score.value == "I" and s.error is None
        folder = Path(s.metadata["cab_attempt_dir"])
        assert folder == root / TASK / "mockllm_model" / "mujoco" / "seed-0" / f"attempt-{s.epoch}"
        assert score.metadata["attempt_dir"] == str(folder)
        record = json.loads((folder / "result.json").read_text())
        assert (record["model"], record["harness"], record["attempt"]) == ("mockllm/model", "mcp", s.epoch)
        assert score.metadata["termination"] == record["termination"]["reason"] == "client_disconnected"
        assert score.explanation.startswith("client_disconnected: ")
        assert score.metadata["predicates"] == record["verdict"]["predicates"]
        assert score.metadata["margins"] == record["verdict"]["margins"]
        assert score.metadata["checkpoints"] == record["checkpoints"]
        assert score.metadata["failure_stage"] == "arrival"
        assert (score.metadata["tool_calls"], score.metadata["sim_seconds"]) == (0, 0.0)
        assert score.answer is None  # no completion claim
        # cab's system prompt and task, then the model's three replies without a tool call
        assert [m.role for m in s.messages] == ["system", "user", "assistant", "user", "assistant", "user", "assistant"]
        assert s.messages[1].text == record["instruction"] + s.messages[1].text[len(record["instruction"]):]
    metrics = {(sc.reducer, k): v.value for sc in log.results.scores for k, v in sc.metrics.items()}
    assert metrics[("mean", "accuracy")] == metrics[("pass_at_1", "accuracy")] == metrics[("pass_at_3", "accuracy")] == 0
    assert metrics[("mean", "wilson_low")] == 0 and 0.79 < metrics[("mean", "wilson_high")] < 0.80

    # cab-report on the attempt folders counts what the log counts
    rep = subprocess.run(["cab-report", str(root), "--out", str(tmp_path / "report"), "--no-views", "--no-figure-files"],
                         capture_output=True, text=True, timeout=300)
    assert rep.returncode == 0, rep.stderr[-2000:]
    [config] = json.loads((tmp_path / "report" / "report.json").read_text())["configs"]
    assert config["config"] == "mockllm/model (mcp, mujoco)"
    assert (config["attempts"], config["successes"]) == (len(log.samples), sum(s.scores["verdict"].value == "C" for s in log.samples))

    # `inspect score` rescores from cab's records alone: the same verdicts (a log names its scorer
    # without its package, "verdict": the scorer is named in full)
    rescored = subprocess.run([*INSPECT, "score", str(next(logs.glob("*.eval"))), "--scorer", "cab/verdict",
                               "--action", "overwrite", "--overwrite", "--display", "none"],
                              capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert rescored.returncode == 0, rescored.stderr[-2000:]
    again = one_log(logs)
    assert [s.scores["verdict"].metadata for s in again.samples] == [s.scores["verdict"].metadata for s in log.samples]


def test_inspect_view_shows_the_sample_score(acceptance_run, tmp_path):
    """`inspect view` serves the log; headless Chromium opens it and shows the task's metrics and
    the sample's score in each epoch."""
    from browser import chromium

    port = free_port()
    server = subprocess.Popen(["inspect", "view", "--log-dir", str(acceptance_run / "logs"), "--port", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while not port_open(port):
            assert server.poll() is None and time.monotonic() < deadline, "inspect view did not come up"
            time.sleep(0.2)
        driver = chromium(tmp_path)
        try:
            driver.get(f"http://127.0.0.1:{port}/")
            text = ""
            deadline = time.monotonic() + 60
            while "3 Samples" not in text and time.monotonic() < deadline:
                time.sleep(0.5)
                text = driver.find_element("tag name", "body").text
        finally:
            driver.quit()
    finally:
        server.terminate()
        server.wait(timeout=30)
    lines = text.splitlines()
    assert "cab/codeaction" in lines and "mockllm/model" in lines
    assert "verdict (mean) 0.0 0.0 0.0 0.793" in lines  # accuracy, stderr, the Wilson interval
    # the sample list: one row per epoch, ID ... SCORE, each scored I (cab's failure)
    rows = lines[lines.index("SCORE") + 1:lines.index("3 Samples")]
    starts = [i for i, line in enumerate(rows) if line == f"{TASK}/seed-0"]
    assert [rows[i + 1] for i in starts] == ["1", "2", "3"]
    assert [rows[j - 1] for j in [*starts[1:], len(rows)]] == ["I", "I", "I"]


def test_oracle_calls_through_inspect_succeed_and_images_reach_the_model(tmp_path, monkeypatch, oracle_calls):
    """mockllm makes the oracle's calls one per turn: the attempt succeeds, the score says so, and
    the camera image of an observing call reaches the model (mockllm takes no image in a tool
    message: Inspect moves it into the user message after the tool message)."""
    offline_tokens(monkeypatch)
    from cab._registry import codeaction

    seen: list[list] = []
    offered: list[list] = []
    script = iter(oracle_calls)

    def model(input, tools, tool_choice, config) -> ModelOutput:
        seen.append(list(input))
        offered.append(list(tools))
        call = next(script)
        out = ModelOutput.for_tool_call("mockllm/model", call["tool"], call["args"])
        out.usage = ModelUsage(input_tokens=1, output_tokens=1, total_tokens=2)
        return out

    [log] = inspect_eval(codeaction(tasks=TASK, sim="mujoco", attempts=1, records=str(tmp_path / "records"), video=False),
                         model=get_model("mockllm/model", custom_outputs=model), log_dir=str(tmp_path / "logs"),
                         display="none")
    assert log.status == "success", log.error
    [sample] = log.samples
    score = sample.scores["verdict"]
    assert score.value == "C", score.explanation
    assert score.explanation == "done: the agent called done"
    assert score.answer.startswith("success_claim=true")
    record = read_result(Path(sample.metadata["cab_attempt_dir"]))
    charged = len(oracle_calls) - 1  # done is not charged
    assert record["verdict"]["success"] is True and record["budget"]["tool_calls_used"] == charged
    assert score.metadata["tool_calls"] == charged and score.metadata["failure_stage"] is None
    assert len(seen) == len(oracle_calls)  # one turn a call; the loop ends when done is accepted
    # the tools the model was offered are cab's, by name and description, in cab's order
    specs = json.loads((Path(__file__).parent / "data" / "tool_schemas.json").read_text())["specs"]
    assert [(t.name, t.description) for t in offered[0]] == [(t["name"], t["description"]) for t in specs]
    # the first call observes: its text in the tool message, its image in the user message after it
    assert oracle_calls[0]["tool"] == "capture_head"
    after = seen[1]
    assert [m.role for m in after] == ["system", "user", "assistant", "tool", "user"]
    tool_msg, user_msg = after[3], after[4]
    assert isinstance(tool_msg, ChatMessageTool) and tool_msg.function == "capture_head" and tool_msg.error is None
    assert json.loads(tool_msg.text.split("\n")[0])["obs_id"] == "obs_0001"
    assert isinstance(user_msg, ChatMessageUser)
    images = [c for c in user_msg.content if isinstance(c, ContentImage)]
    assert len(images) == 1 and images[0].image.startswith("data:image/png;base64,")
    assert "[image obs_0001]" in tool_msg.text  # the label stays with the result it belongs to
    # in the transcript the image stays in the tool message (where a provider takes images in tool results)
    transcript_tool = next(m for m in sample.messages if isinstance(m, ChatMessageTool))
    assert [type(c) for c in transcript_tool.content] == [ContentText, ContentText, ContentImage]


def test_reference_agent_plays_the_paper_harness_on_the_eval_model(tmp_path, monkeypatch, oracle_calls):
    """agent=reference: cab's reference harness in the attempt's process, its requests served by
    Inspect's model bridge with the eval's own model (mockllm, scripted with the oracle's calls):
    each is a model event of the sample's transcript, counted in the log's model usage, generated
    with the eval's settings; a success scored as under the react agent, the record the reference
    harness's, named by the model string."""
    offline_tokens(monkeypatch)
    from cab._registry import codeaction

    outputs = []
    for call in oracle_calls:
        out = ModelOutput.for_tool_call("mockllm/model", call["tool"], call["args"])
        out.usage = ModelUsage(input_tokens=10, output_tokens=2, total_tokens=12)
        outputs.append(out)
    model = get_model("mockllm/model", custom_outputs=outputs)
    [log] = inspect_eval(codeaction(tasks=TASK, sim="mujoco", agent="reference", attempts=1, video=False,
                                    records=str(tmp_path / "records")),
                         model=model, temperature=0.25, log_dir=str(tmp_path / "logs"), display="none")
    assert log.status == "success", log.error
    [sample] = log.samples
    score = sample.scores["verdict"]
    assert score.value == "C" and score.explanation == "done: the agent called done"
    folder = Path(sample.metadata["cab_attempt_dir"])
    assert folder == tmp_path / "records" / TASK / "mockllm_model" / "mujoco" / "seed-0" / "attempt-1"
    record = read_result(folder)
    assert (record["harness"], record["model"], record["agent"]["kind"]) == ("reference", "mockllm_model", "model_api")
    model_cfg = next(json.loads(line) for line in (folder / "events.jsonl").open())["config"]["model_cfg"]
    # the bridge's port (one per sample) is no setting of the configuration: cab-report keeps the samples together
    assert (model_cfg["provider"], model_cfg["model_id"], model_cfg["base_url"]) == ("openai_compatible", "inspect", None)
    n = len(oracle_calls)
    assert record["agent"]["usage"]["input_tokens"] == 10 * n  # every turn answered by the eval's model
    assert sample.output.completion == oracle_calls[-1]["args"]["report"]  # the completion claim
    # the eval's model saw every request: one model event a turn, in the sample's transcript
    events = [e for e in sample.events if e.event == "model"]
    assert len(events) == n and {e.model for e in events} == {"mockllm/model"}
    assert [e.output.message.tool_calls[0].function for e in events] == [c["tool"] for c in oracle_calls]
    first = events[0]
    sample = resolve_sample_attachments(sample)
    first = next(e for e in sample.events if e.event == "model")
    assert first.input[0].role == "system" and first.input[0].text.startswith("# Role\nYou control")  # cab's prompt
    assert first.input[1].role == "user" and first.input[1].text == sample.input  # the task's instruction
    assert "done" in {t.name for t in first.tools} and len(first.tools) == len(events[-1].tools) > 20
    assert all(e.config.temperature == 0.25 for e in events)  # the eval's generation settings apply
    # images after a tool result reach the model (the harness's rule for this API: one user message)
    assert any(isinstance(c, ContentImage) for e in events[1:] for m in e.input if m.role == "user"
               and not isinstance(m.content, str) for c in m.content)
    # and the log's model usage counts them
    usage = log.stats.model_usage["mockllm/model"]
    assert (usage.input_tokens, usage.output_tokens) == (10 * n, 2 * n)
    # the configuration is named by the Inspect model string in cab's report
    from cab_core.analysis.attempts import label_configurations, scan

    attempts = scan(tmp_path / "records").attempts
    label_configurations(attempts)
    assert [a.config for a in attempts] == ["mockllm/model (reference, mujoco)"]


def test_a_simulator_that_cannot_start_is_a_sample_error_not_a_score(tmp_path, monkeypatch):
    """cab exits without a record (here: an unknown simulator): the sample errors, unscored, so
    Inspect's retries (--retry-on-error, eval-set) run it again."""
    offline_tokens(monkeypatch)
    from cab._registry import codeaction

    [log] = inspect_eval(codeaction(tasks=TASK, sim="no_such_sim", attempts=1, records=str(tmp_path / "records")),
                         model="mockllm/model", log_dir=str(tmp_path / "logs"), display="none")
    assert log.status == "error"
    [sample] = log.samples
    assert sample.error is not None and not sample.scores
    assert sample.error.message.startswith('AttemptFailed("cab wrote no result.json')
    assert "cab: unknown sim 'no_such_sim'" in sample.error.message  # cab's own line, from its log beside the folder


def test_a_provider_failure_mid_attempt_is_a_sample_error_and_the_record_says_so(tmp_path, monkeypatch):
    """The model fails after one call: Inspect records a sample error (no score), and the attempt's
    record, which cab wrote as ended by its client, is marked as an infrastructure failure, so
    cab-report leaves it out as the log does."""
    offline_tokens(monkeypatch)
    from cab._registry import codeaction

    turns = iter([ModelOutput.for_tool_call("mockllm/model", "capture_head", {})])

    def model(input, tools, tool_choice, config) -> ModelOutput:
        out = next(turns, None)
        if out is None:
            raise ConnectionError("the provider is out")
        out.usage = ModelUsage(input_tokens=1, output_tokens=1, total_tokens=2)
        return out

    [log] = inspect_eval(codeaction(tasks=TASK, sim="mujoco", attempts=1, records=str(tmp_path / "records"), video=False),
                         model=get_model("mockllm/model", custom_outputs=model), log_dir=str(tmp_path / "logs"),
                         display="none")
    assert log.status == "error"
    [sample] = log.samples
    assert not sample.scores and "the provider is out" in sample.error.message
    folder = Path(sample.metadata["cab_attempt_dir"])
    record = json.loads((folder / "result.json").read_text())
    assert record["termination"]["reason"] == "client_disconnected" and record["budget"]["tool_calls_used"] == 1
    assert record["infrastructure"]["failed"] is True
    assert record["infrastructure"]["failures"][0]["kind"] == "inspect_sample_error"
    with pytest.raises(AttemptFailed, match="not scored"):
        read_result(folder)


def test_an_excluded_record_is_never_a_score(tmp_path):
    """A record whose termination is not the agent's (a provider outage, an interruption) raises,
    as does a folder without a record."""
    folder = tmp_path / "a"
    folder.mkdir()
    with pytest.raises(AttemptFailed, match="cab wrote no result.json"):
        read_result(folder)
    record = json.loads((Path(__file__).parent / "data" / "records" / "click_bell-oracle.json").read_text())
    record["termination"] = {"reason": "provider_failure", "detail": "the provider was out"}
    (folder / "result.json").write_text(json.dumps(record))
    with pytest.raises(AttemptFailed, match="not scored .provider_failure.: provider_failure: the provider was out"):
        read_result(folder)


def test_error_results_keep_their_images_and_errors_without_images_are_tool_errors():
    class Session:
        def __init__(self, result):
            self.result = result

        async def call_tool(self, name, arguments, read_timeout_seconds=None):
            return self.result

    import anyio
    import mcp_types as types

    png = "iVBORw0KGgo="
    with_image = types.CallToolResult(is_error=True, content=[
        types.TextContent(type="text", text=json.dumps({"error": "grasp failed", "obs_id": "obs_2"})),
        types.TextContent(type="text", text="[image obs_2]"),
        types.ImageContent(type="image", data=png, mime_type="image/png")])
    served = ServedAttempt(Session(with_image), Path("."))
    t = tool_def(served, "grasp", "Grasps.", {"type": "object", "properties": {}, "additionalProperties": False})
    content = anyio.run(t.tool)
    assert [type(c) for c in content] == [ContentText, ContentText, ContentImage]
    assert json.loads(content[0].text)["error"] == "grasp failed" and content[1].text == "[image obs_2]"
    assert content[2].image == f"data:image/png;base64,{png}"

    plain = types.CallToolResult(is_error=True, content=[types.TextContent(type="text", text='{"error": "bad arguments"}')])
    t = tool_def(ServedAttempt(Session(plain), Path(".")), "grasp", "Grasps.", {"type": "object", "properties": {}})
    with pytest.raises(ToolError, match="bad arguments"):
        anyio.run(t.tool)

    ended = types.CallToolResult(is_error=True, content=[types.TextContent(
        type="text", text='{"error": "the attempt has ended (tool_budget)", "attempt_ended": true}')])
    s = ServedAttempt(Session(ended), Path("."))
    assert anyio.run(s.call, "observe", {}).is_error and s.ended


def test_schema_references_are_inlined():
    schema = {"$defs": {"P": {"type": "object", "properties": {"x": {"type": "number"}}, "required": ["x"]}},
              "type": "object", "properties": {"a": {"$ref": "#/$defs/P", "description": "first"},
                                               "b": {"type": "array", "items": {"$ref": "#/$defs/P"}}}}
    assert inline_refs(schema) == {"type": "object", "properties": {
        "a": {"type": "object", "properties": {"x": {"type": "number"}}, "required": ["x"], "description": "first"},
        "b": {"type": "array", "items": {"type": "object", "properties": {"x": {"type": "number"}}, "required": ["x"]}}}}
    assert Outcome({}, [], [], False).images == []


def test_task_arguments_make_the_samples_and_cab_settings():
    """-T arguments: a suite stands for its tasks, seeds or a named seed set make one sample per
    task and seed, the budgets and randomisation become cab settings, the attempts the epochs;
    a mistake is one line."""
    from cab._registry import codeaction
    from inspect_ai.scorer._reducer.registry import reducer_log_names
    from inspect_cab.task import cab_overrides, resolve_tasks

    from cab_core.errors import ConfigError
    from cab_core.plugins import all_tasks

    assert resolve_tasks("codeaction") == list(all_tasks())[:25] and len(resolve_tasks("codeaction")) == 25
    assert resolve_tasks("click_bell, codeaction")[0] == "click_bell" and len(resolve_tasks("click_bell,codeaction")) == 25
    with pytest.raises(ConfigError, match="unknown task or suite 'no_such_task'; suites: codeaction"):
        resolve_tasks("no_such_task")
    t = codeaction(tasks="click_bell", sim="mujoco", seeds="3,4", attempts=2)
    assert [(s.id, s.metadata["seed"]) for s in t.dataset] == [("click_bell/seed-3", 3), ("click_bell/seed-4", 4)]
    assert t.epochs == 2 and reducer_log_names(t.epochs_reducer) == ["mean", "pass_at_1"]
    heldout = all_tasks()["click_bell"].seeds("heldout")
    t = codeaction(tasks="click_bell", sim="mujoco", seed_set="heldout")
    assert [s.metadata["seed"] for s in t.dataset] == list(heldout) and t.epochs == 3
    with pytest.raises(ConfigError, match="not both"):
        codeaction(tasks="click_bell", sim="mujoco", seeds="1", seed_set="heldout")
    with pytest.raises(ConfigError, match="-T agent must be one of react, reference"):
        codeaction(tasks="click_bell", sim="mujoco", agent="claude")
    assert cab_overrides("all", 12, 30, False, "sandbox.mode=off planner.x=1") == [
        "randomize=all", "budget.tool_calls=12", "budget.sim_seconds=30.0", "record.video=false",
        "sandbox.mode=off", "planner.x=1"]
