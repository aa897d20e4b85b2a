// Weld-cell HMI page: one WebSocket to the hmi node (/ws), messages as in docs/HMI.md.
// Plain JS, no build step, no external resources (the cell PC has no internet).
"use strict";

const $ = (id) => document.getElementById(id);
const hmi = { ws: null, connected: false, retryMs: 500, nextId: 1, pending: new Map(), received: 0,
              readOnly: false, controls: null, status: null, statusAt: 0,
              operator: sessionStorage.getItem("operator") || "" };  // who signs decisions: asked once per session
window.hmi = hmi; // for a look from the browser console

function fmt(v, digits = 1) {
  return v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits);
}
function text(el, value) { if (el.textContent !== value) el.textContent = value; }
function li(content, cls) { const e = document.createElement("li"); e.textContent = content; if (cls) e.className = cls; return e; }
function el(tag, cls, content) { const e = document.createElement(tag); if (cls) e.className = cls; if (content !== undefined) e.textContent = content; return e; }
function duration(s) {
  if (s === null || s === undefined || Number.isNaN(s)) return "–";
  s = Math.max(0, Math.round(s));
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
  return (h ? h + ":" + String(m).padStart(2, "0") : String(m)) + ":" + String(sec).padStart(2, "0");
}

// -- connection ---------------------------------------------------------------------------------
function setConnected(up, why) {
  hmi.connected = up;
  $("connection").className = "conn " + (up ? "up" : "down");
  text($("connection-text"), up ? "connected" : why);
  applyControls();
}

// Buttons: enabled only when the node says the action is valid now (status.controls, from
// hmi.model.CellView.controls), the WebSocket is up and the page may command.
function applyControls() {
  const why = [];
  document.querySelectorAll("#controls button[data-cmd]").forEach((b) => {
    const c = hmi.controls ? hmi.controls[b.dataset.cmd] : null;
    let ok = hmi.connected && !hmi.readOnly && !!c && c.enabled;
    let title = c ? c.why : "no status from the HMI node yet";
    if (!hmi.connected) title = "no connection to the HMI node";
    else if (hmi.readOnly) title = "view only (no access token)";
    b.disabled = !ok;
    b.title = title;
    if (!ok && c && hmi.connected && !hmi.readOnly && b.dataset.cmd !== "estop") why.push(b.textContent + ": " + c.why);
  });
  $("ack-all").disabled = !hmi.connected || hmi.readOnly || !hmi.unacked;
  text($("controls-why"), why.join(" · "));
  const unsigned = !hmi.operator.trim();
  document.querySelectorAll("#decisions button").forEach((b) => {
    const needsName = b.dataset.signed === "1" && unsigned;
    b.disabled = !hmi.connected || hmi.readOnly || b.dataset.blocked === "1" || needsName;
    if (needsName) b.title = "enter your name above first: every decision is signed";
  });
  text($("operator-why"), unsigned ? "– enter your name: rework decisions and bend results are signed with it" : "");
}

// The operator's name, asked once per session (kept for this tab); sent with every decision.
$("operator-name").value = hmi.operator;
$("operator-name").addEventListener("input", (ev) => {
  hmi.operator = ev.target.value;
  sessionStorage.setItem("operator", hmi.operator.trim());
  applyControls();
});

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
function send(cmd, args) {
  const label = cmd + (args && args.stud_id ? " " + args.stud_id + " " + (args.decision || args.result || "") : "");
  const item = li(label + ": sent…", "pending");
  const replies = $("replies");
  replies.prepend(item);
  while (replies.children.length > 20) replies.lastChild.remove();
  if (!hmi.ws || hmi.ws.readyState !== WebSocket.OPEN) {
    item.className = "fail"; item.textContent = label + ": not sent, no connection to the HMI node";
    return;
  }
  const id = hmi.nextId++;
  hmi.pending.set(id, { cmd: label, el: item });
  hmi.ws.send(JSON.stringify(Object.assign({ cmd, id }, args || {})));
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
    : (msg.error || msg.message || "");
  el.textContent = (p ? p.cmd : (msg.cmd || "?")) + (msg.ok ? " ✔ " : " ✖ ") + detail;
  el.title = new Date().toLocaleTimeString();
}

// -- cell, arm, registration, job, errors ---------------------------------------------------------
function onCell(m) {
  const badge = $("cell-state");
  badge.className = "badge " + m.state;
  text(badge, m.state || "?");
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

// -- status: banner, buttons, progress, part, calibration, decisions (hmi.model.CellView) ----------
function onStatus(m) {
  hmi.status = m;
  hmi.statusAt = Date.now();
  hmi.controls = m.controls;
  applyControls();
  const banner = $("safety-banner");
  if (m.safety) {
    banner.hidden = false;
    banner.className = "banner " + m.safety.kind;
    text($("safety-title"), m.safety.title);
    text($("safety-text"), m.safety.text);
  } else {
    banner.hidden = true;
  }
  const badge = $("cell-state");
  if (m.safety) { badge.className = "badge " + m.safety.kind; text(badge, m.safety.title); }
  else if (m.cell) { badge.className = "badge " + m.cell.state; text(badge, m.cell.state); }
  const p = m.progress;
  $("progress-fill").style.width = p.percent.toFixed(1) + "%";
  text($("progress-text"), p.welded + " / " + p.total + " studs welded" + (p.failed ? ", " + p.failed + " failed" : "")
    + (p.skipped ? ", " + p.skipped + " skipped" : ""));
  text($("station"), p.stations_total ? p.station + " / " + p.stations_total : "–");
  text($("studs-remaining"), String(p.remaining));
  text($("studs-failed"), String(p.failed));
  text($("elapsed"), duration(p.elapsed_s));
  text($("cycle"), p.cycle_s === null ? "–" : fmt(p.cycle_s, 1) + " s/stud" + (p.last_cycle_s !== null ? " (last " + fmt(p.last_cycle_s, 1) + " s)" : ""));
  tickEta();
  const part = m.part;
  text($("part"), part.drawing ? "part " + part.part + " · " + part.drawing : "no drawing");
  text($("drawing"), part.drawing ? part.drawing + " (" + part.studs + " studs" + (part.warnings.length ? ", " + part.warnings.length + " warning(s)" : "") + ")" : "–");
  $("drawing").title = part.drawing_file + (part.warnings.length ? "\n" + part.warnings.join("\n") : "");
  const cal = $("calibration");
  if (m.calibration) {
    cal.className = m.calibration.agree ? "" : "bad";
    text(cal, (m.calibration.agree ? "" : "NODES DIFFER – ") + m.calibration.text);
    cal.title = "published by " + m.calibration.nodes.join(", ");
  } else { cal.className = ""; text(cal, "not published (/calibration/hand_eye)"); }
  renderDecisions(m.decisions);
}

function tickEta() {
  const m = hmi.status;
  if (!m) return;
  const p = m.progress, age = (Date.now() - hmi.statusAt) / 1000;
  if (p.eta_s === null) text($("eta"), "–");
  else if (!p.running) text($("eta"), p.eta_s === 0 ? "done" : duration(p.eta_s));
  else {
    const left = Math.max(0, p.eta_s - age);
    text($("eta"), duration(left) + " (≈ " + new Date(Date.now() + left * 1000).toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" }) + ")");
  }
}
setInterval(tickEta, 1000);

// A decision is two clicks: the first arms the button (its text asks to confirm), the second sends.
function decisionButton(label, confirmText, onConfirm, blocked, why, signed) {
  const b = el("button", "small", label);
  b.dataset.blocked = blocked ? "1" : "0";
  b.dataset.signed = signed ? "1" : "0";
  b.title = blocked ? why : "";
  b.addEventListener("click", () => {
    if (b.dataset.armed === "1") { b.dataset.armed = "0"; b.textContent = label; onConfirm(); return; }
    b.dataset.armed = "1"; b.textContent = confirmText; b.classList.add("armed");
    setTimeout(() => { if (b.dataset.armed === "1") { b.dataset.armed = "0"; b.textContent = label; b.classList.remove("armed"); } }, 5000);
  });
  return b;
}

function sameList(a, b) { return a.length === b.length && a.every((v, i) => v === b[i]); }

function renderDecisions(d) {
  // rebuilt only when the lists change (an armed confirmation survives the once-a-second status)
  const ukey = d.uncertain.concat([String(d.uncertain_enabled)]), rkey = d.rework.map((r) => r.stud_id + ":" + r.verdict);
  const uncertain = $("uncertain"), rework = $("rework");
  if (!hmi.uKey || !sameList(hmi.uKey, ukey)) {
    hmi.uKey = ukey;
    uncertain.replaceChildren(...d.uncertain.map((sid) => {
      const item = el("li", "decision");
      item.dataset.stud = sid;
      item.append(el("b", "", sid),
        decisionButton("Weld again", "Confirm: weld " + sid + " again?", () => send("resolve_stud", { stud_id: sid, decision: "weld_again" }),
                       !d.uncertain_enabled, d.uncertain_why),
        decisionButton("Mark as welded", "Confirm: " + sid + " is welded?", () => send("resolve_stud", { stud_id: sid, decision: "welded" }),
                       !d.uncertain_enabled, d.uncertain_why));
      return item;
    }));
  }
  text($("uncertain-why"), d.uncertain_enabled ? "check each stud at the part, then decide" : d.uncertain_why);
  if (!hmi.rKey || !sameList(hmi.rKey, rkey)) {
    hmi.rKey = rkey;
    rework.replaceChildren(...d.rework.map((r) => {
      const item = el("li", "decision");
      item.dataset.stud = r.stud_id;
      const note = el("input", "note");
      note.placeholder = "note (who checked what)";
      item.append(el("b", "", r.stud_id), el("span", "verdict v-" + r.verdict, r.verdict.replace(/_/g, " ")),
        el("span", "reasons", r.reasons.join(", ")),
        decisionButton("Rework", "Confirm: rework " + r.stud_id + "?", () => send("record_rework", { stud_id: r.stud_id, decision: "rework", note: note.value, operator: hmi.operator.trim() }), false, "", true),
        decisionButton("Accept", "Confirm: accept " + r.stud_id + "?", () => send("record_rework", { stud_id: r.stud_id, decision: "accept", note: note.value, operator: hmi.operator.trim() }), false, "", true),
        note);
      return item;
    }));
  }
  renderBendTests(d.bend_tests || [], d.bend_code || "");
  $("uncertain-box").hidden = !d.uncertain.length;
  $("rework-box").hidden = !d.rework.length;
  $("decisions").hidden = !d.uncertain.length && !d.rework.length && !(d.bend_tests || []).length;
  applyControls();
}

// The bend tests the QA record lists: those to do with Pass / Fail (two clicks), then those done.
function renderBendTests(tests, code) {
  const key = tests.map((t) => t.stud_id + ":" + (t.result || "") + ":" + (t.time || ""));
  text($("bend-code"), code || "–");
  $("bend-box").hidden = !tests.length;
  if (hmi.bKey && sameList(hmi.bKey, key)) return;
  hmi.bKey = key;
  $("bend-tests").replaceChildren(...tests.map((t) => {
    const item = el("li", "decision" + (t.result ? " done" : ""));
    item.dataset.stud = t.stud_id;
    const why = el("span", "reasons", t.reasons.join("; ") + (t.direction ? " – " + t.direction : ""));
    const angle = "bend " + (t.angle_deg === null ? "–" : fmt(t.angle_deg, 0) + "°");
    if (t.result) {
      item.append(el("b", "", t.stud_id), el("span", "verdict v-" + (t.result === "pass" ? "pass" : "fail"), t.result),
        el("span", "", angle + (t.bent_deg !== null ? " (bent " + fmt(t.bent_deg, 0) + "°)" : "")), why,
        el("small", "", "by " + (t.operator || "?") + ", " + (t.time || "").slice(0, 16).replace("T", " ")
           + (t.note ? " – " + t.note : "")));
      return item;
    }
    const bent = el("input", "angle");
    bent.type = "number"; bent.min = "1"; bent.max = "180"; bent.step = "1";
    bent.value = t.angle_deg === null ? "" : String(Math.round(t.angle_deg));
    bent.title = "the angle bent (°)";
    const note = el("input", "note");
    note.placeholder = "note (what was seen)";
    const result = (r) => () => send("record_bend_test", { stud_id: t.stud_id, result: r, note: note.value,
      angle_deg: bent.value === "" ? null : Number(bent.value), operator: hmi.operator.trim() });
    item.append(el("b", "", t.stud_id), el("span", "", angle), why, bent,
      decisionButton("Pass", "Confirm: " + t.stud_id + " passed?", result("pass"), false, "", true),
      decisionButton("Fail", "Confirm: " + t.stud_id + " failed?", result("fail"), false, "", true), note);
    return item;
  }));
}

function onJob(m) {
  text($("job"), m.status + ": " + m.welded.length + " welded, " + m.skipped.length + " skipped, " + m.failed.length + " failed – " + m.message);
  $("job-messages").replaceChildren(...(m.messages || []).map((t) => li(t)));
}

// -- alarms: code, severity, acknowledge; a cleared alarm moves to the history ---------------------
function alarmItem(a, withAck) {
  const item = el("li", "alarm sev-" + a.severity + (a.acked ? " acked" : " unacked") + (a.cleared ? " cleared" : ""));
  item.dataset.key = a.key;
  item.append(el("span", "code", a.code), el("span", "sev", a.severity),
    el("span", "src", new Date((a.cleared || a.raised) * 1000).toLocaleTimeString() + " " + a.source + ": "),
    el("span", "text", a.title + " – " + a.text));
  if (withAck && !a.acked) {
    const b = el("button", "small ack", "Ack");
    b.disabled = !hmi.connected || hmi.readOnly;
    b.addEventListener("click", () => send("ack", { alarm: a.key }));
    item.append(b);
  }
  item.title = a.cleared ? "cleared " + new Date(a.cleared * 1000).toLocaleTimeString() : (a.acked ? "acknowledged, still active" : "active, not acknowledged");
  return item;
}

function onAlarms(m) {
  hmi.unacked = m.unacked;
  const list = $("alarms");
  if (!m.active.length) list.replaceChildren(li("none", "none"));
  else list.replaceChildren(...m.active.map((a) => alarmItem(a, true)));
  $("alarm-history").replaceChildren(...m.history.map((a) => alarmItem(a, false)));
  const chip = $("alarm-summary");
  chip.className = "alarm-chip " + (m.highest || "none") + (m.unacked ? " unacked" : "");
  text(chip, m.active.length ? m.active.length + " alarm(s)" + (m.unacked ? ", " + m.unacked + " new" : "") : "no alarms");
  applyControls();
}
$("ack-all").addEventListener("click", () => send("ack", { alarm: "all" }));

function onOverlay(m) {
  const img = $("overlay");
  img.src = "data:image/jpeg;base64," + m.jpeg_base64;
  img.classList.add("shown");
  $("overlay-empty").style.display = "none";
  text($("overlay-info"), m.source_width + "×" + m.source_height);
}

// The latest inspection's overlay PNG, served by the HMI at the URL the message gives (null: none to show).
function onInspectionOverlay(m) {
  const img = $("inspection-overlay");
  const what = "station " + m.station + (m.file ? " · " + m.file : "");
  if (m.url) {
    img.src = m.url + (token ? "&token=" + encodeURIComponent(token) : "");
    img.classList.add("shown");
    $("inspection-empty").style.display = "none";
    text($("inspection-info"), what);
  } else {
    img.removeAttribute("src");
    img.classList.remove("shown");
    $("inspection-empty").style.display = "";
    text($("inspection-empty"), m.file ? "overlay " + m.file + " not available" : "no overlay for " + what);
    text($("inspection-info"), what);
  }
}

// -- stud table: rows updated in place (thousands of studs) --------------------------------------
const rowsById = new Map();
const COLS = ["stud_id", "status", "inclination_deg", "x", "y", "z", "xy_error_mm", "view", "weld", "inspection"];

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
    const weld = r.weld === "active" ? "● " + (r.phase || "active") : r.weld === "welded" ? "✔ welded"
      : r.reason ? "✖ " + r.reason.replace(/^unreachable: /, "") : r.weld;
    const insp = (r.inspection || "").replace(/_/g, " ") + (r.rework ? " → " + r.rework : "")
      + (r.bend ? " · bend " + r.bend : "");
    const cells = [r.stud_id, r.status.replace(/_/g, " "), fmt(r.inclination_deg, 1), fmt(p[0], 1), fmt(p[1], 1),
                   fmt(p[2], 1), fmt(r.xy_error_mm, 2), r.view === null ? "–" : String(r.view), weld, insp];
    cells.forEach((v, i) => text(tr.children[i], v));
    tr.lastChild.title = (r.inspection_reasons || []).join(", ");
    tr.children[1].title = tr.children[8].title = r.reason || "";
    const cls = "st-" + r.status + (r.weld ? " weld-" + r.weld : "") + (r.inspection ? " insp-" + r.inspection : "");
    if (tr.className !== cls) tr.className = cls;
  }
  for (const [id, tr] of rowsById) if (!seen.has(id)) { tr.remove(); rowsById.delete(id); }
  const counts = Object.entries(m.counts || {}).map(([k, v]) => k.replace(/_/g, " ") + " " + v).join(", ");
  text($("table-info"), m.total + " studs, " + m.welded + " welded" + (counts ? " – " + counts : "") + (m.view >= 0 ? " – view " + m.view + " (" + m.algorithm + ")" : ""));
}

function onHello(msg) {
  hmi.readOnly = !!msg.read_only;
  if (hmi.readOnly) text($("connection-text"), "connected, view only (no access token)");
  applyControls();
}

const HANDLERS = { hello: onHello, targets: onTargets, overlay: onOverlay, arm: onArm, cell: onCell, status: onStatus,
                   alarms: onAlarms, registration: onRegistration, job: onJob, reply: onReply,
                   inspection_overlay: onInspectionOverlay };

setConnected(false, "connecting…");
document.addEventListener("DOMContentLoaded", connect); // once the page's other scripts (plan.js) added their handlers
