"""A sweep as plain data, for the exports that summarise many attempts: the leaderboard rows
(:mod:`cab_core.analysis.leaderboard`) and the sweep exporter plugins (hook ``cab_sweep_exporters``,
which get this data and import nothing of the analysis).

:func:`sweep_data` gives, per configuration, cab-report's figures (from :func:`cab_core.analysis.report.build`:
the same attempts, the same Wilson intervals), success per task with its interval, the
configuration's comparison contract (its attempts' contracts combined as the sweep manifest combines
them) and its attempts' records; and the published figures of a paper (hook
``cab_published_figures``) with, per paper configuration, the counts its tables give and the Wilson
interval of its success, and the cab configuration of the sweep that reproduces it."""
from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cab_core.analysis import contract
from cab_core.analysis.attempts import scan
from cab_core.analysis.measures import wilson
from cab_core.errors import ConfigError, RecordError
from cab_core.plugins import registry

PAPER = "paper"  # the published figures compared with by default (cab-report --against paper)


def published(name: str = PAPER) -> Mapping[str, Any] | None:
    """The published figures ``name`` from the installed task suites (hook ``cab_published_figures``),
    or None when no suite ships them."""
    loader = registry("published_figures").get(name)
    if loader is None:
        return None
    figures = loader()
    if not isinstance(figures, Mapping):
        raise ConfigError(f"published figures {name!r}: expected a mapping, got {type(figures).__name__}")
    return figures


def paper_configuration(figures: Mapping[str, Any] | None, model: Any, harness: Any) -> Mapping[str, Any] | None:
    """The paper's configuration that cab's ``model`` under ``harness`` reproduces (its ``cab`` mapping
    names them), or None."""
    for conf in (figures or {}).get("configurations") or []:
        cab = conf.get("cab") if isinstance(conf, Mapping) else None
        if isinstance(cab, Mapping) and cab.get("model") == model and cab.get("harness") == harness:
            return conf
    return None


def labelled_configurations(configs: list[str], figures: Mapping[str, Any] | None,
                            labels: Mapping[str, str]) -> dict[str, Mapping[str, Any]]:
    """``labels`` (``{configuration: paper name}``, ``--as CONFIG=NAME`` as ``cab-report --against``
    takes it: a configuration as the report names it or by a prefix of exactly one, a paper
    configuration by its name or by ``model (harness)``) resolved: ``{configuration: paper row}``.
    A label that names nothing, or names it ambiguously, is one line."""
    confs = [c for c in (figures or {}).get("configurations") or [] if isinstance(c, Mapping)]
    by_name = {str(c.get("name")): c for c in confs}
    by_cab = {f"{c['cab'].get('model')} ({c['cab'].get('harness')})": c for c in confs if isinstance(c.get("cab"), Mapping)}
    out = {}
    for config, name in labels.items():
        hits = [c for c in configs if c == config] or [c for c in configs if c.startswith(config)]
        if len(hits) != 1:
            raise RecordError(f"--as {config}={name}: {'ambiguous' if hits else 'no'} configuration of the sweep "
                              f"{config!r}; choices: {'; '.join(hits or configs)}")
        paper = by_name.get(name) or by_cab.get(name)
        if paper is None:
            raise ConfigError(f"--as {config}={name}: no such configuration in the published figures"
                              + (f"; choices: {'; '.join(by_name)}" if by_name else " (none are installed)"))
        out[hits[0]] = paper
    return out


def paper_counts(figures: Mapping[str, Any], conf: Mapping[str, Any]) -> dict[str, Any]:
    """A paper configuration's success and coverage counts, the table they come from and the Wilson
    95 % interval of its success: ``{"successes", "attempts", "tasks_covered", "tasks", "table",
    "wilson95"}`` (what the paper does not give: None)."""
    source = figures.get("source") or {}
    cons = conf.get("consistency") or {}
    table = (figures.get("tables") or {}).get("consistency") or {}
    k, n = cons.get("success"), source.get("attempts_per_configuration")
    interval = list(wilson(k, n)) if isinstance(k, int) and isinstance(n, int) and 0 <= k <= n and n > 0 else None
    return {"successes": k, "attempts": n, "tasks_covered": cons.get("coverage"), "tasks": source.get("tasks"),
            "table": " ".join(str(table[x]) for x in ("label", "caption") if table.get(x)) or None,
            "wilson95": interval}


def configuration_contract(results: list[Mapping[str, Any]]) -> dict | None:
    """The contract of a configuration's attempts (``result.json`` as read): their contracts combined
    (:func:`cab_core.analysis.contract.combined`), None when one of them has none (older records)."""
    cs = [contract.of_result(r) for r in results]
    return contract.combined([c for c in cs if c is not None]) if cs and None not in cs else None


def sweep_data(root: Path, r: Mapping[str, Any], figures: Mapping[str, Any] | None = None,
               labels: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The sweep below ``root`` as plain data, from ``r``, cab-report's figures of it
    (:func:`cab_core.analysis.report.build`, which the caller computes: this module sits below the
    report in the import graph, as :mod:`cab_core.analysis.against` does):

    - ``root``, ``sweep`` (the manifest's fingerprint and size, or None), ``id`` (the fingerprint, or
      the folder's name);
    - ``configs``: per configuration, in cab-report's order, cab-report's summary
      (:class:`~cab_core.analysis.measures.ConfigSummary` as a dict: ``config``, ``attempts``,
      ``successes``, ``success_rate``, ``wilson95``, ``tasks``, ``coverage``, ``consistency``, ...),
      and ``per_task`` (task -> ``{"successes", "attempts", "wilson95"}``), ``contract`` (combined,
      or None), ``paper`` (the paper configuration it reproduces, the one ``labels`` gives it
      (:func:`labelled_configurations`) or else the one of its model and harness, with
      :func:`paper_counts` as ``counts``; or None) and ``records``: its attempts' ``{"rel", "dir", "result", "events"}``,
      sorted by folder;
    - ``figures``: the published figures given, each configuration with ``counts`` added, or None."""
    root = Path(root)
    counted = {m["rel"] for m in r["attempt_rows"]}
    by_config: dict[str, list] = defaultdict(list)
    for a in scan(root).attempts:
        if a.rel in counted:
            by_config[a.config].append(a)
    labelled = labelled_configurations([c["config"] for c in r["configs"]], figures, labels or {})
    configs = []
    for c in r["configs"]:
        attempts = sorted(by_config[c["config"]], key=lambda a: a.rel)
        first = attempts[0].result if attempts else {}
        conf = labelled.get(c["config"]) or paper_configuration(figures, first.get("model"), first.get("harness"))
        per_task = {t: {"successes": cell[c["config"]][0], "attempts": cell[c["config"]][1],
                        "wilson95": list(wilson(*cell[c["config"]]))}
                    for t, cell in r["matrix"].items() if c["config"] in cell}
        configs.append({**c, "wilson95": list(c["wilson95"]), "per_task": per_task,
                        "contract": configuration_contract([a.result for a in attempts]),
                        "paper": {**conf, "counts": paper_counts(figures, conf)} if figures and conf else None,
                        "records": [{"rel": a.rel, "dir": a.dir, "result": a.result, "events": a.events}
                                    for a in attempts]})
    figs = None
    if figures is not None:
        figs = {**figures, "configurations": [{**conf, "counts": paper_counts(figures, conf)}
                                              for conf in figures.get("configurations") or []
                                              if isinstance(conf, Mapping)]}
    sweep = r.get("sweep")
    return {"root": root, "sweep": sweep, "id": str((sweep or {}).get("fingerprint") or root.resolve().name),
            "configs": configs, "figures": figs}
