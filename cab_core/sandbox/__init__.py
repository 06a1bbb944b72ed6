"""run_code: agent programs in a separate, confined process that reaches the host only through tool RPC.

Layers, outermost first (each must hold on its own):

1. bubblewrap (``mode="required"`` refuses to run without it): new user, pid, network, ipc, uts and
   cgroup namespaces; no network; a read-only view of ``/usr`` and the Python installation; numpy
   alone mounted as the only third-party package; a private ``/tmp``; no project source, virtual
   environment, records or host ``/proc``; killed with its parent.
2. seccomp (in the child, every thread): no exec, fork or ptrace, no IP/netlink sockets, signals and
   rlimit changes only to itself, no namespaces, mounts, io_uring, bpf or keyrings.
3. Landlock where the kernel has it: reads only below the mounted system paths, no TCP, no signals
   or abstract sockets beyond the sandbox. Without bubblewrap it is what keeps files private.
4. rlimits: address space (``memory_mb``), CPU seconds, file size, open files, no core dumps; the
   host enforces the wall-clock timeout by killing the process group.
5. The Python layer (FACTS A.7): an AST policy (imports of numpy and math only, no classes or
   async; no eval/exec/open/getattr/...; no name starting with ``__``, however it is bound; no
   attribute starting with ``_`` or leading to frames, code or files, by any route: ``.attr``,
   ``match`` class-pattern keywords, or ``{0.attr}``/``{0[_key]}`` fields of ``str.format`` and
   ``format_map``, checked before the run for literal templates and, through a hook the AST rewrite
   puts on every ``.format``/``.format_map``, at run time for built ones), restricted builtins, a
   numpy namespace without file I/O or ctypes. No view of raw memory: numpy's constructors that take
   a buffer, an offset or strides are checked versions (``np.ndarray``, ``recarray``, ``chararray``,
   ``frombuffer``), ``resize(refcheck=False)`` and the bytes of object arrays are refused, ``.data``,
   ``.strides`` and ``.dtype`` are never assigned, ``byte_bounds``/``from_dlpack``/``lib``/``core``
   are out of reach and ``np.empty`` is zeroed. No ``repr`` shows an address (every type's repr
   slot drops " at 0x...") and ``hash`` takes values only. The program's ``math`` and ``numpy`` are
   read-only copies, so it cannot patch what the guest itself uses to send results (strict JSON); a
   program too deeply nested to compile is its own error. ``guest.py``'s docstring lists the routes.

Use ``python -m cab_core.sandbox`` to see which layers this machine provides and how fast they are.
"""
from cab_core.errors import SandboxUnavailable
from cab_core.sandbox.host import FILESYSTEM_POLICY, DispatchResult, Sandbox, SandboxConfig

__all__ = ["Sandbox", "SandboxConfig", "DispatchResult", "SandboxUnavailable", "FILESYSTEM_POLICY"]
