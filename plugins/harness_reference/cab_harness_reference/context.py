"""The reference context policy (FACTS A.10 "Context policy"; paper Appendix "Reference harness").

Deterministic, no model-written summary:

* image bytes only from the ``max_image_rounds`` (2) most recent image-bearing rounds (a round
  opens at each assistant turn); older images become text records keeping their ``obs_id`` so
  they can be fetched again; at most ``max_images_per_result`` (6) images per tool result; an
  exact duplicate image is sent once;
* when the estimated request exceeds the limit, the ``recent_units`` (8) newest assistant+tool
  units are kept verbatim and older units are reduced by fixed rules to compact records (tool
  name, selected arguments, status/error, selected measurements, obs ids), at most
  ``ledger_max_records`` (128), appended to the task message (the anchor, always kept);
* if the request still does not fit, the ledger and then the verbatim units shrink (the anchor
  and the newest unit are kept); if even that does not fit, :class:`ContextOverflow` is raised
  and the attempt ends ``context_length_exceeded``.
"""
from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, replace
from typing import Any

from .types import Capabilities, Image, Message, Text, Thinking, ToolCall, ToolResult

POLICY_VERSION = "cab-deterministic-ledger/1"


class ContextOverflow(Exception):
    """The request does not fit the context even after every reduction."""

    def __init__(self, estimated: int, limit: int):
        super().__init__(f"estimated request {estimated} tokens exceeds the context limit {limit} after compaction")
        self.estimated = estimated
        self.limit = limit


def image_placeholder(img: Image, why: str = "omitted from the active context") -> Text:
    label = f" ({img.label})" if img.label and img.obs_id not in img.label else (f" ({img.label})" if img.label else "")
    return Text(f"[image {img.obs_id}{label} {why}; fetch it again by its obs_id]")


# --- compact records --------------------------------------------------------------------------
_ARG_DROP = {"code"}  # program source is not kept in records
_RESULT_KEEP = ("status", "error", "code", "reason", "achieved", "achieved_pose", "tcp_pose", "contact", "contacts",
                "contact_detected", "in_contact", "finger_gap_m", "gripper", "reached", "position", "point",
                "scale", "distance_m", "namespace_reset", "exception", "program", "abort_reason", "timed_out", "ended")


def _clip(v: Any, n: int = 240) -> Any:
    s = json.dumps(v, sort_keys=True, default=str)
    return v if len(s) <= n else s[: n - 3] + "..."


_OBS_NOTE = re.compile(r"\[image (obs_[A-Za-z0-9_]+)")


def _payload(text: str):
    try:
        return json.JSONDecoder().raw_decode(text.lstrip())[0]
    except (ValueError, TypeError):
        return None


def compact_record(call: ToolCall | None, result: ToolResult | None, obs_ids: list[str]) -> dict:
    rec: dict = {"tool": call.name if call else (result.name if result else "?")}
    if call is not None:
        if call.arguments is None:
            rec["args"] = "(malformed JSON)"
        else:
            args = {k: _clip(v, 160) for k, v in sorted(call.arguments.items()) if k not in _ARG_DROP}
            if "code" in call.arguments:
                args["code_chars"] = len(str(call.arguments["code"]))
            rec["args"] = args
    if result is not None:
        payload = _payload(result.text)
        if isinstance(payload, dict):
            for k in _RESULT_KEEP:
                if payload.get(k) is not None:
                    rec[k] = _clip(payload[k])
            if result.name == "run_code":
                for k in ("ok", "value", "stdout", "tool_calls"):
                    if k in payload and payload[k] not in (None, ""):
                        rec[k] = _clip(payload[k], 400)
        elif result.text:
            rec["text"] = _clip(result.text, 240)
        if result.is_error:
            rec["is_error"] = True
    if obs_ids:
        rec["obs_ids"] = obs_ids
    return rec


# --- the policy -------------------------------------------------------------------------------
@dataclass
class ReferenceContextPolicy:
    max_image_rounds: int = 2
    max_images_per_result: int = 6
    recent_units: int = 8
    ledger_max_records: int = 128
    image_token_estimate: int = 1024
    protocol_overhead_tokens: int = 1024
    chars_per_token: float = 4.0

    @classmethod
    def from_cfg(cls, cfg: dict | None) -> ReferenceContextPolicy:
        cfg = dict(cfg or {})
        cfg.pop("name", None)
        known = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in cfg.items() if k in known})

    # -- estimation ----------------------------------------------------------------------------
    def estimate_part(self, p) -> int:
        c = self.chars_per_token
        if isinstance(p, Text):
            return int(len(p.text) / c) + 1
        if isinstance(p, Image):
            return self.image_token_estimate
        if isinstance(p, ToolCall):
            return int((len(p.name) + len(p.raw_arguments or json.dumps(p.arguments, default=str))) / c) + 8
        if isinstance(p, ToolResult):
            return int(len(p.text) / c) + 8 + sum(self.estimate_part(i) for i in p.images)
        if isinstance(p, Thinking):
            return int(len(p.text) / c) + (64 if p.signature else 0)
        return 0

    def estimate(self, messages: list[Message], fixed_tokens: int = 0) -> int:
        return self.protocol_overhead_tokens + fixed_tokens + sum(
            4 + sum(self.estimate_part(p) for p in m.parts) for m in messages)

    # -- structure -----------------------------------------------------------------------------
    @staticmethod
    def split(messages: list[Message]) -> tuple[list[Message], list[list[Message]]]:
        """Anchor messages (before the first assistant turn) and units (one assistant message and
        everything up to the next one)."""
        anchor: list[Message] = []
        units: list[list[Message]] = []
        for m in messages:
            if m.role == "system":
                continue
            if m.role == "assistant":
                units.append([m])
            elif units:
                units[-1].append(m)
            else:
                anchor.append(m)
        return anchor, units

    # -- images --------------------------------------------------------------------------------
    def _strip_images(self, anchor: list[Message], units: list[list[Message]]) -> list[list[Message]]:
        def has_img(msgs):
            return any(isinstance(p, Image) or (isinstance(p, ToolResult) and p.images) for m in msgs for p in m.parts)

        bearing = [i for i, u in enumerate(units) if has_img(u)]
        keep = set(bearing[-self.max_image_rounds:]) if self.max_image_rounds > 0 else set()
        seen: set[str] = set()
        out_units: list[list[Message]] = [None] * len(units)  # type: ignore[list-item]
        # newest first, so the newest copy of a duplicate image is the one sent
        for i in range(len(units) - 1, -1, -1):
            new_msgs = []
            for m in reversed(units[i]):
                parts = []
                for p in reversed(m.parts):
                    if isinstance(p, ToolResult) and p.images:
                        imgs, notes = [], []
                        cap = p.images[-self.max_images_per_result:] if self.max_images_per_result else []
                        for img in reversed(p.images):
                            if i not in keep:
                                notes.append(image_placeholder(img).text)
                            elif not any(img is c for c in cap):
                                notes.append(image_placeholder(img, "withheld (image cap)").text)
                            else:
                                h = hashlib.sha1(img.png).hexdigest()
                                if h in seen:
                                    notes.append(image_placeholder(img, "identical to a newer image").text)
                                else:
                                    seen.add(h)
                                    imgs.append(img)
                        text = p.text + ("\n" + "\n".join(notes[::-1]) if notes else "")
                        parts.append(replace(p, images=imgs[::-1], text=text))
                    elif isinstance(p, Image):
                        if i not in keep:
                            parts.append(image_placeholder(p))
                        else:
                            h = hashlib.sha1(p.png).hexdigest()
                            if h in seen:
                                parts.append(image_placeholder(p, "identical to a newer image"))
                            else:
                                seen.add(h)
                                parts.append(p)
                    else:
                        parts.append(p)
                new_msgs.append(replace(m, parts=parts[::-1], cache_breakpoint=False))
            out_units[i] = new_msgs[::-1]
        return out_units

    # -- compaction ----------------------------------------------------------------------------
    def unit_records(self, unit: list[Message]) -> list[dict]:
        calls = {p.call_id: p for m in unit if m.role == "assistant" for p in m.parts if isinstance(p, ToolCall)}
        results = {p.call_id: p for m in unit for p in m.parts if isinstance(p, ToolResult)}
        recs = []
        for cid, call in calls.items():
            res = results.get(cid)
            obs: list[str] = []
            if res is not None:
                obs = [i.obs_id for i in res.images] + _OBS_NOTE.findall(res.text)
                payload = _payload(res.text)
                if isinstance(payload, dict):
                    for k in ("obs_id", "obs_ids", "images"):
                        v = payload.get(k)
                        if isinstance(v, str) and v.startswith("obs"):
                            obs.append(v)
                        elif isinstance(v, list):
                            obs += [x for x in v if isinstance(x, str) and x.startswith("obs")]
            for m in unit:  # images sent in a follow-up user message
                if m.role == "user":
                    for p in m.parts:
                        if isinstance(p, Image):
                            obs.append(p.obs_id)
                        elif isinstance(p, Text):
                            obs += _OBS_NOTE.findall(p.text)
            recs.append(compact_record(call, res, sorted(dict.fromkeys(obs))))
        if not calls:
            recs.append({"tool": None, "note": "a response without tool calls"})
        return recs

    def _assemble(self, anchor: list[Message], older: list[list[Message]], recent: list[list[Message]],
                  max_records: int) -> list[Message]:
        out = [replace(m, parts=list(m.parts)) for m in anchor]
        if older:
            recs = [r for u in older for r in self.unit_records(u)]
            keep = min(len(recs), max(0, max_records))
            dropped = len(recs) - keep
            recs = recs[len(recs) - keep:] if keep else []
            lines = ["[Record of earlier interactions, compacted by fixed rules (no summary); newest last."
                     + (f" {dropped} older records dropped." if dropped else "") + "]"]
            lines += [json.dumps(r, sort_keys=True, default=str) for r in recs]
            ledger = Text("\n".join(lines))
            if out and out[-1].role == "user":
                out[-1] = replace(out[-1], parts=out[-1].parts + [ledger])
            else:
                out.append(Message("user", [ledger]))
        for u in recent:
            out += u
        return out

    def build(self, messages: list[Message], capabilities: Capabilities | None = None, limit_tokens: int | None = None,
              fixed_tokens: int = 0) -> list[Message]:
        """The messages to send for the next request (a new list; ``messages`` is not changed).
        ``fixed_tokens`` is the estimated size of the system prompt and tool schemas."""
        anchor, units = self.split(messages)
        units = self._strip_images(anchor, units)
        out = [replace(m, cache_breakpoint=False) for m in anchor] + [m for u in units for m in u]
        if limit_tokens and self.estimate(out, fixed_tokens) > limit_tokens:
            out = None
            n = min(self.recent_units, len(units))
            tries = [(n, self.ledger_max_records)]
            r = self.ledger_max_records // 2
            while r > 0:
                tries.append((n, r))
                r //= 2
            tries += [(k, 0) for k in range(n, 0, -1)]
            est = 0
            for k, recs in tries:
                k = max(1, k) if units else 0
                cand = self._assemble(anchor, units[: len(units) - k], units[len(units) - k:], recs)
                est = self.estimate(cand, fixed_tokens)
                if est <= limit_tokens:
                    out = cand
                    break
            if out is None:
                raise ContextOverflow(est, limit_tokens)
        cap = capabilities.max_images_per_request if capabilities is not None else None
        if cap is not None:
            out = self.cap_images(out, cap)
        if out:
            if anchor:
                out[len(anchor) - 1] = replace(out[len(anchor) - 1], cache_breakpoint=True)
            out[-1] = replace(out[-1], cache_breakpoint=True)
        return out


    @staticmethod
    def cap_images(messages: list[Message], cap: int) -> list[Message]:
        """At most ``cap`` images in one request (a server's limit, e.g. vLLM's
        ``--limit-mm-per-prompt``): the newest are kept, older ones become placeholders."""
        why = f"withheld (the server takes at most {cap} image(s) per request)"
        kept = 0
        out: list[Message] = []
        for m in reversed(messages):
            parts: list = []
            for p in reversed(m.parts):
                if isinstance(p, Image):
                    kept += 1
                    parts.append(p if kept <= cap else image_placeholder(p, why))
                elif isinstance(p, ToolResult) and p.images:
                    imgs, notes = [], []
                    for img in reversed(p.images):
                        kept += 1
                        if kept <= cap:
                            imgs.append(img)
                        else:
                            notes.append(image_placeholder(img, why).text)
                    text = p.text + ("\n" + "\n".join(notes[::-1]) if notes else "")
                    parts.append(replace(p, images=imgs[::-1], text=text))
                else:
                    parts.append(p)
            out.append(replace(m, parts=parts[::-1]))
        return out[::-1]


def build_policy(cfg: dict | None = None) -> ReferenceContextPolicy:
    return ReferenceContextPolicy.from_cfg(cfg)
