"""A machine-wide pool of CPU slots: how many attempts may do CPU work (build a world, step physics,
render, encode video) at the same time, however many are in flight.

A model-bound sweep keeps many attempts in flight (cab_core.conf.in_flight), most of them waiting on
their model. When several act at once, each holds one of ``N`` slots (N: the cores) while it works and
none while it waits on its model, so the cores are not oversubscribed and a waiting attempt costs no
CPU. The slots are files ``slot-<i>`` in a per-user folder of the temporary directory, locked with
``flock``: a slot is free again when its holder releases it or dies (the kernel drops the lock), so a
crashed attempt cannot leak one. Waiting blocks in the kernel, no polling: a process first tries each
slot without blocking; if all are taken it queues on the folder's ``queue`` lock (the processes
waiting take turns in line behind it), and the one at the head blocks on every slot at once (a thread
per slot) and takes the first that frees.

The pool is on in processes whose environment names its size (:data:`ENV`, set by the sweep
supervisor for its attempt processes); elsewhere :func:`held` does nothing. Holding is re-entrant in a
process: a call served inside an attempt's set-up holds the one slot it already has.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

ENV = "CAB_CPU_SLOTS"  # the pool's size in this process; unset or 0: no pool
FOLDER_ENV = "CAB_CPU_SLOTS_DIR"  # the folder of its slot files (default: default_folder())


def default_folder() -> Path:
    """The pool's folder on this machine for this user."""
    return Path(tempfile.gettempdir()) / f"cab-cpu-slots-{os.getuid()}"


class CpuSlots:
    """``n`` slots in ``folder`` (see the module's docstring)."""

    def __init__(self, n: int, folder: Path | str | None = None):
        if n < 1:
            raise ValueError(f"a CPU slot pool needs at least one slot, got {n}")
        self.n = n
        self.folder = Path(folder) if folder is not None else default_folder()
        self.folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        self._lock = threading.RLock()  # one holder per process: threads of one attempt share its slot
        self._fd: int | None = None
        self._depth = 0
        self.waited_s = 0.0  # time spent blocked, all acquisitions of this process together
        self.acquisitions = 0

    def _open(self, name: str) -> int:
        return os.open(self.folder / name, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)

    def _try_any(self) -> int | None:
        start = os.getpid() % self.n  # processes start their scan at different slots
        for k in range(self.n):
            fd = self._open(f"slot-{(start + k) % self.n}")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return fd
            except BlockingIOError:
                os.close(fd)
        return None

    def acquire(self) -> float:
        """Hold a slot (blocking until one is free); returns the seconds waited."""
        self._lock.acquire()
        if self._depth:
            self._depth += 1
            return 0.0
        t0 = time.monotonic()
        try:
            fd = self._try_any()
            if fd is None:
                fd = self._wait()
        except BaseException:  # interrupted while waiting: nothing held
            self._lock.release()
            raise
        waited = time.monotonic() - t0
        self._fd, self._depth = fd, 1
        self.waited_s += waited
        self.acquisitions += 1
        return waited

    def _wait(self) -> int:
        """Block until any slot is free and take it: one thread per slot blocks on its lock in the
        kernel; the first to get one wins, each later one gives its slot back at once."""
        queue = self._open("queue")
        try:
            fcntl.flock(queue, fcntl.LOCK_EX)  # in line behind the one waiter that blocks on the slots
            fd = self._try_any()
            if fd is not None:
                return fd
            won: list[int] = []
            done = threading.Event()
            claim = threading.Lock()

            def wait_for(i: int) -> None:
                slot = self._open(f"slot-{i}")
                fcntl.flock(slot, fcntl.LOCK_EX)  # blocks until its holder releases or dies
                with claim:
                    if not done.is_set():
                        won.append(slot)
                        done.set()
                        return
                os.close(slot)  # another slot came first (or the wait was given up): not held

            for i in range(self.n):
                threading.Thread(target=wait_for, args=(i,), name=f"cpu-slot-{i}", daemon=True).start()
            try:
                done.wait()
            except BaseException:
                with claim:
                    done.set()
                    for slot in won:
                        os.close(slot)
                raise
            return won[0]
        finally:
            os.close(queue)  # closing drops the queue lock

    def release(self) -> None:
        """Give back what :meth:`acquire` took (the slot itself once the outermost hold ends)."""
        if not self._depth:
            raise RuntimeError("release of a CPU slot that is not held")
        self._depth -= 1
        if not self._depth and self._fd is not None:
            os.close(self._fd)  # closing drops the lock
            self._fd = None
        self._lock.release()

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        self.acquire()
        try:
            yield
        finally:
            self.release()


_POOL: CpuSlots | None = None
_POOL_KEY: tuple | None = None


def pool() -> CpuSlots | None:
    """This process's pool as its environment names it (:data:`ENV`, :data:`FOLDER_ENV`), or None."""
    global _POOL, _POOL_KEY
    try:
        n = int(os.environ.get(ENV) or 0)
    except ValueError:
        n = 0
    key = (n, os.environ.get(FOLDER_ENV))
    if key != _POOL_KEY:
        _POOL = CpuSlots(n, key[1]) if n > 0 else None
        _POOL_KEY = key
    return _POOL


@contextlib.contextmanager
def held() -> Iterator[None]:
    """Hold one of this machine's CPU slots while the block runs (nothing when no pool is on)."""
    p = pool()
    if p is None:
        yield
        return
    with p.held():
        yield
