"""``cab-view <attempt dir>``: one HTML page per attempt, from its records.

The page (``view.html`` in the attempt directory; the template ``templates/attempt.html.j2``) shows the instruction, the verdict beside the
agent's claim, the budget, the checkpoints, the head-camera video, and the timeline: every model
turn, every charged call with its arguments, status, physics steps and the result the agent saw,
every program with the calls it made, and the images the agent was shown. It is self-contained
except for the video and the observation images, referenced by relative path inside the attempt
directory, so the directory can be moved or archived as a whole.

Forks (:mod:`cab_core.attempt.fork`) are linked both ways: the page of a fork (``result.json``
``fork: {parent, at}``) links to its parent's page and says at which charged call it started; the page
of an attempt that was forked (its ``forks.jsonl``) links to each fork's page. The links are relative
(``<folder>/view.html``, the page cab-view writes there; ``cab-report`` writes every one it links to).
"""
from __future__ import annotations

import json
from pathlib import Path

from cab_core.analysis import pages
from cab_core.analysis.attempts import Attempt, attempt_dirs, read_jsonl
from cab_core.attempt.fork import FORKS_FILE
from cab_core.errors import CabError, RecordError


def _json(obj) -> str:
    return json.dumps(obj, indent=1)


def shown_file(d: Path, rel: str) -> Path | None:
    """The file ``rel`` (a path below the attempt directory ``d``) if an attempt's page may show it,
    else None: the page shows the observation images and the video, nothing else (never
    ``result.json``, ``privileged/`` or a log; docs/studio.md). Decided on the RESOLVED path: a
    file below ``d/observations/`` or ``d/video.mp4`` itself, so that no ``..`` (however it was
    encoded in a URL) and no symbolic link pointing out of ``observations/`` reaches anything else.
    The studio serves exactly these files (:mod:`cab_core.apps.studio.app`); the page links only
    these."""
    d = Path(d).resolve()
    try:
        f = (d / rel).resolve()
    except (OSError, RuntimeError, ValueError):  # a link loop, a NUL byte
        return None
    allowed = f == d / "video.mp4" or f.is_relative_to(d / "observations")
    return f if allowed and f.is_file() else None


def _images(d: Path, obs_ids) -> list[str]:
    """The observations the agent was shown that the attempt directory holds (``observations/<id>.png``,
    as :func:`shown_file` allows: an id from the records never makes the page link another file)."""
    return [str(o) for o in obs_ids or [] if shown_file(d, f"observations/{o}.png") is not None]


def _status(ev: dict) -> tuple[str, str]:
    """A call's status and its class (good, bad)."""
    r = ev.get("result") or {}
    s = ev.get("status") or r.get("status")
    if ev.get("tool") == "run_code":
        s = "ok" if r.get("ok") else ("ABORTED" if r.get("status") == "ABORTED" else "error")
    elif s is None:
        s = "error" if "error" in r else "ok"
    return str(s), "good" if s in ("SUCCESS", "ok") else "bad"


def _call(d: Path, ev: dict, internal: bool, charged_index: int | None) -> dict:
    r = ev.get("result") or {}
    args = dict(ev.get("arguments") or {})
    code = args.pop("code", None) if ev.get("tool") == "run_code" else None
    status, cls = _status(ev)
    return {"kind": "call", "tool": str(ev.get("tool")), "status": status, "status_class": cls, "internal": internal,
            "charged_index": charged_index, "seq": ev.get("seq"), "t_wall": f"{ev.get('t_wall', 0):.1f}",
            "physics_steps": ev.get("physics_steps"), "not_charged": ev.get("charged") is False,
            "code": None if code is None else str(code), "program": str(r.get("program", "")),
            "outputs": [(k, str(r[k])) for k in ("error", "stdout") if code is not None and r.get(k)],
            "arguments": _json(args) if args else None, "result": _json(r), "images": _images(d, ev.get("obs_ids"))}


def _turn(ev: dict) -> dict:
    u = ev.get("usage") or {}
    cost = (ev.get("cost") or {}).get("usd")
    return {"kind": "turn", "turn": ev.get("turn"), "model": str(ev.get("model", "")),
            "input_tokens": u.get("input_tokens", 0), "output_tokens": u.get("output_tokens", 0),
            "cost": f"{cost:.4f}" if isinstance(cost, (int, float)) else None, "latency": ev.get("latency_s", 0),
            "waited": ev.get("waited_s", 0), "thinking": ev.get("thinking"), "text": ev.get("text")}


def matched_at(ck, latch_at: int | None = None) -> dict[int, list[str]]:
    """Charged-call index -> the checkpoints first matched by then (from the result's checkpoints);
    a subgoal attained by the latch event at ``latch_at``, the call during which the event latched."""
    out: dict[int, list[str]] = {}
    if not isinstance(ck, dict) or "error" in ck:
        return out
    for kind in ("subgoals", "spatial"):
        for c in ck.get(kind, []):
            first = c.get("first") or {}
            k = first.get("calls")
            if k is None and first.get("label") == "latch event":
                k = latch_at
            if c.get("attained") and isinstance(k, int):
                what = c.get("text", "") if kind == "subgoals" else c.get("name", "")
                label = f"{'subgoal' if kind == 'subgoals' else 'spatial'} {c['index']}: {what}"
                out.setdefault(k, []).append(label)
    return out


def timeline(d: Path, events: list[dict], ck=None, latch_at: int | None = None) -> list[dict]:
    """The events in order (what the page's timeline shows of each: ``kind`` call, turn, mark or
    other), each checkpoint marked after the charged call that first matched it. A program's
    internal calls are shown just before its run_code entry (they are logged as they happen, the
    program's own entry when it returns)."""
    out = []
    marks = matched_at(ck, latch_at)
    charged = 0
    for ev in events:
        kind = ev.get("kind")
        if kind in ("call", "internal_call", "call_refused"):
            index = None
            if kind == "call" and ev.get("charged", True):
                charged += 1
                index = charged
            out.append(_call(d, ev, internal=(kind == "internal_call"), charged_index=index))
            out += [{"kind": "mark", "label": m} for m in (marks.get(index, []) if index is not None else [])]
        elif kind == "model_turn":
            out.append(_turn(ev))
        elif kind not in ("attempt_start",):
            rest = {k: v for k, v in ev.items() if k not in ("seq", "kind", "t_wall")}
            out.append({"kind": "other", "name": str(kind), "seq": ev.get("seq"), "details": _json(rest) if rest else None})
    return out


def latch_call(d: Path, v: dict) -> int | None:
    """The charged call during which a latch task's event latched (``verdict.latch``), or None: the
    ``calls`` of the first privileged snapshot recorded as latched (one is taken after every charged
    call), as a spatial checkpoint's first match is counted. The checkpoints credit a subgoal that the
    latch satisfies to the event itself (``first.calls`` null), not to a snapshot."""
    if not (isinstance(v, dict) and isinstance(v.get("latch"), dict) and v["latch"].get("latched")):
        return None
    try:
        with open(d / "privileged" / "snapshots.jsonl") as f:
            for line in f:
                try:
                    snap = json.loads(line)
                except ValueError:
                    continue
                if isinstance(snap, dict) and snap.get("latched") and isinstance(snap.get("calls"), int):
                    return snap["calls"]
    except OSError:
        pass
    return None


def _first_calls(first: dict, latch: dict | None, at_call: int | None) -> str:
    """The "first at call" cell: the charged call of the first match; for a subgoal attained by the
    latch event (no call of its own on record), the call during which the event latched, said so."""
    k = first.get("calls")
    if isinstance(k, int):
        return str(k)
    if first.get("label") == "latch event":
        step = (latch or {}).get("at_step")
        where = f"physics step {step}" if isinstance(step, int) else ""
        if at_call is not None:
            return f"{at_call} (the event latched{', ' + where if where else ''})"
        return f"the latch event{' (' + where + ')' if where else ''}"
    return "" if k is None else str(k)


def _checkpoints(ck, latch: dict | None = None, at_call: int | None = None) -> dict:
    if not isinstance(ck, dict) or "error" in ck:
        return {"unavailable": True, "error": str(ck.get("error")) if isinstance(ck, dict) else None}
    rows = []
    for kind in ("subgoals", "spatial"):
        for c in ck.get(kind, []):
            first = c.get("first") or {}
            rows.append({"name": f"{kind[:-1] if kind == 'subgoals' else 'spatial'} {c['index']}",
                         "what": c.get("text") or c.get("name", ""), "attained": bool(c["attained"]),
                         "first_calls": _first_calls(first, latch, at_call) if first else "",
                         "arm": str(first.get("arm", "")) if first else ""})
    return {"unavailable": False, "subgoal_coverage": f"{ck.get('subgoal_coverage', 0):.0%}",
            "spatial_coverage": f"{ck.get('spatial_coverage', 0):.0%}", "rows": rows}


def _margin_line(m: dict) -> str:
    if m.get("fraction") is None:
        return "no thresholded predicate decided it"
    return (f"{'BORDERLINE: ' if m['borderline'] else ''}{m['fraction']:.1%} of its tolerance ({m['predicate']}; "
            f"borderline below {m['threshold']:.0%})")


def _margins_at(v: dict) -> str:
    """Where the margins were measured, as the page says it: "the final state (...)", or the latched
    event's moment (its physics step, and the step it latched at)."""
    if v.get("margins_at") == "latch":
        step, latched = v.get("margins_at_step"), (v.get("latch") or {}).get("at_step")
        return ("the latch: " + (f"physics step {step}, " if isinstance(step, int) else "")
                + "where the latched event held widest"
                + (f" (it latched at step {latched})" if isinstance(latched, int) else ""))
    return "the final state (when the attempt ended)"


def _margins(v: dict) -> dict | None:
    """Each predicate's margin: how far inside (+) or outside (-) its threshold, in its unit and as
    a fraction of its tolerance."""
    ms = v.get("margins")
    if not isinstance(ms, dict) or not ms:
        return None

    def g(x) -> str:
        return "" if x is None else f"{x:.4g}"

    return {"at": _margins_at(v),
            "rows": [_margin_row(k, m, g) for k, m in ms.items()]}


def _margin_row(name: str, m: dict, g) -> dict:
    """One predicate's row; a measurement that was not a finite number is written as null in the
    record (``non_finite_as_null``) and shown as "not measured"."""
    slack, fraction = m.get("slack"), m.get("fraction")
    if slack is None:
        return {"name": name, "cls": "bad", "slack": "not measured", "fraction": "",
                "measured": g(m.get("measured")), "threshold": g(m.get("threshold"))}
    return {"name": name, "cls": "good" if slack > 0 else "bad", "slack": f"{slack:+.4g} {m.get('unit', '')}",
            "fraction": "" if fraction is None else f"{fraction:+.1%}", "measured": g(m.get("measured")),
            "threshold": g(m.get("threshold"))}


def forks_of(attempt_dir: Path) -> list[dict]:
    """The forks made of an attempt (its ``forks.jsonl``, :data:`cab_core.attempt.fork.FORKS_FILE`):
    ``{"child": relative path, "at": K}``, those whose records still exist."""
    p = Path(attempt_dir) / FORKS_FILE
    if not p.is_file():  # none, or not a file the viewer can read
        return []
    return [f for f in read_jsonl(p) if isinstance(f.get("child"), str) and (Path(attempt_dir) / f["child"]).is_dir()]


def fork_links(d: Path, fork: dict | None) -> dict:
    """The attempt an attempt was forked from (``fork``: its ``result.json`` or configuration's
    ``{parent, at}``) and the forks made of it (its ``forks.jsonl``), for the page's links:
    ``parent`` ({rel, at} or None) and ``children`` ([{rel, at, outcome}], by fork point)."""

    parent = None
    if isinstance(fork, dict) and isinstance(fork.get("parent"), str):
        parent = {"rel": fork["parent"], "at": str(fork.get("at"))}
    children = {f["child"]: f for f in forks_of(d)}  # a fork made again into the same folder: once
    kids = [{"rel": c, "at": str(f.get("at")), "outcome": _fork_outcome(d / c)}
            for c, f in sorted(children.items(), key=lambda kv: (
                kv[1].get("at") if isinstance(kv[1].get("at"), int) else -1, kv[0]))]
    return {"parent": parent, "children": kids}


def _fork_outcome(child: Path) -> str:
    """`` · <model> · success`` (or failure, or unfinished) for a fork's folder."""
    try:
        r = json.loads((child / "result.json").read_text())
        return f" · {r.get('model')} · {'success' if (r.get('verdict') or {}).get('success') else 'failure'}"
    except (OSError, ValueError, AttributeError):
        return " · unfinished"


def _events(d: Path) -> tuple[list[dict], str | None]:
    """The event log, and what is wrong with it when it cannot be read."""
    try:
        return read_jsonl(d / "events.jsonl"), None
    except CabError as e:
        return [], str(e)


def _page(**ctx) -> str:
    """The page: ``templates/attempt.html.j2`` with ``ctx``."""
    return pages.render("attempt.html.j2", **ctx)


def render(a: Attempt, page_of: str = "view.html") -> str:
    """The page of a finished attempt; ``page_of``: what a link to another attempt's page appends
    to its folder (cab-view's ``view.html``; cab-studio's attempt route serves the folder itself)."""
    r = a.result
    v, claim, b = r["verdict"], r["claim"], r["budget"]
    claimed = claim.get("success_claim")
    events, bad = _events(a.dir)
    at_call = latch_call(a.dir, v)
    summary = [
        ("task", f"{r['task']} (seed {r['seed']}, attempt {r['attempt']})"),
        ("configuration", a.config), ("instruction", r.get("instruction", "")),
        ("verdict", "success" if v["success"] else "failure"),
        *([("verdict margin", _margin_line(v["margin"]))] if isinstance(v.get("margin"), dict) else []),
        ("claim", "absent" if claimed is None else ("success" if claimed else "failure")),
        ("report", claim.get("report") or ""),
        ("termination", f"{r['termination']['reason']}: {r['termination'].get('detail', '')}"),
        ("tool calls", f"{b.get('tool_calls_used')}/{b.get('tool_calls_limit')}"),
        ("simulated s", f"{b.get('sim_seconds_used')}/{b.get('sim_seconds_limit')}"),
        ("wall s", str((r.get("timing") or {}).get("wall_seconds"))),
    ]
    return _page(title=a.rel, heading=f"{r['task']} · {a.config} · attempt {r['attempt']}", finished=True,
                 summary=[(k, str(x)) for k, x in summary], **fork_links(a.dir, r.get("fork")), page_of=page_of, events_error=bad,
                 margins=_margins(v), verifier=_json(v),
                 checkpoints=_checkpoints(r.get("checkpoints"), v.get("latch"), at_call),
                 video=shown_file(a.dir, "video.mp4") is not None,
                 timeline=timeline(a.dir, events, r.get("checkpoints"), at_call))


def render_unfinished(d: Path, page_of: str = "view.html") -> str:
    """The page of an attempt without result.json (still running, or interrupted): what its
    event log holds so far. No verdict, checkpoints or video exist before the attempt ends."""
    events, bad = _events(d)
    start = next((e for e in events if e.get("kind") == "attempt_start"), {})
    c = start.get("config") or {}
    config = f"{c.get('model', '?')} ({c.get('harness', '?')}, {c.get('sim', '?')})"
    charged = sum(1 for e in events if e.get("kind") == "call" and e.get("charged", True))
    summary = [
        ("task", f"{start.get('task', '?')} (seed {start.get('seed', '?')}, attempt {start.get('attempt', '?')})"),
        ("configuration", config), ("instruction", start.get("instruction", "")),
        ("state", "unfinished: no result.json (still running, or interrupted)"),
        ("tool calls so far", charged), ("last event at wall s", events[-1].get("t_wall") if events else "–"),
    ]
    return _page(title=d.name, heading=f"{start.get('task', d.name)} · {config} · unfinished", finished=False,
                 summary=[(k, str(x)) for k, x in summary], **fork_links(d, c.get("fork")), page_of=page_of, events_error=bad,
                 timeline=timeline(d, events))


def attempts_below(root: Path) -> list[str]:
    """The attempt directories below ``root``, relative to it, sorted, as cab-report finds them."""
    return sorted(rel for _, rel, _ in attempt_dirs(root))


def check_attempt_dir(d: Path, show: int = 5) -> None:
    """RecordError, in one line, unless ``d`` is an attempt directory (result.json or
    events.jsonl): it does not exist, is a file, or is a sweep or tree whose attempts are named."""
    if not d.exists():
        raise RecordError(f"{d} does not exist")
    if not d.is_dir():
        raise RecordError(f"{d} is not a directory")
    if (d / "result.json").exists() or (d / "events.jsonl").exists():
        return
    below = attempts_below(d)
    if not below and (d / "sweep.json").exists():
        raise RecordError(f"{d} is a sweep directory, not an attempt, and none of its attempts has records yet")
    if not below:
        raise RecordError(f"{d}: result.json is missing: it is not an attempt directory, and no attempt is below it")
    names = ", ".join(below[:show]) + (f", ... ({len(below)} in all)" if len(below) > show else "")
    what = "is a sweep directory" if (d / "sweep.json").exists() else "holds attempt directories"
    raise RecordError(f"{d} {what}, not an attempt (no result.json); attempts: {names}")


def write_view(attempt_dir: Path) -> Path:
    """Write ``view.html`` into the attempt directory (finished or not); returns its path."""
    d = Path(attempt_dir)
    check_attempt_dir(d)
    if (d / "result.json").exists() or not (d / "events.jsonl").exists():
        html_text = render(Attempt.load(d))
    else:
        html_text = render_unfinished(d)
    page = d / "view.html"
    page.write_text(html_text)
    return page
