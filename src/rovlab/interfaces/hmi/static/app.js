// rovlab HMI page: live plots of the rovlab.io.messages stream and the tuning forms.
// Talks to the server over one WebSocket (/ws): JSON commands out, JSON frames in (see server.py).
// Units: SI inside the messages; the page shows heading and yaw rate in degrees.
"use strict";

(function () {
  const DEG = 180 / Math.PI;
  const $ = (id) => document.getElementById(id);

  // ------------------------------------------------------------------------------------------
  // State
  // ------------------------------------------------------------------------------------------
  const hmi = {
    stats: { frames: 0, messages: 0, rows: 0, lastT: NaN, draws: 0, hellos: 0, errors: 0 },
    source: null, // describe() of the source
    state: null, // run state
    docs: null, // {vehicle, truth, config}
    origins: null,
    loop: null, // what the loop uses now
    charts: {},
    sensorStatus: {},
    send: null,
  };
  window.hmi = hmi;

  // ------------------------------------------------------------------------------------------
  // DOM helpers
  // ------------------------------------------------------------------------------------------
  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "class") e.className = v;
      else if (k === "text") e.textContent = v;
      else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
      else if (k === "dataset") Object.assign(e.dataset, v);
      else e.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat()) {
      if (c === null || c === undefined || c === false) continue;
      e.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    }
    return e;
  }

  let toastTimer = null;
  function toast(text, error) {
    const t = $("toast");
    t.textContent = text;
    t.className = "toast" + (error ? " error" : "");
    t.hidden = false;
    clearTimeout(toastTimer);
    toastTimer = setTimeout(() => { t.hidden = true; }, error ? 7000 : 3500);
  }

  function fmtNum(v) {
    if (v === null || v === undefined) return "";
    if (typeof v !== "number") return Array.isArray(v) ? "[" + v.map(fmtNum).join(", ") + "]" : String(v);
    if (v === 0) return "0";
    const a = Math.abs(v);
    if (a < 1e-3 || a >= 1e6) return v.toExponential(Math.min(6, sigDigits(v) - 1));
    return String(+v.toPrecision(10));
  }
  function sigDigits(v) {
    const s = v.toExponential().split("e")[0].replace("-", "").replace(".", "");
    return s.replace(/0+$/, "").length || 1;
  }
  function short(v, digits) {
    if (v === null || v === undefined || !isFinite(v)) return "–";
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(digits === undefined ? 2 : digits);
    return (+v.toPrecision(digits === undefined ? 4 : digits + 1)).toString();
  }

  // key paths as in rovlab.params.edit: a.b, list[2].c, list[name=T1].c
  function parsePath(path) {
    return path.split(".").map((part) => {
      const m = /^([A-Za-z0-9_\-]+)(?:\[([^\]]*)\])?$/.exec(part);
      if (!m) return { key: part };
      if (m[2] === undefined) return { key: m[1] };
      if (m[2].includes("=")) {
        const [f, v] = m[2].split("=");
        return { key: m[1], match: [f.trim(), v.trim()] };
      }
      return { key: m[1], index: parseInt(m[2], 10) };
    });
  }
  function getPath(doc, path) {
    let node = doc;
    for (const step of parsePath(path)) {
      if (node === null || typeof node !== "object" || !(step.key in node)) return undefined;
      node = node[step.key];
      if (step.index !== undefined) {
        if (!Array.isArray(node)) return undefined;
        node = node[step.index];
      } else if (step.match) {
        if (!Array.isArray(node)) return undefined;
        node = node.find((e) => e && String(e[step.match[0]]) === step.match[1]);
      }
    }
    return node;
  }

  // ------------------------------------------------------------------------------------------
  // Connection
  // ------------------------------------------------------------------------------------------
  let ws = null;
  let nextId = 1;
  const pending = new Map();
  let retry = 500;

  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    ws = new WebSocket(`${proto}//${location.host}/ws`);
    ws.onopen = () => { retry = 500; setConn(true); };
    ws.onclose = () => {
      setConn(false);
      for (const [, p] of pending) p.reject({ message: "connection lost" });
      pending.clear();
      setTimeout(connect, retry);
      retry = Math.min(5000, retry * 2);
    };
    ws.onmessage = (ev) => {
      let msg;
      try { msg = JSON.parse(ev.data); } catch (e) { return; }
      dispatch(msg);
    };
  }

  function setConn(online) {
    const c = $("conn");
    c.textContent = online ? "online" : "offline";
    c.className = "conn " + (online ? "online" : "offline");
    for (const id of ["btn-run", "btn-step", "btn-reset", "speed"]) $(id).disabled = !online || !!(hmi.state && hmi.state.live);
    if (online && hmi.state) renderState();
  }

  function send(cmd, args) {
    return new Promise((resolve, reject) => {
      if (!ws || ws.readyState !== WebSocket.OPEN) { reject({ message: "not connected" }); return; }
      const id = nextId++;
      pending.set(id, { resolve, reject });
      ws.send(JSON.stringify(Object.assign({ cmd, id }, args || {})));
      setTimeout(() => {
        if (pending.has(id)) { pending.get(id).reject({ message: "no answer from the server" }); pending.delete(id); }
      }, 15000);
    });
  }
  hmi.send = send;

  function dispatch(msg) {
    switch (msg.type) {
      case "data": onData(msg); break;
      case "state": onState(msg); break;
      case "documents": onDocuments(msg); break;
      case "hello": onHello(msg); break;
      case "reset": clearCharts(); break;
      case "reply": {
        const p = pending.get(msg.id);
        if (p) { pending.delete(msg.id); p.resolve(msg.result || {}); }
        break;
      }
      case "error": {
        hmi.stats.errors++;
        const p = pending.get(msg.id);
        if (p) { pending.delete(msg.id); p.reject(msg); } else toast(msg.message, true);
        break;
      }
    }
  }

  // ------------------------------------------------------------------------------------------
  // Charts
  // ------------------------------------------------------------------------------------------
  const COLORS = { truth: "#1d2430", est: "#d0342c", band: "rgba(208,52,44,0.16)", ref: "#2e9d4f" };
  const MEAS_COLORS = ["#2f6fd6", "#e58a12", "#8a4fd1", "#16a0a8", "#b0407a"];
  const PWM_COLORS = ["#2f6fd6", "#e58a12", "#2e9d4f", "#d0342c", "#8a4fd1", "#8c6d31", "#16a0a8", "#b0407a"];
  const STATE_CHARTS = {
    z: { title: "depth z", unit: "m", k: 1, minSpan: 0.02 },
    psi: { title: "heading ψ", unit: "deg", k: DEG, minSpan: 2, period: 360 }, // an angle: drawn unwrapped (plot.js)
    w: { title: "heave velocity w", unit: "m/s", k: 1, minSpan: 0.02 },
    r: { title: "yaw rate r", unit: "deg/s", k: DEG, minSpan: 1 },
    b_w: { title: "heave bias b_w", unit: "N", k: 1, minSpan: 0.5 },
    b_r: { title: "yaw bias b_r", unit: "N m", k: 1, minSpan: 0.01 },
  };
  // the 4-DOF estimator's heave and yaw biases are the depth-and-heading filter's b_w and b_r
  const STATE_ALIAS = { b_Z: "b_w", b_N: "b_r" };
  let chartList = [];
  let channelsByColumn = {};
  let chartSignature = "";

  function buildCharts() {
    const src = hmi.source;
    const cs = src.controller_states || [];
    const signature = JSON.stringify([src.channels, src.thrusters, cs]);
    if (signature === chartSignature) return;
    chartSignature = signature;
    const grid = $("charts");
    grid.textContent = "";
    hmi.charts = {};
    chartList = [];
    channelsByColumn = {};
    const make = (id, opts) => {
      const canvas = el("canvas", { "aria-label": opts.title });
      grid.appendChild(el("div", { class: "chart", dataset: { chart: id } }, canvas));
      const c = new RovPlot.StripChart(canvas, opts);
      hmi.charts[id] = c;
      chartList.push(c);
      return c;
    };
    for (const [id, spec] of Object.entries(STATE_CHARTS)) {
      const c = make(id, spec);
      // one legend for all state charts (renderLegend); the per-chart legend is off
      c.add({ name: "band", label: "±2σ", kind: "band", fill: COLORS.band, legend: false });
      if (src.has_truth) c.add({ name: "truth", label: "truth", color: COLORS.truth, width: 1.4, legend: false });
      for (const ch of src.channels) {
        if (ch.quantity !== id) continue;
        c.add({ name: "meas:" + ch.column, label: ch.sensor, kind: "dots", color: sensorColor(ch.sensor), legend: false });
      }
      c.add({ name: "est", label: "estimate", color: COLORS.est, width: 1.8, legend: false });
      if (id === "z" || id === "psi") {
        c.add({ name: "ref", label: "reference", kind: "step", color: COLORS.ref, dash: [6, 4], width: 1.5, legend: false });
      }
      if (id === "z" && cs.includes("z_m")) {
        c.add({ name: "zm", label: "MRAC reference model", color: COLORS.ref, dash: [2, 3], width: 1.3 });
      }
    }
    renderLegend();
    for (const ch of src.channels) channelsByColumn[ch.column] = ch;
    if ((src.states || []).includes("x") && (src.states || []).includes("y")) {  // a 4-DOF estimate: the xy track
      const canvas = el("canvas", { "aria-label": "xy track" });
      grid.appendChild(el("div", { class: "chart track", dataset: { chart: "track" } }, canvas));
      const tr = new RovPlot.TrackPlot(canvas, { title: "xy track (north up)", minSpan: 0.5 });
      if (src.has_truth) tr.add({ name: "truth", label: "truth", color: COLORS.truth, width: 1.4 });
      tr.add({ name: "est", label: "estimate", color: COLORS.est, width: 1.4 });
      if (cs.includes("x_d")) tr.add({ name: "ref_model", label: "reference model", color: COLORS.ref, dash: [2, 3], width: 1.2 });
      tr.add({ name: "setpoint", label: "set-point", color: COLORS.ref, marker: true });
      hmi.charts.track = tr;
      chartList.push(tr);
    }
    make("tau_Z", { title: "heave force τ_Z", unit: "N", minSpan: 0.5 }).add({ name: "v", label: "allocated", color: "#2f6fd6", legend: false });
    make("tau_N", { title: "yaw moment τ_N", unit: "N m", minSpan: 0.01 }).add({ name: "v", label: "allocated", color: "#2f6fd6", legend: false });
    const pwm = make("pwm", { title: "thruster commands", unit: "µs", minSpan: 20 });
    src.thrusters.forEach((name, i) => pwm.add({ name, label: name, color: PWM_COLORS[i % PWM_COLORS.length], width: 1.3 }));
    if (cs.includes("F_hat")) {  // MRAC: the adapted parameters, live
      const f = make("mrac_F", { title: "MRAC F̂ (net down force)", unit: "N", minSpan: 0.5 });
      if (src.has_truth) f.add({ name: "truth", label: "truth", color: COLORS.truth, width: 1.2 });
      f.add({ name: "F_hat", label: "F̂", color: COLORS.est, width: 1.6 });
      const m = make("mrac_M", { title: "MRAC M̂, D̂_l, D̂_q", unit: "SI", minSpan: 1 });
      m.add({ name: "M_hat", label: "M̂", color: "#2f6fd6", width: 1.4 });
      m.add({ name: "D_l_hat", label: "D̂_l", color: "#e58a12", width: 1.4 });
      m.add({ name: "D_q_hat", label: "D̂_q", color: "#8a4fd1", width: 1.4 });
    }
  }

  function sensorColor(sensor) {
    const i = Math.max(0, hmi.source.sensors.indexOf(sensor));
    return MEAS_COLORS[i % MEAS_COLORS.length];
  }

  function renderLegend() {
    const box = $("legend");
    box.textContent = "";
    const item = (cls, color, text) => {
      const sw = el("span", { class: "swatch " + cls });
      if (color) { if (cls === "band") sw.style.background = color; else sw.style.borderColor = color; if (cls === "dot") sw.style.background = color; }
      return el("span", { class: "item" }, sw, text);
    };
    if (hmi.source.has_truth) box.appendChild(item("line", COLORS.truth, "truth"));
    box.appendChild(item("line", COLORS.est, "estimate"));
    box.appendChild(item("band", COLORS.band, "±2σ"));
    box.appendChild(item("dash", COLORS.ref, "reference"));
    for (const sensor of hmi.source.sensors) box.appendChild(item("dot", sensorColor(sensor), sensor));
  }

  function clearCharts() {
    for (const c of chartList) c.clear();
    hmi.sensorStatus = {};
    renderBadges();
  }

  function onData(msg) {
    const charts = hmi.charts;
    hmi.stats.frames++;
    hmi.stats.rows += msg.rows || 0;
    for (const [topic, m] of msg.messages) {
      const t = m.t;
      hmi.stats.messages++;
      if (charts.track) pushTrack(charts.track, topic, m);
      if (topic === "/rovlab/truth") {
        for (const [name, v] of Object.entries(m.state)) {
          const k = STATE_ALIAS[name] || name;
          const spec = STATE_CHARTS[k];
          if (spec && v !== null) charts[k].push("truth", t, v * spec.k);
        }
        if (charts.mrac_F && m.state.b_w !== undefined && m.state.b_w !== null) charts.mrac_F.push("truth", t, m.state.b_w);
      } else if (topic === "/rovlab/estimate") {
        for (const [name, v] of Object.entries(m.state)) {
          const k = STATE_ALIAS[name] || name;
          const spec = STATE_CHARTS[k];
          if (!spec || v === null) continue;
          const x = v * spec.k;
          charts[k].push("est", t, x);
          const variance = m.variance[name];
          if (variance !== null && variance !== undefined && variance >= 0) {
            const s = 2 * Math.sqrt(variance) * spec.k;
            charts[k].pushBand("band", t, x - s, x + s);
          }
        }
        hmi.sensorStatus = m.sensors || {};
        badgesDirty = true;
      } else if (topic === "/rovlab/measurement") {
        for (const [col, v] of Object.entries(m.values)) {
          const ch = channelsByColumn[col];
          if (!ch || !STATE_CHARTS[ch.quantity]) continue;
          // moved to the vehicle origin with the sensor's lever arm, as the filter sees it
          charts[ch.quantity].push("meas:" + col, t, (v - ch.offset) * STATE_CHARTS[ch.quantity].k);
        }
      } else if (topic === "/rovlab/reference") {
        if (m.state.z !== undefined && m.state.z !== null) charts.z.push("ref", t, m.state.z);
        if (m.state.psi !== undefined && m.state.psi !== null) charts.psi.push("ref", t, m.state.psi * DEG);
      } else if (topic === "/rovlab/command") {
        if (m.tau.Z !== undefined) charts.tau_Z.push("v", t, m.tau.Z);
        if (m.tau.N !== undefined) charts.tau_N.push("v", t, m.tau.N);
        for (const [name, v] of Object.entries(m.pwm_us || {})) charts.pwm.push(name, t, v);
        for (const [name, v] of Object.entries(m.controller || {})) {
          if (v === null) continue;
          if (name === "z_m" && charts.z) charts.z.push("zm", t, v);
          else if (name === "F_hat" && charts.mrac_F) charts.mrac_F.push("F_hat", t, v);
          else if (charts.mrac_M && (name === "M_hat" || name === "D_l_hat" || name === "D_q_hat")) charts.mrac_M.push(name, t, v);
        }
      }
      if (!(t < hmi.stats.lastT)) hmi.stats.lastT = t;
    }
    clockDirty = true;
  }

  // the xy track: north/east pairs from the truth, the estimate, the reference and the DP reference model
  function pushTrack(track, topic, m) {
    const pair = (o, a, b) => (o && o[a] !== undefined && o[a] !== null && o[b] !== undefined && o[b] !== null);
    if (topic === "/rovlab/truth" && pair(m.state, "x", "y")) track.push("truth", m.state.x, m.state.y);
    else if (topic === "/rovlab/estimate" && pair(m.state, "x", "y")) track.push("est", m.state.x, m.state.y);
    else if (topic === "/rovlab/reference" && pair(m.state, "x", "y")) track.push("setpoint", m.state.x, m.state.y);
    else if (topic === "/rovlab/command" && pair(m.controller, "x_d", "y_d")) track.push("ref_model", m.controller.x_d, m.controller.y_d);
  }

  // draw at most 10 times a second, only what changed
  let lastDraw = 0;
  let badgesDirty = false;
  let clockDirty = false;
  function frame(now) {
    requestAnimationFrame(frame);
    if (now - lastDraw < 95) return;
    lastDraw = now;
    let drew = 0;
    for (const c of chartList) if (c.dirty && c.draw()) drew++;
    if (drew) hmi.stats.draws++;
    if (badgesDirty) renderBadges();
    if (clockDirty) renderClock();
  }

  // ------------------------------------------------------------------------------------------
  // Sensor badges and the Run tab
  // ------------------------------------------------------------------------------------------
  function renderBadges() {
    badgesDirty = false;
    const box = $("badges");
    const src = hmi.source;
    if (!src) return;
    box.textContent = "";
    for (const ch of src.channels) {
      const status = hmi.sensorStatus[ch.column] || "–";
      box.appendChild(el("span", { class: "badge " + status, dataset: { channel: ch.name, status } },
        el("span", { class: "dot" }), `${ch.sensor} ${ch.quantity}`, el("span", { class: "state", text: status })));
    }
    // the live status next to each channel in the Run tab
    for (const node of document.querySelectorAll("[data-live-status]")) {
      const s = hmi.sensorStatus[node.dataset.liveStatus] || "–";
      node.textContent = s;
      node.className = "badge " + s;
    }
  }

  function renderClock() {
    clockDirty = false;
    const t = hmi.stats.lastT;
    $("clock").textContent = isFinite(t) ? `t = ${t.toFixed(1)} s` : "t = –";
  }

  function renderSensors() {
    const box = $("sensors");
    box.textContent = "";
    const src = hmi.source, st = hmi.state;
    for (const sensor of src.sensors) {
      const available = st.sensors[sensor] !== false;
      const btn = el("button", {
        type: "button", class: "toggle " + (available ? "on" : "off"), dataset: { sensor },
        text: available ? "on (sampling)" : "off (dropped out)",
        onclick: () => send("sensor", { sensor, available: !available }).catch((e) => toast(e.message, true)),
      });
      const channels = src.channels.filter((c) => c.sensor === sensor).map((ch) => {
        const sel = el("select", {
          dataset: { channel: ch.name },
          onchange: (ev) => send("filter_mode", { channel: ch.name, mode: ev.target.value })
            .catch((e) => { toast(e.message, true); renderSensors(); }),
        }, ["auto", "off", "on"].map((m) => el("option", { value: m, text: m === "auto" ? "filter: auto" : m === "off" ? "filter: forced off" : "filter: forced on" })));
        sel.value = st.filter_modes[ch.name] || "auto";
        const status = hmi.sensorStatus[ch.column] || "–";
        return el("div", { class: "channel" },
          el("span", {}, `${ch.quantity} `, el("span", { class: "badge " + status, dataset: { liveStatus: ch.column }, text: status })),
          sel);
      });
      box.appendChild(el("div", { class: "sensor" },
        el("div", { class: "head" }, el("span", { class: "name", text: sensor }), btn), channels));
    }
  }

  const REF_FIELDS = [["ref-north", "north_m"], ["ref-east", "east_m"], ["ref-depth", "depth_m"], ["ref-heading", "heading_deg"]];
  // fields the user typed into and has not sent yet: the live refresh leaves them alone, and Set
  // sends every one of them (not only the one that had the focus)
  const refEdited = new Set();
  // the running controller holds a north/east position (the source says which references it follows)
  function positionControl() {
    const refs = (hmi.source && hmi.source.references) || [];
    return refs.includes("x") && refs.includes("y");
  }

  function renderReference() {
    const ref = hmi.state.reference;
    const dp = positionControl();
    for (const id of ["ref-north-label", "ref-east-label"]) $(id).hidden = !dp;
    if (!dp) { refEdited.delete("ref-north"); refEdited.delete("ref-east"); }
    const st = hmi.state;
    const held = "now " + (dp ? `north ${short(ref.north_m, 3)} m, east ${short(ref.east_m, 3)} m, ` : "") +
      `${short(ref.depth_m, 3)} m, ${short(ref.heading_deg, 3)}° `;
    const veh = st.vehicle;
    if (st.live && st.engaged === false) $("ref-now").textContent = "no set-point held: the pilot has the vehicle";
    else if (st.live && st.engaged && veh && !veh.holding) $("ref-now").textContent = held + "wanted, not held: " + (veh.hold_blocked || "waiting for the vehicle");
    else $("ref-now").textContent = held + (st.live ? "(held)" : ref.schedule ? "(scenario schedule)" : "(set by hand)");
    for (const [id, key] of REF_FIELDS) {
      const v = ref[key];
      if (v === undefined) continue;
      const input = $(id);
      const live = short(v, 4);
      input.placeholder = live;
      input.title = `in the loop now: ${live}`;
      if (refEdited.has(id) || document.activeElement === input) continue;
      input.value = live;
      input.classList.remove("bad");
    }
  }

  function editReference(id) {
    const input = $(id);
    if (input.value.trim() === "") refEdited.delete(id); else refEdited.add(id);
    input.classList.toggle("edited", refEdited.has(id));
  }

  function cancelReferenceEdit(id) {
    refEdited.delete(id);
    $(id).classList.remove("edited", "bad");
    $("ref-msg").textContent = "";
    if (hmi.state) renderReference();
  }

  function setReference() {
    const args = {};
    const sent = [];
    for (const [id, key] of REF_FIELDS) {
      if (!refEdited.has(id)) continue;
      const raw = $(id).value.trim();
      if (raw === "") continue;
      const v = Number(raw);
      args[key] = isFinite(v) ? v : raw; // the server explains what is wrong with text or infinity
      sent.push([id, $(id).value]);
    }
    const m = $("ref-msg");
    m.classList.remove("okmsg");
    if (!sent.length) {
      m.textContent = "type a new value first (the fields show the set-point in the loop now)";
      return;
    }
    send("reference", args).then(() => {
      m.textContent = "";
      for (const [id, typed] of sent) {
        if ($(id).value !== typed) continue; // typed into again while the command was on its way: still edited
        refEdited.delete(id);
        $(id).classList.remove("bad", "edited");
        if (document.activeElement === $(id)) $(id).blur(); // the state frame that follows shows the loop's value
      }
    }).catch((e) => {
      m.textContent = e.message;
      const hit = REF_FIELDS.find(([, key]) => key === e.key);
      if (hit) $(hit[0]).classList.add("bad");
    });
  }

  // ------------------------------------------------------------------------------------------
  // Parameter forms
  // ------------------------------------------------------------------------------------------
  let fields = []; // {target, key, input, msg, opts}
  let formSignature = "";

  function problemText(p) {
    const text = p.text || "";
    return p.file && text.startsWith(p.file + ": ") ? text.slice(p.file.length + 2) : text;
  }

  function submit(f) {
    const raw = f.input.value.trim();
    let value = raw;
    if (raw === "") value = f.opts.optional ? null : "";
    const changes = { [f.key]: value };
    if (f.opts.extra) Object.assign(changes, f.opts.extra());
    f.input.classList.remove("ok");
    send("set", { target: f.target, changes }).then(() => {
      f.input.classList.remove("bad");
      f.input.classList.add("ok");
      setMsg(f, "");
      setTimeout(() => f.input.classList.remove("ok"), 1200);
    }).catch((e) => {
      f.input.classList.add("bad");
      const probs = e.problems || [];
      const text = probs.length ? "refused: " + probs.map(problemText).join("; ") : (e.message || "refused");
      setMsg(f, text, e.message);
    });
  }

  function setMsg(f, text, title) {
    f.msg.textContent = text;
    if (title) f.msg.title = title; else f.msg.removeAttribute("title");
  }

  function makeInput(target, key, opts, msgEl) {
    const input = el("input", { type: "text", inputmode: opts.list ? null : "decimal", spellcheck: "false",
      dataset: { target, key }, "aria-label": opts.label || key });
    const f = { target, key, input, msg: msgEl, opts };
    input.addEventListener("change", () => submit(f));
    input.addEventListener("keydown", (ev) => {
      if (ev.key === "Enter") { ev.preventDefault(); input.blur(); }
      if (ev.key === "Escape") { input.classList.remove("bad"); setMsg(f, ""); refreshField(f); input.blur(); }
    });
    fields.push(f);
    return f;
  }

  function fieldRows(box, target, specs) {
    const grid = el("div", { class: "fields" });
    for (const s of specs) {
      const msg = el("div", { class: "field-msg", dataset: { msgFor: `${target}:${s.key}` } });
      const f = makeInput(target, s.key, s, msg);
      grid.append(el("label", { class: "field-label", title: s.key }, s.label, s.sub ? el("small", {}, " " + s.sub) : null),
        f.input, el("span", { class: "unit", text: s.unit || "" }), msg);
    }
    box.appendChild(grid);
  }

  function tableRows(box, target, columns, rows) {
    // rows: [{name, cells: [{key, opts}]}]
    const msg = el("div", { class: "field-msg" });
    const t = el("div", { class: "table" });
    t.style.gridTemplateColumns = `64px repeat(${columns.length}, minmax(0, 1fr))`;
    t.appendChild(el("span", {}));
    for (const c of columns) t.appendChild(el("span", { class: "head", text: c }));
    for (const r of rows) {
      t.appendChild(el("span", { class: "rowname", text: r.name }));
      for (const cell of r.cells) {
        if (!cell) { t.appendChild(el("span", {})); continue; }
        const f = makeInput(target, cell.key, Object.assign({ label: `${r.name} ${cell.label || cell.key}` }, cell.opts || {}), msg);
        t.appendChild(f.input);
      }
    }
    box.append(t, msg);
  }

  function refreshField(f) {
    const doc = hmi.docs[f.target];
    let v = getPath(doc, f.key);
    f.input.value = v === undefined ? "" : fmtNum(v);
    if (f.opts.placeholder) f.input.placeholder = f.opts.placeholder() || "";
  }

  function refreshForms() {
    for (const f of fields) {
      if (document.activeElement === f.input || f.input.classList.contains("bad")) continue;
      refreshField(f);
    }
    renderLoop();
  }

  function vehicleForm(target) {
    const box = $("form-" + target);
    box.textContent = "";
    const doc = hmi.docs[target];
    box.appendChild(el("h4", { text: "Rigid body and buoyancy" }));
    fieldRows(box, target, [
      { key: "rigid_body.mass", label: "mass m", unit: "kg" },
      { key: "rigid_body.I_zz", label: "yaw inertia I_zz", unit: "kg m²" },
      { key: "restoring.displaced_volume", label: "displaced volume Δ", unit: "m³" },
    ]);
    box.appendChild(el("div", { class: "hint", dataset: { buoyancy: target } }));
    box.appendChild(el("h4", { text: "Added mass (SNAME: ≤ 0)" }));
    fieldRows(box, target, [
      { key: "added_mass.X_udot", label: "X_u̇", unit: "kg" },
      { key: "added_mass.Y_vdot", label: "Y_v̇", unit: "kg" },
      { key: "added_mass.Z_wdot", label: "Z_ẇ", unit: "kg" },
      { key: "added_mass.N_rdot", label: "N_ṙ", unit: "kg m²" },
    ]);
    box.appendChild(el("h4", { text: "Damping (≤ 0): linear, quadratic, cubic" }));
    tableRows(box, target, ["linear", "quadratic", "cubic"],
      ["surge", "sway", "heave", "yaw"].map((dof) => ({
        name: dof, cells: ["linear", "quadratic", "cubic"].map((k) => ({ key: `damping.${dof}.${k}`, label: k })),
      })));
    box.appendChild(el("p", { class: "hint", text: "linear N s/m (yaw N m s/rad), quadratic N s²/m², cubic N s³/m³" }));
    const thrusters = doc.thrusters || [];
    const quad = thrusters.filter((t) => (t.model || "quadratic") === "quadratic");
    if (quad.length) {
      box.appendChild(el("h4", { text: "Thruster curves (f = K_L s + K_NL s|s|)" }));
      tableRows(box, target, ["K_L⁺", "K_NL⁺", "K_L⁻", "K_NL⁻"], quad.map((t) => ({
        name: t.name,
        cells: ["K_L_pos", "K_NL_pos", "K_L_neg", "K_NL_neg"].map((k) => ({ key: `thrusters[name=${t.name}].quadratic.${k}`, label: k })),
      })));
      box.appendChild(el("p", { class: "hint", text: "K_L in N/µs, K_NL in N/µs² of PWM offset beyond the dead band" }));
    }
    const tab = thrusters.filter((t) => t.model === "table");
    if (tab.length) {
      box.appendChild(el("h4", { text: "Tabulated thrusters: supply voltage" }));
      fieldRows(box, target, tab.map((t) => ({ key: `thrusters[name=${t.name}].table.voltage`, label: t.name, unit: "V" })));
    }
  }

  function measurementId(m) { return `${m.sensor || m.kind}:${m.quantity}`; }
  let knownMeasurements = [];

  function observerForm() {
    const box = $("form-observer");
    box.textContent = "";
    const cfg = hmi.docs.config;
    const vehicleValue = (k) => () => {
      const v = hmi.loop && hmi.loop.vehicle;
      if (!v) return "";
      const map = { mass: v.mass, I_zz: v.I_zz, Z_wdot: v.added_mass[2], N_rdot: v.added_mass[3], Z_w: v.damping_linear[2], N_r: v.damping_linear[3] };
      return "vehicle: " + short(map[k]);
    };
    const modelExtra = () => (hmi.docs.config.model && hmi.docs.config.model.source) ? {} : { "model.source": "set in the rovlab HMI" };
    box.appendChild(el("h4", { text: "Model used by the filter and the LQR" }));
    box.appendChild(el("p", { class: "hint", text: "Overrides of the vehicle file; leave empty to use the model vehicle's value." }));
    fieldRows(box, "config", [
      ["mass", "mass m", "kg"], ["I_zz", "yaw inertia I_zz", "kg m²"], ["Z_wdot", "added mass Z_ẇ", "kg"],
      ["N_rdot", "added inertia N_ṙ", "kg m²"], ["Z_w", "heave damping Z_w", "N s/m"], ["N_r", "yaw damping N_r", "N m s/rad"],
    ].map(([k, label, unit]) => ({ key: `model.${k}`, label, unit, optional: true, placeholder: vehicleValue(k), extra: modelExtra })));

    box.appendChild(el("h4", { text: "Process noise W (spectral densities)" }));
    fieldRows(box, "config", [
      { key: "process_noise.psd.w", label: "heave force w_w", unit: "N² s" },
      { key: "process_noise.psd.r", label: "yaw moment w_r", unit: "N² m² s" },
      { key: "process_noise.psd.b_w", label: "heave bias drive", unit: "N²/s" },
      { key: "process_noise.psd.b_r", label: "yaw bias drive", unit: "N² m²/s" },
    ]);

    box.appendChild(el("h4", { text: "Bias time constants" }));
    const perMass = cfg.process_noise && cfg.process_noise.bias_time_per_mass !== undefined;
    const radio = el("div", { class: "radio" },
      el("label", {}, el("input", { type: "radio", name: "biasmode", value: "mass", checked: perMass, onchange: () => switchBias("mass") }), " T = factor × M"),
      el("label", {}, el("input", { type: "radio", name: "biasmode", value: "explicit", checked: !perMass, onchange: () => switchBias("explicit") }), " explicit T_w, T_r"));
    box.appendChild(radio);
    if (perMass) {
      fieldRows(box, "config", [{ key: "process_noise.bias_time_per_mass", label: "factor", unit: "s/kg" }]);
    } else {
      fieldRows(box, "config", [
        { key: "process_noise.bias_time_constant.w", label: "heave T_w", unit: "s" },
        { key: "process_noise.bias_time_constant.r", label: "yaw T_r", unit: "s" },
      ]);
    }
    box.appendChild(el("div", { class: "hint", dataset: { biasInUse: "1" } }));

    box.appendChild(el("h4", { text: "Measurements (R per channel)" }));
    const list = cfg.measurements || [];
    for (const m of list) {
      if (!knownMeasurements.some((k) => measurementId(k) === measurementId(m))) knownMeasurements.push(JSON.parse(JSON.stringify(m)));
    }
    const msgBox = el("div", { class: "field-msg" });
    const grid = el("div", { class: "fields" });
    for (const known of knownMeasurements) {
      const id = measurementId(known);
      const i = list.findIndex((m) => measurementId(m) === id);
      const used = i >= 0;
      const unit = known.quantity === "psi" ? "rad²" : known.quantity === "r" ? "rad²/s²" : known.quantity === "w" ? "m²/s²" : "m²";
      const check = el("input", { type: "checkbox", checked: used, dataset: { measurement: id }, onchange: (ev) => toggleMeasurement(known, ev.target.checked, msgBox, ev.target) });
      const label = el("label", { class: "field-label" }, check, ` ${(known.sensor || known.kind)} ${known.quantity}`);
      if (used) {
        const f = makeInput("config", `measurements[${i}].variance`, {
          optional: true, label: `${id} variance`,
          placeholder: () => {
            const name = hmi.loop && Object.keys(hmi.loop.R).find((n) => n.endsWith("." + known.quantity) && (known.sensor ? n.startsWith(known.sensor + ".") : true));
            return name ? "in use: " + short(hmi.loop.R[name], 2) : "";
          },
        }, msgBox);
        grid.append(label, f.input, el("span", { class: "unit", text: unit }));
      } else {
        grid.append(label, el("span", { class: "muted", text: "not fused" }), el("span", {}));
      }
    }
    box.append(grid, msgBox);

    box.appendChild(el("h4", { text: "Sensor management (all channels)" }));
    fieldRows(box, "config", [
      { key: "fusion.timeout_s", label: "lost after no sample for", unit: "s", optional: true, placeholder: () => "5 samples" },
      { key: "fusion.gate_probability", label: "innovation gate probability", unit: "", optional: true, placeholder: () => "0.9999" },
      { key: "fusion.gate_failures_to_lose", label: "gate failures to lose", unit: "", optional: true, placeholder: () => "3" },
      { key: "fusion.startup_s", label: "no gate after the start for", unit: "s", optional: true, placeholder: () => "from the design" },
      { key: "fusion.recovery_time_s", label: "spread a returning sensor's correction over", unit: "s", optional: true, placeholder: () => "5" },
      { key: "fusion.stuck_window_s", label: "stuck-sensor check window", unit: "s", optional: true, placeholder: () => "1" },
      { key: "fusion.reacquire_after_s", label: "re-admit a disagreeing sensor after", unit: "s", optional: true, placeholder: () => "5" },
    ]);
  }

  function switchBias(mode) {
    const loop = hmi.loop.model;
    const changes = mode === "mass"
      ? { "process_noise.bias_time_constant": null, "process_noise.bias_time_per_mass": 100.0 }
      : { "process_noise.bias_time_per_mass": null, "process_noise.bias_time_constant": { w: loop.T_w, r: loop.T_r } };
    send("set", { target: "config", changes }).catch((e) => { toast(e.message, true); formSignature = ""; renderForms(); });
  }

  function toggleMeasurement(known, on, msgBox, check) {
    const list = (hmi.docs.config.measurements || []).slice();
    const id = measurementId(known);
    let next;
    if (on) {
      const order = knownMeasurements.map(measurementId);
      next = list.concat([known]).sort((a, b) => order.indexOf(measurementId(a)) - order.indexOf(measurementId(b)));
    } else {
      next = list.filter((m) => measurementId(m) !== id);
    }
    send("set", { target: "config", key: "measurements", value: next }).then(() => { msgBox.textContent = ""; }).catch((e) => {
      check.checked = !on;
      const probs = e.problems || [];
      msgBox.textContent = "refused: " + (probs.length ? probs.map(problemText).join("; ") : e.message);
      msgBox.title = e.message;
    });
  }

  function controllerForm(box) {
    const current = hmi.docs.config.controller || "lqg";
    box.appendChild(el("h4", { text: "Controller" }));
    // every registered controller, rovlab's and installed plugins' (rovlab.core.components)
    const known = (hmi.loop && hmi.loop.controllers) || [{ name: "lqg", description: "LQR + bias estimate" },
      { name: "mrac", description: "adaptive heave, heading on the LQR" }];
    const sel = el("select", {
      dataset: { key: "controller" },
      onchange: (ev) => send("set", { target: "config", key: "controller", value: ev.target.value })
        .catch((e) => { toast(e.message, true); ev.target.value = current; }),
    }, ...known.map((c) => el("option", { value: c.name, text: c.description ? `${c.name}: ${c.description}` : c.name })));
    sel.value = current;
    const chosen = known.find((c) => c.name === current);
    if (chosen && chosen.description) sel.title = `${chosen.name}: ${chosen.description}`; // in full (the box may cut it)
    box.appendChild(sel);
    const running = hmi.loop && hmi.loop.controller;
    if (running === "mrac") mracForm(box);
    else if (running && hmi.loop.tables && hmi.loop.tables[running]) componentTableForm(box, running, `${running} (its [${running}] table; empty: default, shown grey)`);
  }

  // A component's own table of the design file ([dp], [ekf], a plugin's [pd]), as fields: its
  // numbers (defaults shown grey) and the per-axis tables the file gives. Any component, shipped or
  // not, gets this form from what it declares (hmi.loop.tables: the values in use).
  function componentTableForm(box, name, title) {
    const inUse = (hmi.loop && hmi.loop.tables && hmi.loop.tables[name]) || {};
    const doc = hmi.docs.config[name] || {};
    const extra = () => (hmi.docs.config[name] && hmi.docs.config[name].source) ? {} : { [`${name}.source`]: "tuned in the rovlab HMI" };
    const rows = [];
    const seen = new Set();
    for (const [k, v] of Object.entries(inUse)) {
      if (k === "source" || typeof v !== "number") continue;
      seen.add(k);
      rows.push({ key: `${name}.${k}`, label: k, unit: "SI", optional: true, placeholder: () => short(v, 4), extra });
    }
    for (const [k, v] of Object.entries(doc)) {  // per-axis tables as the file writes them, e.g. bandwidth = { x = 0.6 }
      if (seen.has(k) || !v || typeof v !== "object" || Array.isArray(v)) continue;
      for (const [sub, x] of Object.entries(v)) {
        if (typeof x === "number") rows.push({ key: `${name}.${k}.${sub}`, label: `${k} ${sub}`, unit: "SI", optional: true, extra });
      }
    }
    box.appendChild(el("h4", { text: title }));
    if (rows.length) fieldRows(box, "config", rows);
    else box.appendChild(el("p", { class: "hint", text: `[${name}] has no numbers to tune here` }));
  }

  function mracForm(box) {
    const used = (hmi.loop && hmi.loop.mrac) || {};
    // a new [mrac] table needs its source (closed schema, every number carries its source)
    const extra = () => (hmi.docs.config.mrac && hmi.docs.config.mrac.source) ? {} : { "mrac.source": "tuned in the rovlab HMI" };
    const ph = (v) => () => (v === undefined ? "" : short(v, 4));
    const gain = (i) => ph((used.gain || [])[i]);
    box.appendChild(el("h4", { text: "MRAC reference model (empty: default, shown grey)" }));
    fieldRows(box, "config", [
      { key: "mrac.bandwidth", label: "bandwidth ω_m", unit: "rad/s", optional: true, placeholder: ph(used.bandwidth), extra },
      { key: "mrac.damping", label: "damping ζ_m", unit: "", optional: true, placeholder: ph(used.damping), extra },
      { key: "mrac.max_step", label: "largest depth step", unit: "m", optional: true, placeholder: ph(used.max_step), extra },
    ]);
    box.appendChild(el("h4", { text: "MRAC law and adaptation" }));
    fieldRows(box, "config", [
      { key: "mrac.lambda", label: "λ (s = ė + λ e)", unit: "1/s", optional: true, placeholder: ph(used.lambda), extra },
      { key: "mrac.k_s", label: "k_s", unit: "N s/m", optional: true, placeholder: ph(used.k_s), extra },
      { key: "mrac.sigma", label: "σ-modification", unit: "1/s", optional: true, placeholder: ph(used.sigma), extra },
      { key: "mrac.gain.M", label: "gain Γ_M", unit: "SI", optional: true, placeholder: gain(0), extra },
      { key: "mrac.gain.D_l", label: "gain Γ_Dl", unit: "SI", optional: true, placeholder: gain(1), extra },
      { key: "mrac.gain.D_q", label: "gain Γ_Dq", unit: "SI", optional: true, placeholder: gain(2), extra },
      { key: "mrac.gain.F", label: "gain Γ_F", unit: "SI", optional: true, placeholder: gain(3), extra },
    ]);
  }

  function estimatorTableForm() {
    const name = hmi.loop && hmi.loop.estimator;
    if (!name || !hmi.loop.tables || !hmi.loop.tables[name]) return;
    componentTableForm($("form-observer"), name, `Estimator ${name} (its [${name}] table; empty: default, shown grey)`);
  }

  function lqrForm() {
    const box = $("form-lqr");
    box.textContent = "";
    controllerForm(box);
    box.appendChild(el("h4", { text: "LQR (heading; depth too with LQG)" }));
    const lqr = hmi.docs.config.lqr || {};
    const bryson = lqr.state_max !== undefined || lqr.input_max !== undefined;
    box.appendChild(el("div", { class: "radio" },
      el("label", {}, el("input", { type: "radio", name: "lqrmode", checked: bryson, onchange: () => switchLqr("bryson") }), " Bryson's rule"),
      el("label", {}, el("input", { type: "radio", name: "lqrmode", checked: !bryson, onchange: () => switchLqr("explicit") }), " explicit Q, R")));
    if (bryson) {
      box.appendChild(el("h4", { text: "Largest acceptable deviation" }));
      fieldRows(box, "config", [
        { key: "lqr.state_max.z", label: "depth", unit: "m" },
        { key: "lqr.state_max.psi_deg", label: "heading", unit: "deg" },
        { key: "lqr.state_max.w", label: "heave velocity", unit: "m/s" },
        { key: "lqr.state_max.r_deg_s", label: "yaw rate", unit: "deg/s" },
        { key: "lqr.input_max.Z", label: "heave force", unit: "N" },
        { key: "lqr.input_max.N", label: "yaw moment", unit: "N m" },
      ]);
      box.appendChild(el("h4", { text: "Extra weights (default 1)" }));
      fieldRows(box, "config", [
        { key: "lqr.input_weight.Z", label: "heave force weight", unit: "", optional: true, placeholder: () => "1" },
        { key: "lqr.input_weight.N", label: "yaw moment weight", unit: "", optional: true, placeholder: () => "1" },
        { key: "lqr.state_weight.z", label: "depth weight", unit: "", optional: true, placeholder: () => "1" },
        { key: "lqr.state_weight.psi", label: "heading weight", unit: "", optional: true, placeholder: () => "1" },
      ]);
    } else {
      fieldRows(box, "config", [
        { key: "lqr.Q_diag", label: "Q diagonal (z, ψ, w, r)", unit: "SI", list: true },
        { key: "lqr.R_diag", label: "R diagonal (Z, N)", unit: "SI", list: true },
      ]);
    }
    box.appendChild(el("h4", { text: "Reference feed-forward" }));
    const sel = el("select", {
      dataset: { key: "lqr.reference_gain" },
      onchange: (ev) => send("set", { target: "config", key: "lqr.reference_gain", value: ev.target.value })
        .catch((e) => { toast(e.message, true); }),
    }, el("option", { value: "discrete", text: "discrete model" }), el("option", { value: "continuous", text: "continuous model (thesis)" }));
    sel.value = lqr.reference_gain || "discrete";
    box.appendChild(sel);
  }

  function switchLqr(mode) {
    const loop = hmi.loop;
    let changes;
    if (mode === "explicit") {
      changes = { "lqr.state_max": null, "lqr.input_max": null, "lqr.input_weight": null, "lqr.state_weight": null,
        "lqr.Q_diag": loop.lqr_Q, "lqr.R_diag": loop.lqr_R };
    } else {
      const q = loop.lqr_Q, r = loop.lqr_R;
      if (q.some((x) => !(x > 0)) || r.some((x) => !(x > 0))) {
        toast("Bryson's rule needs every weight > 0 (a zero weight has no largest deviation)", true);
        formSignature = ""; renderForms();
        return;
      }
      const m = (x) => 1 / Math.sqrt(x);
      changes = { "lqr.Q_diag": null, "lqr.R_diag": null,
        "lqr.state_max": { z: m(q[0]), psi_deg: m(q[1]) * DEG, w: m(q[2]), r_deg_s: m(q[3]) * DEG },
        "lqr.input_max": { Z: m(r[0]), N: m(r[1]) } };
    }
    send("set", { target: "config", changes }).catch((e) => { toast(e.message, true); formSignature = ""; renderForms(); });
  }

  function renderLoop() {
    const loop = hmi.loop;
    if (!loop) return;
    const row = (a) => a.map((x) => short(x, 4).padStart(11)).join(" ");
    const m = loop.model;
    let mracText = "";
    if (loop.mrac) {
      const a = loop.mrac;
      const vec = (v) => v.map((x) => short(x, 4).padStart(9)).join(" ");
      mracText = "\n\nMRAC (heave): Z = Yᵀθ̂ − k_s s,  s = ė + λ e,  e = z − z_m\n" +
        `reference model: ω_m = ${short(a.bandwidth)} rad/s, ζ_m = ${short(a.damping)}; hedging ${a.hedge ? "on" : "off"}\n` +
        `θ = [${a.parameters.join(", ")}]  (${a.units.join(", ")})\n` +
        `initial ${vec(a.initial)}\nlower   ${vec(a.lower)}\nupper   ${vec(a.upper)}\ngain Γ  ${vec(a.gain)}\n` +
        `sampled loop spectral radius ${short(a.sampled_radius, 3)}; a ${short(a.max_step)} m step takes ` +
        `${short(a.heave_force_needed[0], 3)} N down / ${short(a.heave_force_needed[1], 3)} N`;
    }
    const ctl = loop.components && loop.components.controller;
    if (ctl && !loop.dp && !loop.K.length) {  // a controller the page has no view of: what it declares
      const lines = [`${ctl.name}: ${ctl.description || ""}`];
      const show = Object.keys(ctl.summary || {}).length ? ctl.summary : (loop.tables && loop.tables[ctl.name]) || {};
      for (const [k, v] of Object.entries(show)) lines.push(`${k} = ${Array.isArray(v) ? "[" + v.map((x) => short(x, 4)).join(", ") + "]" : (typeof v === "number" ? short(v, 4) : (typeof v === "object" ? JSON.stringify(v) : v))}`);
      $("loop-lqr").textContent = lines.join("\n");
      return;
    }
    if (loop.dp) {  // dynamic positioning: the PID gains per axis (Fossen 2011, pole placement)
      const g = loop.dp;
      const axes = ["x", "y", "z", "ψ"];
      $("loop-lqr").textContent = "DP: τ = M ν̇_d + D(ν_d) ν_d − Rᵀ(K_p e + K_i ∫e) − K_d ν̃ − b̂\n" +
        "axis          M        K_p        K_i        K_d\n" +
        axes.map((a, i) => a.padEnd(4) + [g.M[i], g.Kp[i], g.Ki[i], g.Kd[i]].map((x) => short(x, 4).padStart(11)).join("")).join("\n");
      return;
    }
    $("loop-lqr").textContent =
      (loop.mrac ? "heading: N = P r − K x − b̂_N (LQR row N)\n" : "τ = P r − K x − b̂\n") +
      "K (rows Z, N; columns z, ψ, w, r)\n" + loop.K.map(row).join("\n") +
      "\n\nP\n" + loop.P.map(row).join("\n") +
      `\n\nmodel: M_w = ${short(m.M_w)} kg, M_r = ${short(m.M_r)} kg m²\n       Z_w = ${short(m.Z_w)}, N_r = ${short(m.N_r)}` +
      mracText;
    for (const node of document.querySelectorAll("[data-buoyancy]")) {
      const v = loop[node.dataset.buoyancy];
      node.textContent = v ? `net buoyancy B − W = ${short(v.net_buoyancy, 3)} N (positive floats up)` : "";
    }
    for (const node of document.querySelectorAll("[data-bias-in-use]")) {
      node.textContent = `in use: T_w = ${short(m.T_w)} s, T_r = ${short(m.T_r)} s`;
    }
    const cfg = hmi.docs.config;
    const note = $("override-note");
    const over = cfg.model ? Object.keys(cfg.model).filter((k) => k !== "source") : [];
    note.hidden = over.length === 0;
    note.textContent = over.length ? `The configuration "${cfg.name}" overrides ${over.join(", ")} for the filter and the LQR ` +
      "(Observer tab); here they still set the allocation and the thrusters." : "";
  }

  function renderForms() {
    const d = hmi.docs;
    const signature = JSON.stringify([
      (d.vehicle.thrusters || []).map((t) => [t.name, t.model]), (d.truth.thrusters || []).map((t) => [t.name, t.model]),
      (d.config.measurements || []).map(measurementId), knownMeasurements.length,
      d.config.process_noise && d.config.process_noise.bias_time_per_mass !== undefined,
      d.config.lqr && d.config.lqr.state_max !== undefined,
      d.config.controller || "lqg", hmi.loop && hmi.loop.controller, hmi.loop && hmi.loop.estimator,
      Object.keys((hmi.loop && hmi.loop.tables) || {}).join(","),
    ]);
    if (signature !== formSignature) {
      formSignature = signature;
      fields = [];
      vehicleForm("vehicle");
      vehicleForm("truth");
      observerForm();
      estimatorTableForm();
      lqrForm();
    }
    const csel = document.querySelector('[data-key="controller"]');
    if (csel && document.activeElement !== csel) csel.value = d.config.controller || "lqg";
    const sel = document.querySelector('[data-key="lqr.reference_gain"]');
    if (sel && document.activeElement !== sel) sel.value = (d.config.lqr && d.config.lqr.reference_gain) || "discrete";
    refreshForms();
    renderFilesTab();
  }

  // ------------------------------------------------------------------------------------------
  // Files tab
  // ------------------------------------------------------------------------------------------
  function fileItem(path, url, note) {
    return el("li", {}, el("a", { href: url, text: path.split("/").pop(), title: path }), note ? ` — ${note}` : "", ` (${path})`);
  }

  function renderFilesTab() {
    const box = $("save-in-place");
    box.textContent = "";
    for (const target of ["vehicle", "config"]) {
      const o = hmi.origins && hmi.origins[target];
      if (!o || o.packaged || !o.file) continue;
      box.appendChild(el("button", { type: "button", text: `Save ${target} back to ${o.file.split("/").pop()}`,
        onclick: () => save(target, true) }));
    }
    if (hmi.state) $("log-rows").textContent = `${hmi.state.log.rows} rows in ${hmi.state.log.runs} run(s)`;
  }

  function save(target, inPlace) {
    send("save", { target, in_place: inPlace || false }).then((res) => {
      const list = $("saved");
      for (const [t, info] of Object.entries(res.saved)) {
        list.prepend(fileItem(info.path, info.url, `${t}${info.comments_kept ? ", comments kept" : ", comments could not be kept"}`));
      }
      toast("saved " + Object.values(res.saved).map((i) => i.path.split("/").pop()).join(", "));
    }).catch((e) => toast(e.message, true));
  }

  // ------------------------------------------------------------------------------------------
  // Frames from the server
  // ------------------------------------------------------------------------------------------
  function onHello(msg) {
    hmi.stats.hellos++;
    hmi.source = msg.source;
    chartSignature = "";
    buildCharts();
    clearCharts();
    onDocuments(msg.documents);
    onState(msg.state);
    const s = msg.source.scenario;
    $("title").textContent = `${s.name} — ${msg.source.vehicle} / ${msg.source.config} — ${s.plant} plant, seed ${s.seed}`;
    $("title").title = s.description;
    renderSensors();
  }

  function onDocuments(msg) {
    hmi.docs = msg.documents;
    hmi.origins = msg.origins;
    hmi.loop = msg.loop;
    if (msg.source) {
      const changed = JSON.stringify(msg.source.channels) !== JSON.stringify(hmi.source.channels);
      const ctlChanged = JSON.stringify(msg.source.controller_states || []) !== JSON.stringify(hmi.source.controller_states || []);
      hmi.source = msg.source;
      if (changed) { buildCharts(); renderSensors(); renderBadges(); } else if (ctlChanged) buildCharts();
    }
    renderForms();
  }

  function onState(st) {
    const before = hmi.state;
    hmi.state = st;
    renderState();
    if (!before || JSON.stringify(before.sensors) !== JSON.stringify(st.sensors) ||
        JSON.stringify(before.filter_modes) !== JSON.stringify(st.filter_modes)) renderSensors();
  }

  function renderState() {
    const st = hmi.state;
    const run = $("btn-run");
    run.textContent = st.running ? "Pause" : "Start";
    // a vehicle (MAVLink, ROS 2) runs on its own clock: nothing to start, step, reset or speed up
    const live = !!st.live;
    for (const id of ["btn-run", "btn-reset", "speed"]) {
      $(id).disabled = live || !ws || ws.readyState !== WebSocket.OPEN;
      if (live) $(id).title = "a live vehicle runs on its own clock";
    }
    $("btn-step").disabled = live || st.running || !ws || ws.readyState !== WebSocket.OPEN;
    // a vehicle has no scenario schedule; on a MAVLink vehicle the same command hands it back to the pilot
    const canRelease = live && st.engaged !== undefined && st.engaged !== null;
    $("ref-schedule").hidden = live && !(canRelease && st.engaged);
    $("ref-schedule").textContent = live ? "hand the vehicle back to the pilot" : "follow the scenario's schedule";
    const speed = $("speed");
    if (document.activeElement !== speed) {
      const v = String(st.speed);
      if (![...speed.options].some((o) => o.value === v)) speed.appendChild(el("option", { value: v, text: v + "×" }));
      speed.value = v;
    }
    if (!isFinite(hmi.stats.lastT)) $("clock").textContent = `t = ${st.time_s.toFixed(1)} s`;
    const p = st.pacing;
    const lag = p && p.lag_s !== null && p.lag_s !== undefined ? `lag ${(p.lag_s * 1000).toFixed(0)} ms · ` : "";
    const mode = st.live ? "live (the vehicle's clock)" : st.running ? "running" : "paused";
    $("lag").textContent = `${mode} · ${lag}${st.clients || 1} client${st.clients === 1 ? "" : "s"}`;
    renderReference();
    renderFilesTab();
  }

  // ------------------------------------------------------------------------------------------
  // Wiring
  // ------------------------------------------------------------------------------------------
  function init() {
    $("btn-run").addEventListener("click", () => send(hmi.state && hmi.state.running ? "pause" : "start").catch((e) => toast(e.message, true)));
    $("btn-step").addEventListener("click", () => send("step", { n: 1 }).catch((e) => toast(e.message, true)));
    $("btn-reset").addEventListener("click", () => send("reset").catch((e) => toast(e.message, true)));
    $("speed").addEventListener("change", (ev) => send("speed", { value: Number(ev.target.value) }).catch((e) => toast(e.message, true)));
    $("ref-set").addEventListener("click", setReference);
    for (const [id] of REF_FIELDS) {
      $(id).addEventListener("input", () => editReference(id));
      $(id).addEventListener("keydown", (ev) => {
        if (ev.key === "Enter") setReference();
        if (ev.key === "Escape") { $(id).blur(); cancelReferenceEdit(id); }
      });
    }
    $("ref-schedule").addEventListener("click", () => send("reference", { schedule: true }).catch((e) => toast(e.message, true)));
    for (const b of document.querySelectorAll("[data-save]")) b.addEventListener("click", () => save(b.dataset.save, false));
    for (const b of document.querySelectorAll("[data-revert]")) {
      b.addEventListener("click", () => send("revert", { target: b.dataset.revert })
        .then(() => { for (const f of fields) if (f.target === b.dataset.revert) { f.input.classList.remove("bad"); setMsg(f, ""); } refreshForms(); toast("reverted " + b.dataset.revert); })
        .catch((e) => toast(e.message, true)));
    }
    $("export").addEventListener("click", () => send("export", { formats: ["csv", "mcap"] }).then((res) => {
      const list = $("exported");
      list.textContent = "";
      for (const f of res.files) list.appendChild(fileItem(f.path, f.url));
      for (const n of res.notes || []) list.appendChild(el("li", { class: "muted", text: n }));
      toast(`exported ${res.files.length} file(s)`);
    }).catch((e) => toast(e.message, true)));
    for (const b of document.querySelectorAll("#tabs button")) {
      b.addEventListener("click", () => {
        for (const o of document.querySelectorAll("#tabs button")) o.classList.toggle("active", o === b);
        for (const t of document.querySelectorAll(".tab")) t.hidden = t.id !== "tab-" + b.dataset.tab;
      });
    }
    if (window.ResizeObserver) {
      new ResizeObserver(() => { for (const c of chartList) c.dirty = true; }).observe($("charts"));
    }
    connect();
    requestAnimationFrame(frame);
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init); else init();
})();
