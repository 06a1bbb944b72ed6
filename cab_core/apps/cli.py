"""Command-line entry points: ``cab`` (Hydra app), ``cab-plugins``, ``cab-schemas``.
Only this module talks to a person."""
from __future__ import annotations

import json
import os
import sys

from hydra.experimental.callback import Callback

from cab_core.apps.cmdline import check_command_line, expand_seed_set
from cab_core.conf.schema import one_line
from cab_core.config import GROUPS, normalise_overrides, scene_seed  # noqa: F401  (the resolver cab.seed, registered there)
from cab_core.errors import CabError, ConfigError, MissingDependency, PluginError, RendererUnavailable, closest
from cab_core.kits.harness import stdio
from cab_core.plugins import describe, distribution_versions, registry
from cab_core.sweep import layout as sweep_layout  # noqa: F401  (registers cab.swept: the swept keys' folder of an attempt)


def wants_stdio_protocol(argv: list[str]) -> bool:
    """Whether these overrides serve the attempt to its agent on stdin/stdout: a harness selected
    with ``harness=<name>`` whose factory declares ``speaks_on_stdio = True`` (a protocol server),
    unless ``harness.transport=`` names another transport. Then stdout is reserved for protocol
    frames before Hydra starts, so that nothing it or anything after it prints can corrupt the
    stream (cab_core.kits.harness.stdio)."""
    sel = [a.split("=", 1)[1] for a in argv if a.lstrip("+").startswith("harness=")]
    if not sel:
        return False
    transport = [a.split("=", 1)[1] for a in argv if a.lstrip("+").startswith("harness.transport=")]
    if transport and transport[-1] != "stdio":
        return False
    return bool(getattr(registry("harnesses").get(sel[-1]), "speaks_on_stdio", False))


class HydraRaises:
    """``with HydraRaises():`` sets HYDRA_FULL_ERROR=1, which makes Hydra raise what fails before the
    task function starts (e.g. an output folder that cannot be created) instead of printing its
    traceback, so that the caller can say it in one line; the user's value comes back on leaving,
    or earlier with :meth:`release` (a single run's task function releases it first thing: the
    attempt's child processes see the user's value). ``task_started``: the task function ran."""

    VARIABLE = "HYDRA_FULL_ERROR"

    def __init__(self) -> None:
        self.before: str | None = None
        self.held = False
        self.task_started = False

    def __enter__(self) -> HydraRaises:
        self.before = os.environ.get(self.VARIABLE)
        os.environ[self.VARIABLE] = "1"
        self.held = True
        return self

    def release(self) -> None:
        if self.held:
            if self.before is None:
                os.environ.pop(self.VARIABLE, None)
            else:
                os.environ[self.VARIABLE] = self.before
            self.held = False

    def __exit__(self, *exc: object) -> None:
        self.release()


def _refuse(message: str, status: int = 2) -> None:
    print(f"cab: {message}", file=sys.stderr)
    sys.exit(status)


def _before_task(e: Exception) -> str | None:
    """One line for an exception Hydra raised before the task function started, or None for one
    that is a bug (its traceback is shown)."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(e, OSError) and e.filename:
        return f"cannot create the output folder {e.filename} (hydra.run.dir): {e.strerror or e}"
    cause = e.__cause__ or e.__context__  # Hydra's job log could not be opened (logging.config's ValueError)
    if isinstance(e, ValueError) and isinstance(cause, OSError) and cause.filename and _RUN_FOLDER is not None:
        return f"cannot write in the output folder {_RUN_FOLDER[0]} (hydra.run.dir): {cause.strerror or cause}"
    if isinstance(e, (HydraException, OmegaConfBaseException)):
        return one_line(e)
    return None


def version_lines() -> list[str]:
    """``cab --version``: cab's version, then each installed plugin's distribution and version
    (importlib.metadata, through the plugin registry's entry points)."""
    from importlib import metadata

    dists = metadata.packages_distributions().get(__package__.split(".")[0], [])
    core = next(iter(dists), None)
    try:
        lines = [f"cab {metadata.version(core)}" if core else "cab (version unknown: not installed)"]
    except metadata.PackageNotFoundError:
        lines = ["cab (version unknown: not installed)"]
    plugins = {d: v for d, v in distribution_versions().items() if d not in dists}
    lines.append("plugins:" if plugins else "plugins: none installed")
    lines += [f"  {d} {v}" for d, v in plugins.items()]
    return lines


def main() -> None:
    """``cab``: a command-line mistake is one line on stderr and exit status 2, before Hydra
    composes, creates a folder or starts anything (cab_core.apps.cmdline)."""
    if "--version" in sys.argv[1:]:  # cab's, not Hydra's
        print("\n".join(version_lines()))
        return
    global _TYPED
    _TYPED = list(sys.argv[1:])
    sys.argv = [sys.argv[0]] + normalise_overrides(sys.argv[1:])
    try:
        sys.argv = [sys.argv[0]] + expand_seed_set(sys.argv[1:])
        args = check_command_line(sys.argv[1:])
    except (ConfigError, PluginError) as e:  # PluginError: a plugin's config dirs or tasks (cab_core.config)
        _refuse(str(e))
    single = args is not None and not (args.multirun or args.cfg)
    if wants_stdio_protocol(sys.argv[1:]) and "-m" not in sys.argv and "--multirun" not in sys.argv:
        stdio.claim()
    if os.environ.get("HYDRA_FULL_ERROR") == "1":  # the user asked for Hydra's tracebacks
        _hydra_entry()
        return
    if not single:
        if args is None or not args.multirun or args.cfg:
            _hydra_entry()
            return
        _sweep_entry()
        return
    with HydraRaises() as raises:
        try:
            _hydra_entry(raises)
        except Exception as e:
            line = None if raises.task_started else _before_task(e)
            if line is None:
                raise
            _refuse(line)


_SWEEP_DIR: str | None = None  # the sweep's folder, once its manifest is open
_TYPED: list[str] | None = None  # the arguments as typed: the command that runs an attempt or a sweep again
EXIT_UNSCORED = 4  # the attempt (or some of a sweep's) ended on an infrastructure failure: recorded, not scored
EXIT_INTERRUPTED = 130  # Ctrl-C or SIGTERM: the attempt is recorded as interrupted, not scored


def typed_command() -> str:
    """The command line as typed (``cab`` and its arguments, shell-quoted)."""
    import shlex

    return shlex.join(["cab", *(_TYPED if _TYPED is not None else sys.argv[1:])])


def _full_disk(e: BaseException) -> OSError | None:
    """The OSError of a full disk (or an exhausted quota) behind ``e``, if that is what it is."""
    import errno

    for x in (e, e.__cause__, e.__context__):
        if isinstance(x, OSError) and x.errno in (errno.ENOSPC, errno.EDQUOT):
            return x
    return None


def _sweep_entry() -> None:
    """``cab -m``: a disk that fills up while the sweep runs ends it with one line and the resume
    line (a job's records are the supervisor's to write; Hydra's own writes for the next job, its
    .hydra/ files and log, fail here: HYDRA_FULL_ERROR makes Hydra raise them instead of printing
    a traceback); any other error keeps its traceback. Ctrl-C (or SIGTERM) is one line too: the
    attempts in flight are not scored (their records are set aside when the sweep resumes)."""
    with HydraRaises():  # held for the whole sweep: its jobs too
        try:
            with _sigterm_interrupts():  # SIGTERM (a scheduler, `kill`) stops a sweep as Ctrl-C does
                _hydra_entry()
        except KeyboardInterrupt:
            where = f" {_SWEEP_DIR}" if _SWEEP_DIR else ""
            _refuse(f"sweep{where} interrupted; finished attempts are kept, those in flight are not scored: "
                    f"run the same command to resume: {typed_command()}", status=EXIT_INTERRUPTED)
        except Exception as e:
            full = _full_disk(e)
            if full is None:
                raise
            where = full.filename or (f"in the sweep folder {_SWEEP_DIR}" if _SWEEP_DIR else "in the sweep folder")
            _refuse(f"cannot write {where}: {full.strerror}; finished attempts are kept: "
                    "free space, then run the same command again to resume", status=1)


def _hydra_entry(raises: HydraRaises | None = None) -> None:
    """Hydra's app; ``raises``: a single run's :class:`HydraRaises`, released when the task function starts."""
    import hydra

    @hydra.main(version_base=None, config_path="../conf", config_name="config")
    def _app(cfg) -> None:
        if raises is not None:
            raises.task_started = True
            raises.release()  # from here on, Hydra reports failures itself; children see the user's value

        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        # here, not at the top: the engine adds 0.8 s (python -X importtime) to cab_core.apps.cli's 0.35 s,
        # which cab --help, cab-plugins and cab-schemas would pay
        from cab_core.attempt.runner import attempt_spec, run_attempt

        hc = HydraConfig.get()
        out = hc.runtime.output_dir
        if hc.mode == RunMode.MULTIRUN:
            _sweep_job(cfg, hc)
            return
        try:
            spec = attempt_spec(cfg, out)
            _set_aside_unscored(out, f"{hc.job.name}.log")
            with _sigterm_interrupts():
                result = run_attempt(spec)
        except KeyboardInterrupt:  # the record (if the attempt had begun) says interrupted: never scored
            print("cab: interrupted; run the same command to run it again", file=sys.stderr)
            sys.exit(EXIT_INTERRUPTED)
        except RendererUnavailable as e:
            print(f"cab: renderer unavailable: {e}", file=sys.stderr)
            sys.exit(3)
        except (ConfigError, MissingDependency) as e:
            _remove_refused_run_folder(out)
            print(f"cab: {e}", file=sys.stderr)
            sys.exit(2)
        except CabError as e:
            print(f"cab: {type(e).__name__}: {e}", file=sys.stderr)
            sys.exit(1)
        v = result["verdict"]
        b = result["budget"]
        print(f"cab: {result['task']} seed={result['seed']} attempt={result['attempt']} model={result['model']} "
              f"sim={result['sim']}: success={v.get('success')} termination={result['termination']['reason']} "
              f"calls={b['tool_calls_used']}/{b['tool_calls_limit']} sim_s={b['sim_seconds_used']:.2f}/{b['sim_seconds_limit']:g} "
              f"wall_s={result['timing']['wall_seconds']:.1f} -> {out}/result.json")
        line = unscored_line(result)
        if line is not None:
            print(f"cab: {line}", file=sys.stderr)
            sys.exit(EXIT_UNSCORED)

    _app()


def unscored_line(result: dict) -> str | None:
    """One line for an attempt that ended on an infrastructure failure (what failed, where, a hint:
    the harness puts them in the termination's detail), None for a scored attempt."""
    from cab_core.attempt.engine.faults import INFRASTRUCTURE_TERMINATIONS

    t = result.get("termination") or {}
    reason = t.get("reason")
    if reason not in INFRASTRUCTURE_TERMINATIONS:
        return None
    detail = " ".join(str(t.get("detail") or "").split()).rstrip(".") or "(no detail)"
    what = detail if reason == "provider_failure" else f"{INFRASTRUCTURE_TERMINATIONS[reason]}: {detail}"
    end = "" if what.endswith(("?", "!")) else "."
    return f"{what}{end} The attempt is recorded as an infrastructure failure, not scored."


class _sigterm_interrupts:
    """``with _sigterm_interrupts():`` SIGTERM stops a single run as Ctrl-C does (the attempt is
    recorded as interrupted); the handler before it comes back on leaving."""

    def __enter__(self):
        import signal

        def stop(signum, frame):
            raise KeyboardInterrupt("SIGTERM")

        try:
            self.before = signal.signal(signal.SIGTERM, stop)
        except ValueError:  # not the main thread: left as it is
            self.before = None
        return self

    def __exit__(self, *exc: object) -> None:
        import signal

        if self.before is not None:
            signal.signal(signal.SIGTERM, self.before)


def _set_aside_unscored(out: str, job_log: str) -> None:
    """A single run into a folder that holds an attempt that was never scored (interrupted, an
    infrastructure failure, or records without ``result.json``: a process killed mid-attempt) moves
    those records into ``set_aside/NN-<why>/`` (kept, never deleted), as a resumed sweep does, so
    that the same command runs the attempt again. A scored attempt's folder is left as it is (the
    recorder refuses it)."""
    from pathlib import Path

    from cab_core.sweep.attempt_state import (
        INTERRUPTED,
        check_attempt,
        is_infrastructure_failure,
        record_entries,
        set_aside,
    )

    d = Path(out)
    if not (d / "result.json").exists() and not (d / "events.jsonl").exists():
        return
    check = check_attempt(d, None, job_log)
    if check.state != "partial":
        return
    res = check.result
    if res is not None and not is_infrastructure_failure(res):
        return  # a record that is scored but damaged: the user's to look at
    why = INTERRUPTED if res is None or (res.get("termination") or {}).get("reason") == INTERRUPTED else "infrastructure"
    if record_entries(d, job_log):
        set_aside(d, why, job_log)


def _sweep_job(cfg, hc) -> None:
    """One job of ``cab -m``: errors propagate to Hydra, which records the job as failed (a worker
    must not exit); the progress line goes to stderr."""
    from pathlib import Path

    # here, not at the top: the sweep manifest adds 0.55 s (python -X importtime) to cab_core.apps.cli,
    # which cab --help, cab-plugins and cab-schemas would pay (after the engine, a single attempt's
    # import, it adds only 20-50 ms)
    from cab_core.sweep.manifest import run_job

    _, line = run_job(cfg, Path(hc.runtime.output_dir), Path(hc.sweep.dir), f"{hc.job.name}.log")
    sys.stderr.write(line + "\n")  # one write: lines of parallel workers do not interleave
    sys.stderr.flush()


# The run's output folder as on_run_start found it: (the folder, the deepest of it and its parents
# that existed then). A refused attempt removes what Hydra created for it (_remove_refused_run_folder).
_RUN_FOLDER: tuple[str, str] | None = None


class RunFolderCallback(Callback):
    """Hydra callback (``hydra.callbacks.run_folder``): before Hydra creates a single run's output
    folder, note which of its parents exist (a refused command leaves no folder behind) and refuse,
    in one line, an existing folder in which no file can be created."""

    def on_run_start(self, config, **kwargs) -> None:
        global _RUN_FOLDER
        import tempfile

        from omegaconf import OmegaConf

        try:
            folder = os.path.abspath(str(OmegaConf.select(config, "hydra.run.dir")))
        except Exception:  # noqa: BLE001  (Hydra says what is wrong with it when it creates the folder)
            return
        existing = folder
        while not os.path.lexists(existing) and os.path.dirname(existing) != existing:
            existing = os.path.dirname(existing)
        _RUN_FOLDER = (folder, existing)
        if existing == folder and os.path.isdir(folder):
            try:
                with tempfile.TemporaryFile(dir=folder):
                    pass
            except OSError as e:
                _refuse(f"cannot write in the output folder {folder} (hydra.run.dir): {e.strerror or e}")
        _plan_or_preflight(config, multirun=False)


def _plan_or_preflight(config, multirun: bool) -> None:
    """Before Hydra creates a run's or a sweep's folder: with ``sweep.dry_run=true`` print the plan
    (cab_core.apps.plan) and exit, 0 or 2 when a configuration cannot run; otherwise the pre-flight
    of every model configuration with jobs to run: one line per problem (a sweep's names the
    configuration), exit 2, nothing run and no folder written."""
    from omegaconf import OmegaConf

    from cab_core.apps import plan  # here, not at the top: it imports the sweep manifest (0.55 s: see _sweep_job)

    try:
        sweep = _sweep_jobs(config) if multirun else None
        if OmegaConf.select(config, "sweep.dry_run", default=False):
            lines, problems = plan.run_plan(config, sweep)
            print("\n".join(lines), flush=True)
            if problems:
                print(f"cab: {len(problems)} problem(s): a configuration cannot run (listed above)", file=sys.stderr)
            sys.exit(2 if problems else 0)
        network = bool(OmegaConf.select(config, "sweep.preflight_network", default=True))
        confs = plan.configurations(config, sweep)
        problems = plan.preflight(confs, network)
    except CabError as e:  # a configuration that cannot be composed or checked: Hydra would only warn
        _refuse(str(e))
    except Exception as e:  # noqa: BLE001  (Hydra turns a callback's exception into a warning and runs on)
        _refuse(f"the plan or pre-flight failed: {type(e).__name__}: {one_line(e)}", status=1)
    if not problems:
        return
    if not multirun:  # one configuration: its problems without its name
        problems = [p for c in confs for p in c.check.problems]
    print("\n".join(f"cab: {'refused: ' if multirun else ''}{p}" for p in problems), file=sys.stderr)
    sys.exit(2)


def _sweep_jobs(config):
    """The plan's view of a sweep (cab_core.apps.plan.SweepJobs): its jobs, those still to run (a
    sweep folder being resumed), and why that folder would refuse this sweep."""
    from pathlib import Path

    from cab_core.apps.plan import SweepJobs
    from cab_core.sweep.manifest import (  # 0.55 s: see _sweep_job
        MANIFEST,
        SweepManifest,
        completed_results,
        expand_jobs,
    )

    sweep_dir = Path(str(config.hydra.sweep.dir))
    try:
        old = json.loads((sweep_dir / MANIFEST).read_text())
    except (OSError, ValueError):  # a new sweep: every job is to run, and no folder needs naming (the
        jobs = expand_jobs(config)  # manifest's folders cost one composition per swept task and model)
        return SweepJobs(jobs, [1] * len(jobs))
    manifest = SweepManifest.from_hydra(config)
    done = {str(p.parent.relative_to(sweep_dir)) for p in completed_results(sweep_dir)}
    changed = isinstance(old, dict) and old.get("fingerprint") != manifest.fingerprint
    return SweepJobs(manifest.jobs, [0 if f in done else 1 for f in manifest.folders],
                     f"{sweep_dir} holds a sweep with another configuration: running this command there would be "
                     "refused; resume it with its own overrides, or choose a new hydra.sweep.dir" if changed else None)


def _remove_refused_run_folder(out: str) -> None:
    """After a refusal before the attempt's record began: remove what Hydra created for the run
    (its job log, its ``.hydra`` folder, the folder and the parents it made), nothing else."""
    import shutil
    from pathlib import Path

    from hydra.core.hydra_config import HydraConfig

    root = Path(os.path.abspath(out))
    stop = Path(_RUN_FOLDER[1]) if _RUN_FOLDER is not None else root
    if stop not in root.parents:
        return  # the folder existed before this run: it is the user's
    hc = HydraConfig.get()
    ours = {f"{hc.job.name}.log", hc.output_subdir or ""} - {""}
    if any(p.name not in ours for p in root.iterdir()):
        return  # the attempt's record began
    for name in ours:  # the job log's handler keeps writing to the removed file, which nothing sees

        p = root / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        elif p.exists():
            p.unlink(missing_ok=True)
    while root != stop and stop in root.parents:
        try:
            root.rmdir()  # only an empty folder
        except OSError:
            return
        root = root.parent


class SweepManifestCallback(Callback):
    """Hydra callback (``hydra.callbacks.sweep_manifest``): before a sweep launches, write its
    manifest or check it against the one already in the sweep directory. Hydra turns callback
    exceptions into warnings, so a refusal ends the process here, with the reason on stderr."""

    def on_multirun_start(self, config, **kwargs) -> None:
        from omegaconf import OmegaConf

        from cab_core.sweep.manifest import SweepConfigChanged, SweepManifest  # 0.55 s: see _sweep_job

        global _SWEEP_DIR
        if OmegaConf.select(config, "hydra.job.chdir") and "cab_launcher" in str(config.hydra.launcher._target_):
            _refuse("hydra.job.chdir=true cannot work with cab's launcher (its jobs are threads of one process, "
                    "which has one working directory): leave it false, or use hydra/launcher=joblib")
        _plan_or_preflight(config, multirun=True)
        try:
            from cab_core.apps.sweep_contracts import sweep_contracts

            manifest = SweepManifest.from_hydra(config)
            manifest.contracts = sweep_contracts(config, manifest.jobs)  # each configuration's, in sweep.json
            manifest.open(config.hydra.sweep.dir, config.hydra.launcher._target_)
            _SWEEP_DIR = str(config.hydra.sweep.dir)
        except (SweepConfigChanged, sweep_layout.SweepJobsCollide) as e:
            print(f"cab: refused: {e}", file=sys.stderr)
            sys.exit(2)
        except OSError as e:  # the sweep folder cannot be created or written: a mistake in the command
            print(f"cab: cannot write in the sweep folder {config.hydra.sweep.dir} (hydra.sweep.dir): "
                  f"{e.strerror or e}", file=sys.stderr)
            sys.exit(2)
        except Exception as e:  # a sweep without its manifest cannot be resumed safely: stop
            print(f"cab: cannot write the sweep manifest: {type(e).__name__}: {e}", file=sys.stderr)
            sys.exit(1)

    def on_multirun_end(self, config, **kwargs) -> None:
        from cab_core.sweep.manifest import sweep_summary  # 0.55 s: see _sweep_job

        line, complete = sweep_summary(config.hydra.sweep.dir, typed_command())
        print(line, file=sys.stderr, flush=True)
        if not complete:  # attempts given up on (or not written): not a finished sweep
            sys.exit(EXIT_UNSCORED)


def plugins_main() -> None:
    """List installed plugins, their versions and what each provides (disabled ones as disabled:
    CAB_DISABLE_PLUGINS=name1,name2)."""
    import argparse

    ap = argparse.ArgumentParser(prog="cab-plugins", description=plugins_main.__doc__)
    ap.add_argument("--json", action="store_true", help="print JSON")
    a = ap.parse_args()
    try:
        rows = describe()
    except CabError as e:  # a broken plugin: one line naming it and the fix
        print(f"cab-plugins: {e}", file=sys.stderr)
        sys.exit(1)
    # what plain `cab` composes: each row marks the simulator, embodiment and planner it selects
    try:
        from cab_core.config import default_selection

        chosen = default_selection()
    except Exception:  # noqa: BLE001 - a composition that fails is cab's to report; the listing stays
        chosen = {}
    kinds = {"simulators": "sim", "embodiments": "embodiment", "planners": "planner"}
    for r in rows:
        r["defaults"] = {k: chosen[g] for k, g in kinds.items() if chosen.get(g) in (r["provides"].get(k) or ())}
    if a.json:
        print(json.dumps(rows, indent=2))
        return
    import textwrap

    conflicts: dict[str, str] = {}
    for r in rows:
        print(f"{r['plugin']:<22} {r['distribution']} {r['version']}" + ("  (disabled)" if r["disabled"] else ""))
        for kind, names in r["provides"].items():
            if names:
                marked = [f"{n} (default)" if r["defaults"].get(kind) == n else n for n in names]
                print(f"    {kind:<18} {', '.join(marked)}")
        for suite, tasks in (r.get("tasks") or {}).items():  # each suite's tasks; a name two suites define: disabled
            conflicts.update(r.get("task_conflicts") or {})
            listed = [f"{t} (disabled)" if t in conflicts else t for t in tasks]
            label = f"    {'tasks of ' + suite:<18} "
            print(textwrap.fill(", ".join(listed) or "(none)", width=100, initial_indent=label,
                                subsequent_indent=" " * len(label), break_on_hyphens=False))
    for line in conflicts.values():
        print(f"disabled: {line}")


def schemas_main() -> None:
    """Print the JSON Schemas of every tool (from the pydantic argument models)."""
    import argparse

    # here, not at the top: the tools' argument models add 0.46 s (python -X importtime) to
    # cab_core.apps.cli, which cab, cab --help and cab-plugins would pay
    from cab_core.tools import schemas

    ap = argparse.ArgumentParser(prog="cab-schemas", description=schemas_main.__doc__)
    ap.add_argument("tool", nargs="?", help="only this tool")
    a = ap.parse_args()
    rows = schemas()
    if a.tool:
        rows = [r for r in rows if r["name"] == a.tool]
        if not rows:
            names = [r["name"] for r in schemas()]
            near = closest(a.tool, names, cutoff=0.5)  # tool names share words: a looser match still helps
            hint = f"did you mean {' or '.join(near)}? " if near else ""
            print(f"cab-schemas: unknown tool {a.tool!r}; {hint}valid: {', '.join(names)}", file=sys.stderr)
            sys.exit(2)
    print(json.dumps(rows, indent=2))
