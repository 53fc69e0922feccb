// carfeel live panel: one client of the panel's JSON + WebSocket API (README, "The live panel").
// Plain canvas, no library, no build step.
"use strict";

// The credential comes in the URL's fragment (#token=T: a browser never sends a fragment to a
// server), is kept in this tab's sessionStorage (this origin's only: another server on
// 127.0.0.1 has another port, so another origin) and leaves the address bar and the history at
// once. Every request sends it in a header; never in a URL, never in a cookie.
const TOKEN = (() => {
  const given = new URLSearchParams(location.hash.slice(1)).get("token");
  if (given) {
    sessionStorage.setItem("carfeel-token", given);
    history.replaceState(null, "", location.pathname + location.search);
  }
  return sessionStorage.getItem("carfeel-token");
})();
const KEEP = 8000;          // rows kept (8 s at 1 kHz)
const WINDOW_S = 4.0;       // time plots show the last 4 s
const TRAIL_S = 2.5;        // the knob's path on the H-pattern
const STAGE_COLORS = {
  neutral: "#5c6773", synchronization: "#e5534b", gate_open: "#d29922", engagement: "#f0883e",
  free_travel: "#3fb950", stop: "#a371f7", in_gear: "#4aa3ff", returning: "#8b98a5",
};
const TERM_COLORS = {   // the paper's law's terms, then the physical model's own
  torque_aligning_Nm: "#4aa3ff", torque_tire_spin_Nm: "#d29922", torque_friction_Nm: "#a371f7",
  torque_damping_Nm: "#3fb950", torque_stop_Nm: "#e5534b", torque_jacking_Nm: "#f778ba",
  torque_park_Nm: "#d29922", torque_inertia_Nm: "#8b98a5", torque_assist_Nm: "#56d4dd",
};
const TERM_LABELS = {
  torque_aligning_Nm: "aligning", torque_tire_spin_Nm: "tire spin", torque_friction_Nm: "friction",
  torque_damping_Nm: "damping", torque_stop_Nm: "lock", torque_jacking_Nm: "jacking",
  torque_park_Nm: "dry park", torque_inertia_Nm: "rim inertia", torque_assist_Nm: "assist",
};

let options = null;
let session = { state: "idle" };
let buf = {};
let engagement = null;       // {x: [], f: [], ff: []} of the engagement under way (or the last)
let lastStage = null;
let dirty = true;
let socket = null;
window.panelStats = { frames: 0, rows: 0, lost: 0 };   // what this page received (benchmarks)

// -- the API ------------------------------------------------------------------------------------
const NO_TOKEN = "no credential: open the URL carfeel panel printed (http://...#token=...)";
function authorized(init) {
  if (!TOKEN) throw new Error(NO_TOKEN);
  return { ...init, headers: { ...(init.headers || {}), Authorization: "Bearer " + TOKEN } };
}
async function failure(response) {
  const data = await response.json().catch(() => ({ error: response.statusText }));
  return new Error(data.error || response.statusText);
}
async function api(method, path, body) {
  const init = { method, headers: {} };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const response = await fetch(path, authorized(init));
  if (!response.ok) throw await failure(response);
  return response.json();
}
async function download(path, name) {   // fetched with the header: no link carries the token
  try {
    const response = await fetch(path, authorized({}));
    if (!response.ok) throw await failure(response);
    const url = URL.createObjectURL(await response.blob());
    const a = document.createElement("a");
    a.href = url; a.download = name;
    document.body.appendChild(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  } catch (e) {
    say("rec-msg", e.message, true);
  }
}
function say(id, text, bad) {
  const el = document.getElementById(id);
  el.textContent = text || "";
  el.classList.toggle("error", !!bad);
}
const $ = (id) => document.getElementById(id);

// -- controls -----------------------------------------------------------------------------------
function fill(select, values, keep) {
  const old = keep ? select.value : null;
  select.innerHTML = "";
  for (const v of values) {
    const o = document.createElement("option");
    o.value = v; o.textContent = v;
    select.appendChild(o);
  }
  if (old && values.includes(old)) select.value = old;
}
function modelChanged() {
  const model = $("model").value;
  const presets = options.presets[model] || [];
  fill($("preset"), presets);
  $("preset").value = options.default_presets[model];
  const kind = model === "steering" ? "wheel" : "joystick";
  // What the panel may open: the virtual devices, the ones detected here, the recordings.
  fill($("device"), [...options.devices[kind], ...options.devices.real, ...options.devices.replays]);
  fill($("mode"), model === "steering" ? ["impedance"] : options.modes, true);
  if (model !== "steering") $("mode").value = "impedance";
  const scripted = model in options.default_sequences;
  $("sequence-row").classList.toggle("hidden", !scripted);
  if (scripted) $("sequence").value = options.default_sequences[model];
  $("speed").value = model === "steering" ? 80 : 30;
  steeringModelChanged();
}
function steeringModelChanged() {
  const steering = $("model").value === "steering";
  $("steering-model-row").classList.toggle("hidden", !steering);
  $("road-row").classList.toggle("hidden", !steering || $("steering-model").value !== "physical");
}
async function loadOptions() {
  options = await api("GET", "api/options");
  fill($("model"), options.models);
  $("model").value = "hpattern";
  fill($("hand"), options.hands);
  fill($("clock"), options.clocks);
  fill($("steering-model"), options.steering_models);
  fill($("road"), ["preset", ...options.roads]);   // preset: its own tyres' mu
  modelChanged();
}
function startBody() {
  const model = $("model").value;
  const device = $("device").value;
  const body = {
    model, preset: $("preset").value, device, mode: $("mode").value, hand: $("hand").value,
    clock: $("clock").value, speed_kmh: Number($("speed").value),
    duration_s: Number($("duration").value), force: true,
  };
  const telemetry = $("telemetry").value.trim();
  if (telemetry && telemetry !== "none") body.telemetry = telemetry;
  if (model in options.default_sequences) body.sequence = $("sequence").value.trim();
  if (model === "steering") {
    body.steering_model = $("steering-model").value;
    if (body.steering_model === "physical" && $("road").value !== "preset") body.road = $("road").value;
  }
  return body;
}
function knowledgeText(k, dev) {
  // How the run knows its device: measured hands off, a stored profile checked, or declared.
  if (!k) return "–";
  const how = {identified: `identified in ${fmt(k.duration_s, 2)} s`, profile: `profile checked in ${fmt(k.duration_s, 2)} s`,
               declared: "as declared (not measured)", recorded: "as recorded"}[k.how] || k.how;
  const wheel = dev && dev.kind === "wheel";
  const range = (r, f) => r ? ` (${fmt(f(r[0]))}..${fmt(f(r[1]))})` : "";
  return `${how}: inertia ${fmt(k.mass)} ${wheel ? "kg·m²" : "kg"}${range(k.mass_range, (v) => v)}, damping ${fmt(k.damping)}, round trip ${fmt(1e3 * k.round_trip_s)} ms${range(k.delay_range_s, (v) => 1e3 * v)}`;
}
async function start() {
  say("start-msg", "starting the loop's process: hands off the device while it is measured (a few seconds)...");
  $("start").disabled = true;
  try {
    const s = await api("POST", "api/session", startBody());
    buf = {}; engagement = null; lastStage = null;
    setSession(s);
    say("start-msg", "running: " + s.model + " on " + (s.device ? s.device.name : s.run.device));
  } catch (e) {
    say("start-msg", e.message, true);
  } finally {
    updateButtons();
  }
}
async function stop() {
  try { setSession(await api("POST", "api/session/stop")); } catch (e) { say("start-msg", e.message, true); }
}
async function apply() {
  const values = {};
  for (const input of document.querySelectorAll(".tunables input")) {
    if (input.classList.contains("changed")) values[input.dataset.path] = Number(input.value);
  }
  if (!Object.keys(values).length) { say("tune-msg", "change a value first", true); return; }
  try {
    const r = await api("POST", "api/tune", { values });
    const names = Object.entries(r.changes).map(([k, v]) => `${k.split(".").slice(-2).join(".")} ${fmt(v.old)} -> ${fmt(v.new)}`);
    say("tune-msg", "applied" + (r.waits_for ? " (waits for " + r.waits_for + ")" : "") + ": " + names.join(", ") + (r.note ? "; " + r.note : ""));
    for (const input of document.querySelectorAll(".tunables input.changed")) {
      input.classList.remove("changed"); input.dataset.value = input.value;
    }
  } catch (e) {
    say("tune-msg", e.message, true);
  }
}
async function savePreset() {
  try {
    const r = await api("POST", "api/presets", { name: $("preset-name").value.trim() });
    say("save-msg", "saved " + r.saved.join(", ") + " (" + r.preset + ")");
    const model = session.model;
    options = await api("GET", "api/options");
    if ($("model").value === model) fill($("preset"), options.presets[model], true);
  } catch (e) {
    say("save-msg", e.message, true);
  }
}
async function record() {
  try {
    if (session.recording) {
      await api("POST", "api/recording/stop");
      say("rec-msg", "stopping " + session.recording + "...");
    } else {
      const r = await api("POST", "api/recording", { name: $("rec-input").value.trim() || undefined });
      say("rec-msg", "recording " + r.recording);
      session.recording = r.recording;
    }
  } catch (e) {
    say("rec-msg", e.message, true);
  }
  updateButtons();
}
async function listRecordings() {
  try {
    const r = await api("GET", "api/recordings");
    const ul = $("recordings");
    ul.innerHTML = "";
    for (const rec of r.recordings.slice().reverse()) {
      const li = document.createElement("li");
      const name = document.createElement("span");
      name.textContent = rec.name + "  " + (rec.bytes / 1e6).toFixed(2) + " MB" + (rec.partial ? " (in progress)" : "");
      li.appendChild(name);
      if (!rec.partial) {
        const stem = rec.name.replace(/\.csv$/, "");
        for (const ext of ["csv", "json"]) {
          const a = document.createElement("a");
          a.href = "#"; a.textContent = ext; a.className = "dl-" + ext;
          a.onclick = (event) => { event.preventDefault(); download("api/recordings/" + stem + "." + ext, stem + "." + ext); };
          li.appendChild(a);
        }
        const b = document.createElement("button");
        b.textContent = "plot"; b.className = "plot";
        b.onclick = () => showPlot(stem);
        li.appendChild(b);
      }
      ul.appendChild(li);
    }
  } catch (e) {
    say("rec-msg", e.message, true);
  }
}
async function showPlot(stem) {
  $("plot-title").textContent = stem + ".csv (the recording's Fig. 10 and 11)";
  let response;
  try {
    response = await fetch("api/recordings/" + stem + "/plot.png", authorized({}));
    if (!response.ok) throw await failure(response);
  } catch (e) {
    say("rec-msg", e.message, true);
    return;
  }
  $("plot-img").src = URL.createObjectURL(await response.blob());
  $("plot-modal").classList.remove("hidden");
}
async function loadTunables() {
  const box = $("tunables");
  try {
    const r = await api("GET", "api/tune");
    box.innerHTML = "";
    let group = null;
    for (const t of r.tunables) {
      if (t.group !== group) {
        group = t.group;
        const g = document.createElement("div");
        g.className = "tgroup"; g.textContent = group;
        box.appendChild(g);
      }
      const label = document.createElement("label");
      label.title = `${t.path}: ${t.min} .. ${t.max} ${t.unit}${t.note ? "; " + t.note : ""}`;
      const name = document.createElement("span");
      name.textContent = t.label;
      const input = document.createElement("input");
      input.type = "number"; input.value = t.value; input.step = "any";
      input.dataset.path = t.path; input.dataset.value = t.value;
      input.oninput = () => input.classList.toggle("changed", input.value !== input.dataset.value);
      const unit = document.createElement("span");
      unit.className = "unit"; unit.textContent = t.unit;
      label.append(name, input, unit);
      box.appendChild(label);
    }
  } catch (e) {
    box.innerHTML = "";
    const hint = document.createElement("p");
    hint.className = "hint"; hint.textContent = e.message;   // text, never markup
    box.appendChild(hint);
  }
}
function updateButtons() {
  const running = ["starting", "calibrating", "running"].includes(session.state);
  $("start").disabled = running || session.state === "stopping";
  $("stop").disabled = !running;
  $("apply").disabled = !running;
  $("save").disabled = !session.model || session.state === "idle";
  $("record").disabled = !running && !session.recording;
  $("record").textContent = session.recording ? "Stop recording" : "Record";
  $("rec-indicator").classList.toggle("hidden", !session.recording);
  $("rec-name").textContent = session.recording || "";
}

// -- the session -------------------------------------------------------------------------------
function setSession(s) {
  const before = session;
  session = s;
  const pill = $("state");
  pill.textContent = (s.state || "idle").toUpperCase();
  pill.className = "pill " + (s.state || "idle");
  if (s.device) {
    const clock = s.run.clock === "simulated" ? "simulated clock" : "wall clock";
    const model = s.model === "steering" && s.run.steering_model === "physical" ? `steering (physical, ${s.run.road ? s.run.road + " road" : "the preset's road"})` : s.model;
    $("where").textContent = `${model} · ${s.device.name} · ${s.run.mode || "impedance"} · ${fmt(s.rate_hz)} Hz · ${clock}`;
  }
  const steering = s.model === "steering";
  $("gearbox-views").classList.toggle("hidden", steering);
  $("steering-views").classList.toggle("hidden", !steering);
  $("pattern-title").firstChild.textContent = PATTERN_TITLES[s.model] || "H-pattern ";
  const lever = s.model in LEVER_NOTES;
  $("pattern-title").lastChild.textContent = lever ? LEVER_NOTES[s.model] : "knob path, slots and gates";
  $("force-position-title").lastChild.textContent = lever ? "the last 10 s, the lever's marks" : "this engagement (paper Fig. 11)";
  $("stage-legend").classList.toggle("hidden", lever);
  if (s.model && (before.model !== s.model || before.state !== s.state) && s.state === "running") loadTunables();
  if (s.error) say("start-msg", s.error, true);
  if (before.recording && !s.recording) listRecordings();
  // The end is told once its summary is here (a frame may carry the new state before it); a loop
  // that ended without one has its error said above.
  const endedNow = s.state === "ended" && before.state !== "ended";
  const summaryNow = s.state === "ended" && s.summary && !(before.state === "ended" && before.summary);
  if (summaryNow) {
    const stopped = s.summary.stopped;
    const why = { stopped: "stopped on request", duration: "its duration ran out", fault: "a safety fault faded the force out", SIGINT: "Ctrl-C", SIGTERM: "SIGTERM" }[stopped] || stopped;
    say("start-msg", "ended: " + why + (s.faults && s.faults.length ? " (" + s.faults[0] + ")" : ""), s.faults && s.faults.length);
    $("summary").textContent = s.text || "";
    $("summary-box").classList.remove("hidden");
  }
  if (endedNow || summaryNow) listRecordings();
  const events = $("events");
  events.innerHTML = "";
  for (const e of (s.events || []).slice().reverse()) {
    const li = document.createElement("li");
    li.textContent = describeEvent(e);
    if (["error", "fault", "orphaned", "record_error"].includes(e.event)) li.className = "bad";
    events.appendChild(li);
  }
  updateButtons();
  dirty = true;
}
function describeEvent(e) {
  const t = e.time_s !== undefined && e.time_s !== null ? `t=${e.time_s.toFixed(2)} s ` : "";
  switch (e.event) {
    case "ready": return "loop ready, calibrating";
    case "tuning": return t + "tuning ramps in: " + Object.keys(e.changes).join(", ");
    case "tuned": return t + "tuned: " + Object.entries(e.changes).map(([k, v]) => `${k.split(".").pop()} ${fmt(v[0])} -> ${fmt(v[1])}`).join(", ");
    case "recording": return t + "recording " + e.path;
    case "recorded": return t + "recorded " + e.path + ` (${e.rows} rows)`;
    case "fault": return "FAULT: " + e.faults.join("; ");
    case "ended": return "ended (" + e.stopped + ")";
    case "orphaned": return "loop orphaned: " + e.message;
    default: return e.event + (e.message ? ": " + e.message : "");
  }
}
function append(columns) {
  const n = columns.time_s ? columns.time_s.length : 0;
  if (!n) return;
  for (const [name, values] of Object.entries(columns)) {
    const b = buf[name] || (buf[name] = []);
    for (const v of values) b.push(v);
    if (b.length > KEEP) b.splice(0, b.length - KEEP);
  }
  trackEngagement(columns, n);
  dirty = true;
}
function trackEngagement(c, n) {
  const xs = c.x_m || c.position_m, fs = c.force_x_N || c.force_N;
  const ffs = c.force_x_filtered_N || c.force_filtered_N, stages = c.stage;
  if (!xs || !stages) return;
  for (let i = 0; i < n; i++) {
    const stage = stages[i], x = xs[i];
    if (x === null || !stage) continue;
    if (stage !== "neutral" && (lastStage === "neutral" || lastStage === null || !engagement)) {
      engagement = { x: [], f: [], ff: [] };
    }
    if (engagement && stage !== "neutral") {
      const sign = x < 0 ? -1 : 1;
      engagement.x.push(Math.abs(x) * 1e3);
      engagement.f.push(fs[i] * sign);
      engagement.ff.push(ffs[i] * sign);
      if (engagement.x.length > 6000) { engagement.x.shift(); engagement.f.shift(); engagement.ff.shift(); }
    }
    lastStage = stage;
  }
}
function connect() {
  const url = new URL("api/stream", location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  if (!TOKEN) return;
  // A WebSocket cannot carry a header from a page: the credential is offered as a subprotocol,
  // and the panel answers "carfeel".
  socket = new WebSocket(url.toString(), ["carfeel", "carfeel.token." + TOKEN]);
  socket.onmessage = (m) => {
    const msg = JSON.parse(m.data);
    window.panelStats.frames += 1;
    if (msg.columns && msg.columns.time_s) window.panelStats.rows += msg.columns.time_s.length;
    if (msg.lost) window.panelStats.lost += msg.lost;
    if (msg.session) setSession(msg.session);
    else if (msg.state && msg.state !== session.state) setSession({ ...session, state: msg.state });
    if (msg.columns) append(msg.columns);
    if (msg.health) session.health = msg.health;
    if (msg.status) session.status = msg.status;
  };
  socket.onclose = () => setTimeout(connect, 1000);
}

// -- drawing ------------------------------------------------------------------------------------
function fmt(v, digits) {
  if (v === null || v === undefined || Number.isNaN(v)) return "–";
  if (typeof v !== "number") return String(v);
  const d = digits === undefined ? 3 : digits;
  if (v !== 0 && (Math.abs(v) >= 1e5 || Math.abs(v) < 1e-3)) return v.toExponential(2);
  return Number(v.toPrecision(d)).toString();
}
function us(v) {
  return Math.abs(v) >= 1000 ? (v / 1000).toFixed(2) + " ms" : Math.round(v) + " µs";
}
function canvasOf(id) {
  const c = $(id);
  const r = c.getBoundingClientRect();
  const d = window.devicePixelRatio || 1;
  const w = Math.max(10, Math.round(r.width * d)), h = Math.max(10, Math.round(r.height * d));
  if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
  const ctx = c.getContext("2d");
  ctx.setTransform(d, 0, 0, d, 0, 0);
  ctx.clearRect(0, 0, r.width, r.height);
  return { ctx, w: r.width, h: r.height };
}
function niceTicks(lo, hi, count) {
  const span = hi - lo || 1;
  const raw = span / count, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-6; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return out;
}
function extent(arrays, pad) {
  let lo = Infinity, hi = -Infinity;
  for (const a of arrays) for (const v of a) { if (v === null || !Number.isFinite(v)) continue; if (v < lo) lo = v; if (v > hi) hi = v; }
  if (!Number.isFinite(lo)) return [0, 1];
  if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
  const p = (hi - lo) * (pad || 0.08);
  return [lo - p, hi + p];
}
// A plot: {x: [lo, hi], y: [lo, hi], xlabel, ylabel, series: [{xs, ys, color, width}], legend}
function frame(ctx, w, h, spec) {
  const m = { l: 58, r: 12, t: 10, b: 34 };
  const pw = w - m.l - m.r, ph = h - m.t - m.b;
  const [x0, x1] = spec.x, [y0, y1] = spec.y;
  const X = (v) => m.l + ((v - x0) / (x1 - x0)) * pw;
  const Y = (v) => m.t + ph - ((v - y0) / (y1 - y0)) * ph;
  ctx.font = "12px DejaVu Sans, sans-serif";
  ctx.strokeStyle = "#2a3440"; ctx.fillStyle = "#8b98a5"; ctx.lineWidth = 1;
  ctx.textAlign = "center"; ctx.textBaseline = "top";
  for (const v of niceTicks(x0, x1, Math.max(4, Math.floor(pw / 70)))) {
    ctx.beginPath(); ctx.moveTo(X(v), m.t); ctx.lineTo(X(v), m.t + ph); ctx.stroke();
    ctx.fillText(fmt(v), X(v), m.t + ph + 4);
  }
  ctx.textAlign = "right"; ctx.textBaseline = "middle";
  for (const v of niceTicks(y0, y1, Math.max(4, Math.floor(ph / 35)))) {
    ctx.beginPath(); ctx.moveTo(m.l, Y(v)); ctx.lineTo(m.l + pw, Y(v)); ctx.stroke();
    ctx.fillText(fmt(v), m.l - 6, Y(v));
  }
  if (y0 < 0 && y1 > 0) { ctx.strokeStyle = "#4a5663"; ctx.beginPath(); ctx.moveTo(m.l, Y(0)); ctx.lineTo(m.l + pw, Y(0)); ctx.stroke(); }
  ctx.fillStyle = "#c9d1d9"; ctx.textAlign = "center"; ctx.textBaseline = "bottom";
  ctx.fillText(spec.xlabel || "", m.l + pw / 2, h - 1);
  ctx.save(); ctx.translate(13, m.t + ph / 2); ctx.rotate(-Math.PI / 2); ctx.textBaseline = "middle";
  ctx.fillText(spec.ylabel || "", 0, 0); ctx.restore();
  return { X, Y, m, pw, ph };
}
function line(ctx, f, xs, ys, color, width) {
  ctx.strokeStyle = color; ctx.lineWidth = width || 1.5; ctx.beginPath();
  let on = false;
  for (let i = 0; i < xs.length; i++) {
    const x = xs[i], y = ys[i];
    if (x === null || y === null || x === undefined || y === undefined) { on = false; continue; }
    if (on) ctx.lineTo(f.X(x), f.Y(y)); else { ctx.moveTo(f.X(x), f.Y(y)); on = true; }
  }
  ctx.stroke();
}
function legend(ctx, f, items) {
  ctx.font = "12px DejaVu Sans, sans-serif"; ctx.textAlign = "left"; ctx.textBaseline = "middle";
  let x = f.m.l + 8, y = f.m.t + 9;
  for (const [label, color] of items) {
    const width = 26 + ctx.measureText(label).width;
    if (x > f.m.l + 8 && x + width > f.m.l + f.pw) { x = f.m.l + 8; y += 16; }   // next row
    ctx.fillStyle = color; ctx.fillRect(x, y - 1, 14, 3);
    ctx.fillStyle = "#c9d1d9"; ctx.fillText(label, x + 18, y);
    x += width;
  }
}
function windowed(names) {
  const t = buf.time_s || [];
  if (!t.length) return null;
  const now = t[t.length - 1];
  let i = t.length - 1;
  while (i > 0 && t[i - 1] >= now - WINDOW_S) i--;
  const out = { t: t.slice(i), now };
  for (const n of names) out[n] = (buf[n] || []).slice(i);
  return out;
}
function drawTime(id, w, specs, ylabel) {
  const { ctx, w: cw, h } = canvasOf(id);
  if (!w) { empty(ctx, cw, h); return; }
  const y = extent(specs.map((s) => s.ys));
  const f = frame(ctx, cw, h, { x: [w.now - WINDOW_S, w.now], y, xlabel: "time [s]", ylabel });
  ctx.save(); ctx.beginPath(); ctx.rect(f.m.l, f.m.t, f.pw, f.ph); ctx.clip();
  for (const s of specs) line(ctx, f, w.t, s.ys, s.color, s.width);
  ctx.restore();
  legend(ctx, f, specs.filter((s) => s.label).map((s) => [s.label, s.color]));
  return { f, ctx };
}
function empty(ctx, w, h) {
  ctx.fillStyle = "#5c6773"; ctx.font = "14px DejaVu Sans, sans-serif"; ctx.textAlign = "center";
  ctx.textBaseline = "middle"; ctx.fillText("no data yet: start a session", w / 2, h / 2);
}
function stageBand(f, ctx, t, stages) {
  if (!stages) return;
  const yb = f.m.t + f.ph - 6;
  for (let i = 1; i < t.length; i++) {
    ctx.fillStyle = STAGE_COLORS[stages[i]] || "#333";
    ctx.fillRect(f.X(t[i - 1]), yb, Math.max(1, f.X(t[i]) - f.X(t[i - 1]) + 0.5), 6);
  }
}
const PATTERN_TITLES = { shift: "Engagement slot ", sequential: "Sequential lever ", prnd: "Selector " };
const LEVER_NOTES = { sequential: "the knob, its clicks and ends", prnd: "the knob, its positions and ends" };
function drawGearbox() {
  if (session.lever) { drawLever(); return; }
  const shift = session.model === "shift";
  const fx = shift ? "force_N" : "force_x_N", ffx = shift ? "force_filtered_N" : "force_x_filtered_N";
  const px = shift ? "position_m" : "x_m";
  const w = windowed([fx, ffx, px, "stage", "y_m"]);
  const drawn = drawTime("force-time", w, w ? [
    { ys: w[fx], color: "#6e7681", width: 1, label: "raw" },
    { ys: w[ffx], color: "#f0f6fc", width: 2, label: "20 Hz filtered" },
  ] : [], "force on the knob [N]");
  if (w && drawn) stageBand(drawn.f, drawn.ctx, w.t, w.stage);
  drawTime("position-time", w, w ? [
    { ys: w[px].map((v) => (v === null ? null : v * 1e3)), color: "#4aa3ff", width: 2, label: "engage x" },
    ...(shift ? [] : [{ ys: w.y_m.map((v) => (v === null ? null : v * 1e3)), color: "#d29922", width: 1.5, label: "select y" }]),
  ] : [], "knob [mm]");
  drawEngagement();
  drawPattern();
  const stage = lastOf(buf.stage);
  const gear = shift ? (stage ? (stage === "in_gear" ? "1" : "N") : "") : lastOf(buf.gear);
  $("gear").textContent = gear || "·";
  $("gear").classList.toggle("neutral", !gear || gear === "N");
  $("stage").textContent = stage ? stage.replace("_", " ") : "–";
  $("stage").style.background = STAGE_COLORS[stage] || "transparent";
  const list = session.engaged || [];
  $("gears").textContent = list.length ? (list.length > 16 ? "… " : "") + list.slice(-16).join(" ") : "–";
  $("gears").dataset.count = list.length;
  $("gears-count").textContent = list.length ? `(${list.length})` : "";
}
// A one-axis lever (sequential, PRND): force and position against time, the force against the
// position over the window with the lever's detents and ends marked, and the lever itself.
function drawLever() {
  const w = windowed(["force_N", "force_filtered_N", "position_m"]);
  drawTime("force-time", w, w ? [
    { ys: w.force_N, color: "#6e7681", width: 1, label: "raw" },
    { ys: w.force_filtered_N, color: "#f0f6fc", width: 2, label: "20 Hz filtered" },
  ] : [], "force on the knob [N]");
  drawTime("position-time", w, w ? [
    { ys: w.position_m.map((v) => (v === null ? null : v * 1e3)), color: "#4aa3ff", width: 2, label: "lever x" },
  ] : [], "knob [mm]");
  const marks = session.lever, xr = [marks[0].position_m * 1e3 - 2, marks[marks.length - 1].position_m * 1e3 + 2];
  const gear = lastOf(buf.gear);
  {
    const { ctx, w: cw, h } = canvasOf("force-position");
    if (!w || w.t.length < 2) empty(ctx, cw, h);
    else {
      const xs = w.position_m.map((v) => (v === null ? null : v * 1e3));
      const f = frame(ctx, cw, h, { x: xr, y: extent([w.force_N, w.force_filtered_N]), xlabel: "lever position [mm]", ylabel: "force on the knob [N]" });
      leverMarks(ctx, f, marks, gear);
      line(ctx, f, xs, w.force_N, "#6e7681", 1);
      line(ctx, f, xs, w.force_filtered_N, "#f0f6fc", 2);
      legend(ctx, f, [["raw", "#6e7681"], ["20 Hz filtered", "#f0f6fc"]]);
    }
  }
  {
    // The lever's slot seen from above: + x to the right, its marks across it, the knob on it.
    const { ctx, w: cw, h } = canvasOf("pattern");
    const X = (mm) => 24 + ((mm - xr[0]) / (xr[1] - xr[0])) * (cw - 48), y = h / 2;
    ctx.fillStyle = "#0b1015"; ctx.strokeStyle = "#5c6773"; ctx.lineWidth = 1.5;
    ctx.fillRect(X(xr[0]), y - 10, X(xr[1]) - X(xr[0]), 20);
    ctx.strokeRect(X(xr[0]), y - 10, X(xr[1]) - X(xr[0]), 20);
    ctx.font = "bold 16px DejaVu Sans, sans-serif"; ctx.textAlign = "center";
    marks.forEach((mark, i) => {
      const x = X(mark.position_m * 1e3), now = mark.name === gear;
      ctx.strokeStyle = now ? "#4aa3ff" : "#8b98a5"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(x, y - 16); ctx.lineTo(x, y + 16); ctx.stroke();
      ctx.fillStyle = now ? "#4aa3ff" : "#c9d1d9";
      ctx.textBaseline = i % 2 ? "top" : "bottom";    // alternate sides: close marks stay legible
      ctx.fillText(mark.name, x, i % 2 ? y + 20 : y - 20);
    });
    ctx.strokeStyle = "#8b98a5"; ctx.lineWidth = 2;     // scale bar: 10 mm
    ctx.beginPath(); ctx.moveTo(12, h - 12); ctx.lineTo(12 + X(10) - X(0), h - 12); ctx.stroke();
    ctx.fillStyle = "#8b98a5"; ctx.font = "11px DejaVu Sans, sans-serif"; ctx.textAlign = "left"; ctx.textBaseline = "bottom";
    ctx.fillText("10 mm", 12, h - 15);
    const xs = buf.position_m || [];
    const x = xs.length ? xs[xs.length - 1] : null;
    if (x !== null && x !== undefined) {
      ctx.fillStyle = "#f0f6fc"; ctx.strokeStyle = "#4aa3ff"; ctx.lineWidth = 3;
      ctx.beginPath(); ctx.arc(X(x * 1e3), y, 8, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    }
  }
  $("gear").textContent = gear || "·";
  $("gear").classList.toggle("neutral", !gear || gear === "N");
  $("stage").textContent = "–";
  $("stage").style.background = "transparent";
  const list = session.engaged || [];
  $("gears").textContent = list.length ? (list.length > 16 ? "… " : "") + list.slice(-16).join(" ") : "–";
  $("gears").dataset.count = list.length;
  $("gears-count").textContent = list.length ? `(${list.length})` : "";
}
function leverMarks(ctx, f, marks, gear) {
  ctx.setLineDash([4, 4]); ctx.lineWidth = 1;
  for (const mark of marks) {
    const x = f.X(mark.position_m * 1e3), now = mark.name === gear;
    ctx.strokeStyle = now ? "#4aa3ff" : "#5c6773";
    ctx.beginPath(); ctx.moveTo(x, f.m.t); ctx.lineTo(x, f.m.t + f.ph); ctx.stroke();
    ctx.fillStyle = now ? "#4aa3ff" : "#c9d1d9"; ctx.textAlign = "center"; ctx.textBaseline = "bottom";
    ctx.fillText(mark.name, x, f.m.t + f.ph - 2);
  }
  ctx.setLineDash([]);
}
function lastOf(values) {
  // The newest value that is not blank (the rows of the final fade carry no model state).
  if (!values) return "";
  for (let i = values.length - 1; i >= 0 && i >= values.length - 200; i--) if (values[i]) return values[i];
  return "";
}
function drawEngagement() {
  const { ctx, w, h } = canvasOf("force-position");
  const e = engagement;
  if (!e || e.x.length < 2) { empty(ctx, w, h); return; }
  const g = session.gearbox;
  const xr = g ? [0, g.in_gear_position_m * 1e3 + 4] : extent([e.x]);
  const f = frame(ctx, w, h, { x: xr, y: extent([e.f, e.ff]), xlabel: "knob travel into the slot [mm]", ylabel: "force on the knob [N]" });
  if (g) {
    ctx.setLineDash([4, 4]); ctx.lineWidth = 1;
    for (const [name, label, color] of [["synchronization_position_m", "ring", STAGE_COLORS.synchronization], ["teeth_position_m", "teeth", STAGE_COLORS.engagement], ["in_gear_position_m", "in gear", STAGE_COLORS.in_gear]]) {
      const x = f.X(g[name] * 1e3);
      ctx.strokeStyle = color; ctx.beginPath(); ctx.moveTo(x, f.m.t); ctx.lineTo(x, f.m.t + f.ph); ctx.stroke();
      ctx.fillStyle = color; ctx.textAlign = "center"; ctx.textBaseline = "bottom"; ctx.fillText(label, x, f.m.t + f.ph - 4);
    }
    ctx.setLineDash([]);
  }
  line(ctx, f, e.x, e.f, "#6e7681", 1);
  line(ctx, f, e.x, e.ff, "#f0f6fc", 2);
  legend(ctx, f, [["raw", "#6e7681"], ["20 Hz filtered", "#f0f6fc"]]);
}
function drawPattern() {
  const { ctx, w, h } = canvasOf("pattern");
  const g = session.gearbox;
  if (!g) { empty(ctx, w, h); return; }
  const L = session.layout || { planes_y_m: [0], gears: [{ name: "1", plane: 0, direction: 1 }], slot_width_m: 0.008, corridor_width_m: 0.012 };
  const planes = L.planes_y_m, sw = L.slot_width_m, cw = L.corridor_width_m;
  const xmax = g.in_gear_position_m + 0.006;
  const ymin = planes[0] - sw * 1.5, ymax = planes[planes.length - 1] + sw * 1.5;
  const s = Math.min((w - 40) / (ymax - ymin), (h - 84) / (2 * xmax));
  const cx = w / 2 - ((ymin + ymax) / 2) * s, cy = h / 2;
  const P = (x, y) => [cx + y * s, cy - x * s];     // engage x up, select y to the right
  // The gate: the corridor and each gear's slot.
  ctx.fillStyle = "#0b1015"; ctx.strokeStyle = "#44505c"; ctx.lineWidth = 2;
  const [ax, ay] = P(cw / 2, planes[0] - sw / 2), [bx, by] = P(-cw / 2, planes[planes.length - 1] + sw / 2);
  ctx.fillRect(ax, ay, bx - ax, by - ay);
  const engaged = $("gear").textContent;
  for (const gear of L.gears) {
    const y = planes[gear.plane], d = gear.direction;
    const [x0, y0] = P(d > 0 ? xmax : -cw / 2, y - sw / 2), [x1, y1] = P(d > 0 ? cw / 2 : -xmax, y + sw / 2);
    ctx.fillStyle = gear.name === engaged ? "#1b4a75" : "#0b1015";
    ctx.fillRect(x0, y0, x1 - x0, y1 - y0);
    // ring, teeth and in-gear marks across the slot
    for (const [pos, color] of [[g.synchronization_position_m, STAGE_COLORS.synchronization], [g.teeth_position_m, STAGE_COLORS.engagement], [g.in_gear_position_m, STAGE_COLORS.in_gear]]) {
      const [mx, my] = P(d * pos, y - sw / 2), [nx] = P(d * pos, y + sw / 2);
      ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.beginPath(); ctx.moveTo(mx, my); ctx.lineTo(nx, my); ctx.stroke();
    }
    const [lx, ly] = P(d * (xmax + 0.001), y);
    ctx.fillStyle = gear.name === engaged ? "#4aa3ff" : "#c9d1d9";
    ctx.font = "bold 22px DejaVu Sans, sans-serif"; ctx.textAlign = "center";
    ctx.textBaseline = d > 0 ? "bottom" : "top";
    ctx.fillText(gear.name, lx, ly + (d > 0 ? -2 : 2));
  }
  // outline of the gate
  ctx.strokeStyle = "#5c6773"; ctx.lineWidth = 1.5;
  ctx.strokeRect(ax, ay, bx - ax, by - ay);
  for (const gear of L.gears) {
    const y = planes[gear.plane], d = gear.direction;
    const [x0, y0] = P(d > 0 ? xmax : -cw / 2, y - sw / 2), [x1, y1] = P(d > 0 ? cw / 2 : -xmax, y + sw / 2);
    ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
  }
  // scale bar: 10 mm
  ctx.strokeStyle = "#8b98a5"; ctx.lineWidth = 2;
  ctx.beginPath(); ctx.moveTo(12, h - 12); ctx.lineTo(12 + 0.01 * s, h - 12); ctx.stroke();
  ctx.fillStyle = "#8b98a5"; ctx.font = "11px DejaVu Sans, sans-serif"; ctx.textAlign = "left"; ctx.textBaseline = "bottom";
  ctx.fillText("10 mm", 12, h - 15);
  // the knob's path and the knob
  const xs = buf.x_m || buf.position_m || [], ys = buf.y_m || null, t = buf.time_s || [];
  if (!xs.length) return;
  const now = t[t.length - 1];
  let i = t.length - 1;
  while (i > 0 && t[i - 1] >= now - TRAIL_S) i--;
  ctx.lineWidth = 2;
  for (let k = i + 1; k < xs.length; k++) {
    if (xs[k] === null || xs[k - 1] === null) continue;
    const a = (t[k] - (now - TRAIL_S)) / TRAIL_S;
    ctx.strokeStyle = `rgba(74,163,255,${0.15 + 0.85 * a})`;
    const [p0, q0] = P(xs[k - 1], ys ? ys[k - 1] : planes[0]), [p1, q1] = P(xs[k], ys ? ys[k] : planes[0]);
    ctx.beginPath(); ctx.moveTo(p0, q0); ctx.lineTo(p1, q1); ctx.stroke();
  }
  const last = xs.length - 1;
  if (xs[last] !== null) {
    const [kx, ky] = P(xs[last], ys ? ys[last] : planes[0]);
    ctx.fillStyle = "#f0f6fc"; ctx.strokeStyle = "#4aa3ff"; ctx.lineWidth = 3;
    ctx.beginPath(); ctx.arc(kx, ky, 8, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
  }
}
function drawSteering() {
  const terms = Object.keys(TERM_COLORS);
  const w = windowed(["steering_angle_rad", "lateral_accel_m_s2", "torque_Nm", "torque_filtered_Nm", ...terms]);
  drawTime("angle-time", w, w ? [{ ys: w.steering_angle_rad.map((v) => (v === null ? null : v * 180 / Math.PI)), color: "#4aa3ff", width: 2, label: "wheel angle" }] : [], "wheel [deg]");
  drawTime("ay-time", w, w ? [{ ys: w.lateral_accel_m_s2, color: "#d29922", width: 2, label: "Ay" }] : [], "Ay [m/s²]");
  const { ctx, w: cw, h } = canvasOf("torque-terms");
  if (!w) { empty(ctx, cw, h); } else {
    const n = w.t.length, pos = new Array(n).fill(0), neg = new Array(n).fill(0);
    const layers = [];
    for (const term of terms) {
      const v = w[term];
      if (!v.length || v.every((x) => !x)) continue;   // absent, or zero all along: no layer
      const lo = [], hi = [];
      for (let i = 0; i < n; i++) {
        const x = v[i] || 0;
        if (x >= 0) { lo.push(pos[i]); pos[i] += x; hi.push(pos[i]); } else { hi.push(neg[i]); neg[i] += x; lo.push(neg[i]); }
      }
      layers.push([term, lo, hi]);
    }
    const y = extent([pos, neg, w.torque_Nm]);
    const f = frame(ctx, cw, h, { x: [w.now - WINDOW_S, w.now], y, xlabel: "time [s]", ylabel: "torque at the rim [Nm, model]" });
    ctx.save(); ctx.beginPath(); ctx.rect(f.m.l, f.m.t, f.pw, f.ph); ctx.clip();
    for (const [term, lo, hi] of layers) {
      ctx.fillStyle = TERM_COLORS[term] + "b0"; ctx.beginPath();
      for (let i = 0; i < n; i++) { const X = f.X(w.t[i]), Y = f.Y(hi[i]); if (i) ctx.lineTo(X, Y); else ctx.moveTo(X, Y); }
      for (let i = n - 1; i >= 0; i--) ctx.lineTo(f.X(w.t[i]), f.Y(lo[i]));
      ctx.closePath(); ctx.fill();
    }
    line(ctx, f, w.t, w.torque_Nm, "#6e7681", 1);
    line(ctx, f, w.t, w.torque_filtered_Nm, "#f0f6fc", 2);
    ctx.restore();
    legend(ctx, f, [...layers.map(([term]) => [TERM_LABELS[term], TERM_COLORS[term]]), ["total", "#f0f6fc"]]);
  }
  const a = buf.steering_angle_rad || [], tq = buf.torque_filtered_Nm || [];
  const { ctx: c2, w: w2, h: h2 } = canvasOf("torque-angle");
  if (a.length < 2) { empty(c2, w2, h2); return; }
  const deg = a.map((v) => (v === null ? null : v * 180 / Math.PI));
  const f2 = frame(c2, w2, h2, { x: extent([deg]), y: extent([tq]), xlabel: "wheel angle [deg]", ylabel: "torque, filtered [Nm]" });
  line(c2, f2, deg, tq, "#4aa3ff", 1.5);
}
function figures(id, rows) {
  const dl = $(id);
  dl.innerHTML = "";
  for (const [name, value, cls] of rows) {
    const dt = document.createElement("dt"); dt.textContent = name;
    const dd = document.createElement("dd"); dd.textContent = value; if (cls) dd.className = cls;
    dl.append(dt, dd);
  }
}
function drawFigures() {
  const hl = session.health || {}, st = session.status || {}, dev = session.device, lim = session.limits;
  const rate = session.rate_hz;
  figures("health", [
    ["loop rate", hl.rate_hz ? fmt(hl.rate_hz, 5) + " Hz" : "–", hl.rate_hz && rate && Math.abs(hl.rate_hz - rate) > 0.02 * rate ? "warn" : "good"],
    ["periods", hl.periods ? String(Math.round(hl.periods)) : "–"],
    ["overruns (> 1.5 periods)", hl.overruns !== undefined ? String(Math.round(hl.overruns)) : "–", hl.overruns > 0 ? "warn" : "good"],
    ["period error p99 (10 s)", hl.period_error_p99_us !== undefined ? us(hl.period_error_p99_us) : "–", hl.period_error_p99_us > 500 ? "warn" : ""],
    ["period error max (10 s)", hl.period_error_max_us !== undefined ? us(hl.period_error_max_us) : "–", hl.period_error_max_us > 20000 ? "bad" : hl.period_error_max_us > 500 ? "warn" : ""],
    ["session time", st.time_s !== undefined ? st.time_s.toFixed(1) + " s" : "–"],
  ]);
  const unit = dev ? dev.unit : "";
  const faults = session.faults || [];
  const ratio = st.guard_rms / st.guard_limit_rms;
  figures("safety", [
    ["faults", faults.length ? faults.join("; ") : "none", faults.length ? "bad" : "good"],
    ["force limit", lim ? fmt(lim.max_force) + " " + unit : "–"],
    ["slew limit", lim ? fmt(lim.max_slew_per_s) + " " + unit + "/s" : "–"],
    ["time at the limit (last 1 s)", hl.at_limit_share !== undefined ? (100 * hl.at_limit_share).toFixed(1) + " %" : "–", hl.at_limit_share > 0.05 ? "warn" : ""],
    ["oscillation guard", Number.isFinite(ratio) ? fmt(st.guard_rms) + " / " + fmt(st.guard_limit_rms) + " " + unit + " rms" + (st.guard_held_s > 0 ? `, held ${st.guard_held_s.toFixed(2)} of ${st.guard_hold_s} s` : "") : "–", ratio > 1 ? "bad" : ""],
    ["passivity controller acted", st.passivity_acted_s !== undefined ? fmt(st.passivity_acted_s) + " s" : "–"],
    ["tuning", st.tune_ramp ? "ramping in" : st.tune_pending ? "waits for neutral" : "–", st.tune_pending ? "warn" : ""],
  ]);
  const bar = $("guard-bar");
  bar.style.width = Number.isFinite(ratio) ? Math.min(100, 100 * ratio) + "%" : "0";
  bar.style.background = ratio > 1 ? "#e5534b" : ratio > 0.5 ? "#d29922" : "#3fb950";
  const sz = session.sizing;
  const rows = [
    ["device", dev ? dev.name : "–"],
    ["force / travel", dev ? `${fmt(dev.max_force)} ${unit}, ±${fmt(dev.kind === "wheel" ? dev.travel * 180 / Math.PI : dev.travel * 1e3)} ${dev.kind === "wheel" ? "deg" : "mm"}` : "–"],
    ["round-trip delay, reports", dev ? `${fmt(dev.delay_ms)} ms, ${fmt(dev.report_hz)} Hz` : "–"],
    ["device known", knowledgeText(session.knowledge, dev), session.knowledge && session.knowledge.how === "declared" ? "warn" : ""],
    ["sized stiffness, ζ hands off", sz ? `${fmt(sz.stiffness)} ${unit}/${dev && dev.kind === "wheel" ? "rad" : "m"}, ${fmt(sz.zeta, 2)}` : "–"],
    ["force scale", session.scaling ? fmt(session.scaling.force_scale) : "–"],
    ...(session.coupling ? [["physical model's coupling", `${fmt(session.coupling.stiffness)} ${unit}/rad (${(100 * session.coupling.share).toFixed(0)} % of the budget), ζ ${fmt(session.coupling.zeta, 2)}, up to ${fmt(session.coupling.top_speed_kmh)} km/h`]] : []),
    ["loop process", session.loop_process ? `pid ${session.loop_process.pid}, ${session.loop_process.priority}` : "–"],
  ];
  const wt = buf.telemetry_weight;
  if (wt && wt.length) {
    const k = wt.length - 1;
    rows.push(["telemetry weight", fmt(wt[k], 2), wt[k] < 1 ? "warn" : "good"]);
    rows.push(["game speed", fmt((buf.game_speed_m_s || [])[k] * 3.6) + " km/h"]);
    rows.push(["game gear, rpm", `${fmt((buf.game_gear || [])[k])}, ${fmt((buf.game_engine_speed_rpm || [])[k])}`]);
    const ms = (v) => Number.isFinite(v) ? (1e3 * v).toFixed(2) + " ms" : "–";
    rows.push(["packet age", ms(st.telemetry_age_s), st.telemetry_age_s > 0.1 ? "warn" : ""]);
    rows.push(["packet-to-force latency, p99", ms(st.telemetry_latency_s) + ", " + ms(st.telemetry_latency_p99_s),
      st.telemetry_latency_p99_s > 2 / rate ? "warn" : ""]);
  } else {
    rows.push(["telemetry", session.run && session.run.telemetry ? session.run.telemetry : "none (fixed speed " + fmt(session.speed_kmh) + " km/h)"]);
  }
  figures("device-info", rows);
}
function draw() {
  if (dirty) {
    dirty = false;
    try {
      if (session.model === "steering") drawSteering(); else drawGearbox();
      drawFigures();
    } catch (e) {
      console.warn("draw", e);
    }
  }
  requestAnimationFrame(draw);
}

function stageLegend() {
  const box = $("stage-legend");
  for (const [name, color] of Object.entries(STAGE_COLORS)) {
    const chip = document.createElement("span");
    chip.innerHTML = `<i style="background:${color}"></i>${name.replace("_", " ")}`;
    box.appendChild(chip);
  }
}

// -- start --------------------------------------------------------------------------------------
stageLegend();
$("model").onchange = modelChanged;
$("steering-model").onchange = steeringModelChanged;
$("start").onclick = start;
$("stop").onclick = stop;
$("apply").onclick = apply;
$("save").onclick = savePreset;
$("record").onclick = record;
$("plot-close").onclick = () => $("plot-modal").classList.add("hidden");
window.onresize = () => { dirty = true; };
loadOptions().then(() => { connect(); listRecordings(); }).catch((e) => say("start-msg", e.message, true));
requestAnimationFrame(draw);
