"""``cab-view <attempt dir>``: one HTML page per attempt, from its records.

The page (``view.html`` in the attempt directory) shows the instruction, the verdict beside the
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
import sys
from html import escape
from pathlib import Path

from cab_core.analysis.records import Attempt, attempt_dirs, read_jsonl
from cab_core.errors import CabError, RecordError

def _json(obj) -> str:
    return escape(json.dumps(obj, indent=1))


def _fold(label: str, body: str) -> str:
    return f"<details><summary>{escape(label)}</summary>{body}</details>"


def _images(d: Path, obs_ids) -> str:
    out = []
    for o in obs_ids or []:
        rel = f"observations/{o}.png"
        if (d / rel).exists():
            out.append(f'<a href="{escape(rel)}"><img class="obs" src="{escape(rel)}" alt="{escape(o)}" title="{escape(o)}"></a>')
    return "".join(out)


def _status(ev: dict) -> str:
    r = ev.get("result") or {}
    s = ev.get("status") or r.get("status")
    if ev.get("tool") == "run_code":
        s = "ok" if r.get("ok") else ("ABORTED" if r.get("status") == "ABORTED" else "error")
    elif s is None:
        s = "error" if "error" in r else "ok"
    cls = "good" if s in ("SUCCESS", "ok") else "bad"
    return f'<span class="{cls}">{escape(str(s))}</span>'


def _call(d: Path, ev: dict, internal: bool, charged_index: int | None) -> str:
    r = ev.get("result") or {}
    head = (f"<b>{'↳ ' if internal else ''}{escape(str(ev.get('tool')))}</b> {_status(ev)}"
            + (f" · charged call {charged_index}" if charged_index else "")
            + f" · #{ev.get('seq')} · t={ev.get('t_wall', 0):.1f}s")
    if ev.get("physics_steps"):
        head += f" · {ev['physics_steps']} physics steps"
    if ev.get("charged") is False:
        head += " · not charged"
    body = [f"<div>{head}</div>"]
    args = dict(ev.get("arguments") or {})
    code = args.pop("code", None) if ev.get("tool") == "run_code" else None
    if code is not None:
        body.append(f"<div>program <code>{escape(str(r.get('program', '')))}</code></div><pre>{escape(code)}</pre>")
        for key in ("error", "stdout"):
            if r.get(key):
                body.append(f"<div>{key}:</div><pre>{escape(str(r[key]))}</pre>")
    if args:
        body.append(_fold("arguments", f"<pre>{_json(args)}</pre>"))
    body.append(_fold("result the agent saw", f"<pre>{_json(r)}</pre>"))
    body.append(_images(d, ev.get("obs_ids")))
    return f'<div class="call{" internal" if internal else ""}">{"".join(body)}</div>'


def _turn(ev: dict) -> str:
    u = ev.get("usage") or {}
    cost = (ev.get("cost") or {}).get("usd")
    head = (f"<b>model turn {ev.get('turn')}</b> · {escape(str(ev.get('model', '')))} · "
            f"{u.get('input_tokens', 0)} in / {u.get('output_tokens', 0)} out tokens"
            + (f" · ${cost:.4f}" if isinstance(cost, (int, float)) else "")
            + f" · latency {ev.get('latency_s', 0)}s, waited {ev.get('waited_s', 0)}s")
    body = [f"<div>{head}</div>"]
    if ev.get("thinking"):
        body.append(_fold("thinking", f"<pre>{escape(ev['thinking'])}</pre>"))
    if ev.get("text"):
        body.append(f"<pre>{escape(ev['text'])}</pre>")
    return f'<div class="turn">{"".join(body)}</div>'


def matched_at(ck) -> dict[int, list[str]]:
    """Charged-call index -> the checkpoints first matched by then (from the result's checkpoints)."""
    out: dict[int, list[str]] = {}
    if not isinstance(ck, dict) or "error" in ck:
        return out
    for kind in ("subgoals", "spatial"):
        for c in ck.get(kind, []):
            k = (c.get("first") or {}).get("calls")
            if c.get("attained") and isinstance(k, int):
                what = c.get("text", "") if kind == "subgoals" else c.get("name", "")
                label = f"{'subgoal' if kind == 'subgoals' else 'spatial'} {c['index']}: {what}"
                out.setdefault(k, []).append(label)
    return out


def timeline(d: Path, events: list[dict], ck=None) -> str:
    """The events in order, each checkpoint marked after the charged call that first matched it.
    A program's internal calls are shown just before its run_code entry (they are logged as they
    happen, the program's own entry when it returns)."""
    out = []
    marks = matched_at(ck)
    charged = 0
    for ev in events:
        kind = ev.get("kind")
        if kind in ("call", "internal_call", "call_refused"):
            index = None
            if kind == "call" and ev.get("charged", True):
                charged += 1
                index = charged
            out.append(_call(d, ev, internal=(kind == "internal_call"), charged_index=index))
            out += [f'<div class="mark">✓ checkpoint {escape(m)}</div>' for m in marks.get(index, [])]
        elif kind == "model_turn":
            out.append(_turn(ev))
        elif kind not in ("attempt_start",):
            rest = {k: v for k, v in ev.items() if k not in ("seq", "kind", "t_wall")}
            out.append(f'<div class="call"><b>{escape(str(kind))}</b> #{ev.get("seq")}'
                       f'{_fold("details", f"<pre>{_json(rest)}</pre>") if rest else ""}</div>')
    return "".join(out)


def _checkpoints(ck) -> str:
    if not isinstance(ck, dict) or "error" in ck:
        return f"<p>checkpoints unavailable{': ' + escape(str(ck.get('error'))) if isinstance(ck, dict) else ''}</p>"
    rows = []
    for kind in ("subgoals", "spatial"):
        for c in ck.get(kind, []):
            first = c.get("first") or {}
            rows.append(f"<tr><td>{kind[:-1] if kind == 'subgoals' else 'spatial'} {c['index']}</td>"
                        f"<td>{escape(c.get('text') or c.get('name', ''))}</td>"
                        f"<td class=\"{'good' if c['attained'] else 'bad'}\">{'attained' if c['attained'] else 'not attained'}</td>"
                        f"<td>{escape(str(first.get('calls', '')) if first else '')}</td>"
                        f"<td>{escape(str(first.get('arm', '')) if first else '')}</td></tr>")
    return (f"<p>subgoal coverage {ck.get('subgoal_coverage', 0):.0%}, spatial coverage {ck.get('spatial_coverage', 0):.0%}</p>"
            "<table><tr><th>checkpoint</th><th>what</th><th>outcome</th><th>first at call</th><th>arm</th></tr>"
            + "".join(rows) + "</table>")


def _margin_line(m: dict) -> str:
    if m.get("fraction") is None:
        return "no thresholded predicate decided it"
    return (f"{'BORDERLINE: ' if m['borderline'] else ''}{m['fraction']:.1%} of its tolerance ({m['predicate']}; "
            f"borderline below {m['threshold']:.0%})")


def _margins(v: dict) -> str:
    """Each predicate's margin: how far inside (+) or outside (-) its threshold, in its unit and as
    a fraction of its tolerance."""
    ms = v.get("margins")
    if not isinstance(ms, dict) or not ms:
        return ""

    def g(x) -> str:
        return "" if x is None else f"{x:.4g}"

    rows = "".join(f"<tr><td>{escape(k)}</td><td class=\"{'good' if m['slack'] > 0 else 'bad'}\">{m['slack']:+.4g} "
                   f"{escape(m['unit'])}</td><td>{m['fraction']:+.1%}</td><td>{g(m.get('measured'))}</td>"
                   f"<td>{g(m.get('threshold'))}</td></tr>" for k, m in ms.items())
    return (f"<p>margins measured at the {escape(str(v.get('margins_at', 'end')))}</p><table><tr><th>predicate</th>"
            "<th>margin</th><th>of tolerance</th><th>measured</th><th>threshold</th></tr>" + rows + "</table>")


def _page_link(rel: str) -> str:
    """The page of the attempt folder ``rel`` (relative to this one), as a link target."""
    return escape(rel.rstrip("/") + "/view.html")


def fork_rows(d: Path, fork: dict | None) -> str:
    """Table rows linking an attempt to the attempt it was forked from (``fork``: its ``result.json``
    or configuration's ``{parent, at}``) and to the forks made of it (its ``forks.jsonl``)."""
    from cab_core.attempt.fork import forks_of

    out = ""
    if isinstance(fork, dict) and isinstance(fork.get("parent"), str):
        at = fork.get("at")
        out += (f'<tr><th>fork of</th><td><a class="fork-parent" href="{_page_link(fork["parent"])}">'
                f'{escape(fork["parent"])}</a> · fork at call {escape(str(at))}</td></tr>')
    children = {f["child"]: f for f in forks_of(d)}  # a fork made again into the same folder: once
    if children:
        items = "".join(f'<li><a class="fork-child" href="{_page_link(c)}">{escape(c)}</a> · fork at call '
                        f'{escape(str(f.get("at")))}{_fork_outcome(d / c)}</li>'
                        for c, f in sorted(children.items(), key=lambda kv: (
                            kv[1].get("at") if isinstance(kv[1].get("at"), int) else -1, kv[0])))
        out += f"<tr><th>forks</th><td><ul>{items}</ul></td></tr>"
    return out


def _fork_outcome(child: Path) -> str:
    """`` · <model> · success`` (or failure, or unfinished) for a fork's folder."""
    try:
        r = json.loads((child / "result.json").read_text())
        return f" · {escape(str(r.get('model')))} · {'success' if (r.get('verdict') or {}).get('success') else 'failure'}"
    except (OSError, ValueError, AttributeError):
        return " · unfinished"


def _events(d: Path) -> tuple[list[dict], str]:
    """The event log, and a table row saying what is wrong with it when it cannot be read."""
    try:
        return read_jsonl(d / "events.jsonl"), ""
    except CabError as e:
        return [], f"<tr><th>events</th><td class='bad'>{escape(str(e))}</td></tr>"


def _page(title: str, heading: str, summary: list[tuple[str, object]], extra_rows: str,
          sections: list[tuple[str, str]]) -> str:
    """The page (``templates/attempt.html.j2``): the summary table (``extra_rows``: rows made here,
    escaped), then each section (heading, HTML made here)."""
    from cab_core.analysis.pages import Markup, render

    return render("attempt.html.j2", title=title, heading=heading, summary=[(k, str(v)) for k, v in summary],
                  extra_rows=Markup(extra_rows), sections=[(h, Markup(b)) for h, b in sections])


def render(a: Attempt) -> str:
    """The page of a finished attempt."""
    r = a.result
    v, claim, b = r["verdict"], r["claim"], r["budget"]
    claimed = claim.get("success_claim")
    events, bad = _events(a.dir)
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
    video = ('<video src="video.mp4" controls width="480"></video>' if (a.dir / "video.mp4").exists()
             else "<p>no video recorded</p>")
    return _page(a.rel, f"{r['task']} · {a.config} · attempt {r['attempt']}", summary,
                 fork_rows(a.dir, r.get("fork")) + bad,
                 [("Verdict details", f"{_margins(v)}{_fold('verifier record', f'<pre>{_json(v)}</pre>')}"),
                  ("Checkpoints", _checkpoints(r.get("checkpoints"))), ("Video", video),
                  ("Timeline", timeline(a.dir, events, r.get("checkpoints")))])


def render_unfinished(d: Path) -> str:
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
    return _page(d.name, f"{start.get('task', d.name)} · {config} · unfinished", summary,
                 fork_rows(d, c.get("fork")) + bad, [("Timeline so far", timeline(d, events))])


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


def main(argv: list[str] | None = None) -> None:
    import argparse

    ap = argparse.ArgumentParser(prog="cab-view", description="Write view.html for one attempt directory.")
    ap.add_argument("dir", help="an attempt directory (finished, running or interrupted)")
    a = ap.parse_args(argv)
    try:
        page = write_view(Path(a.dir))
    except CabError as e:
        print(f"cab-view: {e}", file=sys.stderr)
        sys.exit(2)
    print(page)
