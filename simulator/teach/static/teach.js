// roger teach's page: the teacher's keys (or gamepad) -> the command, the session's state
// -> the views. The key map, names and ranges come from the server (simulator/teach/channel.py);
// docs/teach.md describes the page.
"use strict";

const $ = (id) => document.getElementById(id);
const teach = {
  config: null, state: null, ws: null, held: new Set(), head: null, lastFrame: 0,
  stats: { states: 0, hz: 0, sent: 0, refused: {}, lastTick: -1, arrivals: [] },
};
window.teach = teach; // for the browser test and the benchmark

function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws`);
  teach.ws = ws;
  ws.onopen = () => { $("conn").textContent = "connected"; $("conn").className = "ok"; };
  ws.onclose = () => {
    $("conn").textContent = "disconnected"; $("conn").className = "bad";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "config") configure(m);
    else if (m.type === "state") show(m);
    else if (m.type === "ack") $("answer").textContent = m.text;
    else if (m.type === "refused") $("answer").textContent = `refused: ${m.reason} (${m.detail})`;
  };
}

function send(msg) {
  if (teach.ws && teach.ws.readyState === WebSocket.OPEN) {
    teach.ws.send(JSON.stringify(msg));
    teach.stats.sent += 1;
  }
}

// -- configuration: the key map table, the command table, the locations --------------------

function configure(c) {
  teach.config = c;
  $("autonomy").textContent = c.autonomy;
  const km = $("keymap").tBodies[0];
  km.innerHTML = "";
  for (const k of c.keymap) {
    const keys = k.codes.map((code) => `<kbd>${code.replace(/^Key/, "")}</kbd>`).join(" ");
    km.insertAdjacentHTML("beforeend", `<tr><td>${keys}</td><td>${k.does}</td></tr>`);
  }
  const cmd = $("commands").tBodies[0];
  cmd.innerHTML = "";
  for (const name of c.action_names) {
    cmd.insertAdjacentHTML("beforeend",
      `<tr><td>${name}</td><td></td><td></td><td></td><td></td></tr>`);
  }
  const sel = $("location");
  sel.innerHTML = '<option value="">next</option>';
  for (const l of c.locations) sel.insertAdjacentHTML("beforeend",
    `<option value="${l.index}">${l.index}: ${l.name}</option>`);
}

// -- the teacher's command -------------------------------------------------------------------

const HEAD = { head_tilt: 18, head_pan: 19, head_nod: 20 };

function measured() {
  // head (tilt, pan, nod) and tail (pan, tilt) as the robot has them now
  const x = teach.state ? teach.state.x : null;
  return x ? x.slice(18, 23) : [-0.26, 0, 0, 0, 0.26];
}

function pad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads) if (p && p.connected) return p;
  return null;
}

function command(dt) {
  const c = teach.config;
  const idx = (n) => c.action_names.indexOf(n);
  const range = (n) => c.action_ranges[idx(n)];
  const y = new Array(c.action_names.length).fill(0);
  const now = measured();
  for (let i = 0; i < 5; i++) y[3 + i] = now[i];
  let active = false;
  const headMove = { head_tilt: 0, head_pan: 0 };
  for (const k of c.keymap) {
    if (!k.codes.some((code) => teach.held.has(code))) continue;
    active = true;
    if (k.entry in headMove) headMove[k.entry] += k.sign;
    else if (k.entry === "walk_turn") y[idx(k.entry)] = k.sign * c.turn_rate;
    else if (k.entry === "action") y[idx(k.entry)] = k.sign;
    else y[idx(k.entry)] = k.sign > 0 ? range(k.entry)[1] : range(k.entry)[0];
  }
  const gp = pad();
  if (gp) {
    const ax = (i) => (Math.abs(gp.axes[i] || 0) > 0.15 ? gp.axes[i] : 0);
    const walk = [[idx("walk_forward"), -ax(1)], [idx("walk_left"), -ax(0)]];
    for (const [i, v] of walk) if (v) { y[i] = v > 0 ? v * c.action_ranges[i][1] : -v * c.action_ranges[i][0]; active = true; }
    if (ax(2)) { y[idx("walk_turn")] = -ax(2) * c.turn_rate; active = true; }
    if (ax(3)) { headMove.head_tilt -= ax(3); active = true; }
    if (gp.buttons[0] && gp.buttons[0].pressed) { y[idx("action")] = -1; active = true; }
    if (gp.buttons[1] && gp.buttons[1].pressed) { y[idx("action")] = 1; active = true; }
  }
  if (headMove.head_tilt || headMove.head_pan) {
    if (!teach.head) teach.head = { head_tilt: now[0], head_pan: now[1] };
    for (const n of ["head_tilt", "head_pan"]) {
      const r = range(n);
      teach.head[n] = Math.min(r[1], Math.max(r[0], teach.head[n] + headMove[n] * c.head_rate * dt));
    }
  } else {
    teach.head = null;
  }
  if (teach.head) { y[idx("head_tilt")] = teach.head.head_tilt; y[idx("head_pan")] = teach.head.head_pan; }
  // keep every entry inside its documented range (the server refuses anything outside)
  for (let i = 0; i < y.length; i++) {
    const r = c.action_ranges[i];
    y[i] = Math.min(r[1], Math.max(r[0], y[i]));
  }
  return { y, active };
}

function sendCommand(stamp) {
  if (!teach.config) return;
  const { y, active } = command(0);
  send({ type: "command", y, active, sent_ms: stamp });
}

function mapped(code) {
  return teach.config && teach.config.keymap.some((k) => k.codes.includes(code));
}

window.addEventListener("keydown", (ev) => {
  if (!mapped(ev.code) || ev.target.tagName === "SELECT") return;
  ev.preventDefault();
  if (teach.held.has(ev.code)) return; // auto-repeat: the timer keeps sending
  teach.held.add(ev.code);
  sendCommand(performance.timeOrigin + ev.timeStamp);
});
window.addEventListener("keyup", (ev) => {
  if (!teach.held.delete(ev.code)) return;
  ev.preventDefault();
  sendCommand(performance.timeOrigin + ev.timeStamp);
});
window.addEventListener("blur", () => { teach.held.clear(); sendCommand(Date.now()); });

let lastTimer = performance.now();
setInterval(() => {
  // while a key or stick is held: the command again every 50 ms (head targets move)
  const now = performance.now();
  const dt = (now - lastTimer) / 1000;
  lastTimer = now;
  if (!teach.config) return;
  const { y, active } = command(dt);
  if (active) send({ type: "command", y, active, sent_ms: performance.timeOrigin + now });
}, 50);

// -- the session's state ---------------------------------------------------------------------

function fmt(v, digits = 3) { return v === null || v === undefined ? "" : Number(v).toFixed(digits); }

function show(s) {
  teach.state = s;
  const st = teach.stats;
  st.states += 1;
  st.lastTick = s.tick;
  const now = performance.now();
  st.arrivals.push(now);
  while (st.arrivals.length && now - st.arrivals[0] > 2000) st.arrivals.shift();
  st.hz = st.arrivals.length > 1 ? (st.arrivals.length - 1) / ((now - st.arrivals[0]) / 1000) : 0;
  st.refused = s.refused;
  if (s.image) $("camera").src = s.image;
  drawField(s);
  for (const b of document.querySelectorAll("#modes button")) b.classList.toggle("on", b.dataset.mode === s.mode);
  const rows = $("commands").tBodies[0].rows;
  const p = s.prediction;
  for (let i = 0; i < rows.length; i++) {
    const cells = rows[i].cells;
    cells[1].textContent = s.teacher_y ? fmt(s.teacher_y[i]) : "";
    cells[2].textContent = p ? fmt(p.mean[i]) : "";
    cells[3].textContent = p ? fmt(p.var[i], 4) : "";
    cells[4].textContent = fmt(s.command[i]);
    cells[1].classList.toggle("taught", s.source === "teacher");
  }
  const d = s.daemon || {};
  $("s-mode").textContent = s.mode;
  $("s-source").textContent = s.source + (s.teacher_active ? " (key held)" : "");
  $("s-tick").textContent = `${s.tick} / ${s.episode} (location ${s.location}, ${fmt(s.t, 1)} s)`;
  $("s-expert").textContent = p ? `${p.expert} (robot's state ${s.fsm.state})` : "–";
  $("s-experts").textContent = d.experts ?? (p ? p.experts : "–");
  $("s-updates").textContent = d.updates ?? (p ? p.updates : "–");
  $("s-taught").textContent = `${s.counts.pairs_sent || 0} / ${s.counts.corrections || 0}` +
    (d.corrections !== undefined ? ` (daemon: ${d.pairs_teacher} / ${d.corrections})` : "");
  $("s-fsm").textContent = `${s.fsm.how}; ${s.fsm.refitting ? "refitting…" : `${s.fsm.fit}, ${s.fsm.ticks} ticks`}`;
  $("s-outcomes").textContent = Object.entries(s.outcomes).map(([k, v]) => `${k} ${v}`).join(", ") || "–";
  $("s-hz").textContent = `${fmt(st.hz, 1)} Hz`;
  const lat = s.latency_ms || {};
  $("s-latency").textContent = lat.received_p99 == null ? "–" : `${lat.received_p99} ms received, ${lat.applied_p99} ms executed`;
  const refused = Object.entries(s.refused || {});
  $("s-refused").textContent = refused.length ? refused.map(([k, v]) => `${k} ${v}`).join(", ") : "0";
  $("record").textContent = s.recording ? "Stop recording" : "Start recording";
  $("record").classList.toggle("on", !!s.recording);
}

function toCanvas(cv, f, x, y) {
  const s = cv.width / (f.length + 0.6);
  return [(x + f.length / 2 + 0.3) * s, (f.width / 2 + 0.3 - y) * s, s];
}

function drawField(s) {
  const cv = $("field"), g = cv.getContext("2d"), f = teach.config.field;
  g.clearRect(0, 0, cv.width, cv.height);
  const [x0, y0, k] = toCanvas(cv, f, -f.length / 2, f.width / 2);
  g.strokeStyle = "#fff"; g.lineWidth = 2;
  g.strokeRect(x0, y0, f.length * k, f.width * k);
  g.beginPath(); g.moveTo(cv.width / 2, y0); g.lineTo(cv.width / 2, y0 + f.width * k); g.stroke();
  for (const [gx, colour] of [[f.length / 2, "#3c6fd8"], [-f.length / 2, "#e2c61b"]]) {
    const [cx, cy] = toCanvas(cv, f, gx, f.goal_width / 2);
    g.fillStyle = colour;
    g.fillRect(cx - (gx > 0 ? 0 : 0.3 * k), cy, 0.3 * k, f.goal_width * k);
  }
  const t = s.truth;
  const [bx, by] = toCanvas(cv, f, t.ball_x, t.ball_y);
  g.fillStyle = "#ff7f00"; g.beginPath(); g.arc(bx, by, 0.05 * k, 0, 2 * Math.PI); g.fill();
  const [rx, ry] = toCanvas(cv, f, t.robot_x, t.robot_y);
  g.save(); g.translate(rx, ry); g.rotate(-t.robot_yaw);
  g.fillStyle = s.source === "teacher" ? "#fff4c2" : "#ddd"; g.strokeStyle = "#222";
  g.beginPath(); g.moveTo(0.16 * k, 0); g.lineTo(-0.1 * k, 0.08 * k); g.lineTo(-0.1 * k, -0.08 * k);
  g.closePath(); g.fill(); g.stroke(); g.restore();
}

// -- buttons ---------------------------------------------------------------------------------

for (const b of document.querySelectorAll("#modes button")) {
  b.addEventListener("click", () => send({ type: "mode", mode: b.dataset.mode }));
}
$("reset").addEventListener("click", () => {
  const v = $("location").value;
  send(v === "" ? { type: "reset" } : { type: "reset", location: Number(v) });
});
$("record").addEventListener("click", () => send({ type: "record", on: !(teach.state && teach.state.recording) }));
$("checkpoint").addEventListener("click", () => send({ type: "checkpoint" }));
$("field").addEventListener("click", (ev) => {
  const cv = $("field"), f = teach.config.field, r = cv.getBoundingClientRect();
  const k = cv.width / (f.length + 0.6);
  const x = (ev.clientX - r.left) * (cv.width / r.width) / k - f.length / 2 - 0.3;
  const y = f.width / 2 + 0.3 - (ev.clientY - r.top) * (cv.height / r.height) / k;
  const cx = Math.max(-f.length / 2, Math.min(f.length / 2, x));
  const cy = Math.max(-f.width / 2, Math.min(f.width / 2, y));
  send({ type: "place_ball", x: cx, y: cy });
});

connect();
