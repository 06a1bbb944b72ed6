"""run_code's Python layer (issue 26, items 2, 4 and 5) and strict JSON in the records.

* numpy gave views outside their buffer: ``np.ndarray(buffer=b, offset=-4096)`` read host-process
  memory; ``ndarray.resize(refcheck=False)`` freed memory a view still used; assigning ``.data``
  re-pointed an object array at bytes of the program's choosing. The program's numpy now has checked
  constructors, hooked array attributes and no raw-memory helpers, and ``repr`` shows no address.
* ``math.isfinite = lambda v: True`` patched the guest's own module: the serialiser then wrote
  ``NaN`` into the tool result and ``events.jsonl``. The program's modules are read-only copies.
* ``"x=" + "1+"*60000 + "1"`` killed the child (RecursionError outside the guest's ``try``).
* The record writer wrote NaN as ``NaN``; it now writes null and says where.

The last test runs ``cab`` itself, as a user would, with a scripted agent trying these programs.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import test_sandbox_policy

from cab_core.attempt.engine import serving
from cab_core.attempt.records.result_format import AttemptRecord, dumps, write_json_atomic
from cab_core.sandbox import DispatchResult, Sandbox, SandboxConfig, guest
from cab_core.sandbox.truncate import strict_payload

CAB = os.path.join(os.path.dirname(sys.executable), "cab")
ADDRESS = re.compile(r"0x[0-9a-fA-F]{6,}")

# the module-scoped sandbox fixture of test_sandbox_policy (no tool is called by these programs), bound
# here by assignment so that pytest finds it in this module and the tests' ``sb`` parameters shadow no import
sb = test_sandbox_policy.sb


@pytest.fixture(autouse=True)
def _marker(sb):
    assert sb.run("marker = 'kept'")["ok"]


def ok(result: dict) -> dict:
    assert result["ok"], result["error"]
    return result


def last_line(result: dict) -> str:
    assert not result["ok"] and not result["namespace_reset"], result
    return result["error"].splitlines()[-1]


def still_works(sb):
    """After a refusal: the same child, the namespace intact."""
    assert ok(sb.run("result = marker"))["value"] == "kept"


def strict_loads(text: str):
    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


# ---------------------------------------------------------------------------- item 2: raw memory
NUMPY_1 = np.__version__.startswith("1.")
RAW = [
    # the reproduction of the issue: 4096 bytes below an 8-byte buffer
    ("b = np.zeros(8, np.uint8)\nprint(np.ndarray((8,), np.uint8, buffer=b, offset=-4096))",
     "ValueError: offset must be non-negative and no greater than buffer length"),
    ("b = np.zeros(8, np.uint8)\nr = np.ndarray((8,), np.uint8, b, -4096)",
     "ValueError: offset must be non-negative and no greater than buffer length"),
    ("b = np.zeros(8, np.uint8)\nr = np.ndarray((8,), np.uint8, buffer=b, offset=4)",
     "ValueError: buffer is smaller than requested size"),
    ("b = np.zeros(8, np.uint8)\nr = np.ndarray((8,), np.uint8, buffer=b, strides=(-512,))",
     "SandboxPolicyError: np.ndarray(strides=...) is not allowed in run_code; use reshape, slicing or transpose"),
    ("b = np.zeros(8, np.uint8)\nr = np.recarray((8,), np.uint8, b, -64)",
     "SandboxPolicyError: np.recarray(buf=, offset=, strides=) is not allowed in run_code"),
    ("b = np.zeros(8, np.uint8)\nr = np.chararray((8,), 1, buffer=b, offset=-64)",
     "SandboxPolicyError: np.chararray(buffer=, offset=, strides=) is not allowed in run_code" if NUMPY_1 else
     # numpy 2 deprecates np.chararray: a lazy name, not among the public names a program is offered
     "AttributeError: module 'numpy' has no attribute 'chararray'"),
    # numpy's submodules with the same constructors are not offered either
    ("b = np.zeros(8, np.uint8)\nr = np.char.chararray((8,), 1, buffer=b, offset=-64)",
     "AttributeError: module 'numpy' has no attribute 'char'"),
    ("b = np.zeros(8, np.uint8)\nr = np.rec.recarray((8,), np.uint8, b, -64)",
     "AttributeError: module 'numpy' has no attribute 'rec'"),
    ("r = np.frombuffer(np.zeros(8, np.uint8), np.uint8, 4, -4)",
     "ValueError: offset must be non-negative and no greater than buffer length"),
    # resize without the reference check frees the memory a view still points at
    ("x = np.zeros(8)\ny = x[:]\nx.resize((100000,), refcheck=False)",
     "SandboxPolicyError: ndarray.resize(refcheck=False) is not allowed: a view of the array would be left "
     "pointing at freed memory"),
    ("x = np.zeros(8)\nf = x.resize\nf(100000, refcheck=False)", "ndarray.resize(refcheck=False) is not allowed"),
    ("x = np.zeros(8)\nnp.ndarray.resize(x, 100000, refcheck=False)", "ndarray.resize(refcheck=False) is not allowed"),
    ("x = np.zeros(8)\nnp.matrix.resize(x, 100000, refcheck=False)", "ndarray.resize(refcheck=False) is not allowed"),
    # the bytes of an object array are its objects' addresses
    ("r = np.frombuffer(np.array([len], dtype='O'), np.uint64)",
     "SandboxPolicyError: np.frombuffer of an array of Python objects is not allowed (its bytes are the objects' "
     "addresses)"),
    ("r = np.array([len], dtype='O').tobytes()",
     "SandboxPolicyError: '.tobytes' of an array of Python objects is not allowed (its bytes are the objects' "
     "addresses)"),
    ("r = np.array([len], dtype='O').data", "'.data' of an array of Python objects is not allowed"),
    ("r = np.ndarray.tobytes(np.array([len], dtype='O'))", "'.tobytes' of an array of Python objects"),
    ("r = np.ndarray((1,), np.uint64, buffer=np.array([len], dtype='O'))",
     "np.frombuffer of an array of Python objects is not allowed"),
    ("r = bytes(np.array([len], dtype='O'))", "SandboxPolicyError: bytes() of an array of Python objects"),
    # the default hash of an object is its address
    ("r = hash(len)", "TypeError: hash() of a builtin_function_or_method is not available in run_code (it would "
     "be derived from the object's address)"),
    ("def f():\n    pass\nr = hash((1, f))", "TypeError: hash() of a function is not available in run_code"),
]


@pytest.mark.parametrize("code, line", RAW)
def test_no_view_leaves_its_buffer(sb, code, line):
    assert line in last_line(sb.run(code))
    still_works(sb)


STATIC = [
    # assigning these re-points an array at other memory (an object array at forged pointers)
    ("x = np.array([None])\nx.data = np.zeros(1, np.uint64).data", "line 2: assigning or deleting '.data'"),
    ("x = np.zeros(8)\nx.strides = (-4096,)", "line 2: assigning or deleting '.strides'"),
    ("x = np.zeros(2, np.uint64)\nx.dtype = 'O'", "line 2: assigning or deleting '.dtype'"),
    ("x = np.zeros(2)\ndel x.data", "line 2: assigning or deleting '.data'"),
    ("x = np.zeros(2)\nx.resize += 1", "line 2: augmented assignment to '.resize' is not allowed"),
    ("match np.zeros(2):\n    case np.ndarray(resize=r):\n        pass", "class pattern keyword 'resize' is not allowed"),
    # helpers that hand out addresses or foreign views
    ("r = np.byte_bounds(np.zeros(2))", "attribute '.byte_bounds'"),
    ("r = np.from_dlpack(np.zeros(2))", "attribute '.from_dlpack'"),
    ("r = np.lib.stride_tricks.as_strided(np.zeros(2), (8,), (-512,))", "attribute '.lib'"),
    ("r = np.core.multiarray", "attribute '.core'"),
    ("r = np.zeros(2).ctypes.data", "attribute '.ctypes'"),
    ("r = np.zeros(2).__array_interface__", "attribute '.__array_interface__'"),
    ("r = np.ndarray.__new__", "attribute '.__new__'"),
]


@pytest.mark.parametrize("code, why", STATIC)
def test_raw_memory_routes_are_refused_before_the_run(sb, code, why):
    r = sb.run(code)
    assert not r["ok"] and r["error"].startswith("code rejected by the sandbox policy:") and why in r["error"], r
    still_works(sb)


def test_ordinary_numpy_still_works(sb):
    r = ok(sb.run(
        "b = np.arange(8, dtype=np.uint8)\n"
        "v = np.ndarray((2, 2), np.uint8, buffer=b, offset=4)\n"  # a view inside the buffer is fine
        "v[0, 0] = 99\n"
        "x = np.zeros(4)\nx.resize(6)\n"
        "result = [v.tolist(), int(b[4]), isinstance(b, np.ndarray), issubclass(np.recarray, np.ndarray),\n"
        "          np.ndarray((2,)).tolist(), np.empty(3).tolist(), np.empty_like(b).tolist(), x.tolist(),\n"
        "          np.frombuffer(b, np.uint8, 2, 6).tolist(), np.zeros(2).tobytes().hex(), len(bytes(b)),\n"
        "          np.ndarray.tolist(np.ones(2)), repr(np.ndarray), hash((1, 'a')) == hash((1, 'a'))]\n"
        "result += [b.view(np.ndarray).shape, np.zeros(2, [('a', 'f8')]).view(np.recarray).a.tolist(),\n"
        "           np.ndarray.view(b, np.uint16).shape, b.view(type=np.ndarray, dtype=np.uint32).shape]\n"
        "match b:\n"
        "    case np.ndarray():\n"
        "        result.append('matched')"))
    assert r["value"] == [[[99, 5], [6, 7]], 99, True, True, [0.0, 0.0], [0.0] * 3, [0] * 8, [0.0] * 6,
                          [6, 7], "00" * 16, 8, [1.0, 1.0], "<class 'numpy.ndarray'>", True, [8], [0.0, 0.0],
                          [4], [2], "matched"]


def test_repr_shows_no_address(sb):
    r = (sb.run(
        "def f():\n    pass\n"
        "g = (i for i in [1])\n"
        "objs = [f, print, load_image, get_arm_pose, g, np.zeros(2).flat, np.random.default_rng(), [].append,\n"
        "        np.nditer(np.zeros(2)), map(abs, [1]), math, np, np.linalg]\n"
        "result = [repr(o) for o in objs] + [str(f), f'{f}', f'{f!r:>5}', '%r %s' % (f, f), '{}'.format(f),\n"
        "          ascii(f), format(f), str(KeyError(f)), repr([f, {'k': f}]), repr(np.array([f], dtype='O')),\n"
        "          np.array([f, len], dtype='O').astype(str).tolist()]\n"
        "print(f, objs)\n"
        "raise ValueError(f)"))
    text = json.dumps(r["value"]) + r["stdout"] + r["error"]
    assert not ADDRESS.search(text), text
    assert r["value"][:4] == ["<function f>", "<function print>", "<function load_image>", "<function get_arm_pose>"]
    assert r["value"][4:7] == ["<generator object <genexpr>>", "<numpy.flatiter object>", "Generator(PCG64)"]
    assert r["value"][10:13] == ["<module 'math'>", "<module 'numpy'>", "<module 'numpy.linalg'>"]  # no paths
    assert r["error"].splitlines()[-1] == "ValueError: <function f>"
    assert sb.confinement_layers["repr_addresses"].startswith("ok (")


# ---------------------------------------------------------------------- item 4: the guest's modules
def test_a_program_cannot_patch_the_guests_modules(sb):
    r = sb.run("import math\nmath.isfinite = lambda v: True\nresult = {'nan': float('nan')}")
    assert last_line(r) == ("SandboxPolicyError: module 'math' is read-only in run_code; bind a name of your own "
                            "instead")
    for code in ("math.isfinite = abs", "np.isfinite = abs", "np.linalg.norm = abs", "del math.pi",
                 "import numpy\nnumpy.zeros = abs", "import math as m\nm.inf = 0.0"):
        assert "is read-only in run_code" in last_line(sb.run(code)), code
    # nothing persisted: the serialiser still turns non-finite numbers into strings, and math is math
    r = ok(sb.run("result = {'nan': float('nan'), 'inf': [float('-inf')], 'a': np.array([np.inf, 1.0]),\n"
                  "          'finite': math.isfinite(float('nan'))}"))
    assert r["value"] == {"nan": "nan", "inf": ["-inf"], "a": ["inf", 1.0], "finite": False}
    strict_loads(json.dumps(r, allow_nan=False))
    still_works(sb)


def test_the_guests_serialiser_uses_its_own_references():
    """The program's math and numpy are copies: a patch of the real modules (which no program reaches)
    would still not change what the guest sends."""
    child = guest.Runner(None, {"tools": [], "max_internal_calls": 5, "stdout_cap": 100})
    assert child.ns["math"] is not guest.math and child.ns["np"] is not child.np
    assert isinstance(child.ns["math"], guest.ReadOnlyModule) and isinstance(child.ns["np"].linalg, guest.ReadOnlyModule)
    assert child.run("import math\nimport numpy\nresult = [math is m, numpy is np]")["value"] == [True, True] \
        if child.run("m = math")["ok"] else False
    assert guest.to_jsonable({"x": float("nan")}, np) == {"x": "nan"}


# ------------------------------------------------------------------------ item 5: deep programs
@pytest.mark.parametrize("code, line", [
    ("x=" + "1+" * 60000 + "1", "RecursionError: the program could not be compiled (maximum recursion depth "
     "exceeded during ast construction); it is nested too deeply or too large. Split long expressions into "
     "several statements."),
    ("x=" + "-" * 60000 + "1", "MemoryError: the program could not be compiled"),
    ("x=" + "(" * 300 + "1" + ")" * 300, "SyntaxError: too many nested parentheses"),
])
def test_a_deeply_nested_program_is_its_error_and_the_namespace_stays(sb, code, line):
    assert sb.run("kept_from_before = 41")["ok"]
    spawns = sb.spawns
    r = sb.run(code)
    assert last_line(r).startswith(line), r["error"]
    assert ok(sb.run("result = kept_from_before + 1"))["value"] == 42
    assert sb.spawns == spawns  # the same child


# ------------------------------------------------------------------------- strict JSON records
def test_the_record_writer_writes_strict_json_and_says_where(tmp_path):
    ev = {"kind": "tool_call", "result": {"value": [1.0, float("nan")], "pose": np.array([np.inf, 0.5])},
          "t": np.float32("-inf")}
    line = dumps(ev)
    assert strict_loads(line) == {"kind": "tool_call", "result": {"value": [1.0, None], "pose": [None, 0.5]},
                                  "t": None, "non_finite_as_null": ["result.value[1]", "result.pose[0]", "t"]}
    assert ev["result"]["value"][1] != ev["result"]["value"][1]  # the caller's object is not changed
    assert dumps({"a": 1.5}) == '{"a": 1.5}'  # finite data: exactly as before
    write_json_atomic(tmp_path / "r.json", {"x": float("inf")})
    assert strict_loads((tmp_path / "r.json").read_text()) == {"x": None, "non_finite_as_null": ["x"]}


def test_a_tool_result_the_agent_sees_is_strict_json():
    """serving.py passes every tool result through ``strict_payload`` before the agent sees it."""
    assert serving.strict_payload is strict_payload
    clean = {"pose": np.array([0.1, 0.2]), "ok": True}
    assert strict_payload(clean) is clean  # finite: untouched, the same object
    out = strict_payload({"pose": np.array([np.nan, 0.2]), "d": float("inf"), "nested": [{"x": float("-inf")}]})
    assert out == {"pose": [None, 0.2], "d": None, "nested": [{"x": None}],
                   "non_finite_as_null": ["pose[0]", "d", "nested[0].x"]}
    strict_loads(json.dumps(out, allow_nan=False))


def test_a_tool_payloads_nan_reaches_the_agent_as_null():
    def dispatch(name, kwargs):
        return DispatchResult({"status": "OK", "error": float("nan")})

    with Sandbox(["probe"], dispatch, lambda o: None, SandboxConfig(timeout_s=30)) as sandbox:
        r = sandbox.run("probe()")
    assert r["ok"] and r["internal_trace"][0]["error"] is None
    assert r["non_finite_as_null"] == ["internal_trace[0].error"]
    strict_loads(json.dumps(r, allow_nan=False))


# ------------------------------------------------------- acceptance: a scripted attempt from outside
PROGRAMS = [
    "b = np.zeros(8, np.uint8)\nprint(np.ndarray((8,), np.uint8, buffer=b, offset=-4096))",
    "import math\nmath.isfinite = lambda v: True\nresult = {'nan': float('nan')}",
    "result = {'nan': float('nan'), 'inf': float('inf'), 'arr': np.array([np.nan])}",
    "def f():\n    pass\nresult = [repr(f), str(print)]",
    "x=" + "1+" * 60000 + "1",
]


def test_a_scripted_attempt_gets_refusals_and_strict_json_records(tmp_path):
    script = tmp_path / "attack.json"
    script.write_text(json.dumps([{"tool": "run_code", "args": {"code": c}} for c in PROGRAMS]
                                 + [{"tool": "done", "args": {"report": "r", "success_claim": False}}]))
    out = tmp_path / "run"
    p = subprocess.run([CAB, "sim=mujoco", "task=click_bell", "model=scripted", f"model.script={script}",
                        "record.video=false", f"hydra.run.dir={out}"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    lines = (out / "events.jsonl").read_text().splitlines()
    events = [strict_loads(line) for line in lines]  # every line, strictly
    result = strict_loads((out / "result.json").read_text())
    assert result["termination"]["reason"] == "done"
    codes = [e for e in events if e.get("kind") == "call" and e.get("tool") == "run_code"]
    assert len(codes) == len(PROGRAMS), [e.get("kind") for e in events]
    seen = [e["result"] for e in codes]
    assert seen[0]["ok"] is False and seen[0]["error"].splitlines()[-1] == (
        "ValueError: offset must be non-negative and no greater than buffer length") and seen[0]["stdout"] == ""
    assert seen[1]["ok"] is False and seen[1]["error"].splitlines()[-1].startswith(
        "SandboxPolicyError: module 'math' is read-only in run_code")
    assert seen[2]["ok"] is True and seen[2]["value"] == {"nan": "nan", "inf": "inf", "arr": ["nan"]}
    assert seen[3]["value"] == ["<function f>", "<function print>"]
    assert seen[4]["ok"] is False and seen[4]["error"].startswith("RecursionError: the program could not be compiled")
    assert not any(s["namespace_reset"] for s in seen)
    assert not ADDRESS.search("\n".join(lines))
    # a record whose measurements went NaN (a body blown away) is still a valid, strict record

    result["verdict"]["values"] = {"distance": float("nan")}
    result["verdict"]["margins"] = {"p": {"slack": float("nan"), "scale": 0.01, "fraction": float("-inf"), "unit": "m"}}
    dumped = AttemptRecord.build(**result).dump()
    assert dumped["verdict"]["values"] == {"distance": None}
    assert dumped["verdict"]["margins"]["p"]["slack"] is None and dumped["verdict"]["margins"]["p"]["fraction"] is None
    assert dumped["non_finite_as_null"] == ["verdict.values.distance", "verdict.margins.p.slack",
                                            "verdict.margins.p.fraction"]
    strict_loads(dumps(dumped))
