// ersac-hil dashboard page: server-sent events in, Plotly out, JSON posts for the controls.
// window.dashboard exposes the page's data (tests and bench/dashboard.py read it):
//   points: every learner episode shown; latency: per episode, when it was drawn.
"use strict";

const D = {
  seq: 0, robot: "", readOnly: true, task: null, state: null, learnerNote: "",
  points: [], means: [], marks: [], critic: null, criticNote: "", agentAlive: null, agentPhase: null, agentDetail: "",
  lastFault: "", latency: [], curveDrawn: false, selection: null,
};
window.dashboard = D;

const $ = (id) => document.getElementById(id);
const fmt = (x, d = 4) => (x === null || x === undefined ? "-" : Number(x).toFixed(d));
const vec = (v, d = 4) => "[" + v.map((x) => fmt(x, d)).join(", ") + "]";
const BLUE = "#1f5fa8", RED = "#c62828", GREY = "#7d8790", ORANGE = "#e07b00";
const MEAN_COLORS = ["#2a7f62", "#6a3d9a", "#1f78b4", "#b15928", "#33a02c", "#8c564b", "#17becf"];
const LEGEND = { orientation: "h", x: 0, xanchor: "left", y: 1.02, yanchor: "bottom" };
const PLOT_CONFIG = { displaylogo: false, responsive: true };

// ------------------------------------------------------------------ learning curve
const T_OK = 0, T_DAMAGE = 1, T_FAILED = 2, T_MEAN = 3;

function pointXY(p) {
  const x = p.index + 1;
  if (p.status !== "ok") return [T_FAILED, x, 0.04, `episode ${x}: ${p.status}${p.detail ? " - " + p.detail : ""}`];
  return [p.damage ? T_DAMAGE : T_OK, x, p.cost, `episode ${x}: cost ${fmt(p.cost)}${p.damage ? " (damage)" : ""}`];
}

function curveTraces() {
  const traces = [
    { name: "cost", mode: "markers", marker: { color: BLUE, size: 7 }, x: [], y: [], text: [], hoverinfo: "text" },
    { name: "hardware damage", mode: "markers", marker: { color: RED, size: 9, symbol: "diamond" }, x: [], y: [], text: [], hoverinfo: "text" },
    { name: "failed attempt", mode: "markers", marker: { color: GREY, size: 9, symbol: "x" }, yaxis: "y3", x: [], y: [], text: [], hoverinfo: "text" },
  ];
  for (const p of D.points) {
    const [t, x, y, text] = pointXY(p);
    traces[t].x.push(x); traces[t].y.push(y); traces[t].text.push(text);
  }
  const params = D.task ? D.task.params : [];
  params.forEach((name, i) => {
    traces.push({
      name: `mean ${name}`, mode: "lines+markers", xaxis: "x", yaxis: "y2",
      line: { shape: "hv", color: MEAN_COLORS[i % MEAN_COLORS.length] },
      marker: { size: 4 }, x: D.means.map((m) => m[0] + 1), y: D.means.map((m) => m[1][i]),
    });
  });
  return traces;
}

function curveLayout() {
  const shapes = [], annotations = [];
  for (const [k, kappa] of D.marks) {
    shapes.push({ type: "line", xref: "x", yref: "paper", x0: k + 0.5, x1: k + 0.5, y0: 0, y1: 1, line: { color: ORANGE, dash: "dot", width: 1.5 } });
    annotations.push({ xref: "x", yref: "paper", x: k + 0.5, y: 1, yanchor: "top", xanchor: "left", showarrow: false, text: `κ=${kappa}`, font: { color: ORANGE, size: 11 } });
  }
  return {
    margin: { l: 60, r: 20, t: 40, b: 40 }, showlegend: true, legend: LEGEND,
    xaxis: { title: { text: "episode" }, anchor: "y2", rangemode: "tozero" },
    yaxis: { title: { text: "cost" }, domain: [0.38, 1] },
    yaxis2: { title: { text: "policy mean" }, domain: [0, 0.28] },
    yaxis3: { overlaying: "y", range: [0, 1], visible: false, fixedrange: true },
    shapes, annotations, uirevision: "curve",
  };
}

function renderCurve() {
  D.curveDrawn = true;
  return Plotly.react($("curve"), curveTraces(), curveLayout(), PLOT_CONFIG);
}

function onEpisode(data) {
  const received = performance.timeOrigin + performance.now();
  const p = data.point;
  D.points.push(p);
  const [t, x, y, text] = pointXY(p);
  const drawn = D.curveDrawn
    ? Plotly.extendTraces($("curve"), { x: [[x]], y: [[y]], text: [[text]] }, [t])
    : renderCurve();
  Promise.resolve(drawn).then(() => requestAnimationFrame(() => {
    D.latency.push({ episode_id: p.episode_id, index: p.index, status: p.status, stamp_s: p.stamp_s,
                     received_ms: received, shown_ms: performance.timeOrigin + performance.now() });
  }));
}

// ------------------------------------------------------------------ critic
function renderCritic() {
  $("critic-note").textContent = D.criticNote ? `(${D.criticNote})` : D.critic ? `after update ${D.critic.episode_count}, κ=${D.critic.kappa}` : "";
  const c = D.critic;
  if (!c) {
    return Plotly.react($("critic"), [], { margin: { t: 10 }, xaxis: { visible: false }, yaxis: { visible: false },
      annotations: [{ text: D.criticNote || "no critic yet", showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.5 }] }, PLOT_CONFIG);
  }
  const n = c.slices.length, cols = Math.min(n, 4), rows = Math.ceil(n / cols);
  const height = Math.max(360, rows * 300);
  const traces = [], layout = {
    margin: { l: 60, r: 20, t: 40, b: 50 }, showlegend: true, legend: LEGEND, height,
    grid: { rows, columns: cols, pattern: "independent", ygap: 0.45, xgap: 0.12 }, shapes: [], uirevision: "critic",
  };
  c.slices.forEach((s, i) => {
    const k = i === 0 ? "" : String(i + 1), first = i === 0;
    const lo = s.J.map((j, m) => j - 2 * s.r[m]), hi = s.J.map((j, m) => j + 2 * s.r[m]);
    const axes = { xaxis: "x" + k, yaxis: "y" + k };
    traces.push({ ...axes, x: s.x, y: lo, mode: "lines", line: { width: 0 }, hoverinfo: "skip", showlegend: false, legendgroup: "band" });
    traces.push({ ...axes, x: s.x, y: hi, mode: "lines", line: { width: 0 }, fill: "tonexty", fillcolor: "rgba(31,95,168,0.18)",
                  name: "J~ ± 2 r~", legendgroup: "band", showlegend: first, hoverinfo: "skip" });
    traces.push({ ...axes, x: s.x, y: s.J, mode: "lines", line: { color: BLUE, width: 2 }, name: "J~", legendgroup: "J", showlegend: first });
    traces.push({ ...axes, x: s.x, y: s.F, mode: "lines", line: { color: ORANGE, width: 2, dash: "dash" }, name: `F~ (κ=${c.kappa})`, legendgroup: "F", showlegend: first });
    traces.push({ ...axes, x: s.obs_x, y: s.obs_y, mode: "markers", marker: { color: GREY, size: 5, opacity: 0.7 }, name: "observations", legendgroup: "obs", showlegend: first });
    layout["xaxis" + k] = { title: { text: s.name }, range: [s.lower, s.upper] };
    layout["yaxis" + k] = { title: { text: i % cols === 0 ? "cost" : "" } };
    layout.shapes.push({ type: "line", xref: "x" + k, yref: `y${k} domain`, x0: s.at, x1: s.at, y0: 0, y1: 1, line: { color: RED, width: 1.5, dash: "dot" } });
  });
  $("critic").style.height = `${height}px`;
  return Plotly.react($("critic"), traces, layout, PLOT_CONFIG);
}

// ------------------------------------------------------------------ state panel
function renderState() {
  const s = D.state;
  $("robot").textContent = D.robot;
  $("mode").textContent = D.readOnly ? "read-only" : "";
  $("s-run").textContent = s ? s.run_id : D.learnerNote || "-";
  $("s-task").textContent = s ? s.task : "-";
  $("s-status").textContent = !s ? "-" : D.learnerNote ? `${s.status} when last seen; now: ${D.learnerNote}` : s.status;
  $("s-episodes").textContent = s ? s.episode_count : "-";
  $("s-kappa").textContent = s ? s.kappa : "-";
  $("s-theta").textContent = s ? vec(s.theta) : "-";
  $("s-weights").textContent = s ? Object.entries(s.weights).map(([k, v]) => `${k} ${v}`).join(", ") : "-";
  $("s-fault").textContent = D.lastFault || "none";
  renderAgent();
  if (!D.readOnly) syncControls();
}

function renderAgent() {
  const phase = D.agentPhase ? D.agentPhase.replaceAll("_", " ") : null;
  const text = D.agentAlive === null ? "?" : D.agentAlive ? (phase || "alive") : "absent";
  const a = $("agent");
  a.textContent = `agent ${text}`;
  a.className = "badge " + (D.agentAlive && D.agentPhase !== "stopped" && D.agentPhase !== "uncommissioned" ? "on" : "off");
  $("s-agent").textContent = D.agentDetail ? `${text}: ${D.agentDetail}` : text;
}

function addNotice(level, text) {
  const li = document.createElement("li");
  li.textContent = text;
  li.className = level;
  const list = $("notices");
  list.prepend(li);
  while (list.children.length > 5) list.lastChild.remove();
}

// ------------------------------------------------------------------ controls
const dirty = new Set();

function showMessage(text, ok) {
  const m = $("message");
  m.textContent = text;
  m.className = ok ? "ok" : "error";
}

function numberOrNull(text) {
  return text.trim() === "" ? null : Number(text);  // NaN is sent as null: refused by the server
}

async function post(path, body) {
  let response, reply;
  try {
    response = await fetch(path, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
    reply = await response.json();
  } catch (err) {
    showMessage(`${path}: ${err}`, false);
    return null;
  }
  if (!response.ok) {
    const e = reply.error || {};
    showMessage(`refused (${e.code || response.status}): ${e.reason || response.statusText}`, false);
    return null;
  }
  return reply;
}

function syncControls() {
  const s = D.state;
  if (!s) return;
  if (!dirty.has("kappa")) { $("kappa-slider").value = s.kappa; $("kappa-number").value = s.kappa; }
  if (!dirty.has("select")) $("select-kappa").value = s.kappa;
  const box = $("weights");
  if (box.dataset.task !== s.task) {
    box.replaceChildren();
    for (const name of Object.keys(s.weights)) {
      const label = document.createElement("label");
      const input = document.createElement("input");
      Object.assign(input, { type: "number", min: "0", step: "any", id: `weight-${name}` });
      input.dataset.term = name;
      input.addEventListener("input", () => dirty.add("weights"));
      label.append(`${name} `, input);
      box.append(label);
    }
    box.dataset.task = s.task;
  }
  if (!dirty.has("weights")) for (const [name, w] of Object.entries(s.weights)) $(`weight-${name}`).value = w;
}

async function setKappa(text) {
  const kappa = numberOrNull(text);
  const state = await post("/api/kappa", { kappa });
  dirty.delete("kappa");
  if (state) showMessage(`kappa set to ${state.kappa}`, true);
  syncControls();
}

async function setWeights() {
  const weights = {};
  for (const input of $("weights").querySelectorAll("input")) {
    const value = numberOrNull(input.value);
    if (!D.state || value !== D.state.weights[input.dataset.term]) weights[input.dataset.term] = value;
  }
  if (!Object.keys(weights).length) { showMessage("no weight changed", true); return; }
  const state = await post("/api/weights", { weights });
  if (state) {
    dirty.delete("weights");
    showMessage(`weights set: ${Object.entries(state.weights).map(([k, v]) => `${k} ${v}`).join(", ")}`, true);
  }
}

function showSelection(reply) {
  D.selection = reply;
  $("sel-theta").textContent = vec(reply.theta);
  $("sel-J").textContent = fmt(reply.J);
  $("sel-r").textContent = fmt(reply.r);
  $("sel-F").textContent = `${fmt(reply.F)} (κ=${reply.kappa})`;
  $("selection").hidden = false;
}

async function select() {
  const reply = await post("/api/select", { kappa: numberOrNull($("select-kappa").value) });
  if (reply) { showSelection(reply); showMessage(`selected theta ${vec(reply.theta)} for κ=${reply.kappa}`, true); }
}

async function adopt() {
  if (!D.selection) return;
  const reply = await post("/api/adopt", { kappa: D.selection.kappa });
  if (reply) { showSelection(reply); dirty.delete("select"); showMessage(`adopted theta ${vec(reply.theta)}`, true); }
}

function wireControls() {
  const slider = $("kappa-slider"), number = $("kappa-number");
  slider.addEventListener("input", () => { dirty.add("kappa"); number.value = slider.value; });
  slider.addEventListener("change", () => setKappa(slider.value));
  number.addEventListener("input", () => { dirty.add("kappa"); slider.value = number.value; });
  // a state refresh must not refill the field while someone edits it (clearing it fires no input)
  number.addEventListener("focus", () => dirty.add("kappa"));
  number.addEventListener("blur", () => {  // left as it was: follow the learner again
    if (D.state && number.value !== "" && Number(number.value) === D.state.kappa) dirty.delete("kappa");
  });
  number.addEventListener("keydown", (e) => { if (e.key === "Enter") setKappa(number.value); });
  $("kappa-apply").addEventListener("click", () => setKappa(number.value));
  $("weights-apply").addEventListener("click", setWeights);
  $("select-kappa").addEventListener("input", () => dirty.add("select"));
  $("select").addEventListener("click", select);
  $("adopt").addEventListener("click", adopt);
}

// ------------------------------------------------------------------ events
function applyState(data) {
  D.state = data.state; D.task = data.task; D.learnerNote = data.learner_note;
  D.means = data.means; D.marks = data.kappa_marks;
}

const handlers = {
  snapshot(data) {
    D.robot = data.robot; D.readOnly = data.read_only; applyState(data);
    D.points = data.points; D.critic = data.critic; D.criticNote = data.critic_note;
    D.agentAlive = data.agent_alive; D.lastFault = data.last_fault;
    D.agentPhase = data.agent_phase; D.agentDetail = data.agent_detail;
    renderState(); renderCurve(); renderCritic();
  },
  episode: onEpisode,
  curve(data) { D.points = data.points; renderCurve(); },
  state(data) { applyState(data); renderState(); renderCurve(); },
  critic(data) { D.critic = data.critic; D.criticNote = data.critic_note; renderCritic(); },
  agent(data) {
    if (data.alive !== null && data.alive !== undefined) D.agentAlive = data.alive;
    D.agentPhase = data.phase; D.agentDetail = data.detail; renderAgent();
  },
  fault(data) { D.lastFault = data.last_fault; $("s-fault").textContent = D.lastFault; },
  notice(data) { addNotice(data.level, data.text); },
};

function connect() {
  const source = new EventSource("/api/events");
  const badge = $("connection");
  source.onopen = () => { badge.textContent = "live"; badge.className = "badge on"; };
  source.onerror = () => { badge.textContent = "reconnecting"; badge.className = "badge off"; };
  for (const [kind, handle] of Object.entries(handlers)) {
    source.addEventListener(kind, (e) => {
      const data = JSON.parse(e.data);
      if (kind !== "snapshot" && data.seq <= D.seq) return;
      D.seq = data.seq;
      handle(data);
    });
  }
}

if ($("controls")) wireControls();
connect();
