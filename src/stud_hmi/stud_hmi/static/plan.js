// The plan of the whole part (docs/HMI.md, "The plan of the part"): the "plan" message of
// stud_hmi.part_plan drawn as inline SVG in metres (x right, y up), every stud coloured by its
// state (CSS class ps-<state>), the rail, the carriage with the arm's reach (from every "arm"
// message), the station being worked and the unreachable studs with their reasons. Zoom with the
// wheel or the + / − buttons, scroll by dragging, "Fit part" to see it all (done on load).
// Plain JS, no build step. Loaded after app.js: it adds its handlers to app.js's HANDLERS (app.js
// connects once every script of the page has run).
"use strict";

(() => {
  const NS = "http://www.w3.org/2000/svg";
  const $p = (id) => document.getElementById(id);
  const svg = $p("plan"), world = $p("plan-world");
  const layer = { rail: $p("plan-rail"), station: $p("plan-station"), marks: $p("plan-marks"),
                  studs: $p("plan-studs"), carriage: $p("plan-carriage") };
  // view: centre (cx, cy) [m] and scale [px/m]; fitKey: the layout and frame the view was fitted to
  const plan = { msg: null, view: null, fitScale: null, fitKey: null, circles: new Map(), selected: null,
                 carriage: null, minPx: 3 };
  window.hmiPlan = plan; // for a look from the browser console (and the browser test)

  function node(tag, attrs, parent) {
    const e = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
    if (parent) parent.append(e);
    return e;
  }
  function size() {
    const r = svg.getBoundingClientRect();
    return [Math.max(r.width, 1), Math.max(r.height, 1)];
  }

  // The view that fits box [x0, y0, x1, y1] into w x h px: as stud_hmi.part_plan.fit_view (the
  // browser test holds the two together).
  function fitView(box, w, h, margin = 24, minExtent = 0.05) {
    const bw = Math.max(box[2] - box[0], minExtent), bh = Math.max(box[3] - box[1], minExtent);
    const scale = Math.min(Math.max(w - 2 * margin, 1) / bw, Math.max(h - 2 * margin, 1) / bh);
    return { cx: (box[0] + box[2]) / 2, cy: (box[1] + box[3]) / 2, scale };
  }

  function fit() {
    const m = plan.msg;
    const box = m && (m.bounds_m || (m.rail ? [m.rail.extent_m[0], -0.5, m.rail.extent_m[1], 0.5] : null));
    if (!box) return;
    const [w, h] = size();
    plan.view = fitView(box, w, h);
    plan.fitScale = plan.view.scale;
    applyView();
  }

  // -- view: one transform for everything in metres; markers keep a readable size on screen -------
  function applyView() {
    const v = plan.view;
    if (!v) return;
    const [w, h] = size();
    world.setAttribute("transform", `matrix(${v.scale} 0 0 ${-v.scale} ${w / 2 - v.scale * v.cx} ${h / 2 + v.scale * v.cy})`);
    svg.dataset.scale = String(v.scale);
    const minR = plan.minPx / v.scale;
    for (const c of plan.circles.values()) c.setAttribute("r", Math.max(Number(c.dataset.r), minR));
    for (const c of layer.marks.children) c.setAttribute("r", Math.max(Number(c.dataset.r), 1.5 * minR));
    const base = layer.carriage.querySelector(".base");
    if (base) base.setAttribute("r", 1.5 * minR);
    const cam = layer.station.querySelector(".camera");
    if (cam) cam.setAttribute("r", 2 * minR);
    scaleBar(v.scale, h);
  }

  function scaleBar(scale, h) {
    $p("plan-scalebar").setAttribute("transform", `translate(0, ${h - 14})`);
    // a round length (1, 2, 5 x 10^k m) between 60 and 150 px
    let len = Math.pow(10, Math.floor(Math.log10(60 / scale)));
    for (const f of [1, 2, 5, 10]) if (f * len * scale >= 60) { len *= f; break; }
    $p("plan-scalebar-line").setAttribute("x2", String(16 + len * scale));
    const mm = len * 1000;
    $p("plan-scalebar-text").textContent = mm >= 1000 ? len.toFixed(len < 10 ? 1 : 0).replace(/\.0$/, "") + " m"
      : mm.toFixed(mm < 1 ? 2 : 0) + " mm";
  }

  function zoomAt(factor, px, py) {
    const v = plan.view;
    if (!v) return;
    const [w, h] = size();
    if (px === undefined) { px = w / 2; py = h / 2; }
    const lo = (plan.fitScale || v.scale) / 8, hi = 50000; // 50000 px/m: 0.02 mm a pixel
    const scale = Math.min(hi, Math.max(lo, v.scale * factor));
    const wx = v.cx + (px - w / 2) / v.scale, wy = v.cy - (py - h / 2) / v.scale; // the point under the cursor stays
    plan.view = { cx: wx - (px - w / 2) / scale, cy: wy + (py - h / 2) / scale, scale };
    applyView();
  }

  svg.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const r = svg.getBoundingClientRect();
    zoomAt(Math.pow(1.2, -ev.deltaY / 100), ev.clientX - r.left, ev.clientY - r.top);
  }, { passive: false });
  $p("plan-zoom-in").addEventListener("click", () => zoomAt(1.5));
  $p("plan-zoom-out").addEventListener("click", () => zoomAt(1 / 1.5));
  $p("plan-fit").addEventListener("click", fit);
  window.addEventListener("resize", applyView);

  // drag scrolls; a press that does not move is a click (a stud's details)
  let drag = null;
  svg.addEventListener("pointerdown", (ev) => {
    if (!plan.view || ev.button !== 0) return;
    drag = { x: ev.clientX, y: ev.clientY, cx: plan.view.cx, cy: plan.view.cy, moved: false, target: ev.target };
    try { svg.setPointerCapture(ev.pointerId); } catch (e) { /* a synthetic pointer: no capture needed */ }
  });
  svg.addEventListener("pointermove", (ev) => {
    if (!drag) return;
    const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
    if (!drag.moved && Math.hypot(dx, dy) < 4) return;
    drag.moved = true;
    svg.classList.add("dragging");
    plan.view = { cx: drag.cx - dx / plan.view.scale, cy: drag.cy + dy / plan.view.scale, scale: plan.view.scale };
    applyView();
  });
  svg.addEventListener("pointerup", (ev) => {
    if (!drag) return;
    const d = drag;
    drag = null;
    svg.classList.remove("dragging");
    if (svg.hasPointerCapture(ev.pointerId)) svg.releasePointerCapture(ev.pointerId);
    if (!d.moved) select(d.target && d.target.dataset ? d.target.dataset.stud || null : null);
  });

  // -- a stud's details: pointed at (its title), clicked (the line under the plan) ------------------
  function select(id, centre) {
    if (plan.selected && plan.circles.has(plan.selected)) plan.circles.get(plan.selected).classList.remove("selected");
    plan.selected = id && plan.circles.has(id) ? id : null;
    const c = plan.selected ? plan.circles.get(plan.selected) : null;
    if (c) {
      c.classList.add("selected");
      layer.studs.append(c); // on top
      if (centre && plan.view) { plan.view = { ...plan.view, cx: Number(c.getAttribute("cx")), cy: Number(c.getAttribute("cy")) }; applyView(); }
    }
    showDetail();
  }
  function showDetail() {
    const s = plan.selected && plan.msg ? plan.msg.studs.find((x) => x.stud_id === plan.selected) : null;
    text($p("plan-detail"), s ? s.stud_id + " · " + s.detail : "click a stud for its state and reason");
  }

  // -- the plan message --------------------------------------------------------------------------
  function onPlan(m) {
    plan.msg = m;
    plan.minPx = m.marker_min_px || plan.minPx;
    const inStation = new Set(m.station ? m.station.stud_ids : []);
    const seen = new Set();
    for (const s of m.studs) {
      seen.add(s.stud_id);
      let c = plan.circles.get(s.stud_id);
      if (!c) {
        c = node("circle", { "data-stud": s.stud_id }, layer.studs);
        node("title", {}, c);
        plan.circles.set(s.stud_id, c);
      }
      c.setAttribute("cx", s.xy_m[0]);
      c.setAttribute("cy", s.xy_m[1]);
      c.dataset.r = String(s.d_m > 0 ? s.d_m / 2 : 0);
      const cls = "stud ps-" + s.state + (inStation.has(s.stud_id) ? " in-station" : "")
        + (s.stud_id === plan.selected ? " selected" : "");
      if (c.getAttribute("class") !== cls) c.setAttribute("class", cls);
      c.dataset.state = s.state;
      c.firstChild.textContent = s.stud_id + " · " + s.detail;
    }
    for (const [id, c] of plan.circles) if (!seen.has(id)) { c.remove(); plan.circles.delete(id); }
    if (plan.selected && !seen.has(plan.selected)) plan.selected = null;

    layer.marks.replaceChildren(...m.marks.map((k) => {
      const c = node("circle", { class: "mark", cx: k.xy_m[0], cy: k.xy_m[1], "data-r": String(k.d_m / 2) });
      node("title", {}, c).textContent = "mark " + k.label;
      return c;
    }));
    drawRail(m);
    drawStation(m.station);
    plan.carriage = m.carriage;
    drawCarriage();
    legend(m);
    unreachableList(m.unreachable);
    const n = m.studs.length, b = m.bounds_m;
    text($p("plan-info"), (m.frame === "world" ? "world" : "drawing coordinates: the part is not registered yet")
      + " · " + n + " studs" + (b ? " · " + fmtLen(b[2] - b[0]) + " × " + fmtLen(b[3] - b[1]) : "")
      + (m.station ? " · station " + m.station.index + " / " + m.station.total : ""));
    const key = m.frame + ":" + m.layout_revision;
    if (plan.fitKey !== key && (b || m.rail)) { plan.fitKey = key; fit(); } else applyView();
    showDetail();
  }

  function fmtLen(m) { return m >= 1 ? m.toFixed(2) + " m" : (m * 1000).toFixed(0) + " mm"; }
  function text(el, value) { if (el.textContent !== value) el.textContent = value; }

  function drawRail(m) {
    const g = layer.rail;
    g.replaceChildren();
    g.setAttribute("class", m.frame === "world" ? "" : "unregistered");
    if (!m.rail) return;
    const [x0, x1] = m.rail.extent_m;
    node("line", { class: "rail", x1: x0, y1: 0, x2: x1, y2: 0 }, g);
    if (x1 - x0 <= 200) for (let x = Math.ceil(x0); x <= x1; x++) node("line", { class: "tick", x1: x, y1: -0.03, x2: x, y2: 0.03 }, g);
    node("title", {}, g).textContent = "rail " + (m.rail.length_m ? m.rail.length_m + " m" : "(length not given)");
  }

  function drawStation(st) {
    const g = layer.station;
    g.replaceChildren();
    if (!st) return;
    if (st.corners_m) node("polygon", { class: "footprint", points: st.corners_m.map((p) => p.join(",")).join(" ") }, g);
    const cam = node("circle", { class: "camera", cx: st.camera_xyz_m[0], cy: st.camera_xyz_m[1], r: 0.01 }, g);
    node("title", {}, cam).textContent = "camera of station " + st.index + " / " + st.total + " at "
      + st.camera_xyz_m.map((v) => (v * 1000).toFixed(0)).join(", ") + " mm";
  }

  function drawCarriage() {
    const g = layer.carriage, c = plan.carriage, m = plan.msg;
    if (!c || !m || !m.rail) { g.replaceChildren(); g.setAttribute("visibility", "hidden"); return; }
    g.setAttribute("visibility", "visible");
    g.setAttribute("class", (m.frame === "world" ? "" : "unregistered") + (c.moving ? " moving" : ""));
    let reach = g.querySelector(".reach");
    if (!reach) {
      reach = node("circle", { class: "reach" }, g);
      node("rect", { class: "carriage", width: 0.2, height: 0.12 }, g);
      node("circle", { class: "base" }, g);
      node("title", {}, g);
    }
    reach.setAttribute("cx", c.base_xy_m[0]); reach.setAttribute("cy", c.base_xy_m[1]); reach.setAttribute("r", c.reach_m);
    const rect = g.querySelector(".carriage");
    rect.setAttribute("x", c.position_m - 0.1); rect.setAttribute("y", -0.06);
    const base = g.querySelector(".base");
    base.setAttribute("cx", c.base_xy_m[0]); base.setAttribute("cy", c.base_xy_m[1]);
    g.dataset.position = String(c.position_m);
    g.querySelector("title").textContent = "carriage at " + c.position_m.toFixed(3) + " m" + (c.moving ? " (moving)" : "")
      + "; the arm reaches " + (c.reach_m * 1000).toFixed(0) + " mm about its base";
    text($p("plan-carriage-text"), "carriage " + c.position_m.toFixed(3) + " m" + (c.moving ? " moving" : ""));
    if (plan.view) base.setAttribute("r", 1.5 * plan.minPx / plan.view.scale);
  }

  function legend(m) {
    $p("plan-legend").replaceChildren(...m.states.map((s) => {
      const item = document.createElement("li");
      item.dataset.state = s.state;
      const sw = document.createElement("span");
      sw.className = "swatch ps-" + s.state;
      item.append(sw, document.createTextNode(s.label + " " + s.count));
      if (!s.count) item.className = "none";
      return item;
    }));
  }

  function unreachableList(list) {
    $p("plan-unreachable-box").hidden = !list.length;
    text($p("plan-unreachable-count"), String(list.length));
    $p("plan-unreachable").replaceChildren(...list.map((u) => {
      const item = document.createElement("li");
      item.dataset.stud = u.stud_id;
      const b = document.createElement("b");
      b.textContent = u.stud_id;
      item.append(b, document.createTextNode(" " + u.reason));
      item.title = "show " + u.stud_id + " on the plan";
      item.addEventListener("click", () => select(u.stud_id, true));
      return item;
    }));
  }

  // -- hooked into app.js's dispatch -------------------------------------------------------------
  HANDLERS.plan = onPlan;
  const onArmMessage = HANDLERS.arm;
  HANDLERS.arm = (m) => {
    onArmMessage(m);
    plan.carriage = m.carriage || null;
    drawCarriage();
    if (!m.carriage) text($p("plan-carriage-text"), "");
  };
  plan.fit = fit;
  plan.zoomAt = zoomAt;
  plan.fitView = fitView;
})();
