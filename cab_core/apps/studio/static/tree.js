// cab-studio: the tree page and a group's page, polled every 2 s (no reload).
"use strict";
const POLL_MS = 2000;
function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) { if (k === "class") e.className = v; else e.setAttribute(k, v); }
  for (const k of kids) e.append(k instanceof Node ? k : document.createTextNode(k == null ? "" : String(k)));
  return e;
}
function hms(s) {
  if (s == null) return "–";
  s = Math.round(s); const h = Math.floor(s / 3600), m = Math.floor(s % 3600 / 60), x = s % 60;
  return `${h}:${String(m).padStart(2, "0")}:${String(x).padStart(2, "0")}`;
}
function cell(cls, v) { return el("td", {class: cls}, v); }
async function pollTree() {
  const r = await fetch("/api/tree"); if (!r.ok) return;
  const data = await r.json();
  const body = document.querySelector("#groups tbody");
  body.replaceChildren(...data.groups.map(g => {
    const link = el("a", {href: "/group?rel=" + encodeURIComponent(g.rel), class: "group-link"}, g.name || g.rel);
    const rep = el("a", {href: "/report?rel=" + encodeURIComponent(g.rel), class: "report-link"}, "report");
    const tr = el("tr", {"data-rel": g.rel}, el("td", {}, link), cell("kind", g.kind), cell("done", g.done),
      cell("success", g.success), cell("running", g.running), cell("infra", g.infra),
      cell("not_started", g.kind === "sweep" ? g.not_started : "–"), cell("planned", g.planned == null ? "–" : g.planned),
      cell("extra", g.kind === "sweep" ? g.extra : "–"), cell("eta", g.running ? hms(g.eta_s) : (g.kind === "sweep" && g.not_started ? "stopped" : "–")),
      el("td", {}, rep));
    return tr;
  }));
  document.getElementById("empty").hidden = data.groups.length > 0;
  const plays = document.getElementById("plays");
  if (data.plays.length) plays.replaceChildren(...data.plays.map(p => el("li", {},
    el("a", {href: p.attempt_url || "/play/" + p.id}, `${p.task} (${p.sim}, seed ${p.seed}) by ${p.handle}`), ` · ${p.state}`)));
}
async function pollGroup(rel) {
  const r = await fetch("/api/group?rel=" + encodeURIComponent(rel)); if (!r.ok) return;
  const g = await r.json();
  const row = document.querySelector("#summary tr:nth-child(2)");
  const set = (c, v) => { row.querySelector("." + c).textContent = v; };
  set("done", g.done); set("success", g.success); set("running", g.running); set("infra", g.infra);
  set("not_started", g.kind === "sweep" ? g.not_started : "–"); set("planned", g.planned == null ? "–" : g.planned);
  set("extra", g.kind === "sweep" ? g.extra : "–"); set("eta", g.running ? hms(g.eta_s) : "–");
  const base = rel === "." ? "" : rel + "/";
  document.querySelector("#attempts tbody").replaceChildren(...g.attempts.map(a => {
    const verdict = a.state === "done" ? (a.success ? "success" : "failure") : "–";
    return el("tr", {"data-rel": a.rel}, el("td", {}, el("a", {href: "/attempt/" + base + a.rel + "/", class: "attempt-link"}, a.rel)),
      cell("config", a.config), cell("state " + (a.stale ? "stale" : ""), a.state + (a.stale ? " (stale)" : "") + (a.why ? ` (not scored: ${a.why})` : "")),
      cell("verdict " + (a.success ? "good" : (a.state === "done" ? "bad" : "")), verdict));
  }));
}
function loop(f) { f().catch(() => {}).finally(() => setTimeout(() => loop(f), POLL_MS)); }
if (document.getElementById("groups")) loop(pollTree);
const title = document.getElementById("title");
if (title && title.dataset.rel !== undefined && document.getElementById("attempts")) loop(() => pollGroup(title.dataset.rel));
