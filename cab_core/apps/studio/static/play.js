// cab-studio: the play page. A person makes the calls a model would make: one form per tool, built
// from the tool's JSON Schema; every result as the model gets it (payload and images), the budgets left.
"use strict";
const root = document.getElementById("play"), PID = root.dataset.id;
let INFO = null, TOOLS = {}, imageRounds = [], callCount = 0, ended = false;

function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") e.className = v; else if (v !== null && v !== undefined) e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k instanceof Node ? k : document.createTextNode(k == null ? "" : String(k)));
  return e;
}
function resolve(schema, defs) {
  let s = schema || {};
  if (s.$ref) s = Object.assign({}, defs[s.$ref.split("/").pop()] || {}, {description: s.description || (defs[s.$ref.split("/").pop()] || {}).description});
  if (s.anyOf) {
    const real = s.anyOf.filter(x => x.type !== "null");
    if (real.length === 1) s = Object.assign({}, resolve(real[0], defs), {description: s.description, default: s.default, title: s.title, nullable: true});
  }
  return s;
}
function kindOf(name, s) {
  if (s.enum) return "enum";
  if (s.type === "boolean") return "bool";
  if (s.type === "number" || s.type === "integer") return "number";
  if (s.type === "string") return (name === "code" || name === "report") ? "text" : (name === "obs_id" ? "obs" : "string");
  if (s.type === "array") {
    const it = s.items || {};
    if (it.type === "number" || it.type === "integer") {
      const pixel = s.minItems === 2 && s.maxItems === 2 && (/^px/.test(name) || /pixel/i.test(s.description || ""));
      return pixel ? "pixel" : "numbers";
    }
    if (it.type === "array" && name === "pixels") return "pixels";
    if (it.type === "string" || it.enum) return "strings";
  }
  return "json";
}
function fieldFor(name, raw, required, defs) {
  const s = resolve(raw, defs), kind = kindOf(name, s), id = "arg-" + name;
  let input;
  if (kind === "enum" || kind === "bool") {
    const opts = kind === "bool" ? ["true", "false"] : s.enum;
    input = el("select", {id, name, "data-kind": kind}, el("option", {value: ""}, required ? "(choose)" : "(default)"),
               ...opts.map(o => el("option", {value: String(o)}, String(o))));
  } else if (kind === "text" || kind === "json") {
    input = el("textarea", {id, name, "data-kind": kind, rows: name === "code" ? 14 : 3, spellcheck: "false"});
  } else {
    input = el("input", {id, name, "data-kind": kind, type: "text"});
  }
  const shape = {numbers: "numbers: 0.1, 0.2, 0.3 or [0.1, 0.2, 0.3]", pixel: "pixel u, v (click an image)",
                 pixels: "[[u, v], ...] (each click adds one)", strings: "a, b or [\"a\", \"b\"]", json: "JSON"}[kind];
  if (s.default !== undefined && s.default !== null) input.setAttribute("placeholder", "default " + JSON.stringify(s.default));
  else if (shape) input.setAttribute("placeholder", shape);
  return el("div", {class: "field"}, el("label", {for: id}, name + (required ? " *" : "")), " ", input,
            el("div", {class: "help"}, (s.description || "") + (shape ? ` (${shape})` : "")));
}
function showTool(name) {
  const t = TOOLS[name], p = t.parameters || {}, req = new Set(p.required || []), defs = p.$defs || {};
  document.getElementById("tool-description").textContent = t.description;
  document.getElementById("fields").replaceChildren(
    ...Object.entries(p.properties || {}).map(([k, v]) => fieldFor(k, v, req.has(k), defs)));
}
function parseList(v, number) {
  v = v.trim();
  if (v.startsWith("[")) { try { return JSON.parse(v); } catch (e) { return v; } }
  const parts = v.split(number ? /[\s,]+/ : /,/).map(x => x.trim()).filter(x => x !== "");
  return number ? parts.map(x => (isFinite(Number(x)) ? Number(x) : x)) : parts;
}
function collect() {
  const args = {};
  for (const f of document.querySelectorAll("#fields [data-kind]")) {
    const v = f.value, kind = f.dataset.kind;
    if (v.trim() === "") continue;
    if (kind === "number") args[f.name] = isFinite(Number(v)) ? Number(v) : v;
    else if (kind === "bool") args[f.name] = v === "true";
    else if (kind === "numbers" || kind === "pixel") args[f.name] = parseList(v, true);
    else if (kind === "strings") args[f.name] = parseList(v, false);
    else if (kind === "pixels" || kind === "json") { try { args[f.name] = JSON.parse(v); } catch (e) { args[f.name] = v; } }
    else args[f.name] = v;
  }
  return args;
}
function clickPixel(img, ev) {
  const r = img.getBoundingClientRect();
  const u = Math.min(img.naturalWidth - 1, Math.max(0, Math.floor((ev.clientX - r.left) * img.naturalWidth / r.width)));
  const v = Math.min(img.naturalHeight - 1, Math.max(0, Math.floor((ev.clientY - r.top) * img.naturalHeight / r.height)));
  const obs = document.querySelector('#fields [data-kind="obs"]');
  if (obs) obs.value = img.dataset.obs;
  const px = [...document.querySelectorAll('#fields [data-kind="pixel"]')];
  const target = px.find(f => f.value.trim() === "") || px[0];
  if (target) target.value = `${u}, ${v}`;
  const many = document.querySelector('#fields [data-kind="pixels"]');
  if (many) { let cur = []; try { cur = JSON.parse(many.value || "[]"); } catch (e) {} cur.push([u, v]); many.value = JSON.stringify(cur); }
  document.getElementById("clicked").textContent = `clicked ${img.dataset.obs} at u=${u}, v=${v}`;
}
function showBudget(b) {
  if (!b || b.tool_calls_remaining === undefined) return;
  document.getElementById("budget").replaceChildren(
    el("span", {id: "calls-left"}, `tool calls left: ${b.tool_calls_remaining} / ${b.tool_calls_limit}`), " · ",
    el("span", {id: "sim-left"}, `simulated seconds left: ${Number(b.sim_seconds_remaining).toFixed(2)} / ${b.sim_seconds_limit}`));
}
function addResult(tool, args, res) {
  callCount += 1;
  const payload = res.payload || {}, bad = payload.error != null || payload.ok === false;
  const card = el("div", {class: "result" + (bad ? " error" : ""), "data-tool": tool, "data-n": callCount},
    el("div", {}, el("b", {}, `${callCount}. ${tool}`), " ", bad ? el("span", {class: "bad"}, "error") :
       el("span", {class: payload.status && payload.status !== "SUCCESS" ? "bad" : "good"}, payload.status || "ok")),
    el("details", {}, el("summary", {}, "arguments"), el("pre", {}, JSON.stringify(args, null, 1))),
    el("pre", {class: "payload"}, JSON.stringify(payload, null, 1)));
  if (res.images && res.images.length) {
    const box = el("div", {class: "images"});
    for (const im of res.images) {
      const img = el("img", {class: "obs", src: im.url, "data-obs": im.obs_id, alt: im.obs_id, title: im.obs_id + " (click a pixel)"});
      img.addEventListener("click", ev => clickPixel(img, ev));
      box.append(el("div", {class: "caption"}, `[image ${im.obs_id}]`), img);
    }
    card.append(box);
    imageRounds.push(box);
    const keep = (INFO && INFO.max_image_rounds) || 2;
    while (imageRounds.length > keep) {  // as a model's context keeps them: older images by id only
      const old = imageRounds.shift();
      const ids = [...old.querySelectorAll("img")].map(i => i.dataset.obs);
      old.replaceChildren(el("div", {class: "gone"}, `images ${ids.join(", ")}: no longer shown (older than the last ${keep} results with images); look again by id`));
    }
  }
  document.getElementById("results").prepend(card);
}
function finish(status) {
  ended = true;
  document.getElementById("call").disabled = true;
  const st = document.getElementById("state");
  if (status && status.attempt_url) {
    st.replaceChildren("The attempt has ended. ", el("a", {href: status.attempt_url, id: "result-link"}, "See the result"));
    setTimeout(() => { location.href = status.attempt_url; }, 1500);
  } else if (status && status.state === "failed") {
    st.replaceChildren(el("span", {class: "bad"}, "The attempt failed: " + (status.error || "")));
  } else {
    st.textContent = "The attempt has ended; writing its records…";
    setTimeout(poll, 1000);
  }
}
async function call(ev) {
  ev.preventDefault();
  if (ended) return;
  const tool = document.getElementById("tool").value, args = collect(), btn = document.getElementById("call");
  btn.disabled = true; document.getElementById("busy").hidden = false;
  try {
    const r = await fetch(`/api/play/${PID}/call`, {method: "POST", headers: {"Content-Type": "application/json"},
                                                 body: JSON.stringify({tool, args})});
    const res = await r.json();
    if (res.payload !== undefined) addResult(tool, args, res);
    showBudget(res.budget);
    if (res.ended) finish(res.status);
    else document.getElementById("state").textContent = `Playing: ${callCount} call(s) made.`;
  } finally {
    document.getElementById("busy").hidden = true;
    if (!ended) btn.disabled = false;
  }
}
function setup(info) {
  INFO = info;
  document.getElementById("system-prompt").textContent = info.system_prompt;
  document.getElementById("instruction").textContent = info.instruction;
  const sel = document.getElementById("tool");
  for (const t of info.tools) { TOOLS[t.name] = t; sel.append(el("option", {value: t.name}, t.name)); }
  sel.addEventListener("change", () => showTool(sel.value));
  showTool(sel.value);
  document.getElementById("call-form").addEventListener("submit", call);
  document.getElementById("call-form").append(el("p", {id: "clicked", class: "hint"}));
}
async function poll() {
  const r = await fetch(`/api/play/${PID}`); const s = await r.json();
  if (s.state === "failed") return finish(s);
  if (s.ready && !INFO) {
    setup(s.info);
    document.getElementById("state").textContent = `Playing: ${s.calls} call(s) made.`;
  }
  showBudget(s.budget);
  if (s.ended || s.state === "finished") return finish(s);
  setTimeout(poll, s.ready ? 3000 : 1000);  // while playing: an ending without a call (the wall-clock budget) shows
}
poll();
