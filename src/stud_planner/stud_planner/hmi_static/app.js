// Weld-cell HMI page: one WebSocket to the hmi node (/ws), messages as in docs/HMI.md.
// Plain JS, no build step, no external resources (the cell PC has no internet).
"use strict";

const $ = (id) => document.getElementById(id);
const hmi = { ws: null, connected: false, retryMs: 500, nextId: 1, pending: new Map(), received: 0 };
window.hmi = hmi; // for a look from the browser console

function fmt(v, digits = 1) {
  return v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits);
}
function text(el, value) { if (el.textContent !== value) el.textContent = value; }
function li(content, cls) { const e = document.createElement("li"); e.textContent = content; if (cls) e.className = cls; return e; }

// -- connection ---------------------------------------------------------------------------------
function setConnected(up, why) {
  hmi.connected = up;
  $("connection").className = "conn " + (up ? "up" : "down");
  text($("connection-text"), up ? "connected" : why);
  document.querySelectorAll("#controls button").forEach((b) => { b.disabled = !up; });
}

// The access token (docs/HMI.md), when the page was opened as http://host:port/?token=...
const token = new URLSearchParams(location.search).get("token");

function connect() {
  const url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws"
    + (token ? "?token=" + encodeURIComponent(token) : "");
  let ws;
  try { ws = new WebSocket(url); } catch (e) { scheduleReconnect(); return; }
  hmi.ws = ws;
  ws.onopen = () => { hmi.retryMs = 500; setConnected(true); };
  ws.onmessage = (ev) => {
    hmi.received++;
    let msg;
    try { msg = JSON.parse(ev.data); } catch (e) { console.warn("bad message", e); return; }
    const handler = HANDLERS[msg.type];
    if (handler) handler(msg);
  };
  ws.onclose = () => {
    if (hmi.ws !== ws) return;
    hmi.ws = null;
    for (const [id, p] of hmi.pending) { p.el.className = "fail"; p.el.textContent = p.cmd + ": connection lost before the reply (check the cell!)"; }
    hmi.pending.clear();
    scheduleReconnect();
  };
}

function scheduleReconnect() {
  const s = Math.round(hmi.retryMs / 100) / 10;
  setConnected(false, "disconnected: reconnecting in " + s + " s");
  setTimeout(connect, hmi.retryMs);
  hmi.retryMs = Math.min(hmi.retryMs * 2, 5000);
}

// -- buttons ------------------------------------------------------------------------------------
function send(cmd) {
  const el = li(cmd + ": sent…", "pending");
  const replies = $("replies");
  replies.prepend(el);
  while (replies.children.length > 20) replies.lastChild.remove();
  if (!hmi.ws || hmi.ws.readyState !== WebSocket.OPEN) {
    el.className = "fail"; el.textContent = cmd + ": not sent, no connection to the HMI node";
    return;
  }
  const id = hmi.nextId++;
  hmi.pending.set(id, { cmd, el });
  hmi.ws.send(JSON.stringify({ cmd, id }));
}
document.querySelectorAll("#controls button[data-cmd]").forEach((b) => b.addEventListener("click", () => send(b.dataset.cmd)));

function onReply(msg) {
  const p = hmi.pending.get(msg.id);
  if (p) hmi.pending.delete(msg.id);
  const el = p ? p.el : li("", "");
  if (!p) $("replies").prepend(el);
  el.className = msg.ok ? "ok" : "fail";
  const detail = msg.results && msg.results.length
    ? msg.results.map((r) => r.service + ": " + (r.success ? "ok" : "FAILED") + (r.message ? " – " + r.message : "")).join("; ")
    : (msg.error || "");
  el.textContent = (msg.cmd || "?") + (msg.ok ? " ✔ " : " ✖ ") + detail;
  el.title = new Date().toLocaleTimeString();
}

// -- cell, arm, registration, job, errors ---------------------------------------------------------
function onCell(m) {
  const badge = $("cell-state");
  badge.className = "badge " + m.state;
  text(badge, m.state || "?");
  const pct = m.studs_total ? (100 * m.studs_welded) / m.studs_total : 0;
  $("progress-fill").style.width = pct.toFixed(1) + "%";
  text($("progress-text"), m.studs_welded + " / " + m.studs_total + " studs welded");
  text($("station"), m.stations_total ? m.station + " / " + m.stations_total : "–");
  text($("studs-failed"), String(m.studs_failed));
  text($("cell-message"), m.message || "");
  text($("unreachable"), m.unreachable && m.unreachable.length ? "unreachable: " + m.unreachable.join(", ") : "");
}

function onArm(m) {
  const mode = $("arm-mode");
  mode.className = "mode-" + m.mode;
  text(mode, m.mode);
  const c = $("arm-connected");
  c.className = m.connected ? "" : "bad";
  text(c, m.connected ? "connected" : "NOT connected");
  text($("arm-stud"), m.current_stud || "–");
  text($("arm-job"), m.total ? m.done + " / " + m.total : "–");
  text($("arm-tool"), m.tool_position_mm ? m.tool_position_mm.map((v) => fmt(v, 1)).join(", ") : "–");
  text($("arm-message"), m.message || "–");
  const errs = $("arm-errors");
  errs.replaceChildren(...(m.errors || []).map((e, i) => li(e + (m.error_codes && m.error_codes[i] !== undefined ? " (0x" + m.error_codes[i].toString(16) + ")" : ""))));
}

function onRegistration(m) {
  const r = $("registration");
  r.className = m.valid ? "" : "bad";
  text(r, m.valid ? "valid, residual " + fmt(m.residual_mm, 2) + " mm" : "NOT valid: " + m.message);
}

function onJob(m) {
  text($("job"), m.status + ": " + m.welded.length + " welded, " + m.skipped.length + " skipped, " + m.failed.length + " failed – " + m.message);
  $("job-messages").replaceChildren(...(m.messages || []).map((t) => li(t)));
}

function onErrors(m) {
  const items = m.items || [];
  if (!items.length) { $("errors").replaceChildren(li("none", "none")); return; }
  $("errors").replaceChildren(...items.map((e) => {
    const el = li("", e.level + (e.active ? "" : " inactive"));
    const src = document.createElement("span");
    src.className = "src";
    src.textContent = new Date(e.last * 1000).toLocaleTimeString() + " " + e.name + ": ";
    el.append(src, e.message + (e.count > 1 ? " (×" + e.count + ")" : ""));
    el.title = e.level + (e.active ? ", still reported" : ", cleared");
    return el;
  }));
}

function onOverlay(m) {
  const img = $("overlay");
  img.src = "data:image/jpeg;base64," + m.jpeg_base64;
  img.classList.add("shown");
  $("overlay-empty").style.display = "none";
  text($("overlay-info"), m.source_width + "×" + m.source_height);
}

// -- stud table: rows updated in place (thousands of studs) --------------------------------------
const rowsById = new Map();
const COLS = ["stud_id", "status", "inclination_deg", "x", "y", "z", "xy_error_mm", "view", "weld"];

function makeRow(id) {
  const tr = document.createElement("tr");
  tr.dataset.stud = id;
  for (const c of COLS) { const td = document.createElement("td"); td.className = "c-" + c.replace("_deg", "").replace("_mm", ""); tr.append(td); }
  return tr;
}

function onTargets(m) {
  const tbody = document.querySelector("#studs tbody");
  const seen = new Set();
  let prev = null;
  for (const r of m.rows) {
    seen.add(r.stud_id);
    let tr = rowsById.get(r.stud_id);
    if (!tr) { tr = makeRow(r.stud_id); rowsById.set(r.stud_id, tr); }
    if ((prev ? prev.nextSibling : tbody.firstChild) !== tr) tbody.insertBefore(tr, prev ? prev.nextSibling : tbody.firstChild);
    prev = tr;
    const p = r.position_mm || [null, null, null];
    const weld = r.weld === "active" ? "● " + (r.phase || "active") : r.weld === "welded" ? "✔ welded" : r.weld;
    const cells = [r.stud_id, r.status.replace(/_/g, " "), fmt(r.inclination_deg, 1), fmt(p[0], 1), fmt(p[1], 1),
                   fmt(p[2], 1), fmt(r.xy_error_mm, 2), r.view === null ? "–" : String(r.view), weld];
    cells.forEach((v, i) => text(tr.children[i], v));
    const cls = "st-" + r.status + (r.weld ? " weld-" + r.weld : "");
    if (tr.className !== cls) tr.className = cls;
  }
  for (const [id, tr] of rowsById) if (!seen.has(id)) { tr.remove(); rowsById.delete(id); }
  const counts = Object.entries(m.counts || {}).map(([k, v]) => k.replace(/_/g, " ") + " " + v).join(", ");
  text($("table-info"), m.total + " studs, " + m.welded + " welded" + (counts ? " – " + counts : "") + (m.view >= 0 ? " – view " + m.view + " (" + m.algorithm + ")" : ""));
}

function onHello(msg) {
  hmi.readOnly = !!msg.read_only;
  if (hmi.readOnly) {
    text($("connection-text"), "connected, view only (no access token)");
    document.querySelectorAll("#controls button[data-cmd]").forEach((b) => { b.disabled = true; });
  }
}

const HANDLERS = { hello: onHello, targets: onTargets, overlay: onOverlay, arm: onArm, cell: onCell,
                   errors: onErrors, registration: onRegistration, job: onJob, reply: onReply };

setConnected(false, "connecting…");
connect();
