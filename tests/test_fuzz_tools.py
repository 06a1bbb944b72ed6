"""Property-based fuzzing of every tool (issue 12, item 3): the call contract holds for any arguments.

One MuJoCo attempt per module serves the cases (``done``'s refusals get their own attempt, since a
wrongly accepted ``done`` ends its attempt). For each tool of the registry, hypothesis draws arguments
of four kinds, from the tool's own JSON schema (``TOOLS[name].json_schema()``):

* ``valid``: hypothesis-jsonschema's ``from_schema``; an ``obs_id``/``pair_id`` is a live id of the
  attempt, the newest one, a well-formed id that does not exist, or the schema's random string;
* ``boundary``: one field set to a bound of its declared range (the bound, the next float outside),
  length (empty, at and past min/max) or item count, or a variant of an enum value;
* ``odd_value``: one field set to NaN, +-inf, +-1e308, -0.0, 5e-324, 10**400, 2**63, a number as a
  string, a boolean, null, an object, an empty or nested list, a 1 MB string or a 100,000-item list;
* ``structure``: an unknown field (one or 300), a required field dropped, or arguments that are not
  an object (a list, a string, a number, a boolean, null).

Each case is sent directly (``Episode.call``) and, for every robot tool, from ``run_code``: many
cases per program, each call guarded so one failure does not stop the batch, the kwargs written as
Python literals (``float('nan')``, ``'x' * 1000000``). Every answer must satisfy the contract:

* a success, or a typed error: ``error`` with a ``code`` in :data:`ERROR_CODES`, whose text starts
  as that code's does and is at most :data:`ERROR_CHARS` characters;
* arguments the published schema refuses (or that hold a non-finite number) are refused with
  ``invalid_tool_arguments``;
* no attempt ends (``done`` aside) and the budget is charged as the catalog says: exactly one call
  per direct call or ``run_code`` (whatever the program calls), none for ``done``;
* no host traceback and no host path (the repository, site-packages, the temp dir, the attempt's
  output directory, the sandbox's directory) reaches the agent;
* every number the agent gets is finite, and an estimate marked valid has a non-degenerate value (a
  unit ray direction, finite points and pixels, a positive finite depth);
* a success matches the tool's documented result model (``TOOLS[name].result``), an action's status
  is SUCCESS, FAILED or ABORTED.

Besides the random cases: a deterministic sweep puts every odd value in every field of every tool
(both surfaces), and degenerate geometry (vectors of 5e-324, the camera centre, planes through it,
pixels at the range limits, sub-pixel boxes, targets at the workspace envelope) is tried explicitly.

From ``run_code``, every internal trace entry is checked against the host's record of that internal
call (``events.jsonl``, kind ``internal_call``: the exact payload the program received), and the
program's own per-case summary against both.

Deterministic (derandomized, no example database, no shrinking); the number of cases per tool is
printed in the terminal summary. ``CAB_FUZZ_SCALE=4`` runs four times as many cases and
``CAB_FUZZ_SHRINK=1`` minimises a failing case.
"""
from __future__ import annotations

import copy
import json
import math
import os
import re
import sys
import tempfile
from collections import Counter
from pathlib import Path

import jsonschema
import pydantic
import pytest
from helpers_data import replaced
from hypothesis import HealthCheck, Phase, assume, given, settings
from hypothesis import strategies as st
from hypothesis_jsonschema import from_schema

pytest.importorskip("mujoco")

from hydra import compose, initialize_config_module  # noqa: E402

from cab_core.apps.cli import normalise_overrides  # noqa: E402
from cab_core.attempt.engine.episode import Episode  # noqa: E402
from cab_core.attempt.runner import attempt_spec  # noqa: E402
from cab_core.errors import AttemptEnded  # noqa: E402
from cab_core.plugins import all_tasks, create  # noqa: E402
from cab_core.tools import TOOLS, validate_args  # noqa: E402

ROBOT_TOOLS = [n for n in TOOLS if n not in ("run_code", "done")]
MOTION = {n for n, t in TOOLS.items() if t.advances_physics}
ACTIONS = MOTION - {"capture_motion_pair"}  # their successes are ActionResults with a status
RENDERS = {n for n, t in TOOLS.items() if t.renders}
ESTIMATE_KINDS = {"pixel_point", "ray", "world_point", "depth"}
ID_FIELDS = ("obs_id", "pair_id")

# typed error codes an agent may get, and how each error text starts
ERROR_CODES = {
    "invalid_tool_arguments": ("bad arguments", "unknown tool"),
    "tool_error": ("tool error: ",),
    "observation_unavailable": ("observation unavailable",),
}
ERROR_CHARS = 1000  # an error the agent gets is short, whatever it sent
STATUSES = {"SUCCESS", "FAILED", "ABORTED"}

SCALE = float(os.environ.get("CAB_FUZZ_SCALE", "1"))
BUDGET_CALLS = 1_000_000

# hypothesis examples per tool: direct calls, and run_code programs (each a batch of cases)
DIRECT_EXAMPLES = 30
DIRECT_EXAMPLES_SLOW = 15  # rendering and motion tools
PROGRAMS = 3
BATCH = (4, 12)
DONE_EXAMPLES = 60
PROGRAM_CASES = 40  # cases per program in the sweep: its result stays under run_code's 32 KiB cap


def fuzz_settings(n: int):
    phases = [Phase.explicit, Phase.generate] + ([Phase.shrink] if os.environ.get("CAB_FUZZ_SHRINK") else [])
    return settings(max_examples=max(1, round(n * SCALE)), deadline=None, derandomize=True, database=None,
                    phases=phases, print_blob=False,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much, HealthCheck.large_base_example])


# -- the tools' schemas ------------------------------------------------------------------------------
def _inline(node, root):
    if isinstance(node, dict):
        if "$ref" in node:
            return _inline(root["$defs"][node["$ref"].rsplit("/", 1)[-1]], root)
        return {k: _inline(v, root) for k, v in node.items() if k != "$defs"}
    if isinstance(node, list):
        return [_inline(v, root) for v in node]
    return node


SCHEMAS = {n: _inline(t.json_schema(), t.json_schema()) for n, t in TOOLS.items()}
VALIDATORS = {n: jsonschema.Draft202012Validator(s) for n, s in SCHEMAS.items()}


def _nonnull(sub: dict) -> dict:
    """The non-null branch of an optional field's ``anyOf``."""
    for b in sub.get("anyOf", ()):
        if b.get("type") != "null":
            return b
    return sub


def nonfinite(v, path: str = "$"):
    """Paths of the non-finite floats in a JSON-like value."""
    if isinstance(v, float) and not math.isfinite(v):
        yield path
    elif isinstance(v, dict):
        for k, x in v.items():
            yield from nonfinite(x, f"{path}.{k}")
    elif isinstance(v, (list, tuple)):
        for i, x in enumerate(v):
            yield from nonfinite(x, f"{path}[{i}]")


def schema_refuses(tool: str, args) -> bool:
    """Whether the schema the agent is shown refuses these arguments (no arguments read as {}); a
    non-finite number is refused too: JSON has none."""
    args = {} if args is None else args
    return next(nonfinite(args), None) is not None or not VALIDATORS[tool].is_valid(args)


# world x, y, z ranges (m) around the arms' home TCPs (left arm at -x, right at +x)
NEAR = {"target_xyz": [(-0.45, 0.45), (-0.4, 0.1), (0.85, 1.1)], "tcp_xyz": [(-0.45, 0.45), (-0.4, 0.1), (0.85, 1.1)],
        "left_xyz": [(-0.45, -0.15), (-0.4, 0.1), (0.85, 1.1)], "right_xyz": [(0.15, 0.45), (-0.4, 0.1), (0.85, 1.1)]}
QUAT_FIELDS = {"target_quat", "left_quat", "right_quat"}

# -- cases ---------------------------------------------------------------------------------------------
HUGE_STR = "x" * 1_000_000
HUGE_LIST = [0.5] * 100_000
DEEP: list = [0.1]
DEEP_DICT: dict = {"x": 0.1}
for _ in range(40):
    DEEP, DEEP_DICT = [DEEP], {"x": DEEP_DICT}
ODD_VALUES = [math.nan, math.inf, -math.inf, 1e308, -1e308, -0.0, 5e-324, 10**400, -(10**400), 2**63,
              "0.1", "nan", "1e308", True, False, None, {"x": 0.1}, {}, DEEP_DICT, [], [[]], [None], DEEP, "",
              "left\x00", "\udbad", HUGE_STR, HUGE_LIST]
UNKNOWN_KEYS = ["zzz", "", "ARM", "__proto__", "obs_id ", "x" * 300]
NON_OBJECTS = [None, [], [{"arm": "left"}], "left", '{"arm": "left"}', 0, 1e308, True]
BAD_IDS = {"obs_id": ["obs_9999", "obs_0000", "OBS_0001", "obs_0001 ", "../obs_0001", "obs_-1", "pair_001"],
           "pair_id": ["pair_999", "pair_000", "PAIR_001", "pair_001 ", "obs_0001", "pair_-1"]}


def _short(v, n: int = 80):
    """A readable stand-in for a large value (failure messages)."""
    if isinstance(v, str):
        return repr(v) if len(v) <= n else f"<str len={len(v)} {v[:20]!r}...>"
    if isinstance(v, list):
        if len(v) > 8:
            return f"<list len={len(v)} [{_short(v[0])}, ...]>"
        return "[" + ", ".join(_short(x) for x in v) + "]"
    if isinstance(v, dict):
        if len(v) > 12:
            return f"<dict len={len(v)}>"
        return "{" + ", ".join(f"{_short(k)}: {_short(x)}" for k, x in v.items()) + "}"
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) > 10**20:
        return f"<int of {len(str(abs(v)))} digits>"
    return repr(v)


class Case:
    """One case: its kind (valid | boundary | odd_value | structure), the mutation, the arguments."""

    __slots__ = ("kind", "what", "args")

    def __init__(self, kind: str, what: str, args: object):
        self.kind, self.what, self.args = kind, what, args

    def __repr__(self) -> str:
        return f"Case({self.kind}: {self.what}: {_short(self.args)})"


def slots(value, sub: dict, path: tuple = ()) -> list[tuple[tuple, dict, bool]]:
    """(path, schema, present) for every field of an instance below the root (list items and
    nested objects included) and for every absent optional property."""
    out = []
    sub = _nonnull(sub)
    if sub.get("type") == "object" and isinstance(value, dict):
        for k, ps in sub.get("properties", {}).items():
            if k in value:
                out.append((path + (k,), _nonnull(ps), True))
                out += slots(value[k], ps, path + (k,))
            else:
                out.append((path + (k,), _nonnull(ps), False))
    elif sub.get("type") == "array" and isinstance(value, list):
        for i, v in enumerate(value):
            out.append((path + (i,), _nonnull(sub.get("items", {})), True))
            out += slots(v, sub.get("items", {}), path + (i,))
    return out


def example(sub: dict):
    """A simple instance of a schema (for boundary lists)."""
    sub = _nonnull(sub)
    t = sub.get("type")
    if "enum" in sub:
        return sub["enum"][0]
    if t in ("number", "integer"):
        lo = sub.get("minimum", sub.get("exclusiveMinimum", 0))
        hi = sub.get("maximum", sub.get("exclusiveMaximum", lo + 1))
        return lo + (hi - lo) / 2 if t == "number" else int(lo)
    if t == "string":
        return "a" * max(1, sub.get("minLength", 0))
    if t == "array":
        return [example(sub.get("items", {})) for _ in range(max(1, sub.get("minItems", 0)))]
    if t == "object":
        return {k: example(sub["properties"][k]) for k in sub.get("required", [])}
    if t == "boolean":
        return True
    return None


def boundary_values(sub: dict) -> list:
    """Values at and just past the declared limits of one field."""
    sub = _nonnull(sub)
    t = sub.get("type")
    vals: list = []
    if "enum" in sub:
        for e in sub["enum"]:
            vals += [e, e.upper(), f" {e}", e[:-1]] if isinstance(e, str) else [e]
    if t in ("number", "integer"):
        for k in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
            if k in sub:
                b = float(sub[k])
                vals += [sub[k], math.nextafter(b, -math.inf), math.nextafter(b, math.inf)]
        vals += [0, 0.0, -0.0, 1e-300, -1e-300]
    elif t == "string":
        lo, hi = sub.get("minLength", 0), sub.get("maxLength")
        vals += ["", "a" * lo, "a" * max(0, lo - 1)]
        if hi is not None:
            vals += ["a" * hi, "é" * hi, "a" * (hi + 1)]
    elif t == "array":
        lo, hi = sub.get("minItems", 0), sub.get("maxItems")
        item = example(sub.get("items", {}))
        for n in sorted({0, lo, max(0, lo - 1)} | ({hi, hi + 1} if hi is not None else {lo + 1})):
            vals.append([copy.deepcopy(item) for _ in range(n)])
    elif t == "object":
        vals += [{}, example(sub)]
    elif t == "boolean":
        vals += [True, False, 0, 1, "true"]
    return vals


def cases(tool: str, fz: Fuzz, kinds=("valid", "valid", "valid", "boundary", "boundary", "odd_value",
                                         "odd_value", "structure")):
    """Strategy for one case of ``tool``, with the attempt's live ids."""
    schema = SCHEMAS[tool]
    valid = from_schema(TOOLS[tool].json_schema())
    required = schema.get("required", [])

    @st.composite
    def draw_case(draw):
        kind = draw(st.sampled_from(kinds))
        args = draw(valid)
        for f in ID_FIELDS:
            if f in args:
                # the draws do not depend on the attempt's state (hypothesis replays them)
                how = draw(st.sampled_from(["live", "live", "newest", "unknown", "schema"]))
                pick, bad, ids = draw(st.integers(0, 2**16)), draw(st.sampled_from(BAD_IDS[f])), fz.ids[f]
                if how == "live" and ids:
                    args[f] = ids[pick % len(ids)]
                elif how == "newest" and ids:
                    args[f] = ids[-1]
                elif how == "unknown":
                    args[f] = bad
        if kind == "valid":
            # half of the absolute targets near the arms, mostly keeping the orientation, so plans and motions run
            if any(k in args for k in NEAR) and draw(st.booleans()):
                for k in sorted(NEAR.keys() & args.keys()):
                    args[k] = [draw(st.floats(lo, hi)) for lo, hi in NEAR[k]]
                for k in sorted(QUAT_FIELDS & args.keys()):
                    if draw(st.integers(0, 3)):
                        del args[k]
            return Case(kind, "from_schema", args)
        where = slots(args, schema)
        if kind == "structure" or not where:
            how = draw(st.sampled_from(["unknown_field", "unknown_fields", "drop_required", "non_object"]))
            if how == "unknown_field" or (how == "drop_required" and not required):
                key = draw(st.sampled_from(UNKNOWN_KEYS))
                return Case("structure", f"unknown field {_short(key, 12)}",
                            {**args, key: copy.deepcopy(draw(st.sampled_from(ODD_VALUES[:20])))})
            if how == "unknown_fields":
                return Case("structure", "300 unknown fields", {**args, **{f"k{i}": i for i in range(300)}})
            if how == "drop_required":
                key = draw(st.sampled_from(required))
                return Case("structure", f"without {key}", {k: v for k, v in args.items() if k != key})
            return Case("structure", "not an object", copy.deepcopy(draw(st.sampled_from(NON_OBJECTS))))
        path, sub, _ = where[draw(st.integers(0, len(where) - 1))]
        pool = boundary_values(sub) if kind == "boundary" else ODD_VALUES
        if not pool:
            pool = ODD_VALUES
        new = copy.deepcopy(draw(st.sampled_from(pool)))
        return Case(kind, ".".join(map(str, path)), replaced(args, path, new))

    return draw_case()


def grid(tool: str, fz: Fuzz) -> list[Case]:
    """The deterministic sweep of one tool: every odd value in every field of a simple instance with
    the newest live ids (lists: their first and last item; every absent optional field too; the 1 MB
    string and the 100,000-item list in the first field only, to keep the record small), each unknown
    key, each required field dropped, each non-object."""
    schema = SCHEMAS[tool]
    base = example(schema)
    for f in ID_FIELDS:
        if f in base and fz.ids[f]:
            base[f] = fz.ids[f][-1]

    def ends(path):  # list items other than the first and the last are left to the random cases
        node = base
        for p in path:
            if isinstance(node, list) and 0 < p < len(node) - 1:
                return False
            node = node[p] if isinstance(node, (list, dict)) and (isinstance(node, list) or p in node) else None
        return True

    where = [path for path, _, _ in slots(base, schema) if ends(path)]
    huge = [v for v in ODD_VALUES if v is HUGE_STR or v is HUGE_LIST]
    out = [Case("odd_value", ".".join(map(str, path)), replaced(base, path, copy.deepcopy(v)))
           for i, path in enumerate(where) for v in ODD_VALUES if i == 0 or not any(v is h for h in huge)]
    out += [Case("structure", f"unknown field {_short(k, 12)}", {**base, k: 0.1}) for k in UNKNOWN_KEYS]
    out += [Case("structure", f"without {k}", {x: v for x, v in base.items() if x != k})
            for k in schema.get("required", [])]
    out += [Case("structure", "not an object", copy.deepcopy(v)) for v in NON_OBJECTS]
    return out


# -- Python literals for programs ---------------------------------------------------------------------
def py_literal(v) -> str:
    """Python source for a JSON-like value: non-finite floats as float('nan') etc., long runs as
    multiplications (a program is at most 200,000 characters)."""
    if v is None or isinstance(v, bool):
        return repr(v)
    if isinstance(v, int):
        return repr(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else f"float({repr(v)!r})"
    if isinstance(v, str):
        if len(v) > 256 and v.count(v[0]) == len(v):
            return f"({v[0]!r} * {len(v)})"
        return repr(v)
    if isinstance(v, list):
        if len(v) > 64 and all(x == v[0] and type(x) is type(v[0]) for x in v):
            return f"[{py_literal(v[0])}] * {len(v)}"
        return "[" + ", ".join(py_literal(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k!r}: {py_literal(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


PROGRAM = """
_out = []
for _j in range(len(_cases)):
    _kw = _cases[_j]
    try:
        _r = {tool}(**_kw) if isinstance(_kw, dict) else {tool}(_kw)
        if isinstance(_r, dict):
            _out.append([_j, 'dict', 'error' in _r, _r.get('code')])
        else:
            _out.append([_j, 'other', repr(_r)[:100]])
    except Exception as _e:
        _out.append([_j, 'exc', repr(_e)[:300]])
result = _out
"""


def program_text(tool: str, arg_list: list) -> str:
    return "_cases = [\n" + "".join(f"    {py_literal(a)},\n" for a in arg_list) + "]" + PROGRAM.format(tool=tool)


# -- the contract ------------------------------------------------------------------------------------
HOST_FRAME = re.compile(r'File "(?!<run_code:\d+>")')


def host_markers(ep: Episode) -> list[str]:
    repo = Path(__file__).resolve().parents[1]
    marks = {str(repo), str(Path(ep.out).resolve()), str(ep.out), "site-packages", "dist-packages",
             tempfile.gettempdir().rstrip("/") + "/", "cab-sandbox-", sys.prefix, sys.base_prefix + "/lib",
             os.path.expanduser("~").rstrip("/") + "/"}
    return sorted(m for m in marks if len(m) > 4)


def is_typed_error(tool: str, payload: dict) -> bool:
    # a run_code result always has an "error" field (null, or the program's error): only a code makes it typed
    return "code" in payload if tool == "run_code" else "error" in payload


def estimate_problems(payload: dict) -> list[str]:
    """An estimate marked valid has a non-degenerate value."""
    kind, v = payload.get("kind"), payload.get("value")
    if kind not in ESTIMATE_KINDS or payload.get("valid") is not True:
        return []

    def vec(x, n):
        return (isinstance(x, list) and len(x) == n and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                            and math.isfinite(c) for c in x))

    if kind == "pixel_point" and not vec(v, 2):
        return [f"valid pixel_point estimate with value {_short(v)}"]
    if kind == "world_point" and not vec(v, 3):
        return [f"valid world_point estimate with value {_short(v)}"]
    if kind == "depth" and not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
        return [f"valid depth estimate with value {_short(v)}"]
    if kind == "ray":
        if not (isinstance(v, dict) and vec(v.get("origin"), 3) and vec(v.get("dir"), 3)):
            return [f"valid ray estimate with value {_short(v)}"]
        norm = math.sqrt(sum(c * c for c in v["dir"]))
        if abs(norm - 1.0) > 1e-6:
            return [f"valid ray estimate whose dir has norm {norm!r}: {v['dir']}"]
    return []


def check_answer(tool: str, args, payload, markers: list[str]) -> list[str]:
    """Every way one answer breaks the contract (empty when it keeps it)."""
    if not isinstance(payload, dict):
        return [f"payload is {type(payload).__name__}, not an object"]
    out: list[str] = []
    text = json.dumps(payload, default=repr)
    args_text = json.dumps(args, default=repr)
    if is_typed_error(tool, payload):
        code, err = payload.get("code"), payload.get("error")
        if code not in ERROR_CODES:
            out.append(f"error without a known code ({code!r}): {_short(err, 200)}")
        elif not (isinstance(err, str) and err.startswith(ERROR_CODES[code])):
            out.append(f"{code} whose error text does not start with {ERROR_CODES[code]}: {_short(err, 200)}")
        if isinstance(err, str) and len(err) > ERROR_CHARS:
            out.append(f"error text of {len(err)} characters (at most {ERROR_CHARS}): {_short(err, 200)}")
        if schema_refuses(tool, args) and code != "invalid_tool_arguments":
            out.append(f"arguments the schema refuses answered {code!r}, not invalid_tool_arguments: "
                       f"{_short(err, 200)}")
    elif schema_refuses(tool, args):
        out.append(f"arguments the schema refuses were accepted: {_short(text, 300)}")
    else:
        if tool in ACTIONS and payload.get("status") not in STATUSES:
            out.append(f"action result with status {payload.get('status')!r}")
        model = TOOLS[tool].result  # a success matches its documented result model, where there is one
        if model is not None:
            try:
                model.model_validate({k: v for k, v in payload.items() if k != "budget"})
            except pydantic.ValidationError as e:
                out.append(f"success does not match {model.__name__}: {' '.join(str(e).split())[:400]}")
    # the program's own traceback may reach the agent in run_code's "error"; no host frame may, anywhere
    m = HOST_FRAME.search(text)
    if m:
        out.append(f"host traceback frame in the payload: {text[max(0, m.start() - 80):m.end() + 120]!r}")
    tb_text = (json.dumps({k: v for k, v in payload.items() if k != "error"}, default=repr) if tool == "run_code"
               else text)
    if "Traceback (most recent call last)" in tb_text:
        i = tb_text.index("Traceback")
        out.append(f"traceback in the payload: {tb_text[max(0, i - 80):i + 200]!r}")
    for mark in markers:
        if mark in text and mark not in args_text:
            i = text.index(mark)
            out.append(f"host path {mark!r} in the payload: {text[max(0, i - 80):i + 120]!r}")
    bad = list(nonfinite(payload))
    if bad:
        out.append(f"non-finite numbers at {bad[:6]}")
    out += estimate_problems(payload)
    return out


# -- the attempt -------------------------------------------------------------------------------------
def make_episode(out: Path) -> Episode:
    overrides = ["+sim=mujoco", "task=click_bell", f"budget.tool_calls={BUDGET_CALLS}", "budget.sim_seconds=1000000",
                 "budget.wall_seconds=1000000", "record.video=false"]
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(overrides))
    s = attempt_spec(cfg, out)
    return Episode(s, all_tasks()[s.task], create("simulators", s.sim, s.sim_cfg), create("planners", s.planner, {}),
                   create("embodiments", s.embodiment, {}))


class Fuzz:
    """One live attempt, the ids it has handed out, and the cases run on it."""

    counts: Counter = Counter()  # (tool, surface, kind) -> cases, over the whole module

    def __init__(self, ep: Episode):
        self.ep = ep
        self.ids: dict[str, list[str]] = {f: [] for f in ID_FIELDS}
        self.markers = host_markers(ep)
        self.events = Path(ep.out) / "events.jsonl"

    def used(self) -> int:
        return self.ep.ledger.summary()["tool_calls_used"]

    def learn(self, v) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                if k in ID_FIELDS and isinstance(x, str) and x not in self.ids[k]:
                    self.ids[k].append(x)
                else:
                    self.learn(x)
        elif isinstance(v, list):
            for x in v:
                self.learn(x)

    def _charged(self, resp, before: int, cost: int) -> list[str]:
        out = []
        if resp.ended or self.ep.ended:
            out.append(f"the attempt ended: {self.ep.termination}")
        if self.used() != before + cost:
            out.append(f"charged {self.used() - before} calls, not {cost}")
        budget = resp.payload.get("budget") if isinstance(resp.payload, dict) else None
        if cost and not (isinstance(budget, dict) and budget.get("tool_calls_remaining") == BUDGET_CALLS - self.used()):
            out.append(f"budget in the payload {budget!r} disagrees with the ledger ({self.used()} used)")
        return out

    def direct(self, tool: str, case: Case) -> list[str]:
        before = self.used()
        resp = self.ep.call(tool, case.args)
        Fuzz.counts[(tool, "direct", case.kind)] += 1
        self.learn(resp.payload)
        problems = check_answer(tool, case.args, resp.payload, self.markers)
        return problems + self._charged(resp, before, 0 if tool == "done" else 1)

    def _internal_events(self, offset: int) -> list[dict]:
        with open(self.events, "rb") as f:
            f.seek(offset)
            lines = f.read().decode("utf-8").splitlines()
        return [e for e in map(json.loads, lines) if e.get("kind") == "internal_call"]

    def program(self, tool: str, batch: list[Case]) -> list[str]:
        """Run the batch from run_code programs (a program that an ABORTED action stops is followed by
        one with the cases it did not reach); every problem, prefixed by its case."""
        problems: list[str] = []
        pending = list(batch)
        while pending:
            code = program_text(tool, [c.args for c in pending])
            before, offset = self.used(), self.events.stat().st_size
            resp = self.ep.call("run_code", {"code": code})
            p = resp.payload
            problems += [f"run_code: {x}" for x in check_answer("run_code", {"code": code}, p, self.markers)]
            problems += [f"run_code: {x}" for x in self._charged(resp, before, 1)]
            if not isinstance(p, dict) or is_typed_error("run_code", p) or self.ep.ended:
                return problems + [f"run_code answered {_short(p.get('error') if isinstance(p, dict) else p, 400)}"]
            self.learn(p)
            internal = self._internal_events(offset)
            trace = p.get("internal_trace") or []
            sent = [c for c in pending if isinstance(c.args, dict)]  # the others are refused in the program
            aborted = p.get("status") == "ABORTED"
            n = p["interrupted_action"]["index"] + 1 if aborted else len(sent)
            if not aborted and not (p.get("ok") is True and p.get("error") is None and p.get("result_assigned")):
                return problems + [f"program failed: ok={p.get('ok')} error={_short(p.get('error'), 400)}"]
            if not (len(trace) == len(internal) == p.get("tool_calls") == n):
                return problems + [f"{n} cases reached the host, but the trace has {len(trace)} entries, the record "
                                   f"{len(internal)} internal calls and tool_calls is {p.get('tool_calls')}"]
            for k, (case, entry, ev) in enumerate(zip(sent, trace, internal)):
                pay = ev.get("result")
                self.learn(pay)
                Fuzz.counts[(tool, "run_code", case.kind)] += 1
                # judged by the arguments the host received: a program's NaN, inf and ints past 2**63 arrive
                # as strings, long strings cut (cab_core.sandbox.guest.to_jsonable)
                errs = check_answer(tool, ev.get("arguments"), pay, self.markers)
                if entry.get("index") != k or entry.get("tool") != tool or ev.get("tool") != tool:
                    errs.append(f"trace entry {entry} / record {ev.get('tool')!r} for call {k} of {tool}")
                if isinstance(pay, dict):
                    if entry.get("ok") is not ("error" not in pay) or entry.get("error") != pay.get("error"):
                        errs.append(f"trace entry {entry} disagrees with the payload {_short(pay, 300)}")
                problems += [f"{case!r} (from run_code): {x}" for x in errs]
            if aborted:
                last = next(i for i, c in enumerate(pending) if c is sent[n - 1])
                # the program's summary was lost with its namespace: its refused cases run again
                pending = [c for c in pending[:last] if not isinstance(c.args, dict)] + pending[last + 1:]
                continue
            rows = p.get("value")
            by_case = {id(c): ev for c, ev in zip(sent, internal)}
            if not (isinstance(rows, list) and len(rows) == len(pending)):
                return problems + [f"program summary {_short(rows, 300)} for {len(pending)} cases"]
            for j, (case, row) in enumerate(zip(pending, rows)):
                if isinstance(case.args, dict):
                    pay = by_case[id(case)].get("result")
                    want = [j, "dict", isinstance(pay, dict) and "error" in pay,
                            pay.get("code") if isinstance(pay, dict) else None]
                    if row != want:
                        problems.append(f"{case!r} (from run_code): the program got {row}, the host sent {want}")
                else:
                    Fuzz.counts[(tool, "run_code", case.kind)] += 1
                    if not (row[:2] == [j, "exc"] and "TypeError" in row[2] and "keyword arguments only" in row[2]):
                        problems.append(f"{case!r} (from run_code, positional): {row}")
            pending = []
        return problems


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("CAB_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    yield
    mp.undo()


@pytest.fixture(scope="module")
def fz(tmp_path_factory, cache_dir, request):
    request.config.pluginmanager.register(_Summary(), "cab-fuzz-summary")
    ep = make_episode(tmp_path_factory.mktemp("fuzz") / "attempt")
    fuzz = Fuzz(ep)
    # live ids for the geometry tools: observations of every camera and one motion pair
    for tool, args in [("capture_evidence_views", {}), ("capture_motion_pair", {"arm": "left", "dx": 0.0, "dy": 0.0,
                                                                                 "dz": 0.01}),
                       ("capture_head", {})]:
        fuzz.learn(ep.call(tool, args).payload)
    assert fuzz.ids["obs_id"] and fuzz.ids["pair_id"]
    try:
        yield fuzz
    finally:
        ep.close()


class _Summary:
    """Prints the cases per tool at the end of the run (also without -s)."""

    def pytest_terminal_summary(self, terminalreporter):
        c = Fuzz.counts
        if not c:
            return
        tr = terminalreporter
        tr.section("tool fuzzing: cases per tool")
        kinds = ("valid", "boundary", "odd_value", "structure")
        surfaces = ("direct", "run_code", "validate_args")
        tr.write_line(f"{'tool':28s} " + " ".join(f"{s:>13s}" for s in surfaces) + " |"
                      + " ".join(f"{k:>9s}" for k in kinds))
        for tool in [*TOOLS, "total"]:
            def n(surface=None, kind=None, tool=tool):
                return sum(v for (t, s, k), v in c.items() if tool in (t, "total") and surface in (s, None)
                           and kind in (k, None))
            tr.write_line(f"{tool:28s} " + " ".join(f"{n(surface=s):13d}" for s in surfaces) + " |"
                          + " ".join(f"{n(kind=k):9d}" for k in kinds))


def _fail(problems: list[str], case) -> None:
    assert not problems, f"{case!r}:\n  " + "\n  ".join(problems)


# -- the tests ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("tool", ROBOT_TOOLS + ["run_code"])
def test_direct_calls_keep_the_contract(fz, tool):
    n = DIRECT_EXAMPLES_SLOW if tool in MOTION | RENDERS else DIRECT_EXAMPLES

    @fuzz_settings(n)
    @given(data=st.data())
    def run(data):
        case = data.draw(cases(tool, fz), label="case")
        _fail(fz.direct(tool, case), case)

    run()


@pytest.mark.parametrize("tool", ROBOT_TOOLS)
def test_program_calls_keep_the_contract(fz, tool):
    @fuzz_settings(PROGRAMS)
    @given(data=st.data())
    def run(data):
        batch = data.draw(st.lists(cases(tool, fz), min_size=BATCH[0], max_size=BATCH[1]), label="batch")
        _fail(fz.program(tool, batch), batch)

    run()


@pytest.mark.parametrize("tool", ROBOT_TOOLS + ["run_code"])
def test_every_odd_value_in_every_field(fz, tool):
    """The deterministic sweep: each odd value in each field, directly and (robot tools) from programs."""
    problems = []
    todo = grid(tool, fz)
    for case in todo:
        problems += [f"{case!r}: {p}" for p in fz.direct(tool, case)]
    if tool != "run_code":
        for i in range(0, len(todo), PROGRAM_CASES):
            problems += fz.program(tool, todo[i:i + PROGRAM_CASES])
    assert not problems, f"{len(problems)} problems:\n  " + "\n  ".join(p[:600] for p in problems[:25])


def degenerate_cases(obs: str, pair: str, centre: list[float]) -> list[tuple[str, dict]]:
    """Inputs at the corners of the declared ranges and degenerate geometry: vectors of the smallest
    floats (normalised internally), a point at the camera centre, a plane through it, pixels at the
    range limits, a sub-pixel box, a zero-width triangulation."""
    tiny, big, out = 5e-324, 1000.0, []
    corners = [-10000.0, -0.5, 0.0, 10000.0]
    out += [("ray", {"obs_id": obs, "px": [u, v]}) for u in corners for v in corners]
    out += [("project", {"obs_id": obs, "xyz": xyz}) for xyz in
            ([-10.0, -10.0, -10.0], [10.0, 10.0, 10.0], centre, [centre[0], centre[1], centre[2] - 1e-12])]
    for n in ([tiny, 0.0, 0.0], [0.0, 0.0, tiny], [big, big, big], [1e-300, -1e-300, 1e-300], [0.0, 0.0, 0.0]):
        for point in (centre, [10.0, -10.0, 10.0], [0.0, 0.0, 0.74]):
            for px in ([320.0, 240.0], [-10000.0, 10000.0]):
                out.append(("plane_intersect", {"obs_id": obs, "px": px, "plane_point_xyz": point,
                                                "plane_normal_xyz": n, "plane_offset_sigma_m": 10.0,
                                                "pixel_sigma_px": 100.0}))
    out += [("triangulate_correspondence", {"pair_id": pair, "px_before": a, "px_after": b, "pixel_sigma_px": s})
            for a, b in (([160.0, 120.0], [160.0, 120.0]), ([-10000.0, -10000.0], [10000.0, 10000.0]),
                         ([0.0, 0.0], [0.0, 1e-9])) for s in (0.0, 100.0)]
    out += [("scale_from_object_size", {"obs_id": obs, "bbox": bbox, "extent_axis": axis, "known_extent_m": k})
            for bbox in ([100.0, 100.0, 100.0000001, 100.0000001], [-10000.0, -10000.0, 10000.0, 10000.0],
                         [0.0, 0.0, 640.0, 480.0]) for axis in ("width", "height", "diagonal") for k in (1e-6, 10.0)]
    out += [("grasp_quat_candidates", {"approach_axis_world": a, "opening_axis_world": b})
            for a, b in (([tiny, 0.0, 0.0], [0.0, tiny, 0.0]), ([1e-300, 1e-300, 0.0], [1e-300, -1e-300, 0.0]),
                         ([big, 0.0, 0.0], [0.0, big, 0.0]), ([0.0, 0.0, -big], [tiny, 0.0, 0.0]))]
    quats = ([tiny, 0.0, 0.0, 0.0], [1e-300, 1e-300, 1e-300, 1e-300], [big, big, big, big], [0.0, 0.0, 0.0, 0.0])
    out += [("preview_tcp_pose", {"obs_id": obs, "arm": "left", "tcp_xyz": [-0.3, -0.1, 0.9], "quat_wxyz": q})
            for q in quats]
    out += [("compare_tcp_poses", {"obs_id": obs, "candidates": [
        {"arm": "left", "tcp_xyz": [-0.3, -0.1, 0.9], "quat_wxyz": q},
        {"arm": "right", "tcp_xyz": centre, "quat_wxyz": q}]}) for q in quats]
    out += [("check_tcp_pose_reachability", {"arm": "right", "target_xyz": [0.3, -0.1, 0.9], "target_quat": q})
            for q in quats]
    out += [("camera_aim_pose", {"camera": c, "target_xyz": t, "pitch": p, "standoff": d})
            for c in ("left_camera", "right_camera") for t in ([-10.0, -10.0, -10.0], [10.0, 10.0, 10.0], centre)
            for p in (60.0, 90.0) for d in (0.05, 1.0)]
    # the workspace envelope of absolute targets (x, y in [-0.8, 0.8], z in [0.4, 1.5]): at and just past its corners
    env = [[-0.8, -0.8, 0.4], [0.8, 0.8, 1.5], [math.nextafter(-0.8, -1), 0.0, 0.9], [0.0, 0.0, math.nextafter(1.5, 2)]]
    out += [("reach_tcp", {"arm": arm, "target_xyz": t}) for arm in ("left", "right") for t in env]
    out += [("reach_both_tcp", {"left_xyz": a, "right_xyz": b}) for a, b in zip(env, reversed(env))]
    out += [("check_tcp_pose_reachability", {"arm": "left", "target_xyz": t}) for t in env]
    out += [("probe_contact_along", {"arm": "left", "direction_xyz": [0.0, 0.0, tiny], "distance_m": 1e-300,
                                     "step_m": 0.002}),
            ("reach_tcp", {"arm": "left", "target_xyz": [-0.3, -0.15, 0.95], "target_quat": [tiny, 0.0, 0.0, 0.0]})]
    return out


def test_degenerate_geometry_keeps_the_contract(fz):
    """Every degenerate input is a typed error or a success whose estimates are non-degenerate."""
    head = fz.ep.call("capture_head", {}).payload
    fz.learn(head)
    E = head["cam_pose_snapshot"]["E"]
    centre = [-sum(E[r][c] * E[r][3] for r in range(3)) for c in range(3)]  # C = -R^T t
    assert all(math.isfinite(c) for c in centre)
    todo = degenerate_cases(head["obs_id"], fz.ids["pair_id"][-1], centre)
    problems = []
    for tool, args in todo:
        case = Case("boundary", "degenerate", args)
        problems += [f"{tool} {case!r}: {p}" for p in fz.direct(tool, case)]
    for tool in dict.fromkeys(t for t, _ in todo):
        problems += [f"{tool}: {p}" for p in fz.program(tool, [Case("boundary", "degenerate", a)
                                                                 for t, a in todo if t == tool])]
    assert not problems, f"{len(problems)} problems:\n  " + "\n  ".join(p[:700] for p in problems[:30])


def test_programs_cannot_call_run_code_or_done(fz):
    """Neither is bound in a program: each call is a NameError there, nothing ends, run_code costs one."""
    for name in ("done", "run_code"):
        before = fz.used()
        r = fz.ep.call("run_code", {"code": "_out = []\n" + "\n".join(
            f"try:\n    {name}(**{py_literal(a)})\nexcept Exception as _e:\n    _out.append(repr(_e))"
            for a in ({"report": "ok", "success_claim": True}, {"code": "result = 1"}, {})) + "\nresult = _out"})
        assert r.payload["ok"] is True and r.payload["tool_calls"] == 0, r.payload
        assert r.payload["value"] == [f"NameError(\"name '{name}' is not defined\")"] * 3
        assert not r.ended and not fz.ep.ended and fz.used() == before + 1
        Fuzz.counts[(name, "run_code", "valid")] += 3


@pytest.fixture(scope="module")
def done_fz(tmp_path_factory, cache_dir):
    ep = make_episode(tmp_path_factory.mktemp("fuzz-done") / "attempt")
    try:
        yield Fuzz(ep)
    finally:
        ep.close()


def test_done_refuses_every_odd_value_for_free(done_fz):
    todo = [c for c in grid("done", done_fz) if schema_refuses("done", c.args)]
    assert len(todo) >= 50
    problems = []
    for case in todo:
        assert not done_fz.ep.ended, f"an earlier done ended the attempt: {done_fz.ep.termination}"
        problems += [f"{case!r}: {p}" for p in done_fz.direct("done", case)]
    assert not problems, f"{len(problems)} problems:\n  " + "\n  ".join(p[:600] for p in problems[:25])


def test_done_refuses_invalid_arguments_for_free(done_fz):
    """done with arguments its schema refuses: invalid_tool_arguments, not charged, the attempt goes on."""

    @fuzz_settings(DONE_EXAMPLES)
    @given(data=st.data())
    def run(data):
        case = data.draw(cases("done", done_fz, kinds=("boundary", "odd_value", "structure")), label="case")
        assume(schema_refuses("done", case.args))  # a valid done ends the attempt: see the last test
        assert not done_fz.ep.ended, f"an earlier done ended the attempt: {done_fz.ep.termination}"
        _fail(done_fz.direct("done", case), case)

    run()


@fuzz_settings(200)
@given(args=from_schema(TOOLS["done"].json_schema()))
def test_done_validation_accepts_every_schema_valid_argument(args):
    m = validate_args("done", args)
    assert m.report == args["report"] and m.success_claim == args.get("success_claim")
    Fuzz.counts[("done", "validate_args", "valid")] += 1


def test_done_accepts_valid_arguments_and_ends(fz):
    """Last on the module's attempt: a valid done at the schema's limits ends it, free, recorded."""
    hi = SCHEMAS["done"]["properties"]["report"]["maxLength"]
    report = ("é\x00✓" * hi)[:hi]
    before = fz.used()
    r = fz.ep.call("done", {"report": report, "success_claim": False})
    Fuzz.counts[("done", "direct", "boundary")] += 1
    assert r.ended and fz.ep.ended and fz.ep.termination["reason"] == "done"
    assert r.payload == {"ok": True, "note": "episode ended; attempt recorded."}
    assert fz.used() == before
    with pytest.raises(AttemptEnded):
        fz.ep.call("get_arm_pose", {"arm": "left"})
    res = fz.ep.finish()
    assert res["claim"] == {"success_claim": False, "report": report}
    assert res["termination"]["reason"] == "done" and res["budget"]["tool_calls_used"] == before
