"""What can be checked of a model configuration before any attempt (``ReferenceHarness.check_model``):
the provider's credentials, and with the network its endpoint (it answers, it lists the model) and,
for an OpenAI-compatible server, the probe of its capabilities (``probe.py``).

The endpoint is asked for its model list, the cheapest request every provider's API has and one
that spends no tokens: Anthropic ``GET /v1/models`` (``x-api-key``, ``anthropic-version``), OpenAI
and OpenAI-compatible servers ``GET {base_url}/models`` (a Bearer key where one is configured),
Google ``GET {base}/v1beta/models?key=``. The base is ``model.base_url``, else the provider's
environment variable, else the SDK's public default. An endpoint that answers without a model list
(404) is reachable and its list unknown; one that refuses the key (401, 403) or does not answer at
all is a problem; a list without the model is one too (a dated id ``<model_id>-YYYYMMDD`` counts as
the alias it extends)."""
from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

from cab_core.contracts.harness import ModelCheck
from cab_core.errors import CabError

from .probe import probe_endpoint, wants_probe

TIMEOUT_S = 5.0
ANTHROPIC_VERSION = "2023-06-01"
DEFAULT_BASES = {"anthropic": "https://api.anthropic.com", "openai": "https://api.openai.com/v1",
                 "google": "https://generativelanguage.googleapis.com"}
BASE_URL_ENVS = {"anthropic": "ANTHROPIC_BASE_URL", "openai": "OPENAI_BASE_URL",
                 "openai_compatible": "OPENAI_BASE_URL"}


def endpoint(provider: str, model_cfg: dict) -> str | None:
    """The base URL the provider's SDK talks to for this configuration (None: not known)."""
    env = BASE_URL_ENVS.get(provider)
    base = model_cfg.get("base_url") or (os.environ.get(env) if env else None) or DEFAULT_BASES.get(provider)
    return str(base).rstrip("/") if base else None


def _request(provider: str, base: str, key: str | None) -> tuple[str, dict, dict]:
    """The model-list request of a provider: (URL, headers, query parameters)."""
    if provider == "anthropic":
        return f"{base}/v1/models", {"x-api-key": key or "", "anthropic-version": ANTHROPIC_VERSION}, {"limit": 1000}
    if provider == "google":
        return f"{base}/v1beta/models", {}, {"key": key or "", "pageSize": 1000}
    return f"{base}/models", ({"Authorization": f"Bearer {key}"} if key else {}), {}


def _listed(provider: str, body: Any) -> list[str] | None:
    """The model ids of a model-list answer (None: not a list this code knows)."""
    if not isinstance(body, dict):
        return None
    rows = body.get("models") if provider == "google" else body.get("data")
    if not isinstance(rows, list):
        return None
    key = "name" if provider == "google" else "id"
    ids = [str(r.get(key)) for r in rows if isinstance(r, dict) and r.get(key)]
    return [i.removeprefix("models/") for i in ids]


def _knows(ids: list[str], model_id: str) -> bool:
    return any(i == model_id or (i.startswith(model_id + "-") and i[len(model_id) + 1:].isdigit()) for i in ids)


def _key(provider_obj: Any) -> tuple[str | None, str | None]:
    """(the key's environment variable, its value) as the provider reads them."""
    envs = getattr(provider_obj, "key_envs", None) or (getattr(provider_obj, "key_env", None),)
    envs = [e for e in envs if e]
    for e in envs:
        if os.environ.get(e):
            return e, os.environ[e]
    return (" or ".join(envs) if envs else None), None


def check_model(model_cfg: dict, network: bool, create_provider: Callable[[dict], Any],
                timeout_s: float = TIMEOUT_S) -> ModelCheck:
    """The :class:`ModelCheck` of a reference-harness configuration; ``create_provider`` builds its
    provider (the harness's own factory)."""
    name = model_cfg.get("provider")
    check = ModelCheck(provider=str(name) if name else None)
    try:
        provider = create_provider(model_cfg)
    except CabError as e:  # no provider, an unknown one, its SDK missing: the message names the fix
        check.problems.append(str(e))
        return check
    check.endpoint = endpoint(str(name), model_cfg)
    key_env, key = _key(provider)
    check.key_env = key_env
    try:
        provider.check_credentials()
        check.key_present = key_env is not None and key is not None or None
    except CabError as e:
        check.key_present = False
        check.problems.append(str(e))
    if not network or check.endpoint is None or check.key_present is False:
        return check
    model_id = str(model_cfg.get("model_id") or model_cfg.get("model") or "")
    _ask_endpoint(check, str(name), key, model_id, timeout_s)
    if check.reachable and name == "openai_compatible" and wants_probe(model_cfg):
        check.capabilities = caps = probe_endpoint(dict(model_cfg))
        # what the harness cannot work around: tools refused, or images refused by a server that answers
        # (one failing every request is an outage, which the attempts report as one)
        if caps.get("tools") == "rejected" or (caps.get("images") is False and caps.get("tools") == "accepted"):
            check.problems += [str(p) for p in caps.get("problems") or [] if "the harness" not in str(p)]
    return check


def _ask_endpoint(check: ModelCheck, provider: str, key: str | None, model_id: str, timeout_s: float) -> None:
    # here, not at the top: httpx2 comes with the providers' SDKs (this package's extras), which a
    # configuration of another provider need not have installed
    import httpx2

    assert check.endpoint is not None
    url, headers, params = _request(provider, check.endpoint, key)
    log = logging.getLogger("httpx2")  # it logs each request at INFO, which Hydra prints among the plan's lines
    level = log.level
    log.setLevel(logging.WARNING)
    try:
        r = httpx2.get(url, headers=headers, params=params, timeout=timeout_s, follow_redirects=True)
    except httpx2.HTTPError as e:
        check.reachable = False
        why = " ".join(str(e).split()) or type(e).__name__
        check.problems.append(f"the endpoint {check.endpoint} does not answer ({type(e).__name__}: {why}): "
                              "start the server, or fix model.base_url (or set sweep.preflight_network=false "
                              "to skip this check)")
        return
    finally:
        log.setLevel(level)
    check.reachable = True
    if r.status_code in (401, 403):
        check.problems.append(f"the endpoint {check.endpoint} refuses the key in {check.key_env} "
                              f"(HTTP {r.status_code} on GET {url.removeprefix(check.endpoint)}): set a valid key")
        return
    if r.status_code != 200:
        return  # it answers, without a model list this code can read
    try:
        ids = _listed(provider, r.json())
    except ValueError:
        ids = None
    if ids is None or not model_id:
        return
    check.model_listed = _knows(ids, model_id)
    if not check.model_listed:
        shown = ", ".join(sorted(ids)[:8]) + (", ..." if len(ids) > 8 else "")
        check.problems.append(f"the endpoint {check.endpoint} does not list the model {model_id!r} "
                              f"(it lists: {shown or 'none'}): fix model.model_id")
