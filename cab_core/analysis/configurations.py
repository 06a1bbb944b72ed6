"""What names a configuration: the model, its harness and simulator, and the model settings that
differ among the attempts (or planned jobs) being reported together.

The paper names a configuration ``model (harness, sim)``. Two attempts of the same model
configuration with another ``model.model_id``, ``base_url``, reasoning effort or any other setting
that changes what answers are two configurations: :func:`configuration_labels` adds the settings
that differ within a set to the label, ``my_model[model_id=modelA] (my_harness, my_sim)``, and
leaves a configuration whose settings are the same everywhere as the paper names it. A setting that
does not change which model answers or how (:data:`NOT_IDENTITY`: retries, timeouts, limits,
pricing, the key's variable, the published usage) never splits a configuration, and neither does
a setting that follows the task (one value per task: a scripted agent's script for each task), as a
configuration is what is compared across tasks; ``model.name`` names a configuration outright (two
names are two configurations whatever their settings). Where the name must be a folder name and the
model's own name is not one (a provider/model string such as ``openai/gpt-4o``), ``model.label`` is what the
label shows in its place.

One rule for every reader: cab-report and the analyses (through
:func:`cab_core.analysis.attempts.scan`), the parquet export, cab-studio, and a sweep's plan, which
labels its jobs from their resolved configurations (the ``attempt_start`` event's ``config``, the
shape of :meth:`cab_core.attempt.spec.AttemptSpec.as_record`: ``model``, ``harness``, ``sim``,
``model_cfg``).
"""
from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

#: model settings that are not the model's identity: how it is called, paid for or limited
NOT_IDENTITY = frozenset({"name", "retry", "timeout_s", "connect_timeout_s", "limits", "pricing", "api_key_env",
                          "key_env", "paper_usage", "session", "label"})

_UNSET = object()


def base_label(model: Any, harness: Any, sim: Any) -> str:
    """The paper's name of a configuration: ``model (harness, sim)``."""
    return f"{model} ({harness}, {sim})"


def identity(model_cfg: Mapping | None) -> dict[str, Any]:
    """The settings of a model configuration that are its identity, flattened to dotted keys
    (``thinking.type``, ``extra_body.enable_thinking``); ``{}`` for none (records without it)."""
    out: dict[str, Any] = {}

    def walk(prefix: str, node: Mapping) -> None:
        for k, v in node.items():
            key = f"{prefix}{k}"
            if isinstance(v, Mapping) and v:
                walk(key + ".", v)
            else:
                out[key] = v

    walk("", {k: v for k, v in (model_cfg or {}).items() if k not in NOT_IDENTITY})
    return out


def _shown(value: Any) -> str:
    if value is _UNSET:
        return "unset"
    if isinstance(value, str):
        return value
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def _labelled(config: Mapping) -> Mapping:
    """``config`` named by its ``model_cfg``'s ``label`` where it has one (a string), else as it is."""
    cfg = config.get("model_cfg")
    label = cfg.get("label") if isinstance(cfg, Mapping) else None
    return {**config, "model": label} if isinstance(label, str) and label else config


def configuration_labels(configs: Sequence[Mapping]) -> list[str]:
    """The label of each of ``configs`` (each a mapping with ``model``, ``harness``, ``sim`` and,
    where known, ``model_cfg`` and ``task``), in order: its :func:`base_label`, and where the
    configurations of that base label differ in identity settings (:func:`identity`) for one task
    (all configurations without ``task`` count as one task), those settings in brackets after the
    model, ``my_model[model_id=modelA,reasoning_effort=high] (my_harness, my_sim)``. The model is
    named by ``model_cfg["label"]`` where there is one, else by ``model``. A configuration
    without ``model_cfg`` (a record written before cab kept it) keeps its base label."""
    configs = [_labelled(c) for c in configs]
    bases = [base_label(c.get("model"), c.get("harness"), c.get("sim")) for c in configs]
    ids: list[dict[str, Any] | None] = [identity(c["model_cfg"]) if isinstance(c.get("model_cfg"), Mapping) else None
                                        for c in configs]
    varying: dict[str, list[str]] = {}
    for base in set(bases):
        known = [(c.get("task"), s) for c, b, s in zip(configs, bases, ids) if b == base and s is not None]
        keys = sorted({k for _, s in known for k in s})
        values: dict[str, dict] = {k: {} for k in keys}  # key -> task -> the values it takes for that task
        for task, settings in known:
            for k in keys:
                values[k].setdefault(task, set()).add(_shown(settings.get(k, _UNSET)))
        varying[base] = [k for k in keys if any(len(v) > 1 for v in values[k].values())]
    labels = []
    for c, base, i in zip(configs, bases, ids):
        keys = varying[base]
        if i is None or not keys:
            labels.append(base)
            continue
        shown = ",".join(f"{k}={_shown(i.get(k, _UNSET))}" for k in keys)
        labels.append(base_label(f"{c.get('model')}[{shown}]", c.get("harness"), c.get("sim")))
    return labels
