"""The run_code child: executes agent programs in a confined process.

This file is copied, alone, into a private directory and started with ``python -I -S -B`` (under
bubblewrap where available). It imports only the standard library and numpy, and never anything from
``cab_core``: the host does not even need to be importable from here.

Wire protocol (both directions, over the child's stdin/stdout pipes): a frame is
``struct.pack(">II", len(json_bytes), len(blob)) + json_bytes + blob``; ``blob`` carries raw image
bytes (HxWx3 uint8, C order) and is empty otherwise.

host -> child: init, run, reply (to call), image (to load_image), exit
child -> host: ready, out (captured print text), call (a tool call), load_image, done

Start-up order, so that nothing the program can do runs before the confinement is in place:
rlimits -> parent-death signal -> import numpy -> build the namespace -> Landlock -> seccomp ->
``ready``. Every layer that could not be applied is reported in ``ready`` (the host decides whether
that is acceptable: ``mode="required"`` refuses to run without bubblewrap and seccomp).

The Python layer (``check_tree`` before a program runs, restricted builtins and numpy while it runs)
means: no program reaches an attribute whose name starts with ``_`` (or is in ``BANNED_ATTRS``), and
no name starting with ``__`` is used or bound. The routes to an attribute by name, and how each is
held:

* ``obj.attr`` (``ast.Attribute``), including inside f-strings, whose fields and nested format specs
  are ordinary expressions in the AST;
* ``case C(attr=p)``: class-pattern keywords (``MatchClass.kwd_attrs``) pass the same test. Positional
  class patterns read the names in a class's ``__match_args__``; no class the program can name has one
  (the tests check the whole reachable namespace), and the program cannot define classes;
* ``getattr``/``vars``/``dir``/``type``/``object`` are not available;
* ``str.format`` and ``str.format_map`` resolve ``{0.attr}`` and ``{0[key]}`` fields themselves (and
  those nested in a spec, ``{0:{1.attr}}``). A literal template is checked before the program runs.
  A template can also be built at run time, so every load of an attribute named ``format`` or
  ``format_map`` is rewritten into ``__cab_format_attr__(obj, name)`` (a builtin the program cannot
  name): where that is ``str.format``/``format_map``, bound or not, on a ``str`` or a subclass, the
  program gets a wrapper that parses the template with the interpreter's own parser (``_string``,
  behind ``string.Formatter``) and raises ``SandboxPolicyError`` before anything is formatted if a
  field steps to a refused attribute or to an item whose key starts with ``_``; otherwise it is the
  real method and formatting is unchanged. A plain first part (``{name}``) is an argument or mapping
  key, not a step, and is allowed. The only ways to the raw method without such a load (a class
  pattern keyword, an augmented assignment ``x.format += ...``) are refused by the policy, and no
  public object in reach is a raw format method under another name (checked by the tests). ``%``
  formatting and ``format(value, spec)`` resolve no fields and are not affected;
* names bound without an ``ast.Name`` node (``except E as n``, ``case ... as n``, ``*n``, ``**n``,
  ``global``/``nonlocal``) follow the ``__`` rule: ``except E as __builtins__`` ends with an implicit
  ``del __builtins__``, and exec fills a missing ``__builtins__`` with the real builtins. Each run also
  starts from the safe builtins again.

It also means no view of raw memory and no address:

* numpy's classes and helpers that take a raw buffer, an offset or strides are replaced in the
  program's numpy (``_raw_memory``): ``np.ndarray`` (a ``GuardedClass``: ``isinstance`` and class
  patterns see the real class; a call takes a buffer only through ``np.frombuffer``, which checks the
  offset and size, and no strides), ``np.recarray``/``np.chararray`` (no buffer, offset or strides),
  ``np.frombuffer`` (no object arrays), ``np.empty``/``empty_like`` (zeroed). ``byte_bounds``,
  ``from_dlpack``, ``ctypes``, ``lib`` (``stride_tricks``) and ``core`` are out of reach;
* ``.resize``, ``.tobytes``, ``.tostring``, ``.data`` and ``.view`` go through the same hook as
  ``format``: ``resize`` keeps numpy's reference check (``refcheck=False`` frees memory a view still
  uses), ``view`` takes the program's array classes for numpy's (``x.view(np.recarray)``), and an
  object array's bytes (its objects' addresses) are refused, as is ``bytes()`` of one. ``.data``,
  ``.strides`` and ``.dtype`` are never assigned or deleted (``x.data = ...`` re-points an object
  array at forged pointers);
* ``repr`` (and so ``str``, f-strings, ``%``, ``format``, exception messages and numpy's object
  arrays) shows no address: ``hide_addresses`` wraps every type's repr slot before seccomp, and
  ``hash`` takes values only (the default hash is the address);
* the program's ``math`` and ``numpy`` (and numpy's submodules) are ``ReadOnlyModule`` copies: a
  patch such as ``math.isfinite = ...`` is refused and could not reach the guest's own modules, and
  the serialiser uses references bound at import (``_isfinite``, ``_json_dumps``) and sends strict
  JSON;
* a program too deeply nested to parse or compile is reported as its error; the child and the
  namespace stay.
"""
from __future__ import annotations

import _string  # str.format's own field parser (string.Formatter's too)
import ast
import json
import linecache
import math
import operator
import os
import re
import resource
import struct
import sys
import traceback
import types
import warnings

_HEADER = struct.Struct(">II")
# The guest's own references for what it sends: bound before any program runs, and in no namespace a
# program reaches (a program's ``math`` and ``numpy`` are read-only copies, see ``_filtered_module``).
_json_dumps = json.dumps
_isfinite = math.isfinite
_MAX_FRAME = 256 * 1024 * 1024  # the host never sends more than one image plus a JSON reply


# --------------------------------------------------------------------------------------------- wire
class _Wire:
    def __init__(self, rfd: int, wfd: int):
        self.rfd = rfd
        self.wfd = wfd

    def _read_exact(self, n: int) -> bytearray:
        buf = bytearray(n)
        view = memoryview(buf)
        got = 0
        while got < n:
            k = os.readv(self.rfd, [view[got:]])
            if k == 0:
                raise EOFError("host closed the pipe")
            got += k
        return buf

    def recv(self):
        jl, bl = _HEADER.unpack(bytes(self._read_exact(_HEADER.size)))
        if jl > _MAX_FRAME or bl > _MAX_FRAME:
            raise EOFError("oversized frame from host")
        msg = json.loads(bytes(self._read_exact(jl)).decode("utf-8"))
        blob = self._read_exact(bl) if bl else None
        return msg, blob

    def send(self, msg: dict) -> None:
        # strict JSON: ``to_jsonable`` already turned every non-finite float into a string
        data = _json_dumps(msg, separators=(",", ":"), allow_nan=False).encode("utf-8")
        frame = _HEADER.pack(len(data), 0) + data
        view = memoryview(frame)
        while view:
            k = os.write(self.wfd, view)
            view = view[k:]


# ------------------------------------------------------------------------------------- AST policy
ALLOWED_IMPORTS = {"numpy", "math", "numpy.linalg", "numpy.random", "numpy.fft", "numpy.polynomial"}
BANNED_NAMES = {
    "eval", "exec", "open", "compile", "__import__", "getattr", "setattr", "delattr", "globals",
    "locals", "vars", "input", "breakpoint", "exit", "quit", "memoryview", "type", "super", "object",
    "classmethod", "staticmethod", "property", "help", "dir", "id",
}
# Attributes that lead from ordinary objects to frames, code, globals, files or raw memory. Every
# attribute starting with "_" is refused as well (dunders and numpy's private modules).
BANNED_ATTRS = {
    "gi_frame", "gi_code", "gi_yieldfrom", "gi_suspended", "cr_frame", "cr_code", "cr_await",
    "cr_origin", "ag_frame", "ag_code", "ag_await", "f_globals", "f_locals", "f_builtins", "f_back",
    "f_code", "f_trace", "tb_frame", "tb_next", "co_code", "co_consts", "func_globals", "func_code",
    "mro", "ctypes", "ctypeslib", "tofile", "dump", "dumps", "load", "loads", "loadtxt", "fromfile",
    "fromregex", "genfromtxt", "save", "savez", "savez_compressed", "savetxt", "memmap", "DataSource",
    "lib", "core", "testing", "distutils", "f2py", "os", "sys", "modules", "builtins",
    "byte_bounds", "from_dlpack", "cffi", "capsule", "set_numeric_ops",
}
# ndarray attributes that hand out raw bytes or can free memory a view still uses: every load of one
# goes through the run-time hook (like ``format``), which checks the object it is taken from.
ARRAY_ATTRS = ("resize", "tobytes", "tostring", "data", "view")
# Attributes no program assigns or deletes: they re-point an array at other memory or reinterpret it.
FROZEN_ATTRS = {"data", "strides", "dtype"}
_BANNED_NODES = {
    ast.ImportFrom: "from-imports are not allowed; use `import numpy` or `import math`",
    ast.ClassDef: "class definitions are not allowed",
    ast.AsyncFunctionDef: "async code is not allowed",
    ast.AsyncFor: "async code is not allowed",
    ast.AsyncWith: "async code is not allowed",
    ast.Await: "async code is not allowed",
}


def attr_refused(name: str) -> bool:
    """Whether the Python layer refuses the attribute ``name``, however the program names it."""
    return name.startswith("_") or name in BANNED_ATTRS


# ``str.format`` and ``str.format_map`` resolve ``{0.attr}`` and ``{0[key]}`` fields by name, out of
# the AST's sight; every load of an attribute with one of these names goes through this hook.
FORMAT_METHODS = ("format", "format_map")
FORMAT_HOOK = "__cab_format_attr__"  # a name the program cannot write: it starts with "__"
HOOKED_ATTRS = FORMAT_METHODS + ARRAY_ATTRS  # every load of one of these goes through the hook
# str.format expands a spec's fields two levels deep and refuses ("Max string recursion exceeded")
# before parsing a third; the check looks one level further and no deeper.
_FORMAT_LEVELS = 3


def _field_problem(field: str) -> str | None:
    """Why a replacement field's ``.attr``/``[key]`` steps are refused, or None. May raise ValueError
    part-way (a malformed field), after every step before the error passed."""
    _first, steps = _string.formatter_field_name_split(field)  # the first part is an argument
    for is_attr, key in steps:
        if is_attr and attr_refused(key):
            return f"format field '{{{field}}}' reaches attribute '.{key}'"
        if not is_attr and isinstance(key, str) and key.startswith("_"):
            return f"format field '{{{field}}}' looks up item '[{key}]'"
    return None


def format_problems(template: str, level: int = 0) -> list[str]:
    """The fields of ``template`` that ``str.format``/``format_map`` would traverse to a refused
    attribute or ``_`` item, in the order it resolves them, those in format specs included.

    Uses the interpreter's own parser (``_string``, behind ``string.Formatter``), so it reads fields
    exactly as ``str.format`` does. Where the template stops parsing, the check stops: ``str.format``
    raises its ValueError there, having resolved only the fields before, which were checked."""
    problems = []
    try:
        for _literal, field, spec, _conversion in _string.formatter_parser(template):
            if field is None:
                continue
            problem = _field_problem(field)
            if problem:
                problems.append(problem)
            if spec and "{" in spec and level + 1 < _FORMAT_LEVELS:
                problems += format_problems(spec, level + 1)
    except ValueError:
        pass
    return problems


def _literal_template(node: ast.AST) -> str | None:
    """The literal template of ``'...'.format``/``format_map`` or ``str.format('...', ...)``."""
    if isinstance(node, ast.Attribute) and node.attr in FORMAT_METHODS:
        if isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            return node.value.value
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in FORMAT_METHODS
            and isinstance(node.func.value, ast.Name) and node.func.value.id == "str" and node.args
            and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
        return node.args[0].value
    return None


def _bound_identifiers(node: ast.AST) -> list[str]:
    """Names a node binds or declares without an ``ast.Name`` node. ``except E as __builtins__`` is
    one: the handler ends with an implicit ``del``, and exec gives globals without ``__builtins__``
    the interpreter's real builtins."""
    if isinstance(node, (ast.FunctionDef, ast.ExceptHandler, ast.MatchAs, ast.MatchStar)):
        names = [node.name]
    elif isinstance(node, ast.MatchMapping):
        names = [node.rest]
    elif isinstance(node, (ast.Global, ast.Nonlocal)):
        names = list(node.names)
    elif isinstance(node, ast.arg):
        names = [node.arg]
    elif isinstance(node, ast.alias):
        names = [node.asname]
    elif type(node).__name__ in ("TypeVar", "ParamSpec", "TypeVarTuple"):  # 3.12: def f[T]()
        names = [node.name]  # type: ignore[attr-defined]  # nodes of 3.12, matched by their class name
    else:
        names = []
    return [n for n in names if n]


def check_tree(tree: ast.AST) -> list[str]:
    """Return the policy violations in ``tree`` (empty when the program may run)."""
    problems: list[str] = []
    for node in ast.walk(tree):
        line = getattr(node, "lineno", "?")
        for kind, why in _BANNED_NODES.items():
            if isinstance(node, kind):
                problems.append(f"line {line}: {why}")
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name not in ALLOWED_IMPORTS:
                    problems.append(f"line {line}: import of '{alias.name}' is not allowed "
                                    "(only numpy and math can be imported)")
        elif isinstance(node, ast.Attribute):
            if attr_refused(node.attr):
                problems.append(f"line {line}: access to attribute '.{node.attr}' is not allowed")
            elif node.attr in FROZEN_ATTRS and isinstance(node.ctx, (ast.Store, ast.Del)):
                problems.append(f"line {line}: assigning or deleting '.{node.attr}' is not allowed (it would "
                                "re-point or reinterpret an array's memory); use .astype(), .view() or np.array()")
        elif isinstance(node, ast.Name):
            if node.id in BANNED_NAMES or node.id.startswith("__"):
                problems.append(f"line {line}: name '{node.id}' is not allowed")
        elif isinstance(node, ast.MatchClass):
            # ``case C(attr=p)`` reads ``subject.attr`` by name, with no ast.Attribute node
            for attr in node.kwd_attrs:
                if attr_refused(attr):
                    problems.append(f"line {line}: access to attribute '.{attr}' is not allowed")
                elif attr in FORMAT_METHODS:  # would bind the raw method, past the format hook
                    problems.append(f"line {line}: class pattern keyword '{attr}' is not allowed; "
                                    f"call .{attr}() on the string instead")
                elif attr in ARRAY_ATTRS:  # would bind the raw attribute, past the hook
                    problems.append(f"line {line}: class pattern keyword '{attr}' is not allowed; "
                                    f"use .{attr} on the array instead")
        elif (isinstance(node, ast.AugAssign) and isinstance(node.target, ast.Attribute)
              and node.target.attr in HOOKED_ATTRS):  # loads the raw attribute, past the hook
            problems.append(f"line {line}: augmented assignment to '.{node.target.attr}' is not allowed")
        for name in _bound_identifiers(node):
            if name.startswith("__"):
                problems.append(f"line {line}: name '{name}' is not allowed")
        template = _literal_template(node)
        if template is not None:  # refused now; templates built at run time are checked by the hook
            problems += [f"line {line}: {p}, which is not allowed" for p in format_problems(template)]
    return list(dict.fromkeys(problems))  # each problem once, in the order found


# ---------------------------------------------------------------------- format hook (run time)
class SandboxPolicyError(Exception):
    """Raised into a program that does at run time what the Python layer refuses."""


def check_format_template(template: str) -> None:
    problems = format_problems(template)
    if problems:
        raise SandboxPolicyError(f"{problems[0]}, which is not allowed")


def _checked_bound(method, template: str):
    """``template.format`` (or ``format_map``) that checks the template before formatting."""

    def checked(*args, **kwargs):
        check_format_template(template)
        return method(*args, **kwargs)

    checked.__name__ = checked.__qualname__ = method.__name__
    checked.__doc__ = method.__doc__
    return checked  # no functools.wraps: its __wrapped__ would hand back the raw method


def _checked_unbound(descriptor):
    """``str.format`` (or ``format_map``) that checks its first argument before formatting."""

    def checked(*args, **kwargs):
        if args and isinstance(args[0], str):
            check_format_template(args[0])
        return descriptor(*args, **kwargs)  # a non-string first argument: str's own TypeError

    checked.__name__ = checked.__qualname__ = descriptor.__name__
    checked.__doc__ = descriptor.__doc__
    return checked


_real_np = None  # the guest's numpy, once the Runner imported it (the hook checks arrays against it)


def _array_method(arr, name: str, value):
    """``arr.resize`` that keeps numpy's reference check; ``tobytes``/``tostring``/``data`` of arrays
    that hold no Python objects (those of an object array are the objects' addresses)."""
    if name == "resize":
        def resize(*args, **kwargs):
            if not kwargs.pop("refcheck", True):
                raise SandboxPolicyError("ndarray.resize(refcheck=False) is not allowed: a view of the array "
                                         "would be left pointing at freed memory")
            return value(*args, refcheck=True, **kwargs)

        resize.__name__ = resize.__qualname__ = "resize"
        resize.__doc__ = value.__doc__
        return resize
    if name == "view":  # x.view(np.recarray): the program's array classes stand in for numpy's own
        def view(*args, **kwargs):
            args = tuple(a._cab_real if isinstance(a, GuardedClass) else a for a in args)
            kwargs = {k: v._cab_real if isinstance(v, GuardedClass) else v for k, v in kwargs.items()}
            return value(*args, **kwargs)

        view.__name__ = view.__qualname__ = "view"
        view.__doc__ = value.__doc__
        return view
    if arr.dtype.hasobject:
        raise SandboxPolicyError(f"'.{name}' of an array of Python objects is not allowed (its bytes are the "
                                 "objects' addresses)")
    return value


def _array_attr(obj, name: str):
    value = getattr(obj, name)
    nd = _real_np.ndarray if _real_np is not None else None
    if nd is None:
        return value
    if isinstance(obj, nd):
        return _array_method(obj, name, value)
    if isinstance(value, types.MethodDescriptorType) and issubclass(value.__objclass__, nd):
        descriptor = value  # np.ndarray.resize, np.matrix.tobytes, ...: checked for the array it is given

        def unbound(*args, **kwargs):
            if not args or not isinstance(args[0], nd):
                return descriptor(*args, **kwargs)  # numpy's own TypeError
            return _array_method(args[0], name, getattr(args[0], name))(*args[1:], **kwargs)

        unbound.__name__ = unbound.__qualname__ = name
        unbound.__doc__ = descriptor.__doc__
        return unbound
    return value


def format_attr(obj, name: str):
    """What the program gets for ``obj.format`` / ``obj.format_map`` and for the ndarray attributes of
    ``ARRAY_ATTRS`` (the AST is rewritten to call this). String formatting methods come back checked,
    array methods guarded (``_array_method``); anything else is the attribute itself."""
    if name in ARRAY_ATTRS:
        return _array_attr(obj, name)
    value = getattr(obj, name)
    if value is str.format or value is str.format_map:  # str.format, np.str_.format, ...
        return _checked_unbound(value)
    if (isinstance(value, types.BuiltinMethodType) and isinstance(getattr(value, "__self__", None), str)
            and value.__name__ in FORMAT_METHODS):  # 'x'.format, np.str_('x').format, ...
        return _checked_bound(value, value.__self__)  # type: ignore[arg-type]  # a str: tested above
    if isinstance(obj, str) or (isinstance(obj, type) and issubclass(obj, str)):
        # a string type that overrides the method: nothing in reach does; refuse rather than guess
        raise SandboxPolicyError(f"'.{name}' of this string type is not allowed")
    return value


class _FormatHook(ast.NodeTransformer):
    """Rewrites every load of ``X.format`` / ``X.format_map`` to ``__cab_format_attr__(X, 'format')``.

    Patterns are left alone: a value pattern (``case str.format:``) only compares, and a class
    pattern keyword of these names is refused by the policy."""

    def visit_Attribute(self, node: ast.Attribute):
        self.generic_visit(node)
        if node.attr not in HOOKED_ATTRS or not isinstance(node.ctx, ast.Load):
            return node
        call = ast.Call(func=ast.Name(FORMAT_HOOK, ast.Load()), args=[node.value, ast.Constant(node.attr)],
                        keywords=[])
        return ast.copy_location(call, node)

    def visit_match_case(self, node: ast.match_case):
        if node.guard is not None:
            node.guard = self.visit(node.guard)
        node.body = [self.visit(stmt) for stmt in node.body]
        return node


def hook_format(tree: ast.Module) -> ast.Module:
    return ast.fix_missing_locations(_FormatHook().visit(tree))


# ------------------------------------------------------------------------------------ safe numpy
_NP_DENY = {
    "load", "loads", "save", "savez", "savez_compressed", "savetxt", "loadtxt", "genfromtxt",
    "fromfile", "fromregex", "memmap", "DataSource", "recfromcsv", "recfromtxt", "ctypeslib", "info",
    "source", "lookfor", "who", "show_config", "show_runtime", "get_include", "test", "safe_eval",
    "deprecate", "deprecate_with_doc", "add_newdoc", "add_docstring", "add_newdoc_ufunc", "disp",
    "set_string_function", "seterrcall", "geterrcall", "byte_bounds", "from_dlpack", "set_numeric_ops",
}
_NP_MODULES = {
    "numpy.linalg", "numpy.random", "numpy.fft", "numpy.polynomial", "numpy.lib.scimath",
    "numpy.polynomial.polynomial", "numpy.polynomial.chebyshev", "numpy.polynomial.legendre",
    "numpy.polynomial.hermite", "numpy.polynomial.hermite_e", "numpy.polynomial.laguerre",
}


class ReadOnlyModule(types.ModuleType):
    """The program's own ``math``, ``numpy`` and numpy submodules: copies it reads but cannot change,
    so a program's patch (``math.isfinite = ...``) never reaches the modules the guest itself uses."""

    def __setattr__(self, name, value):
        raise SandboxPolicyError(f"module '{self.__name__}' is read-only in run_code; bind a name of your own "
                                 "instead")

    def __delattr__(self, name):
        raise SandboxPolicyError(f"module '{self.__name__}' is read-only in run_code")


class GuardedClass(type):
    """What a program gets for an ndarray class (``np.ndarray``, ``np.recarray``, ``np.chararray``):
    ``isinstance``, ``issubclass``, class patterns and the public attributes are the real class's;
    calling it goes through a constructor that takes no raw buffer, negative offset or strides."""

    def __instancecheck__(cls, obj):
        return isinstance(obj, cls._cab_real)

    def __subclasscheck__(cls, sub):
        return issubclass(sub._cab_real if isinstance(sub, GuardedClass) else sub, cls._cab_real)

    def __call__(cls, *args, **kwargs):
        return cls._cab_new(*args, **kwargs)

    def __getattr__(cls, name):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(cls._cab_real, name)

    def __repr__(cls):
        return repr(cls._cab_real)


def _guarded(real, new):
    return GuardedClass(real.__name__, (), {"_cab_real": real, "_cab_new": staticmethod(new),
                                            "__doc__": real.__doc__, "__module__": real.__module__})


def _object_bytes_refused(real):
    def new(*args, **kwargs):
        if args and _real_np is not None and isinstance(args[0], _real_np.ndarray) and args[0].dtype.hasobject:
            raise SandboxPolicyError(f"{real.__name__}() of an array of Python objects is not allowed (its bytes are "
                                     "the objects' addresses)")
        return real(*args, **kwargs)

    new.__name__ = new.__qualname__ = real.__name__
    return new


def _raw_memory(np) -> dict:
    """numpy's names that take a raw buffer, an offset or strides, or hand out uninitialised memory,
    replaced by checked versions: no array a program makes can see outside the bytes it was given."""
    # np.char.chararray: numpy 2 deprecates the top-level np.chararray (a lazy name, so not among the
    # module's public names: a program is offered the checked version under numpy 1 only); numpy 2.5
    # (Python >= 3.12) warns on np.char.chararray too, yet still offers it, so it is still guarded
    real_nd, real_frombuffer, real_rec = np.ndarray, np.frombuffer, np.recarray
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        real_char = np.char.chararray

    def frombuffer(buffer, dtype=float, count=-1, offset=0, **kwargs):
        if isinstance(buffer, real_nd) and buffer.dtype.hasobject:
            raise SandboxPolicyError("np.frombuffer of an array of Python objects is not allowed (its bytes are "
                                     "the objects' addresses)")
        offset = operator.index(offset)
        if offset < 0:
            raise ValueError("offset must be non-negative and no greater than buffer length")
        return real_frombuffer(buffer, dtype, count, offset, **kwargs)

    def ndarray(shape, dtype=float, buffer=None, offset=0, strides=None, order=None):
        if strides is not None:
            raise SandboxPolicyError("np.ndarray(strides=...) is not allowed in run_code; use reshape, slicing "
                                     "or transpose")
        order = "F" if order == "F" else "C"
        if buffer is None:
            return np.zeros(shape, dtype, order)  # zeroed: no stale memory either
        shape = tuple(shape) if isinstance(shape, (tuple, list)) else (operator.index(shape),)
        count = 1
        for n in shape:
            count *= operator.index(n)
        # frombuffer checks the offset and that count items fit in the buffer
        return frombuffer(buffer, dtype, count, offset).reshape(shape, order=order)

    def no_raw(real, label, buffer_key):
        def new(*args, **kwargs):
            names = real.__new__.__code__.co_varnames[1:real.__new__.__code__.co_argcount]
            given = dict(zip(names, args), **kwargs)
            if given.get(buffer_key) is not None or given.get("offset", 0) != 0 or given.get("strides") is not None:
                raise SandboxPolicyError(f"{label}({buffer_key}=, offset=, strides=) is not allowed in run_code")
            return np.zeros_like(real(*args, **kwargs))  # zeroed: no stale memory either

        new.__name__ = new.__qualname__ = real.__name__
        return new

    return {
        "ndarray": _guarded(real_nd, ndarray),
        "recarray": _guarded(real_rec, no_raw(real_rec, "np.recarray", "buf")),
        "chararray": _guarded(real_char, no_raw(real_char, "np.chararray", "buffer")),
        "frombuffer": frombuffer,
        "empty": np.zeros,  # np.empty hands out whatever the memory held before (addresses included)
        "empty_like": np.zeros_like,
    }


def _filtered_module(mod, cache: dict):
    """A read-only module holding ``mod``'s public names minus file access, foreign modules and raw
    memory (numpy's buffer, offset and stride constructors are replaced by checked ones)."""
    if mod.__name__ in cache:
        return cache[mod.__name__]
    out = ReadOnlyModule(mod.__name__, getattr(mod, "__doc__", None))
    cache[mod.__name__] = out
    space = vars(out)  # filled directly: the module refuses setattr
    replaced = _raw_memory(mod) if mod.__name__ == "numpy" else {}
    for key, value in list(vars(mod).items()):
        if key.startswith("_") or key in _NP_DENY:
            continue
        if isinstance(value, types.ModuleType):
            if value.__name__ in _NP_MODULES:
                space[key] = _filtered_module(value, cache)
            continue
        space[key] = replaced.get(key, value)
    return out


# ------------------------------------------------------------------------------- JSON conversion
_MAX_NODES = 20000
_MAX_STR = 20000  # one string
_MAX_CHARS = 200000  # all strings together
_MAX_ARRAY = 20000
_TRUNC = "__cab_truncated"  # the marker of cab_core.sandbox.truncate.MARK (this file imports nothing of cab_core)


def to_jsonable(value, np, budget=None, depth=0):
    """Convert a program value to plain JSON data (bounded; non-finite floats become strings)."""
    if budget is None:
        budget = [_MAX_NODES, _MAX_CHARS]
    budget[0] -= 1
    if depth > 64:
        return {f"{_TRUNC}_value__": "nested too deeply"}
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, int):
        return value if abs(value) < 2**63 else str(value)
    if isinstance(value, float):
        return value if _isfinite(value) else repr(value)
    if isinstance(value, str):
        n = max(0, min(len(value), _MAX_STR, budget[1]))
        budget[1] -= n
        if n < len(value):
            return value[:n] + f"...[{_TRUNC}_chars__: {len(value) - n}]"
        return value
    if isinstance(value, np.ndarray):
        if value.size > _MAX_ARRAY:
            return {f"{_TRUNC}_array__": {"shape": list(value.shape), "dtype": str(value.dtype),
                                         "head": to_jsonable(value.ravel()[:32].tolist(), np, budget, depth + 1)}}
        return to_jsonable(value.tolist(), np, budget, depth + 1)
    if isinstance(value, np.generic):
        return to_jsonable(value.item(), np, budget, depth + 1)
    if isinstance(value, complex):
        return {"real": to_jsonable(value.real, np, budget), "imag": to_jsonable(value.imag, np, budget)}
    if isinstance(value, dict):
        out = {}
        for i, (k, v) in enumerate(value.items()):
            if budget[0] <= 0:
                out[f"{_TRUNC}_keys__"] = len(value) - i
                break
            key = k if isinstance(k, str) else str(to_jsonable(k, np, budget, depth + 1))
            out[key] = to_jsonable(v, np, budget, depth + 1)
        return out
    if isinstance(value, (set, frozenset)):
        try:
            value = sorted(value)
        except TypeError:
            value = sorted(value, key=repr)
    if isinstance(value, (list, tuple, range)):
        listed = []
        for i, v in enumerate(value):
            if budget[0] <= 0:
                listed.append({f"{_TRUNC}_items__": len(value) - i})
                break
            listed.append(to_jsonable(v, np, budget, depth + 1))
        return listed
    if isinstance(value, (bytes, bytearray)):
        return to_jsonable(repr(bytes(value[:_MAX_STR])), np, budget, depth + 1)
    return to_jsonable(repr(value), np, budget, depth + 1)


# ------------------------------------------------------------------------------- OS confinement
_ARCH = {
    # machine: (AUDIT_ARCH, syscall numbers)
    "x86_64": (0xC000003E, dict(
        seccomp=317, landlock_create_ruleset=444, landlock_add_rule=445, landlock_restrict_self=446,
        execve=59, execveat=322, fork=57, vfork=58, clone=56, clone3=435, socket=41, ptrace=101,
        process_vm_readv=310, process_vm_writev=311, kill=62, tkill=200, tgkill=234,
        rt_sigqueueinfo=129, rt_tgsigqueueinfo=297, pidfd_open=434, pidfd_send_signal=424,
        pidfd_getfd=438, prlimit64=302, unshare=272, setns=308, mount=165, umount2=166,
        pivot_root=155, chroot=161, bpf=321, perf_event_open=298, userfaultfd=323, keyctl=250,
        add_key=248, request_key=249, io_uring_setup=425, io_uring_enter=426, io_uring_register=427,
        open_tree=428, move_mount=429, fsopen=430, fsconfig=431, fsmount=432, fspick=433,
        mount_setattr=442, kcmp=312, process_madvise=440, process_mrelease=448,
        name_to_handle_at=303, open_by_handle_at=304, kexec_load=246, init_module=175,
        finit_module=313, delete_module=176, reboot=169, swapon=167, swapoff=168, acct=163,
        quotactl=179, personality=135, setpriority=141, ioprio_set=251, sched_setaffinity=203,
        sched_setscheduler=144, sched_setparam=142, sched_setattr=314,
    )),
    "aarch64": (0xC00000B7, dict(
        seccomp=277, landlock_create_ruleset=444, landlock_add_rule=445, landlock_restrict_self=446,
        execve=221, execveat=281, clone=220, clone3=435, socket=198, ptrace=117,
        process_vm_readv=270, process_vm_writev=271, kill=129, tkill=130, tgkill=131,
        rt_sigqueueinfo=138, rt_tgsigqueueinfo=240, pidfd_open=434, pidfd_send_signal=424,
        pidfd_getfd=438, prlimit64=261, unshare=97, setns=268, mount=40, umount2=39,
        pivot_root=41, chroot=51, bpf=280, perf_event_open=241, userfaultfd=282, keyctl=219,
        add_key=217, request_key=218, io_uring_setup=425, io_uring_enter=426, io_uring_register=427,
        open_tree=428, move_mount=429, fsopen=430, fsconfig=431, fsmount=432, fspick=433,
        mount_setattr=442, kcmp=272, process_madvise=440, process_mrelease=448,
        name_to_handle_at=264, open_by_handle_at=265, kexec_load=104, init_module=105,
        finit_module=273, delete_module=106, reboot=142, swapon=224, swapoff=225, acct=89,
        quotactl=60, personality=92, setpriority=140, ioprio_set=30, sched_setaffinity=122,
        sched_setscheduler=119, sched_setparam=118, sched_setattr=274,
    )),
}
# Refused outright (EPERM): new programs, new processes, other processes' memory, namespaces,
# mounts, kernel objects that widen the attack surface.
_DENY = (
    "execve", "execveat", "fork", "vfork", "ptrace", "process_vm_readv", "process_vm_writev", "tkill",
    "pidfd_open", "pidfd_send_signal", "pidfd_getfd", "unshare", "setns", "mount", "umount2",
    "pivot_root", "chroot", "bpf", "perf_event_open", "userfaultfd", "keyctl", "add_key",
    "request_key", "io_uring_setup", "io_uring_enter", "io_uring_register", "open_tree",
    "move_mount", "fsopen", "fsconfig", "fsmount", "fspick", "mount_setattr", "kcmp",
    "process_madvise", "process_mrelease", "name_to_handle_at", "open_by_handle_at", "kexec_load",
    "init_module", "finit_module", "delete_module", "reboot", "swapon", "swapoff", "acct",
    "quotactl", "personality", "setpriority", "ioprio_set", "sched_setaffinity",
    "sched_setscheduler", "sched_setparam", "sched_setattr",
)
_EPERM, _ENOSYS = 1, 38
_RET_ALLOW, _RET_ERRNO, _RET_KILL_PROCESS = 0x7FFF0000, 0x00050000, 0x80000000
_CLONE_THREAD = 0x00010000
_AF_UNIX = 1


def _bpf_program(machine: str, mypid: int) -> list[tuple[int, int, int, int]]:
    audit_arch, nr = _ARCH[machine]
    LD, JEQ, JGE, JSET, RET = 0x20, 0x15, 0x35, 0x45, 0x06
    deny = _RET_ERRNO | _EPERM

    def ld(off):
        return (LD, 0, 0, off)

    def ret(k):
        return (RET, 0, 0, k)

    arg0 = 16  # low 32 bits of args[0] (little-endian)
    prog = [ld(4), (JEQ, 1, 0, audit_arch), ret(_RET_KILL_PROCESS), ld(0)]
    if machine == "x86_64":  # the x32 ABI: syscall numbers with bit 30 set
        prog += [(JGE, 0, 1, 0x40000000), ret(deny)]

    def arg0_in(name, values):
        body = [ld(arg0)]
        for i, v in enumerate(values):
            body.append((JEQ, len(values) - i, 0, v & 0xFFFFFFFF))
        body += [ret(deny), ret(_RET_ALLOW)]
        return [(JEQ, 0, len(body), nr[name])] + body

    for name in _DENY:
        if name in nr:
            prog += [(JEQ, 0, 1, nr[name]), ret(deny)]
    prog += [(JEQ, 0, 1, nr["clone3"]), ret(_RET_ERRNO | _ENOSYS)]  # libc falls back to clone
    # clone: threads only (CLONE_THREAD set); fork/posix_spawn/subprocess are refused.
    prog += [(JEQ, 0, 4, nr["clone"]), ld(arg0), (JSET, 0, 1, _CLONE_THREAD), ret(_RET_ALLOW), ret(deny)]
    prog += arg0_in("socket", [_AF_UNIX])  # no IP, netlink, packet or other socket families
    for name in ("kill", "tgkill", "rt_sigqueueinfo", "rt_tgsigqueueinfo"):
        prog += arg0_in(name, [mypid])  # signals only to itself
    prog += arg0_in("prlimit64", [0, mypid])  # its own limits only
    prog.append(ret(_RET_ALLOW))
    return prog


def _libc():
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    libc.prctl.restype = ctypes.c_int
    return ctypes, libc


def _no_new_privs(ctypes, libc) -> None:
    if libc.prctl(38, ctypes.c_ulong(1), ctypes.c_ulong(0), ctypes.c_ulong(0), ctypes.c_ulong(0)) != 0:
        raise OSError(ctypes.get_errno(), "PR_SET_NO_NEW_PRIVS failed")


def install_seccomp() -> str:
    machine = os.uname().machine
    if machine not in _ARCH:
        raise OSError(f"no seccomp filter for architecture {machine}")
    ctypes, libc = _libc()

    # ctypes is the module _libc returns (imported only when the filter is installed), not a name mypy resolves
    class SockFilter(ctypes.Structure):  # type: ignore[name-defined]
        _fields_ = [("code", ctypes.c_uint16), ("jt", ctypes.c_uint8), ("jf", ctypes.c_uint8),
                    ("k", ctypes.c_uint32)]

    class SockFprog(ctypes.Structure):  # type: ignore[name-defined]
        _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.POINTER(SockFilter))]

    insns = _bpf_program(machine, os.getpid())
    arr = (SockFilter * len(insns))(*[SockFilter(*i) for i in insns])  # type: ignore[operator]
    prog = SockFprog(len(insns), arr)
    _no_new_privs(ctypes, libc)
    nr = _ARCH[machine][1]["seccomp"]
    # SECCOMP_SET_MODE_FILTER with SECCOMP_FILTER_FLAG_TSYNC: every thread (BLAS workers too).
    if libc.syscall(ctypes.c_long(nr), ctypes.c_ulong(1), ctypes.c_ulong(1), ctypes.byref(prog)) != 0:
        raise OSError(ctypes.get_errno(), "seccomp(SET_MODE_FILTER) failed")
    return f"ok ({len(insns)} instructions)"


def install_landlock(read_paths: list[str]) -> str:
    """Allow reading (and mapping) only ``read_paths``; deny all other file access, TCP and signals
    or abstract sockets reaching outside the sandbox."""
    machine = os.uname().machine
    if machine not in _ARCH:
        raise OSError(f"no Landlock support for architecture {machine}")
    nr = _ARCH[machine][1]
    ctypes, libc = _libc()
    abi = libc.syscall(ctypes.c_long(nr["landlock_create_ruleset"]), None, ctypes.c_ulong(0), ctypes.c_ulong(1))
    if abi < 1:
        raise OSError(ctypes.get_errno(), "Landlock is not available in this kernel")
    fs = (1 << 13) - 1
    if abi >= 2:
        fs |= 1 << 13  # REFER
    if abi >= 3:
        fs |= 1 << 14  # TRUNCATE
    if abi >= 5:
        fs |= 1 << 15  # IOCTL_DEV
    net = 0x3 if abi >= 4 else 0  # BIND_TCP | CONNECT_TCP
    scoped = 0x3 if abi >= 6 else 0  # ABSTRACT_UNIX_SOCKET | SIGNAL
    size = 24 if abi >= 6 else (16 if abi >= 4 else 8)
    attr = ctypes.create_string_buffer(struct.pack("=QQQ", fs, net, scoped)[:size], size)
    rfd = libc.syscall(ctypes.c_long(nr["landlock_create_ruleset"]), attr, ctypes.c_ulong(size), ctypes.c_ulong(0))
    if rfd < 0:
        raise OSError(ctypes.get_errno(), "landlock_create_ruleset failed")
    read_file, read_dir, execute = 1 << 2, 1 << 3, 1 << 0
    try:
        for path in read_paths:
            try:
                pfd = os.open(path, os.O_PATH | os.O_CLOEXEC)
            except OSError:
                continue
            try:
                is_dir = os.path.isdir(path)
                access = (read_file | execute | read_dir) if is_dir else (read_file | execute)
                rule = ctypes.create_string_buffer(struct.pack("=Qi", access, pfd), 12)
                if libc.syscall(ctypes.c_long(nr["landlock_add_rule"]), ctypes.c_int(rfd), ctypes.c_int(1), rule,
                                ctypes.c_ulong(0)) != 0:
                    raise OSError(ctypes.get_errno(), f"landlock_add_rule({path}) failed")
            finally:
                os.close(pfd)
        _no_new_privs(ctypes, libc)
        if libc.syscall(ctypes.c_long(nr["landlock_restrict_self"]), ctypes.c_int(rfd), ctypes.c_ulong(0)) != 0:
            raise OSError(ctypes.get_errno(), "landlock_restrict_self failed")
    finally:
        os.close(rfd)
    return f"ok (ABI {abi})"


_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")
_REPR_KEEP = (str, bytes, bytearray, int, float, complex, bool, type(None), list, tuple, dict, set, frozenset)
_repr_slots: dict = {}  # original slot -> (original, replacement): kept alive as long as the process
_repr_replacements: set = set()  # the replacements' addresses (a second call wraps nothing twice)


def hide_addresses(keep: tuple = ()) -> str:
    """Make ``repr`` of every type show no object address (``<function f>``, not ``<function f at 0x..>``).

    An address is what turns a read of raw memory into a map of the process. Every route to a
    repr (``repr``, ``str``, f-strings, ``%r``, ``format``, exceptions' messages, numpy's object
    arrays and casts to strings) goes through the type's ``tp_repr`` slot, so the slot of each type
    is replaced by a wrapper that calls the original and drops " at 0x...". Types whose repr is
    their content (``str``, numbers, containers, ``keep``) are left alone. Run before seccomp; the
    slot offset is checked against ``PyType_GetSlot`` for every type before anything is written."""
    import ctypes

    get_slot = ctypes.pythonapi.PyType_GetSlot
    get_slot.restype, get_slot.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_int]
    tp_repr = 66  # Py_tp_repr
    word = ctypes.sizeof(ctypes.c_void_p)
    offset = 3 * word + 8 * word  # PyObject_VAR_HEAD, then tp_name ... tp_as_async
    reprfunc = ctypes.PYFUNCTYPE(ctypes.py_object, ctypes.py_object)
    types_, stack, seen = [], [object], set()
    while stack:
        t = stack.pop()
        if id(t) in seen:
            continue
        seen.add(id(t))
        types_.append(t)
        stack.extend(type.__subclasses__(t))
    kept = _REPR_KEEP + tuple(keep)
    plan = []
    for t in types_:
        if issubclass(t, kept):
            continue
        slot = ctypes.c_void_p.from_address(id(t) + offset)
        current = get_slot(t, tp_repr)
        if slot.value != current:
            raise OSError(f"the type layout of this Python is not the expected one ({t.__name__})")
        if current and current not in _repr_replacements:  # not wrapped yet
            plan.append((slot, current))
    for slot, current in plan:
        if current not in _repr_slots:
            original = reprfunc(current)

            def wrapper(obj, original=original):
                try:
                    return _ADDRESS.sub("", original(obj))
                except BaseException:  # noqa: BLE001 - a repr that fails (recursion) says what it is
                    return f"<{type(obj).__name__} object>"

            replacement = reprfunc(wrapper)
            _repr_slots[current] = (original, replacement)
            _repr_replacements.add(ctypes.cast(replacement, ctypes.c_void_p).value)
        slot.value = ctypes.cast(_repr_slots[current][1], ctypes.c_void_p).value

    def probe():
        pass

    # mypy reads probe.__call__ as a call of the function rather than its method-wrapper object
    if _ADDRESS.search(repr(probe)) or _ADDRESS.search(repr([probe.__call__])):  # type: ignore[operator]
        raise OSError("repr still shows addresses")
    return f"ok ({len(plan)} types)"


def apply_rlimits(limits: dict) -> str:
    pairs = {
        "as_bytes": resource.RLIMIT_AS, "cpu_s": resource.RLIMIT_CPU, "fsize_bytes": resource.RLIMIT_FSIZE,
        "nofile": resource.RLIMIT_NOFILE, "core": resource.RLIMIT_CORE,
    }
    done = []
    for key, res in pairs.items():
        if key in limits and limits[key] is not None:
            value = int(limits[key])
            resource.setrlimit(res, (value, value))
            done.append(f"{key}={value}")
    return "ok (" + ", ".join(done) + ")"


def set_parent_death_signal(expected_ppid: int) -> str:
    ctypes, libc = _libc()
    if libc.prctl(1, ctypes.c_ulong(9), ctypes.c_ulong(0), ctypes.c_ulong(0), ctypes.c_ulong(0)) != 0:  # PR_SET_PDEATHSIG, SIGKILL
        raise OSError(ctypes.get_errno(), "PR_SET_PDEATHSIG failed")
    if expected_ppid and os.getppid() != expected_ppid:
        os._exit(70)  # the host already died
    return "ok"


# --------------------------------------------------------------------------------------- program
class ProgramStopped(BaseException):
    """Raised into a program by the host (internal call limit, attempt ended). Not an Exception, so
    ``except Exception`` in the program does not swallow it; a later tool call raises it again."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


class _Out:
    """Captured stdout: streamed to the host as it is printed, up to the cap."""

    def __init__(self, wire: _Wire, cap: int):
        self.wire = wire
        self.cap = cap
        self.sent = 0

    def reset(self):
        self.sent = 0

    def write(self, text) -> int:
        text = str(text)
        room = self.cap - self.sent
        if room > 0 and text:
            self.wire.send({"op": "out", "text": text[:room]})
        self.sent += len(text)  # past the cap only counted; the total goes back with ``done``
        return len(text)

    def flush(self):
        pass


_HASH_VALUES = (int, float, complex, str, bytes, type(None), range)


def _value_hash(obj):
    """``hash`` of values only: the default hash of other objects (functions, arrays' iterators,
    classes) is their address."""
    if isinstance(obj, (tuple, frozenset)):
        for item in obj:
            _value_hash(item)
    elif not isinstance(obj, _HASH_VALUES) and not (_real_np is not None and isinstance(obj, _real_np.generic)):
        raise TypeError(f"hash() of a {type(obj).__name__} is not available in run_code (it would be derived "
                        "from the object's address)")
    return hash(obj)


_value_hash.__name__ = _value_hash.__qualname__ = "hash"

_SAFE_BUILTIN_NAMES = (
    "abs", "min", "max", "sum", "round", "sorted", "reversed", "enumerate", "zip", "len", "range",
    "map", "filter", "any", "all", "isinstance", "repr", "list", "dict", "tuple", "set", "str", "int",
    "float", "bool",
    # harmless additions (not in the upstream list) that numeric scripts use routinely
    "pow", "divmod", "iter", "next", "frozenset", "slice", "format", "callable", "chr", "ord",
    "complex", "bytes", "issubclass", "hash", "ascii", "bin", "hex", "oct",
    # exceptions
    "Exception", "ArithmeticError", "AssertionError", "AttributeError", "FloatingPointError",
    "IndexError", "KeyError", "LookupError", "MemoryError", "NameError", "NotImplementedError",
    "OverflowError", "RecursionError", "RuntimeError", "StopIteration", "TypeError",
    "UnboundLocalError", "ValueError", "ZeroDivisionError", "Warning", "UserWarning",
    "RuntimeWarning", "DeprecationWarning",
)


class Runner:
    def __init__(self, wire: _Wire, init: dict):
        self.wire = wire
        self.tools = [t for t in init["tools"] if t not in ("run_code", "done")]
        self.max_calls = int(init["max_internal_calls"])
        self.python_layer = bool(init.get("python_layer", True))
        self.out = _Out(wire, int(init["stdout_cap"]))
        self.calls = 0
        self.stopped: ProgramStopped | None = None
        self.run_id = 0
        import numpy

        global _real_np
        self.np = _real_np = numpy
        for name in ("linalg", "random", "fft", "polynomial"):
            __import__("numpy." + name)
        self.safe_np = _filtered_module(numpy, {})
        self.safe_math = _filtered_module(math, {})
        self.ns = self._namespace()

    # -- the program's world
    def _restricted_import(self, name, globals=None, locals=None, fromlist=(), level=0):
        # Import statements in the program arrive with fromlist None (the AST policy admits no other
        # form) and get the filtered numpy. numpy's C code imports its own lazy submodules through
        # the builtins of the calling frame, i.e. through here: CPython's PyImport_Import passes an
        # empty list as fromlist and then reads the module from sys.modules, so the real submodule
        # goes back to numpy's C code, never to the program (which has no way to call this itself).
        if level == 0 and name == "math" and fromlist is None:
            return self.safe_math
        if level == 0 and fromlist is None and name in ALLOWED_IMPORTS:
            return self.safe_np
        if level == 0 and fromlist is not None and (name == "numpy" or name.startswith("numpy.")):
            return __import__(name, None, None, fromlist, 0)
        raise ImportError(f"import of '{name}' is not allowed (only numpy and math can be imported)")

    def _namespace(self) -> dict:
        # plain functions, not bound methods: nothing in their repr or attributes leads to the Runner
        def print(*args, sep=" ", end="\n", file=None, flush=False):
            self._print(*args, sep=sep, end=end)

        def load_image(obs_id):
            """load_image(obs_id) -> the observation's pixels, an HxWx3 uint8 array."""
            return self._load_image(obs_id)

        print.__qualname__, load_image.__qualname__ = "print", "load_image"
        print_ = print
        if self.python_layer:
            import builtins

            safe = {k: getattr(builtins, k) for k in _SAFE_BUILTIN_NAMES}
            safe["__import__"] = self._restricted_import
            safe["print"] = print_
            safe["hash"] = _value_hash
            for name in ("bytes",):  # an object array's bytes are its objects' addresses
                safe[name] = _guarded(safe[name], _object_bytes_refused(safe[name]))
            safe["None"] = None
            safe[FORMAT_HOOK] = format_attr
            np_mod, math_mod = self.safe_np, self.safe_math
        else:  # test-only: the OS layer alone must hold
            import builtins

            safe = dict(vars(builtins))
            safe["print"] = print_
            np_mod, math_mod = self.np, math
        self.builtins = safe
        ns = {"__builtins__": safe, "__name__": "__main__", "np": np_mod, "math": math_mod,
              "print": print_, "load_image": load_image}
        for name in self.tools:
            ns[name] = self._make_tool(name)
        return ns

    def _print(self, *args, sep=" ", end="\n", file=None, flush=False):
        sep = " " if sep is None else str(sep)
        end = "\n" if end is None else str(end)
        self.out.write(sep.join(str(a) for a in args) + end)

    def _make_tool(self, name: str):
        runner = self

        def tool(*args, **kwargs):
            if args:
                raise TypeError(f"{name}() takes keyword arguments only, e.g. {name}(arm='left')")
            return runner._call(name, kwargs)

        tool.__name__ = tool.__qualname__ = name
        tool.__doc__ = f"Robot tool {name}: keyword arguments as in its schema; returns a dict."
        return tool

    def _check_stopped(self):
        if self.stopped is not None:
            raise ProgramStopped(self.stopped.kind, str(self.stopped))

    def _call(self, name: str, kwargs: dict):
        self._check_stopped()
        if self.calls >= self.max_calls:
            self.stopped = ProgramStopped(
                "call_cap", f"internal tool-call limit reached: at most {self.max_calls} tool calls per "
                f"run_code; the program was stopped before call {self.calls + 1} ({name})")
            raise ProgramStopped(self.stopped.kind, str(self.stopped))
        self.calls += 1
        args = {str(k): to_jsonable(v, self.np) for k, v in kwargs.items()}
        self.wire.send({"op": "call", "tool": name, "kwargs": args})
        msg, _ = self.wire.recv()
        if msg.get("stop"):
            self.stopped = ProgramStopped(msg["stop"], msg.get("message") or msg["stop"])
            raise ProgramStopped(self.stopped.kind, str(self.stopped))
        return msg["payload"]

    def _load_image(self, obs_id):
        self._check_stopped()
        if not isinstance(obs_id, str):
            raise TypeError("load_image(obs_id) takes an obs_id string, e.g. load_image('obs_3')")
        self.wire.send({"op": "load_image", "obs_id": obs_id})
        msg, blob = self.wire.recv()
        if msg.get("stop"):
            self.stopped = ProgramStopped(msg["stop"], msg.get("message") or msg["stop"])
            raise ProgramStopped(self.stopped.kind, str(self.stopped))
        if msg.get("error"):
            raise ValueError(msg["error"])
        arr = self.np.frombuffer(blob, dtype=self.np.uint8).reshape(msg["shape"])
        return arr  # frombuffer over a private bytearray: writable, not shared with anything

    # -- running
    def _format_error(self, exc: BaseException, filename_prefix: str = "<run_code:") -> str:
        if isinstance(exc, SyntaxError):
            return "".join(traceback.format_exception_only(type(exc), exc)).rstrip()
        frames = [f for f in traceback.extract_tb(exc.__traceback__) if f.filename.startswith(filename_prefix)]
        lines = ["Traceback (most recent call last):"] if frames else []
        for f in frames:
            lines.append(f'  File "{f.filename}", line {f.lineno}, in {f.name}')
            if f.line:
                lines.append(f"    {f.line.strip()}")
        lines.append("".join(traceback.format_exception_only(type(exc), exc)).rstrip())
        return "\n".join(lines)

    def run(self, code: str) -> dict:
        self.run_id += 1
        self.calls = 0
        self.stopped = None
        self.out.reset()
        self.ns.pop("result", None)
        filename = f"<run_code:{self.run_id}>"
        reply = {"op": "done", "ok": True, "error": None, "value": None, "result_assigned": False, "stopped": None}
        tree: ast.Module | None
        try:  # parsing, the policy, the hook and compiling: a program too deep for any is its error
            tree = ast.parse(code, filename, "exec")
            if self.python_layer:
                problems = check_tree(tree)
                if problems:
                    reply.update(ok=False, error="code rejected by the sandbox policy:\n" + "\n".join(problems[:20]))
                    return reply
                tree = hook_format(tree)
            compiled = compile(tree, filename, "exec")
        except SyntaxError as exc:
            reply.update(ok=False, error=self._format_error(exc))
            return reply
        except (RecursionError, MemoryError, ValueError, OverflowError) as exc:
            why = str(exc) or "out of memory"
            reply.update(ok=False, error=f"{type(exc).__name__}: the program could not be compiled ({why}); it is "
                         "nested too deeply or too large. Split long expressions into several statements.")
            return reply
        finally:
            tree = None  # a deep tree is freed here, not at the next program
        if self.python_layer:
            # The policy admits no way to rebind or delete __builtins__; were one found, exec would
            # fill a missing one with the real builtins, so every run starts from the safe ones.
            self.ns["__builtins__"] = self.builtins
        lines = code.splitlines(True)
        linecache.cache[filename] = (len(code), None, lines, filename)
        old = linecache.cache.pop(f"<run_code:{self.run_id - 64}>", None)  # keep the last 64 programs
        del old
        saved = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = self.out  # numpy warnings and library prints are captured too
        try:
            exec(compiled, self.ns)
        except ProgramStopped as exc:
            reply.update(ok=False, error=str(exc), stopped=exc.kind)
        except BaseException as exc:  # noqa: BLE001 - every program failure is reported, not raised
            reply.update(ok=False, error=self._format_error(exc))
        finally:
            sys.stdout, sys.stderr = saved
        if self.stopped is not None and reply["stopped"] is None:  # the program swallowed the stop
            reply.update(ok=False, error=str(self.stopped), stopped=self.stopped.kind)
        reply["stdout_chars"] = self.out.sent
        if "result" in self.ns:
            reply["result_assigned"] = True
            try:
                reply["value"] = to_jsonable(self.ns["result"], self.np)
            except BaseException as exc:  # noqa: BLE001
                reply["value"] = {f"{_TRUNC}_value__": f"result could not be converted: {type(exc).__name__}"}
        return reply


def main(argv: list[str]) -> int:
    # The RPC pipes move to private descriptors; fd 0 reads /dev/null and fd 1 joins stderr, so a
    # stray write to stdout (a C library, an escaped program) cannot corrupt the protocol.
    rfd, wfd = os.dup(0), os.dup(1)
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    os.close(devnull)
    os.dup2(2, 1)
    wire = _Wire(rfd, wfd)
    init, _ = wire.recv()
    layers: dict[str, str] = {}

    def attempt(name, fn, *args):
        try:
            layers[name] = fn(*args)
        except Exception as exc:  # noqa: BLE001 - reported to the host, which decides
            layers[name] = f"failed: {exc}"

    attempt("rlimits", apply_rlimits, init.get("limits", {}))
    if init.get("parent_death_signal"):
        attempt("parent_death_signal", set_parent_death_signal, init.get("host_pid", 0))
    for path in reversed(init.get("sys_path", [])):
        sys.path.insert(0, path)
    runner = Runner(wire, init)
    import numpy

    if runner.python_layer:
        attempt("repr_addresses", hide_addresses, (numpy.ndarray, numpy.generic, numpy.dtype))
    if init.get("landlock_read"):
        attempt("landlock", install_landlock, init["landlock_read"])
    if init.get("seccomp"):
        attempt("seccomp", install_seccomp)
    wire.send({"op": "ready", "pid": os.getpid(), "layers": layers, "python": sys.version.split()[0],
               "numpy": numpy.__version__, "python_layer": runner.python_layer})
    while True:
        try:
            msg, _ = wire.recv()
        except EOFError:
            return 0
        if msg.get("op") == "run":
            try:
                reply = runner.run(msg["code"])
            except BaseException as exc:  # noqa: BLE001 - the child outlives whatever a program caused
                reply = {"op": "done", "ok": False, "error": f"{type(exc).__name__}: {exc}"[:2000], "value": None,
                         "result_assigned": False, "stopped": None}
            try:
                wire.send(reply)
            except ValueError:  # not strict JSON: never expected, since to_jsonable made the value
                reply.update(value=None, result_assigned=False, ok=False,
                             error="the program's result could not be sent as JSON")
                wire.send(reply)
        elif msg.get("op") == "exit":
            return 0


if __name__ == "__main__":
    code = main(sys.argv[1:])
    sys.stderr.flush()
    os._exit(code)  # no interpreter teardown: the repr slots point into callbacks it would free
