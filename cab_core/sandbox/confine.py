"""How the run_code child is launched: the bubblewrap command line, or the plain (rlimits) fallback.

Everything here is computed in the host from its own interpreter: which Python to run, where its
standard library lives, and where numpy is. The child sees only those (read-only) plus a private
``/tmp``; the project, the virtual environment's site-packages, the records and the host's ``/proc``
are never mounted.
"""
from __future__ import annotations

import functools
import glob
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field

#: where numpy and the guest program appear inside the bubblewrap sandbox
SANDBOX_SITE = "/opt/cab/site"
SANDBOX_RUNNER = "/opt/cab/guest.py"
_SYSTEM_DIRS = ("/usr",)
_SYSTEM_MAYBE_LINKS = ("/lib", "/lib64", "/lib32", "/libx32", "/bin", "/sbin")
_CHILD_ENV = {
    "LANG": "C.UTF-8",
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "PATH": "/usr/bin:/bin",
}
_TMPFS_BYTES = 64 * 1024 * 1024


@dataclass
class LaunchPlan:
    """One way to start the child. ``init`` is merged into the guest's init frame."""

    confinement: str  # "bubblewrap" | "rlimits" | "none"
    argv: list[str]
    cwd: str
    env: dict[str, str]
    init: dict = field(default_factory=dict)
    description: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class PythonLayout:
    executable: str  # the real interpreter binary (not a venv shim)
    prefixes: tuple[str, ...]  # the installation holding the standard library
    numpy_dir: str
    numpy_libs: str | None  # manylinux wheels keep OpenBLAS/gfortran in a sibling ``numpy.libs``

    @staticmethod
    def current() -> PythonLayout:
        import numpy

        exe = os.path.realpath(getattr(sys, "_base_executable", None) or sys.executable)
        prefixes = tuple(dict.fromkeys(os.path.realpath(p) for p in (sys.base_prefix, sys.base_exec_prefix)))
        numpy_dir = os.path.realpath(os.path.dirname(numpy.__file__))
        libs = os.path.join(os.path.dirname(os.path.dirname(numpy.__file__)), "numpy.libs")
        numpy_libs = os.path.realpath(libs) if os.path.isdir(libs) else None
        return PythonLayout(exe, prefixes, numpy_dir, numpy_libs)


def find_bwrap(spec: str) -> str | None:
    """Resolve the configured bubblewrap (a name looked up on PATH, or a path); None if absent."""
    if not spec:
        return None
    if os.sep in spec:
        return spec if os.path.isfile(spec) and os.access(spec, os.X_OK) else None
    return shutil.which(spec)


@functools.lru_cache(maxsize=8)
def bwrap_options(bwrap: str) -> frozenset[str]:
    """The long options this bubblewrap understands (``--size`` needs 0.7, for instance)."""
    try:
        out = subprocess.run([bwrap, "--help"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return frozenset()
    text = out.stdout + out.stderr
    return frozenset(tok for tok in text.split() if tok.startswith("--"))


def _within(path: str, root: str) -> bool:
    return path == root or path.startswith(root.rstrip("/") + "/")


def _site_dirs() -> list[str]:
    """Directories that hold third-party packages for any Python on this machine."""
    import site

    found = []
    candidates = list(sys.path)
    try:
        candidates += site.getsitepackages()
    except AttributeError:  # pragma: no cover - some embedded interpreters
        pass
    user_site = getattr(site, "USER_SITE", None)
    if user_site:
        candidates.append(user_site)
    for prefix in {sys.base_prefix, sys.prefix, "/usr", "/usr/local"}:
        candidates += glob.glob(os.path.join(prefix, "lib", "python3*", "site-packages"))
        candidates += glob.glob(os.path.join(prefix, "lib", "python3*", "dist-packages"))
        candidates += glob.glob(os.path.join(prefix, "lib", "python3", "dist-packages"))
        candidates += glob.glob(os.path.join(prefix, "local", "lib", "python3*", "dist-packages"))
    for path in candidates:
        if path and ("site-packages" in path or "dist-packages" in path) and os.path.isdir(path):
            found.append(os.path.realpath(path))
    return list(dict.fromkeys(found))


def project_root() -> str:
    """The directory holding the ``cab_core`` package (a checkout or a site-packages dir)."""
    return os.path.realpath(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def bwrap_plan(bwrap: str, workdir: str, layout: PythonLayout, hide_paths: tuple[str, ...] = ()) -> LaunchPlan:
    opts = bwrap_options(bwrap)
    argv = [bwrap, "--unshare-all", "--die-with-parent", "--new-session", "--cap-drop", "ALL"]
    if "--hostname" in opts:
        argv += ["--hostname", "cab-sandbox"]
    mounted: list[str] = []  # host paths visible inside at the same path
    for d in _SYSTEM_DIRS:
        argv += ["--ro-bind", d, d]
        mounted.append(os.path.realpath(d))
    for d in _SYSTEM_MAYBE_LINKS:
        if os.path.islink(d):
            argv += ["--symlink", os.readlink(d), d]
        elif os.path.isdir(d) and d not in ("/bin", "/sbin"):  # no shell tools unless /usr brings them
            argv += ["--ro-bind", d, d]
            mounted.append(d)
    bound_prefixes = []
    for prefix in layout.prefixes:
        if not any(_within(prefix, m) for m in mounted):
            argv += ["--ro-bind", prefix, prefix]
            mounted.append(prefix)
        bound_prefixes.append(prefix)
    exe = layout.executable
    if not any(_within(exe, m) for m in mounted):
        argv += ["--ro-bind", exe, exe]
        mounted.append(exe)
    argv += ["--ro-bind-try", "/etc/ld.so.cache", "/etc/ld.so.cache"]
    argv += ["--ro-bind", layout.numpy_dir, f"{SANDBOX_SITE}/numpy"]
    if layout.numpy_libs:
        argv += ["--ro-bind", layout.numpy_libs, f"{SANDBOX_SITE}/numpy.libs"]
    argv += ["--ro-bind", os.path.join(workdir, "guest.py"), SANDBOX_RUNNER]
    argv += ["--proc", "/proc", "--dev", "/dev"]
    if "--size" in opts:
        argv += ["--size", str(_TMPFS_BYTES)]
    argv += ["--tmpfs", "/tmp"]
    # Mask anything importable or private that happens to live under a mounted system directory:
    # every site-packages/dist-packages, the project, the venv, and whatever the caller names.
    hidden = []
    for path in _site_dirs() + [project_root(), os.path.realpath(sys.prefix)] + [os.path.realpath(p) for p in hide_paths]:
        if os.path.isdir(path) and any(_within(path, m) for m in mounted) and path not in hidden:
            if any(_within(p, path) for p in bound_prefixes) or _within(exe, path):
                continue  # never mask the interpreter itself
            hidden.append(path)
    for path in hidden:
        argv += ["--tmpfs", path]
    argv += ["--remount-ro", "/", "--chdir", "/tmp", "--clearenv"]
    for k, v in _CHILD_ENV.items():
        argv += ["--setenv", k, v]
    argv += ["--", exe, "-I", "-S", "-B", SANDBOX_RUNNER]
    landlock = ["/usr", "/lib", "/lib64", "/lib32", "/libx32", "/etc/ld.so.cache", "/opt/cab", *bound_prefixes, exe]
    return LaunchPlan(
        confinement="bubblewrap",
        argv=argv,
        cwd=workdir,
        env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LANG": "C.UTF-8"},
        init={"sys_path": [SANDBOX_SITE], "seccomp": True, "landlock_read": landlock,
              "parent_death_signal": False},
        description=[f"bubblewrap {bwrap}: new user/pid/net/ipc/uts/cgroup namespaces, no network, "
                     "read-only /usr and Python, numpy only, tmpfs /tmp, no project/venv/records, "
                     f"masked: {', '.join(hidden) or 'none'}"],
    )


def plain_plan(workdir: str, layout: PythonLayout, os_layers: bool) -> LaunchPlan:
    """The child without bubblewrap: rlimits always; seccomp and Landlock when ``os_layers``."""
    site = os.path.join(workdir, "site")
    os.makedirs(site, exist_ok=True)
    for name, target in (("numpy", layout.numpy_dir), ("numpy.libs", layout.numpy_libs)):
        link = os.path.join(site, name)
        if target and not os.path.lexists(link):
            os.symlink(target, link)
    read = ["/usr", "/lib", "/lib64", "/lib32", "/libx32", "/etc/ld.so.cache", *layout.prefixes,
            layout.executable, layout.numpy_dir, workdir]
    if layout.numpy_libs:
        read.append(layout.numpy_libs)
    return LaunchPlan(
        confinement="rlimits" if os_layers else "none",
        argv=[layout.executable, "-I", "-S", "-B", os.path.join(workdir, "guest.py")],
        cwd=workdir,
        env=dict(_CHILD_ENV),
        init={"sys_path": [site], "seccomp": os_layers, "landlock_read": read if os_layers else None,
              "parent_death_signal": True, "host_pid": os.getpid()},
        description=["no bubblewrap: plain child process with rlimits"
                     + (", seccomp and Landlock where the kernel has them" if os_layers else " only (mode=off)")],
    )
