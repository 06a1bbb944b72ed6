"""run_code's Python layer: routes to underscore attributes that use no ``.attr`` syntax (issue 12).

Three routes got past the AST policy, which only looked at ``ast.Attribute`` and ``ast.Name`` nodes:

* keyword attributes of ``match`` class patterns (``case Exception(__traceback__=tb)``) read an
  attribute by name;
* ``str.format`` / ``str.format_map`` resolve ``{0.attr}`` and ``{0[key]}`` fields themselves, from a
  literal template or one built at run time, through the method however it was obtained;
* names bound without an ``ast.Name`` node (``except E as __builtins__``, ``case _ as __x``): the
  handler's implicit ``del __builtins__`` made the next run start with the real builtins.

Each is refused with a message the program sees as its run_code result (statically when the code says
it, at run time when only the running program knows), the namespace survives, and ordinary
formatting keeps working. The attacks in ``test_sandbox.py`` are kept there and still run.
"""
from __future__ import annotations

import types

import numpy as np
import pytest

from cab_core.sandbox import Sandbox, SandboxConfig
from cab_core.sandbox import guest as runner


def _dispatch(name, kwargs):
    raise AssertionError(f"no tool is called by these programs: {name}")


@pytest.fixture(scope="module")
def sb():
    sandbox = Sandbox(["get_arm_pose"], _dispatch, lambda obs_id: np.zeros((2, 2, 3), np.uint8),
                      SandboxConfig(timeout_s=30))
    yield sandbox
    sandbox.close()


def ok(result: dict) -> dict:
    assert result["ok"], result["error"]
    return result


def still_works(sb):
    """After a refusal: same child, namespace intact, ordinary programs run."""
    assert ok(sb.run("result = marker"))["value"] == "kept"


@pytest.fixture(autouse=True)
def _marker(sb):
    ok(sb.run("marker = 'kept'"))


# ------------------------------------------------------------------- refused before the program runs
TB = "try:\n    1 / 0\nexcept Exception as e:\n    err = e\n"

STATIC = [
    # (1) keyword attributes in class patterns, however deeply the pattern nests
    (TB + "match err:\n    case Exception(__traceback__=tb):\n        result = str(tb)",
     "line 6: access to attribute '.__traceback__' is not allowed"),
    ("match 1:\n    case int(__class__=c):\n        result = repr(c)", "attribute '.__class__'"),
    ("match 1:\n    case int(real=r, _x=c):\n        pass", "attribute '._x'"),
    (TB + "match [err]:\n    case [Exception(__traceback__=tb)]:\n        pass", "attribute '.__traceback__'"),
    (TB + "match {'k': err}:\n    case {'k': Exception(__traceback__=tb)} | [Exception(__context__=tb)]:\n"
     "        pass", "attribute '.__traceback__'"),
    (TB + "match {'k': err}:\n    case {'k': Exception(__traceback__=tb)} | [Exception(__context__=tb)]:\n"
     "        pass", "attribute '.__context__'"),
    ("g = (i for i in [1])\nmatch g:\n    case Exception(gi_frame=f):\n        pass", "attribute '.gi_frame'"),
    # a class pattern would hand out the raw str.format, which the run-time check cannot see
    ("match 'x{0.__class__}':\n    case str(format=f):\n        result = f(1)",
     "line 2: class pattern keyword 'format' is not allowed"),
    ("match 'x':\n    case str(format_map=f):\n        pass", "class pattern keyword 'format_map' is not allowed"),
    # the raw method would be loaded (and combined) without going through the hook
    ("s = 'x'\ns.format += 1", "line 2: augmented assignment to '.format' is not allowed"),
    ("def f():\n    pass\nf.format_map = 1\nf.format_map += 1", "augmented assignment to '.format_map'"),
    # the hook's own name, like every "__" name, cannot be used or rebound
    ("result = __cab_format_attr__(1, 'real')", "name '__cab_format_attr__' is not allowed"),
    # (3) names bound without an ast.Name node
    (TB.replace("as e", "as __builtins__").replace("err = e", "pass"), "line 3: name '__builtins__' is not allowed"),
    ("match 1:\n    case __builtins__:\n        pass", "name '__builtins__' is not allowed"),
    ("match 1:\n    case int() as __x:\n        pass", "name '__x' is not allowed"),
    ("match [1, 2]:\n    case [1, *__rest]:\n        pass", "name '__rest' is not allowed"),
    ("match {'a': 1}:\n    case {'a': 1, **__rest}:\n        pass", "name '__rest' is not allowed"),
    ("def f():\n    global __builtins__\n    return 1", "name '__builtins__' is not allowed"),
    ("def f():\n    def g():\n        nonlocal __y\n    return g", "line 3: name '__y' is not allowed"),
    # (2) literal format strings: every field, including those nested in a format spec
    ("result = '{0.__class__}'.format(1)", "line 1: format field '{0.__class__}' reaches attribute '.__class__'"),
    ("result = '{.__class__}'.format(1)", "format field '{.__class__}' reaches attribute '.__class__'"),
    ("result = 'a {} {0.real.__class__!r:>9}'.format(1)",
     "format field '{0.real.__class__}' reaches attribute '.__class__'"),
    ("result = '{0.__func__.__globals__}'.format(load_image)",
     "format field '{0.__func__.__globals__}' reaches attribute '.__func__'"),
    ("result = '{0[__builtins__]}'.format({})", "format field '{0[__builtins__]}' looks up item '[__builtins__]'"),
    ("result = '{0[0]._x}'.format([1])", "format field '{0[0]._x}' reaches attribute '._x'"),
    ("result = '{x.__class__}'.format_map({'x': 1})", "format field '{x.__class__}' reaches attribute '.__class__'"),
    ("result = '{0:{1.__class__}}'.format(1, 2)", "format field '{1.__class__}' reaches attribute '.__class__'"),
    ("result = '{0!r:>{1[_k]}}'.format(1, {})", "format field '{1[_k]}' looks up item '[_k]'"),
    ("g = (i for i in [1])\nresult = '{0.gi_frame.f_back}'.format(g)",
     "line 2: format field '{0.gi_frame.f_back}' reaches attribute '.gi_frame'"),
    ("fmt = '{0.__class__}'.format\nresult = fmt(1)", "line 1: format field '{0.__class__}'"),
    ("result = str.format('{0.__class__}', 1)", "format field '{0.__class__}' reaches attribute '.__class__'"),
    ("result = str.format_map('{a._b}', {'a': 1})", "format field '{a._b}' reaches attribute '._b'"),
    ("result = ('{0.' '__class__}').format(1)", "format field '{0.__class__}'"),  # implicit concatenation
    # f-strings compile to expressions: the attribute rule sees them, nested specs included
    ("x = 1\nresult = f'{x.__class__}'", "line 2: access to attribute '.__class__' is not allowed"),
    ("x = 1\nresult = f'{x:{x.__class__}}'", "line 2: access to attribute '.__class__' is not allowed"),
]


@pytest.mark.parametrize("code, why", STATIC)
def test_refused_by_the_policy_before_running(sb, code, why):
    r = sb.run(code)
    assert not r["ok"] and r["error"].startswith("code rejected by the sandbox policy:\n"), r["error"]
    assert why in r["error"], r["error"]
    assert r["value"] is None and r["stdout"] == "" and not r["namespace_reset"]
    still_works(sb)


def test_all_problems_of_one_program_are_listed(sb):
    r = sb.run("match 1:\n    case int(__class__=c) as __x:\n        pass\ns = '{0._a}{0[_b]}'.format(1)")
    head, *problems = r["error"].splitlines()
    assert head == "code rejected by the sandbox policy:" and sorted(problems) == [
        "line 2: access to attribute '.__class__' is not allowed",
        "line 2: name '__x' is not allowed",
        "line 4: format field '{0._a}' reaches attribute '._a', which is not allowed",
        "line 4: format field '{0[_b]}' looks up item '[_b]', which is not allowed",
    ]


# ------------------------------------------------------------------ refused while the program runs
DUNDER = "'{0.' + '__class__}'"  # a template the policy cannot read: it is built at run time

RUNTIME = [
    (f"s = {DUNDER}\nresult = s.format(1)", "{0.__class__}", "reaches attribute '.__class__'", 2),
    ("fmt = ('{0.__func__' + '.__globals__[__name__]}').format\nresult = fmt(load_image)",
     "{0.__func__.__globals__[__name__]}", "reaches attribute '.__func__'", 2),
    (f"result = ({DUNDER}).format_map({{'0': 1}})", "{0.__class__}", "reaches attribute '.__class__'", 1),
    (f"result = str.format({DUNDER}, 1)", "{0.__class__}", "reaches attribute '.__class__'", 1),
    (f"f = str.format\nresult = f({DUNDER}, 1)", "{0.__class__}", "reaches attribute '.__class__'", 2),
    ("f = str.format_map\nresult = f('{x[' + '_k]}', {'x': {'_k': 1}})", "{x[_k]}", "looks up item '[_k]'", 2),
    (f"result = list(map(str.format, [{DUNDER}], [1]))", "{0.__class__}", "reaches attribute '.__class__'", 1),
    (f"result = np.str_({DUNDER}).format(1)", "{0.__class__}", "reaches attribute '.__class__'", 1),
    (f"result = np.str_.format(np.str_({DUNDER}), 1)", "{0.__class__}", "reaches attribute '.__class__'", 1),
    ("result = ('{0:{1.' + '__class__}}').format(1, 2)", "{1.__class__}", "reaches attribute '.__class__'", 1),
    ("result = ('{0:>{1:{0._' + 'x}}}').format(1, 2)", "{0._x}", "reaches attribute '._x'", 1),
    ("g = (i for i in [1])\nresult = ('{0.gi_' + 'frame}').format(g)", "{0.gi_frame}",
     "reaches attribute '.gi_frame'", 2),
    ("t = f'{{0.{\"__cl\" + \"ass__\"}}}'\nresult = t.format(1)", "{0.__class__}", "reaches attribute '.__class__'", 2),
    (f"def f():\n    pass\nf.format = ({DUNDER}).format\nresult = f.format(1)", "{0.__class__}",
     "reaches attribute '.__class__'", 4),
    # a field refused after harmless ones: nothing is formatted (and nothing leaks) before the refusal
    ("result = ('{0} {0.real} {0.' + '__class__}').format(1)", "{0.__class__}", "reaches attribute '.__class__'", 1),
]


@pytest.mark.parametrize("code, field, what, line", RUNTIME)
def test_refused_while_running(sb, code, field, what, line):
    r = sb.run(code)
    assert not r["ok"] and not r["namespace_reset"] and r["value"] is None, r
    last = r["error"].splitlines()[-1]
    assert last == f"SandboxPolicyError: format field '{field}' {what}, which is not allowed", r["error"]
    assert 'File "<run_code:' in r["error"] and f", line {line}, in " in r["error"], r["error"]
    assert "runner.py" not in r["error"]  # only the program's frames, as for any program error
    still_works(sb)


def test_runtime_refusal_is_an_exception_the_program_can_handle(sb):
    r = ok(sb.run(f"try:\n    s = ({DUNDER}).format(1)\nexcept Exception as e:\n"
                  "    result = [str(e), isinstance(e, ValueError)]"))
    assert r["value"] == ["format field '{0.__class__}' reaches attribute '.__class__', which is not allowed",
                          False]
    assert "class" not in r["stdout"]


# ------------------------------------------------------------------------ ordinary formatting works
def test_ordinary_formatting_still_works(sb):
    code = """
v = 3.14159
p = {'x': 2.0, 'name': 'cup'}
w, d = 8, 2
dyn = '{:' + '.2f}'
fmt = '{0} and {1}'.format
out = [
    '{:.3f}'.format(v), '{0} {1}'.format('a', 'b'), '{} {}'.format(1, 2), '{0[1]}'.format([1, 2]),
    '{p[x]:.1f} {p[name]!r}'.format(p=p), '{0.real}|{0.imag}'.format(3), '{a}-{b}'.format_map({'a': 1, 'b': 2}),
    str.format('{}-{}', 1, 2), dyn.format(v), '{0:{1}}'.format(v, '.1f'), '{:>{w}}|'.format('a', w=3),
    '{{literal}} {0}'.format(1), f'{v:{w}.{d}f}|', f'{v:.2e}', f'{p["name"]!r:>6}', format(v, '.2f'),
    '%s %d' % ('s', 2), '%(name)s' % p, np.str_('{:.1f}').format(2.25),
    fmt(1, 2), list(map('{}!'.format, [1, 2])), '{_k}'.format_map({'_k': 5}), '{0[-1]}'.format({'-1': 'neg'}),
    '{0.shape}'.format(np.zeros((2, 3))), '{:,}'.format(1234567), '{0!s:^7}'.format('mid'),
]
result = out
"""
    r = ok(sb.run(code))
    assert r["value"] == [
        "3.142", "a b", "1 2", "2", "2.0 'cup'", "3|0", "1-2", "1-2", "3.14", "3.1", "  a|", "{literal} 1",
        "    3.14|", "3.14e+00", " 'cup'", "3.14", "s 2", "cup", "2.2", "1 and 2", ["1!", "2!"], "5", "neg",
        "(2, 3)", "1,234,567", "  mid  ",
    ]


def test_format_errors_and_non_strings_behave_as_before(sb):
    r = sb.run("s = '{0' + ''\nresult = s.format(1)")
    assert r["error"].splitlines()[-1] == "ValueError: expected '}' before end of string"
    r = sb.run("result = ('{0.' + 'real').format(1)")
    assert r["error"].splitlines()[-1] == "ValueError: expected '}' before end of string"
    r = sb.run("result = {}.format")
    assert r["error"].splitlines()[-1] == "AttributeError: 'dict' object has no attribute 'format'"
    r = sb.run("result = str.format(1)")
    assert "TypeError" in r["error"].splitlines()[-1] and "format" in r["error"].splitlines()[-1]
    r = sb.run("result = '{5} {'.format(1)")  # str.format's own error, as before: it fails at field 5
    assert r["error"].splitlines()[-1] == "IndexError: Replacement index 5 out of range for positional args tuple"
    r = sb.run("result = ('{0:>{1:{0:{1}}}}' + '').format(1, 2)")  # nested too deeply: str.format refuses
    assert r["error"].splitlines()[-1] == "ValueError: Max string recursion exceeded"
    r = sb.run("result = format(1, '{0.__class__}')")  # a spec is no template: nothing is resolved
    assert r["error"].splitlines()[-1] == ("ValueError: Invalid format specifier '{0.__class__}' "
                                           "for object of type 'int'")
    r = ok(sb.run("def f():\n    pass\nf.format = 7\nresult = f.format"))
    assert r["value"] == 7
    r = ok(sb.run("match 'x':\n    case str.format:\n        result = 'no'\n    case _:\n        result = 'yes'"))
    assert r["value"] == "yes"  # a value pattern only compares: left as it is, and it compiles
    still_works(sb)


def test_every_run_starts_from_the_safe_builtins():
    """Defence in depth behind the name rule: were ``__builtins__`` deleted from the namespace, exec
    would put the real builtins there; the child puts its own back before each run."""
    child = runner.Runner(None, {"tools": [], "max_internal_calls": 5, "stdout_cap": 100})
    del child.ns["__builtins__"]
    reply = child.run("result = hasattr")
    assert reply["error"].splitlines()[-1] == "NameError: name 'hasattr' is not defined"
    assert child.ns["__builtins__"] is child.builtins and child.run("result = abs(-2)")["value"] == 2


def test_except_as_builtins_no_longer_hands_out_the_real_builtins(sb):
    """The handler's implicit ``del __builtins__`` left the namespace without the name, and exec gave the
    next run the interpreter's real builtins (``hasattr``, and an ``__import__`` that imports the real
    numpy, whose ``compat.py3k.open_latin1`` opens files)."""
    r = sb.run("try:\n    1 / 0\nexcept Exception as __builtins__:\n    pass")
    assert not r["ok"] and "line 3: name '__builtins__' is not allowed" in r["error"]
    for code in ("result = hasattr(1, 'real')", "result = [hasattr]"):  # not among the safe builtins
        r = sb.run(code)
        assert r["error"].splitlines()[-1] == "NameError: name 'hasattr' is not defined"
    assert ok(sb.run("import numpy\nresult = numpy is np"))["value"] is True  # the filtered numpy


# ----------------------------------------------------------------- what else could reach attributes
def _reachable():
    """Every public module and class the program's namespace reaches by ``.name`` chains."""
    import builtins
    import math

    for name in ("linalg", "random", "fft", "polynomial"):
        __import__("numpy." + name)
    roots = [("np", runner._filtered_module(np, {})), ("math", math)]
    roots += [(n, getattr(builtins, n)) for n in runner._SAFE_BUILTIN_NAMES]
    seen, stack = set(), list(roots)
    while stack:
        path, obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        yield path, obj
        if isinstance(obj, (types.ModuleType, type)):
            for key, value in list(vars(obj).items()):
                # .format and .format_map are not followed: every such access goes through the hook
                if not key.startswith("_") and key not in runner.BANNED_ATTRS | {"format", "format_map"}:
                    stack.append((f"{path}.{key}", value))


def test_no_reachable_class_pattern_or_raw_format_route():
    """Positional class patterns read the attributes named by ``__match_args__``, and an object that is
    ``str.format`` itself, or a method bound to a string, reached under another name would skip the
    run-time check. Neither is reachable."""
    raw_format = (str.format, str.format_map)
    found = []
    for path, obj in _reachable():
        if isinstance(obj, type) and getattr(obj, "__match_args__", None) is not None:
            found.append((path, obj.__match_args__))
        if any(obj is f for f in raw_format) or (isinstance(obj, types.BuiltinMethodType)
                                                and isinstance(getattr(obj, "__self__", None), str)):
            found.append((path, obj))
    assert found == []
