"""cab's launcher for sweeps on one machine: each job runs in a thread of the ``cab -m`` process.

A cab job does little itself: it supervises one attempt, which runs in a worker process of its own
(``cab_core.sweep.supervisor``; forked from the sweep's fork server, ``cab_core.sweep.zygote``), and
waits. Hydra's joblib launcher gives every job slot a process of its own besides (loky's, about
52 MiB each); here a slot is a thread, so N attempts in flight cost N attempt workers and nothing
more. A thread waiting on its worker holds no lock and uses no CPU.

What Hydra keeps process-wide is made safe for threads here:

* ``HydraConfig`` (the ``${hydra:...}`` resolver, ``HydraConfig.get()`` in a task function) is one
  object per process; while jobs run, its ``cfg`` is kept per thread (:class:`_PerThreadHydraConfig`),
  the launch's own config serving every thread that has set none.
* Composition (``load_sweep_config``) is not thread-safe: every job's config is composed in the
  launching thread, one at a time, just before the job starts.
* Logging is configured once (``hydra.job_logging`` without its file handlers); each job's file
  handlers (``<output_dir>/<job name>.log`` by default) receive only the records of that job's thread.

Start-ups are staggered: the first ``n_jobs`` jobs start ``stagger_s`` apart, so that a large sweep
does not ask for its N workers in the same instant (later jobs start as slots free up).

Ctrl-C (or a job's ``KeyboardInterrupt``) stops the launch: no new job starts, and the interruption
goes on to the caller while the threads of the jobs in flight are left to die with the process
(daemon threads; their attempt workers watch this process and end with it).
"""
import logging
import logging.config
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


@dataclass
class LocalLauncherConf:
    _target_: str = "hydra_plugins.cab_launcher.local_launcher.LocalLauncher"
    n_jobs: int = -1  # jobs (attempts) in flight at once; -1: one per core (negative: cores + 1 + n_jobs)
    stagger_s: float = 0.25  # seconds between the start-ups of the first n_jobs jobs


ConfigStore.instance().store(group="hydra/launcher", name="cab_local", node=LocalLauncherConf,
                             provider="cab")


class _PerThreadHydraConfig(HydraConfig):
    """``HydraConfig`` whose ``cfg`` is each thread's own; a thread that set none sees ``default``."""

    def __init__(self, default: Any) -> None:  # not through Singleton: installed by hand (_per_thread)
        object.__setattr__(self, "_local", threading.local())
        object.__setattr__(self, "_default", default)

    @property  # type: ignore[override]
    def cfg(self) -> Any:
        return getattr(self._local, "cfg", self._default)

    @cfg.setter
    def cfg(self, value: Any) -> None:
        self._local.cfg = value


class _per_thread:
    """While the block runs, ``HydraConfig.instance()`` keeps ``cfg`` per thread."""

    def __enter__(self) -> None:
        self._saved = Singleton._instances.get(HydraConfig)
        shared = object.__new__(_PerThreadHydraConfig)
        shared.__init__(self._saved.cfg if self._saved is not None else None)
        Singleton._instances[HydraConfig] = shared

    def __exit__(self, *exc: object) -> None:
        if self._saved is not None:
            Singleton._instances[HydraConfig] = self._saved
        else:
            Singleton._instances.pop(HydraConfig, None)


class _JobFiles(logging.Handler):
    """The root logger's handler that passes each record to the file handlers of the job whose
    thread logged it (none: the record is not a job's, and the console handlers have it)."""

    def __init__(self) -> None:
        super().__init__()
        self._local = threading.local()

    def open(self, handlers: list[logging.Handler]) -> None:
        self._local.handlers = handlers

    def close_job(self) -> None:
        for h in getattr(self._local, "handlers", []):
            h.close()
        self._local.handlers = []

    def emit(self, record: logging.LogRecord) -> None:
        for h in getattr(self._local, "handlers", []):
            if record.levelno >= h.level:
                h.handle(record)


def _is_file_handler(spec: Any) -> bool:
    return isinstance(spec, dict) and str(spec.get("class", "")).endswith("FileHandler")


def _configure_logging(config: DictConfig, router: _JobFiles) -> None:
    """``hydra.job_logging`` without its file handlers (whose
    file names name a job's folder): those are opened per job (:func:`_job_file_handlers`)."""
    job_logging = config.hydra.job_logging
    if job_logging is None:
        return
    plain = OmegaConf.to_container(job_logging, resolve=False)
    assert isinstance(plain, dict)
    files = {name for name, spec in (plain.get("handlers") or {}).items() if _is_file_handler(spec)}
    plain["handlers"] = {k: v for k, v in (plain.get("handlers") or {}).items() if k not in files}
    for section in [plain.get("root") or {}, *(plain.get("loggers") or {}).values()]:
        if isinstance(section, dict) and "handlers" in section:
            section["handlers"] = [h for h in section["handlers"] if h not in files]
    resolved = OmegaConf.to_container(OmegaConf.create(plain), resolve=True)
    logging.config.dictConfig(resolved)  # type: ignore[arg-type]
    if files:
        logging.getLogger().addHandler(router)


def _job_file_handlers(hydra_cfg: Any) -> list[logging.Handler]:
    """The file handlers of ``hydra.job_logging`` for the job whose Hydra config this is."""
    job_logging = hydra_cfg.job_logging
    if job_logging is None:
        return []
    formatters = job_logging.get("formatters") or {}
    out: list[logging.Handler] = []
    for spec in (job_logging.get("handlers") or {}).values():
        plain = OmegaConf.to_container(spec, resolve=True)
        if not _is_file_handler(plain):
            continue
        assert isinstance(plain, dict)
        handler = logging.FileHandler(str(plain["filename"]), mode=str(plain.get("mode", "a")),
                                      encoding=plain.get("encoding"))
        fmt = formatters.get(plain.get("formatter")) if plain.get("formatter") else None
        if fmt is not None:
            handler.setFormatter(logging.Formatter(fmt.get("format"), fmt.get("datefmt")))
        if plain.get("level") is not None:
            handler.setLevel(plain["level"])
        out.append(handler)
    return out


def _abandon() -> None:
    """Stop the attempts of the jobs in flight (cab_core.sweep.supervisor.abandon): the process
    is about to end while their threads supervise them."""
    from cab_core.sweep.supervisor import abandon

    abandon()


class LocalLauncher(Launcher):
    def __init__(self, n_jobs: int = -1, stagger_s: float = 0.25) -> None:
        self.n_jobs = int(n_jobs)
        self.stagger_s = max(0.0, float(stagger_s))
        self.config: DictConfig | None = None
        self.task_function: TaskFunction | None = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.task_function = task_function
        self.hydra_context = hydra_context

    def slots(self, jobs: int) -> int:
        """Jobs in flight at once for a batch of ``jobs`` jobs."""
        n = self.n_jobs if self.n_jobs > 0 else (os.cpu_count() or 1) + 1 + self.n_jobs  # as joblib counts
        return max(1, min(n, jobs))

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        assert self.config is not None and self.task_function is not None and self.hydra_context is not None
        if self.config.hydra.job.get("chdir"):  # one working directory per process, not per thread
            raise ValueError("hydra.job.chdir=true cannot work with cab's launcher (its jobs are threads of one "
                             "process); leave it false, or use hydra/launcher=joblib")
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = str(self.config.hydra.sweep.dir)
        os.makedirs(sweep_dir, exist_ok=True)
        slots = self.slots(len(job_overrides))
        log.info(f"Launching jobs ({slots} at a time, in threads), sweep output dir : {sweep_dir}")
        for idx, overrides in enumerate(job_overrides):
            log.info(f"\t#{initial_job_idx + idx} : {' '.join(filter_overrides(overrides))}")
        router = _JobFiles()
        _configure_logging(self.config, router)
        returns: list[JobReturn | None] = [None] * len(job_overrides)
        stop: list[BaseException] = []  # a job's KeyboardInterrupt (or the like), ending the launch
        free = threading.Semaphore(slots)
        task = self._job_task(router)

        def run(i: int, sweep_config: DictConfig) -> None:
            try:
                assert self.hydra_context is not None
                returns[i] = run_job(hydra_context=self.hydra_context, config=sweep_config, task_function=task,
                                     job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir",
                                     configure_logging=False)
            except BaseException as e:  # noqa: BLE001  (run_job keeps a task's Exception in the JobReturn)
                stop.append(e)
            finally:
                free.release()

        threads: list[threading.Thread] = []
        try:
            with _per_thread():
                for i, overrides in enumerate(job_overrides):
                    while not stop and not free.acquire(timeout=0.5):
                        pass
                    if stop:
                        break
                    sweep_config = self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
                    with open_dict(sweep_config):
                        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{initial_job_idx + i}"
                        sweep_config.hydra.job.num = initial_job_idx + i
                    t = threading.Thread(target=run, args=(i, sweep_config), daemon=True,
                                         name=f"cab-job-{initial_job_idx + i}")
                    t.start()
                    threads.append(t)
                    if i < slots - 1 and self.stagger_s:
                        time.sleep(self.stagger_s)
                for t in threads:
                    while t.is_alive() and not stop:
                        t.join(0.5)
        except BaseException:  # Ctrl-C: the jobs in flight are abandoned, their attempts not scored
            _abandon()
            raise
        if stop:  # a job ended in something other than an Exception (run_job keeps those)
            _abandon()
            raise stop[0]
        out = [r for r in returns if r is not None]
        assert len(out) == len(job_overrides)
        return out

    def _job_task(self, router: _JobFiles) -> Callable[[Any], Any]:
        """The task function as a thread runs it: its job's log files open around it."""
        task_function = self.task_function
        assert task_function is not None

        def task(cfg: Any) -> Any:
            router.open(_job_file_handlers(HydraConfig.get()))
            try:
                return task_function(cfg)
            finally:
                router.close_job()

        return task
