"""What an OpenAI-compatible endpoint (vLLM, llama.cpp's ``llama-server``, Ollama, a hosted API)
really accepts, found by a few small requests before the first attempt against it.

Local servers break agent harnesses in known ways that would otherwise be scored as the model's
failure: vLLM rejects images in ``tool`` messages (vllm-project/vllm #43203) and caps images per
request (``--limit-mm-per-prompt``: 400 "At most N image(s) may be provided in one request"); its
tool parsers lose a closing brace or leave the calls in ``content`` (#17790, #22885, #17161);
``llama-server`` answers 500 to ``tools`` unless started with ``--jinja`` (#19905); Ollama's ``/v1``
ignores ``num_ctx`` and silently keeps only the end of a long conversation (ollama #18107).

:func:`probe_endpoint` returns the endpoint's *capability profile*, a JSON-able dict::

    {"base_url": ..., "model_id": ..., "reachable": true, "model_listed": true,
     "engine": {"name": "vllm", "version": "0.11.2", "source": "GET /version",
                "server_header": "uvicorn", "owned_by": "vllm"},
     "tools": "accepted" | "rejected" | "unknown",
     "tool_calls": "parsed" | "content" | "broken_json" | "none" | null,
     "images": true | false | null,                  # an image in a user message
     "images_in_tool_results": true | false | null,  # an image in a tool message
     "max_images_per_request": 4 | null,             # null: no cap up to MAX_IMAGES_TRIED
     "context": {"tested_tokens": 14745, "needle_found": false, "prompt_tokens": 2048},
     "effective_context_tokens": 2048 | null,
     "stream_tool_calls": true | false | null,
     "requests": 9, "seconds": 0.41,
     "problems": ["ollama keeps only 2048 tokens of a 14745-token prompt: ..."]}

The harness applies it (:meth:`OpenAICompatibleProvider.apply_profile
<cab_harness_reference.openai_compatible_provider.OpenAICompatibleProvider.apply_profile>`) and
records it in ``result.json`` (``agent.serving``). Profiles are cached per ``(base_url, model_id)``
for the process, and in ``cache_dir`` when one is given (a sweep's folder), so each attempt does
not probe again. The probe uses only the standard library's HTTP client: it must see status codes,
bodies and headers exactly as the server sent them.
"""
from __future__ import annotations

import hashlib
import json
import re
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

MAX_IMAGES_TRIED = 8
NEEDLE = "PELICAN-7731"
DEFAULT_NEEDLE_TOKENS = 16384
# a 1x1 PNG, the smallest real image
_PNG_URL = "data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR4nGNgYGD4DwABBAEAwS2OUAAAAABJRU5ErkJggg=="
_TOOL = {"type": "function", "function": {
    "name": "record_word", "description": "Record one word.",
    "parameters": {"type": "object", "properties": {"word": {"type": "string"}}, "required": ["word"]}}}
_ASK_TOOL = "Call the tool record_word with the word 'apple'. Do not answer in text."
_CTX_NUMBER = re.compile(r"maximum context length is (\d+)|context (?:size|length|window)[^0-9]{0,40}(\d+)", re.I)
_IMAGE_CAP = re.compile(r"At most (\d+) image", re.I)

_cache: dict[tuple[str, str], dict] = {}


class _Reply:
    def __init__(self, status: int | None, body: Any, text: str, headers: dict[str, str], error: str = ""):
        self.status, self.body, self.text, self.headers, self.error = status, body, text, headers, error

    @property
    def ok(self) -> bool:
        return self.status == 200 and isinstance(self.body, dict)

    def message(self) -> dict:
        try:
            return self.body["choices"][0]["message"] or {}
        except (KeyError, IndexError, TypeError):
            return {}

    def error_text(self) -> str:
        if isinstance(self.body, dict) and isinstance(self.body.get("error"), dict):
            return str(self.body["error"].get("message") or self.text)
        if isinstance(self.body, dict) and isinstance(self.body.get("error"), str):
            return self.body["error"]
        if isinstance(self.body, dict) and isinstance(self.body.get("message"), str):  # vLLM before 0.10
            return self.body["message"]
        return self.text or self.error


class _Http:
    """JSON over HTTP with the endpoint's key, counting requests."""

    def __init__(self, base_url: str, key: str | None, timeout_s: float):
        self.base = base_url.rstrip("/")
        self.root = re.sub(r"/v1$", "", self.base)
        self.key = key
        self.timeout_s = timeout_s
        self.requests = 0

    def _do(self, url: str, body: dict | None, timeout: float) -> _Reply:
        self.requests += 1
        headers = {"content-type": "application/json", "accept": "application/json"}
        if self.key:
            headers["authorization"] = f"Bearer {self.key}"
        data = json.dumps(body).encode() if body is not None else None
        req = urllib.request.Request(url, data=data, headers=headers, method="POST" if body is not None else "GET")
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                status, raw, hdrs = r.status, r.read(), dict(r.headers)
        except urllib.error.HTTPError as e:
            status, raw, hdrs = e.code, e.read(), dict(e.headers or {})
        except (urllib.error.URLError, OSError, ValueError) as e:
            return _Reply(None, None, "", {}, f"{type(e).__name__}: {getattr(e, 'reason', e)}")
        text = raw.decode("utf-8", "replace")
        try:
            parsed = json.loads(text) if text.strip() else None
        except ValueError:
            parsed = None
        return _Reply(status, parsed, text, {k.lower(): v for k, v in hdrs.items()})

    def get(self, path: str, root: bool = False) -> _Reply:
        return self._do((self.root if root else self.base) + path, None, min(self.timeout_s, 10.0))

    def chat(self, body: dict) -> _Reply:
        return self._do(self.base + "/chat/completions", body, self.timeout_s)

    def stream(self, body: dict) -> tuple[int | None, list[dict], str]:
        """A streamed chat request: its status and the parsed ``data:`` chunks."""
        self.requests += 1
        headers = {"content-type": "application/json", "accept": "text/event-stream"}
        if self.key:
            headers["authorization"] = f"Bearer {self.key}"
        req = urllib.request.Request(self.base + "/chat/completions", data=json.dumps(body).encode(),
                                     headers=headers, method="POST")
        chunks: list[dict] = []
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s) as r:
                for line in r:
                    s = line.decode("utf-8", "replace").strip()
                    if not s.startswith("data:") or s == "data: [DONE]":
                        continue
                    try:
                        chunks.append(json.loads(s[5:].strip()))
                    except ValueError:
                        continue
                return r.status, chunks, ""
        except urllib.error.HTTPError as e:
            return e.code, [], e.read().decode("utf-8", "replace")
        except (urllib.error.URLError, OSError, ValueError) as e:
            return None, [], f"{type(e).__name__}: {e}"


# --- tool calls left in content ------------------------------------------------------------------

_TAGGED = re.compile(r"<tool_call>\s*(.*?)\s*(?:</tool_call>|$)", re.S)
_FENCE = re.compile(r"^```(?:json)?\s*(.*?)\s*```$", re.S)


def repair_json(raw: str) -> Any:
    """``raw`` parsed as JSON, or with the closing braces it lost appended (vLLM's parsers drop
    the last ``}``); None when neither parses."""
    try:
        return json.loads(raw)
    except ValueError:
        pass
    s = raw.rstrip()
    missing = s.count("{") - s.count("}")
    if 0 < missing <= 2:
        try:
            return json.loads(s + "}" * missing)
        except ValueError:
            return None
    return None


def _as_call(obj: Any, names: set[str] | None) -> tuple[str, dict] | None:
    if not isinstance(obj, dict) or not isinstance(obj.get("name"), str):
        return None
    args = obj.get("arguments", obj.get("parameters", {}))
    if isinstance(args, str):
        args = repair_json(args) if args.strip() else {}
    if not isinstance(args, dict) or (names is not None and obj["name"] not in names):
        return None
    return obj["name"], args


def salvage_calls(content: str, names: set[str] | None = None) -> tuple[list[tuple[str, dict]], str]:
    """Tool calls a server's parser left in ``content``: ``<tool_call>{...}</tool_call>`` blocks or
    a bare JSON object (or list of them) with ``name`` and ``arguments``; only names in ``names``
    when given. A block that lost a closing brace is repaired only when it is the one call found.
    Returns the calls and the content with them removed; no calls and the content unchanged when
    none parse."""
    if not content:
        return [], content
    blocks = _TAGGED.findall(content)
    if blocks:
        parsed = []
        for b in blocks:
            try:
                parsed.append(json.loads(b))
            except ValueError:
                parsed.append(repair_json(b) if len(blocks) == 1 else None)
        calls = [_as_call(p, names) for p in parsed]
        if not calls or any(c is None for c in calls):
            return [], content
        return [c for c in calls if c], _TAGGED.sub("", content).strip()
    s = content.strip()
    m = _FENCE.match(s)
    if m:
        s = m.group(1)
    if not s.startswith(("{", "[")):
        return [], content
    try:
        obj = json.loads(s)
    except ValueError:
        obj = repair_json(s)  # a lost brace is repaired only when that gives one call
        if not isinstance(obj, dict):
            return [], content
    items = obj if isinstance(obj, list) else [obj]
    calls = [_as_call(o, names) for o in items]
    if not calls or any(c is None for c in calls):
        return [], content
    return [c for c in calls if c], ""


# --- the probe -----------------------------------------------------------------------------------


def _engine(http: _Http, models: _Reply, model_id: str) -> dict:
    owned = None
    if models.ok:
        for m in models.body.get("data") or []:
            if isinstance(m, dict) and m.get("id") == model_id:
                owned = m.get("owned_by")
    eng: dict[str, Any] = {"name": None, "version": None, "source": None,
                           "server_header": models.headers.get("server"), "owned_by": owned}
    r = http.get("/version", root=True)
    if r.ok and isinstance(r.body.get("version"), str):
        eng.update(name="vllm", version=r.body["version"], source="GET /version")
        return eng
    r = http.get("/props", root=True)
    if r.ok and ("default_generation_settings" in r.body or "build_info" in r.body):
        eng.update(name="llama.cpp", version=r.body.get("build_info"), source="GET /props")
        n_ctx = (r.body.get("default_generation_settings") or {}).get("n_ctx")
        if isinstance(n_ctx, int):
            eng["n_ctx"] = n_ctx
        return eng
    r = http.get("/api/version", root=True)
    if r.ok and isinstance(r.body.get("version"), str):
        eng.update(name="ollama", version=r.body["version"], source="GET /api/version")
        return eng
    hint = f"{eng['server_header'] or ''} {owned or ''}".lower()
    for name in ("vllm", "llama.cpp", "llamacpp", "ollama", "sglang", "tgi", "lmstudio"):
        if name in hint:
            eng.update(name="llama.cpp" if name == "llamacpp" else name, source="server header or owned_by")
    return eng


def _tools(http: _Http, model: str, profile: dict, problems: list[str]) -> None:
    r = http.chat({"model": model, "max_tokens": 64, "tools": [_TOOL],
                   "messages": [{"role": "user", "content": _ASK_TOOL}]})
    eng = profile["engine"]["name"] or "the server"
    if not r.ok:
        err = r.error_text()
        profile["tools_error"] = f"HTTP {r.status}: {err[:300]}" if r.status else err[:300]
        plain = http.chat({"model": model, "max_tokens": 8, "messages": [{"role": "user", "content": "Say ok."}]})
        if not plain.ok:  # not the tools: the endpoint fails every request (a key, a model name, a crash)
            problems.append(f"{eng} fails a plain request too (HTTP {plain.status}: {plain.error_text()[:160]}): "
                            "check the key, model.model_id and the server's log")
            return
        profile["tools"] = "rejected"
        if "jinja" in err.lower() or (eng == "llama.cpp" and r.status == 500):
            problems.append(f"llama.cpp answers {r.status} to tools ({err[:120]}): start llama-server with --jinja "
                            "(and --chat-template-file with a template that supports tools if it still fails); "
                            "meanwhile the harness describes the tools in the prompt")
        elif eng == "vllm" and "auto" in err.lower():
            problems.append(f"vLLM refuses tools ({err[:120]}): start vllm serve with --enable-auto-tool-choice "
                            "--tool-call-parser <the model's parser>")
        else:
            problems.append(f"{eng} refuses tools (HTTP {r.status}: {err[:120]}): enable tool calling on the server")
        return
    profile["tools"] = "accepted"
    msg = r.message()
    calls = msg.get("tool_calls") or []
    if calls:
        raw = ((calls[0] or {}).get("function") or {}).get("arguments") or ""
        try:
            ok = isinstance(json.loads(raw) if raw.strip() else {}, dict)
        except ValueError:
            ok = False
        profile["tool_calls"] = "parsed" if ok else "broken_json"
        if not ok:
            problems.append(f"{eng}'s tool parser returned unparseable arguments ({raw[:60]!r}): the harness repairs "
                            "a lost closing brace where that gives one call; check --tool-call-parser")
        return
    found, _ = salvage_calls(msg.get("content") or "", {"record_word"})
    if found:
        profile["tool_calls"] = "content"
        problems.append(f"{eng} leaves tool calls in the message text: the harness salvages them (marked "
                        "salvaged in the record); start vllm serve with --enable-auto-tool-choice and the "
                        "model's --tool-call-parser")
    else:
        profile["tool_calls"] = "none"  # the model answered in text: nothing to learn about the parser


def _images(http: _Http, model: str, profile: dict, problems: list[str]) -> None:
    def user_images(n: int) -> _Reply:
        content: list[dict] = [{"type": "text", "text": "How many images? Answer with a number."}]
        content += [{"type": "image_url", "image_url": {"url": _PNG_URL}} for _ in range(n)]
        return http.chat({"model": model, "max_tokens": 8, "messages": [{"role": "user", "content": content}]})

    r = user_images(MAX_IMAGES_TRIED)
    if r.ok:
        profile["images"], profile["max_images_per_request"] = True, None
    else:
        m = _IMAGE_CAP.search(r.error_text())
        cap = int(m.group(1)) if m else None
        if cap is None:  # no number given: the largest count accepted
            for n in (1, 2, 4):
                if not user_images(n).ok:
                    break
                cap = n
        profile["max_images_per_request"] = cap
        profile["images"] = bool(cap)
        if not cap:
            problems.append(f"the endpoint refuses images ({r.error_text()[:120]}): serve a vision model")
            return
        problems.append(f"the server takes at most {cap} image(s) per request: the harness keeps the newest {cap} "
                        "(raise vLLM's --limit-mm-per-prompt to send more)")
    if profile["tools"] != "accepted":
        return  # no tool messages are sent to it
    r = http.chat({"model": model, "max_tokens": 8, "tools": [_TOOL], "messages": [
        {"role": "user", "content": _ASK_TOOL},
        {"role": "assistant", "content": None, "tool_calls": [
            {"id": "probe_1", "type": "function", "function": {"name": "record_word", "arguments": '{"word": "apple"}'}}]},
        {"role": "tool", "tool_call_id": "probe_1", "content": [
            {"type": "text", "text": '{"status": "ok"}'}, {"type": "image_url", "image_url": {"url": _PNG_URL}}]}]})
    profile["images_in_tool_results"] = r.ok
    if not r.ok:
        profile["images_in_tool_results_error"] = f"HTTP {r.status}: {r.error_text()[:300]}"
        problems.append("images are refused in tool messages: the harness sends them in a user message after "
                        "the tool results")


def _needle(http: _Http, model: str, tokens: int, profile: dict, problems: list[str]) -> None:
    sentence = "The grey stone sat on the quiet hill under the pale sky. "  # ~13 tokens, 57 chars
    n = max(1, int(tokens * 4 / len(sentence)))
    prompt = (f"Remember this code word: {NEEDLE}.\n\n" + sentence * n +
              "\n\nWhat was the code word given at the very start? Answer with the code word only.")
    r = http.chat({"model": model, "max_tokens": 16, "messages": [{"role": "user", "content": prompt}]})
    ctx: dict[str, Any] = {"tested_tokens": tokens, "needle_found": None, "prompt_tokens": None}
    profile["context"] = ctx
    eng = profile["engine"]["name"] or "the server"
    if not r.ok:
        err = r.error_text()
        m = _CTX_NUMBER.search(err)
        if m:
            limit = int(m.group(1) or m.group(2))
            ctx["error"] = err[:300]
            profile["effective_context_tokens"] = limit
            problems.append(f"{eng} serves a context of {limit} tokens: the harness compacts to it "
                            "(raise --max-model-len / -c / num_ctx for more)")
        else:
            ctx["error"] = f"HTTP {r.status}: {err[:300]}"
        return
    text = str(r.message().get("content") or "")
    found = NEEDLE.lower() in text.lower() or NEEDLE.split("-")[1] in text
    used = (r.body.get("usage") or {}).get("prompt_tokens")
    ctx["needle_found"] = found
    ctx["prompt_tokens"] = used if isinstance(used, int) else None
    if not found:  # the start of the prompt is gone: the server kept what it counted, where it says
        kept = used if isinstance(used, int) and 0 < used < tokens else None
        profile["effective_context_tokens"] = kept
        what = (f"keeps only {kept} tokens of a {tokens}-token prompt" if kept
                else f"lost a code word at the start of a {tokens}-token prompt")
        fix = ("set num_ctx in the model's Modelfile or OLLAMA_CONTEXT_LENGTH (its /v1 ignores num_ctx)"
               if eng == "ollama" else "start the server with a longer context (-c / --max-model-len)")
        problems.append(f"{eng} {what} (silent truncation): {fix}"
                        + ("; the harness compacts to it" if kept else "; set model.context_tokens lower"))


def _stream(http: _Http, model: str, profile: dict) -> None:
    status, chunks, _ = http.stream({"model": model, "max_tokens": 64, "stream": True, "tools": [_TOOL],
                                     "messages": [{"role": "user", "content": _ASK_TOOL}]})
    if status != 200:
        profile["stream_tool_calls"] = None
        return
    deltas = [((c.get("choices") or [{}])[0] or {}).get("delta") or {} for c in chunks]
    if any(d.get("tool_calls") for d in deltas):
        profile["stream_tool_calls"] = True
    else:
        text = "".join(str(d.get("content") or "") for d in deltas)
        profile["stream_tool_calls"] = False if salvage_calls(text, {"record_word"})[0] else None


def probe_endpoint(model_cfg: dict, *, cache_dir: str | Path | None = None, refresh: bool = False) -> dict:
    """The capability profile of the OpenAI-compatible endpoint of ``model_cfg`` (``base_url``,
    ``model_id``, ``api_key_env``, ``context_tokens``, ``probe_needle_tokens``, ``probe_timeout_s``):
    a few small requests, cached per ``(base_url, model_id)`` for the process and, with
    ``cache_dir``, in a file there. An endpoint that does not answer gives a profile with
    ``reachable: false`` (not cached: the attempt's own request then fails as an outage)."""
    import os

    base = str(model_cfg.get("base_url") or os.environ.get("OPENAI_BASE_URL") or "").rstrip("/")
    model = str(model_cfg.get("model_id") or model_cfg.get("model") or "")
    key_env = model_cfg.get("api_key_env", "OPENAI_API_KEY")
    key = os.environ.get(key_env) if key_env else None
    ident = (base, model)
    path = None
    if cache_dir is not None:
        digest = hashlib.sha1(f"{base}\n{model}".encode()).hexdigest()[:12]
        path = Path(cache_dir) / f"endpoint-probe-{digest}.json"
    if not refresh:
        if ident in _cache:
            return _cache[ident]
        if path is not None and path.is_file():
            try:
                prof = json.loads(path.read_text())
            except ValueError:
                prof = None
            if isinstance(prof, dict) and prof.get("base_url") == base and prof.get("model_id") == model:
                _cache[ident] = prof
                return prof
    t0 = time.monotonic()
    http = _Http(base, key, float(model_cfg.get("probe_timeout_s") or 120.0))
    problems: list[str] = []
    profile: dict[str, Any] = {"base_url": base, "model_id": model, "reachable": True, "model_listed": None,
                               "engine": {}, "tools": "unknown", "tool_calls": None, "images": None,
                               "images_in_tool_results": None, "max_images_per_request": None,
                               "max_images_tried": MAX_IMAGES_TRIED, "context": None,
                               "effective_context_tokens": None, "stream_tool_calls": None,
                               "problems": problems}
    models = http.get("/models")
    if models.status is None:
        profile["reachable"] = False
        problems.append(f"nothing answers at {base} ({models.error}): start the server or fix model.base_url")
        profile.update(requests=http.requests, seconds=round(time.monotonic() - t0, 3))
        return profile
    if models.ok:
        ids = [m.get("id") for m in models.body.get("data") or [] if isinstance(m, dict)]
        profile["model_listed"] = model in ids
        if model not in ids:
            problems.append(f"{base} does not serve {model!r} (it lists {', '.join(map(str, ids[:5])) or 'none'}): "
                            "set model.model_id to a served name")
    profile["engine"] = _engine(http, models, model)
    _tools(http, model, profile, problems)
    _images(http, model, profile, problems)
    configured = model_cfg.get("context_tokens")
    tokens = int(model_cfg.get("probe_needle_tokens") or DEFAULT_NEEDLE_TOKENS)
    if configured:
        tokens = min(tokens, int(int(configured) * 0.9))
    if tokens > 0:
        _needle(http, model, tokens, profile, problems)
    if profile["tools"] == "accepted":
        _stream(http, model, profile)
    profile.update(requests=http.requests, seconds=round(time.monotonic() - t0, 3))
    _cache[ident] = profile
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(profile, indent=1, sort_keys=True))
        tmp.replace(path)
    return profile


def wants_probe(model_cfg: dict) -> bool:
    """``model.probe``: true, false, or ``auto`` (the default): probe a local server (no API key,
    ``api_key_env: null``) and leave hosted APIs, whose requests are paid, alone."""
    v = model_cfg.get("probe", "auto")
    if isinstance(v, bool):
        return v
    if str(v).lower() in ("true", "1", "yes", "on"):
        return True
    if str(v).lower() in ("false", "0", "no", "off"):
        return False
    return "api_key_env" in model_cfg and not model_cfg.get("api_key_env")


def serving_summary(profile: dict) -> dict:
    """The ``serving`` entry of ``result.json``'s ``agent`` block: engine, version and the profile."""
    eng = profile.get("engine") or {}
    return {"engine": eng.get("name"), "version": eng.get("version"), "base_url": profile.get("base_url"),
            "model_id": profile.get("model_id"), "profile": profile}


def clear_cache() -> None:
    _cache.clear()
