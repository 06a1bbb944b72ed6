"""What every harness tells and shows its agent, in one place: the initial prompt (the system
prompt and the first user message; FACTS A.10, paper Appendix "Initial prompt": role, environment
facts with the harness-parameter JSON, both budgets, run_code limits and the termination rules;
the first user message is the task instruction alone), the run_code limits it states, and which
images a tool result carries to the agent. A harness that uses these gives its agent the same
prompt and the same images as any other."""
from __future__ import annotations

import io
import json
import logging

import numpy as np

log = logging.getLogger(__name__)

def _budget_lines(budget: dict) -> list[str]:
    calls = budget.get("tool_calls_limit", budget.get("tool_calls_remaining"))
    sim = budget.get("sim_seconds_limit", budget.get("sim_seconds_remaining"))
    return [
        f"- Tool calls: {calls}. Every call you make counts as one, except done; a run_code program counts as one "
        "call however many tools it uses inside. Invalid or malformed calls still count. When the calls are spent, "
        "the attempt ends.",
        f"- Simulated time: {sim} s. Only actions that move the robot advance the simulation and spend this "
        "budget (reach_tcp, reach_both_tcp, move_delta, move_both_delta, probe_contact_along, set_gripper, "
        "capture_motion_pair). An action already running finishes; the attempt ends at the next tool boundary "
        "once this time is spent.",
        "- Every tool result reports the budget remaining.",
    ]


def system_prompt(budget: dict, harness_parameters: dict, run_code: dict | None = None) -> str:
    """``budget`` is ``episode.ledger.remaining()``; ``harness_parameters`` the motion tools' rules
    the prompt states (:data:`cab_core.tools.motion.HARNESS_PARAMETERS`); ``run_code`` holds the
    sandbox limits (``timeout_s``, ``max_internal_calls``, ``max_images``, ``result_cap_bytes``,
    ``stdout_cap``)."""
    rc = {"timeout_s": 180, "max_internal_calls": 500, "max_images": 6, "result_cap_bytes": 32768, "stdout_cap": 8000}
    rc.update({k: v for k, v in (run_code or {}).items() if v is not None})
    params = json.dumps(harness_parameters, sort_keys=True, default=str)
    lines = [
        "# Role",
        "You control a dual-arm robot (two arms, each with a parallel gripper, and a head camera plus wrist "
        "cameras) through the tools provided. Your goal is the task in the user message. Act only through "
        "tool calls.",
        "",
        "# Facts about the environment",
        "- There is no depth sensor and no ground truth about objects. Any metric value you use (a position, a "
        "size, a distance) must come from evidence you gathered with the tools.",
        "- Tool results are typed JSON. What a motion achieved can differ from what was commanded: rely on the "
        "`achieved` values, not on `commanded`.",
        "- Images come from camera captures; each has an observation id (obs_...). Only the most recent images "
        "stay visible to you; earlier ones can be examined again by id (load_image inside run_code, or "
        "the tools that take an obs_id).",
        "- Metric scale can be obtained without touching the scene from three independent sources: calibrated "
        "camera motion (capture_motion_pair, then triangulate_correspondence), the visible gripper geometry "
        "known from forward kinematics (scale_from_gripper), and a size you assume for an object "
        "(scale_from_object_size, always coarse).",
        "- Contact feedback reports only the robot's own parts, never what was touched.",
        "- The motion planner avoids only the robot itself: not the table, objects, the other arm or a held "
        "object.",
        "- A motion that deviates, stalls or leaves the workspace is interrupted and reported with status "
        "ABORTED and the state actually reached; decide yourself how to recover.",
        "- Harness parameters (JSON): " + params,
        "",
        "# Budgets",
        *_budget_lines(budget),
        "",
        "# How to act",
        "- Direct tool calls and run_code are equally supported; choose whichever fits the step. The calls of one "
        "response run in order; if one of them is interrupted (ABORTED), the remaining calls of that response are "
        "cancelled and not executed.",
        "- Invalid arguments return an error you can correct in a later call.",
        "- Every response must contain at least one tool call.",
        "",
        "# run_code",
        "run_code runs a Python program in a sandbox where every tool (except run_code and done) is a function "
        "taking keyword arguments and returning a plain dict; `np`, `math`, `print` and `load_image(obs_id)` "
        "(an RGB array) are bound. Only `import numpy` and `import math` are allowed. Variables and functions "
        "persist between programs; assign `result` to return a value. Limits (JSON): "
        + json.dumps({"timeout_s": rc["timeout_s"], "max_internal_tool_calls": rc["max_internal_calls"],
                      "max_images_per_result": rc["max_images"], "result_cap_bytes": rc["result_cap_bytes"],
                      "stdout_cap_chars": rc["stdout_cap"]}, sort_keys=True)
        + ". A timeout or an aborted action inside the program interrupts it and resets the variables; "
        "the result says so.",
        "",
        "# Termination",
        "- Call done(report, success_claim) once, when you judge the task complete or decide you cannot proceed. "
        "It ends the attempt and does not reveal whether the task succeeded; success_claim is your own judgment.",
        "- The attempt also ends when a budget is spent, or after three responses in a row without a tool call.",
        "- The outcome is judged on the final state of the scene, whether or not you call done.",
    ]
    return "\n".join(lines)


def first_user_message(instruction: str) -> str:
    return instruction.strip()


def continuation_note(fork: dict | None) -> str:
    """What an agent that did not see the earlier calls is told when an attempt is a fork
    (``spec.fork``): where the world stands and that the calls made so far count. Empty otherwise.
    A harness that rebuilds its agent's conversation (the reference harness) needs no note."""
    if not fork:
        return ""
    k = int(fork["at"])
    return (f"\n\nThis attempt continues an earlier one from the state after its tool call {k}: the robot and "
            f"the objects are where that attempt left them, its {k} tool call(s) and the simulated time they "
            "took count against the budgets, and the observations it took can be used by their ids.")


def png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image as PILImage

    buf = io.BytesIO()
    PILImage.fromarray(np.asarray(image, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def result_images(episode, obs_ids: list[str], cap: int) -> tuple[list[tuple[str, bytes]], list[str]]:
    """The images one tool result carries: the last ``cap`` distinct observations as PNG, and the
    ids withheld (over the cap, or unreadable: reported, never fatal)."""
    ids = list(dict.fromkeys(obs_ids))
    keep = min(len(ids), max(0, int(cap or 0)))
    withheld = ids[:len(ids) - keep]
    shown = []
    for oid in ids[len(ids) - keep:]:
        try:
            shown.append((oid, png_bytes(episode.image(oid))))
        except Exception as e:  # an observation that cannot be read is reported, not fatal
            withheld.append(oid)
            log.warning("observation %s unavailable: %r", oid, e)
    return shown, withheld


def run_code_limits(spec) -> dict:
    """The run_code limits the system prompt states, from an attempt's spec."""
    rc = dict(getattr(spec, "sandbox", None) or {})
    if spec is not None:
        rc["max_internal_calls"] = spec.run_code_max_internal_calls
    return rc
