// The operator view's page: frames from the station over a WebSocket, drawn
// on a canvas in 3-D (a small perspective renderer written for this page:
// no library, nothing loaded from elsewhere), the per-vehicle table, the
// events, and the end buttons (docs/operator-view.md). Mission frame: x east,
// y north, z up, metres.
"use strict";
(() => {
  const token = document.querySelector('meta[name="gcs-token"]').content;
  const $ = (id) => document.getElementById(id);
  const TRAIL = 60; // positions kept per vehicle (6 s at 10 Hz)
  const view = {
    mode: "live", frames: 0, frame: null, scene: null, drawn: [], drawnT: null, trails: new Map(),
    draws: 0, answers: [],
  };
  const cam = { yaw: -0.9, pitch: 0.45, dist: 0, target: [0, 0, 0], fov: 0.9 };
  view.camera = cam;
  view.redraw = () => { dirty = true; };
  window.gcsView = view; // read by the browser test and handy in the console
  let dirty = true;
  let ws = null;
  let closedOnPurpose = false;

  // ------------------------------------------------------------- socket
  function connect() {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    ws = new WebSocket(`${proto}://${location.host}/ws?token=${encodeURIComponent(token)}`);
    ws.onopen = () => setConn("connected", true);
    ws.onclose = () => {
      setConn("disconnected", false);
      if (!closedOnPurpose) setTimeout(connect, 2000);
    };
    ws.onmessage = (ev) => {
      const msg = JSON.parse(ev.data);
      if (msg.type === "hello") hello(msg);
      else if (msg.type === "frame") onFrame(msg);
      else if (msg.type === "answer") onAnswer(msg);
    };
  }
  function send(obj) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(obj)); }
  function setConn(text, ok) { const c = $("conn"); c.textContent = text; c.className = "figure " + (ok ? "ok" : "bad"); }

  function hello(msg) {
    view.mode = msg.mode;
    if (msg.name) { $("name").textContent = msg.name; document.title = msg.name + " - gcs-swarm"; }
    const box = $("buttons");
    box.textContent = "";
    for (const [action, label] of msg.actions || []) {
      const b = document.createElement("button");
      b.textContent = label; b.className = "danger"; b.id = "end-" + action;
      b.onclick = () => askConfirm(action, label);
      box.appendChild(b);
    }
    $("replay").hidden = msg.mode !== "replay";
    $("events").textContent = "";
    events(msg.events);
    if (msg.mode === "replay") {
      $("slider").min = String(msg.start || 0);
      $("slider").max = String(msg.duration || 1);
    }
  }
  function askConfirm(action, label) {
    $("confirm-text").textContent = `${label} every vehicle and end the mission?`;
    $("confirm").hidden = false;
    $("confirm-yes").textContent = "Yes, " + label;
    $("confirm-yes").onclick = () => { $("confirm").hidden = true; send({ type: "end", action }); };
  }
  $("confirm-no").onclick = () => { $("confirm").hidden = true; };
  function onAnswer(msg) {
    view.answers.push(msg);
    const a = $("answer"); a.textContent = msg.text || ""; a.className = msg.ok ? "ok" : "err";
  }

  // -------------------------------------------------------------- frames
  const fmt = (x, d) => (x === null || x === undefined ? "-" : x.toFixed(d));
  const txt = (x) => (x === null || x === undefined ? "-" : String(x));
  function onFrame(f) {
    view.frame = f; view.scene = f.scene; view.frames += 1;
    $("clock").textContent = f.t.toFixed(2);
    $("stage").textContent = f.stage;
    $("behaviour").textContent = f.behaviour ? `${f.behaviour} (episode ${f.episode})` : "-";
    const drops = (f.view ? f.view.dropped : 0);
    $("drops").textContent = `view drops ${drops} · setpoint drops ${f.setpoints_dropped ?? 0}`;
    const v = f.vehicles;
    if (f.replay && f.replay.restart) view.trails.clear();
    for (let k = 0; k < v.sysid.length; k++) {
      const p = v.pos[k];
      if (!p) continue;
      let tr = view.trails.get(v.sysid[k]);
      if (!tr) { tr = []; view.trails.set(v.sysid[k], tr); }
      tr.push(p); if (tr.length > TRAIL) tr.shift();
    }
    if (cam.dist === 0) fit();
    if ($("follow").checked && f.leader) cam.target = f.leader.slice();
    table(v); events(f.events);
    if (f.replay) replayBar(f.replay);
    dirty = true;
  }

  function table(v) {
    const body = document.querySelector("#vehicles tbody");
    while (body.rows.length > v.sysid.length) body.deleteRow(-1);
    for (let k = 0; k < v.sysid.length; k++) {
      const row = body.rows[k] || body.insertRow();
      const p = v.pos[k];
      const cells = [
        v.label ? v.label[k] : v.sysid[k], txt(v.autopilot[k]), txt(v.phase[k]), txt(v.mode[k]),
        v.armed[k] === null ? "-" : v.armed[k] ? "yes" : "no",
        fmt(v.rate_hz[k], 1), v.loss[k] === null ? "-" : (100 * v.loss[k]).toFixed(1) + "%",
        fmt(v.heard_s[k], 2), p ? `${p[0].toFixed(2)} ${p[1].toFixed(2)} ${p[2].toFixed(2)}` : "-",
        fmt(v.radius[k], 3), fmt(v.nearest[k], 3), fmt(v.clearance[k], 2),
        fmt(v.accel[k], 2), fmt(v.correction[k], 2), v.in_formation[k] ? "in" : "out",
      ];
      while (row.cells.length < cells.length) row.insertCell();
      cells.forEach((c, i) => { const s = String(c); if (row.cells[i].textContent !== s) row.cells[i].textContent = s; });
      row.dataset.sysid = v.sysid[k];
      row.className = v.in_formation[k] ? "in" : (v.phase[k] === "lost" || v.phase[k] === "failed" ? "lost" : "out");
    }
  }

  function events(list) {
    if (!list || !list.length) return;
    const box = $("events");
    const atEnd = box.scrollTop + box.clientHeight >= box.scrollHeight - 4;
    for (const e of list) {
      const d = document.createElement("div");
      d.className = "ev-" + e.kind;
      d.textContent = `t=${e.t.toFixed(2)} ${e.kind.padEnd(6)} ${e.text}`;
      box.appendChild(d);
    }
    while (box.childNodes.length > 500) box.removeChild(box.firstChild);
    if (atEnd) box.scrollTop = box.scrollHeight;
  }

  // -------------------------------------------------------------- replay
  let sliding = false;
  function replayBar(r) {
    if (!sliding) $("slider").value = String(r.t);
    $("replay-t").textContent = `${r.t.toFixed(1)} / ${r.duration.toFixed(1)} s`;
    $("play").textContent = r.playing ? "Pause" : "Play";
  }
  $("play").onclick = () => send({ type: view.frame && view.frame.replay && view.frame.replay.playing ? "pause" : "play" });
  $("speed").onchange = () => send({ type: "speed", value: Number($("speed").value) });
  $("slider").oninput = () => { sliding = true; };
  $("slider").onchange = () => { sliding = false; view.trails.clear(); send({ type: "seek", t: Number($("slider").value) }); };

  // ------------------------------------------------------------ 3-D view
  const canvas = $("scene");
  const ctx = canvas.getContext("2d");
  let basis = null;
  function camera() {
    const cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch);
    const back = [cp * Math.cos(cam.yaw), cp * Math.sin(cam.yaw), sp];
    const eye = cam.target.map((t, i) => t + cam.dist * back[i]);
    const f = back.map((x) => -x);
    let r = [f[1], -f[0], 0]; // f x up(z)
    const rn = Math.hypot(r[0], r[1]) || 1; r = r.map((x) => x / rn);
    const u = [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]];
    const focal = canvas.height / (2 * Math.tan(cam.fov / 2));
    basis = { eye, f, r, u, focal };
  }
  function project(p) {
    const d = [p[0] - basis.eye[0], p[1] - basis.eye[1], p[2] - basis.eye[2]];
    const z = d[0] * basis.f[0] + d[1] * basis.f[1] + d[2] * basis.f[2];
    if (z < 0.05) return null;
    const x = d[0] * basis.r[0] + d[1] * basis.r[1] + d[2] * basis.r[2];
    const y = d[0] * basis.u[0] + d[1] * basis.u[1] + d[2] * basis.u[2];
    return [canvas.width / 2 + basis.focal * x / z, canvas.height / 2 - basis.focal * y / z, z];
  }
  function poly(points, close) {
    let started = false;
    ctx.beginPath();
    for (const p of points) {
      const s = project(p);
      if (!s) { started = false; continue; }
      if (!started) { ctx.moveTo(s[0], s[1]); started = true; } else ctx.lineTo(s[0], s[1]);
    }
    if (close && started) ctx.closePath();
  }
  function boxEdges(lo, hi) {
    const c = (i) => [i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]];
    const edges = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];
    for (const [a, b] of edges) { poly([c(a), c(b)]); ctx.stroke(); }
  }
  function boxFaces(lo, hi) {
    const c = (i) => [i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]];
    for (const q of [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]]) {
      poly(q.map(c), true); ctx.fill();
    }
  }
  function ellipse(centre, a, b) { // centre + cos t a + sin t b
    const pts = [];
    for (let k = 0; k <= 64; k++) {
      const t = (2 * Math.PI * k) / 64, cs = Math.cos(t), sn = Math.sin(t);
      pts.push([0, 1, 2].map((i) => centre[i] + cs * a[i] + sn * b[i]));
    }
    poly(pts); ctx.stroke();
  }
  const scaled = (v, s) => v.map((x) => x * s);
  function circle(centre, radius, a, b) { ellipse(centre, scaled(a, radius), scaled(b, radius)); }
  function grid(z, half, step) {
    const cx = Math.round(cam.target[0] / step) * step, cy = Math.round(cam.target[1] / step) * step;
    for (let k = -half; k <= half; k += step) {
      poly([[cx + k, cy - half, z], [cx + k, cy + half, z]]); ctx.stroke();
      poly([[cx - half, cy + k, z], [cx + half, cy + k, z]]); ctx.stroke();
    }
  }
  let ground = null;
  function groundZ() { // the floor, else a reference plane 2 m under the lowest vehicle first seen
    if (view.scene.floor !== null) return view.scene.floor;
    if (ground === null) {
      const zs = view.frame.vehicles.pos.filter((p) => p).map((p) => p[2]);
      if (!zs.length) return 0;
      ground = Math.floor(Math.min(...zs)) - 2;
    }
    return ground;
  }
  function colour(v, k) {
    if (v.in_formation[k]) return "#58a6ff";
    const ph = v.phase[k];
    if (ph === "lost" || ph === "failed") return "#ff7b72";
    if (ph === "ending" || ph === "ended") return "#d2a8ff";
    return "#9aa5b1";
  }

  function draw() {
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    const f = view.frame, sc = view.scene;
    view.drawn = [];
    if (!f || !sc) return;
    camera();
    const span = Math.max(10, Math.ceil(cam.dist));
    const step = span > 60 ? 10 : span > 25 ? 5 : 1;
    ctx.lineWidth = 1;
    ctx.strokeStyle = "#1e2a36";
    grid(groundZ(), span, step);
    if (sc.fence) { ctx.strokeStyle = "#e3b341"; ctx.setLineDash([6, 4]); boxEdges(sc.fence.min, sc.fence.max); ctx.setLineDash([]); }
    for (const o of sc.obstacles) {
      const lo = o.centre.map((c, i) => c - o.half[i]), hi = o.centre.map((c, i) => c + o.half[i]);
      ctx.fillStyle = "rgba(180,110,60,0.18)"; boxFaces(lo, hi);
      ctx.strokeStyle = "#c9824a"; boxEdges(lo, hi);
      // The avoidance field's edge, rho = r0 (an ellipsoid; its three sections).
      const [fx, fy, fz] = o.field;
      ctx.strokeStyle = "rgba(201,130,74,0.45)"; ctx.setLineDash([3, 4]);
      ellipse(o.centre, [fx, 0, 0], [0, fy, 0]);
      ellipse(o.centre, [fx, 0, 0], [0, 0, fz]);
      ellipse(o.centre, [0, fy, 0], [0, 0, fz]);
      ctx.setLineDash([]);
    }
    if (f.leader) {
      ctx.strokeStyle = "rgba(127,216,143,0.35)";
      circle(f.leader, sc.sphere_radius, basis.r, basis.u); // the sphere's outline
      circle(f.leader, sc.sphere_radius, [1, 0, 0], [0, 1, 0]); // its equator
      const s = project(f.leader);
      if (s) {
        ctx.fillStyle = "#7fd88f"; ctx.beginPath();
        ctx.moveTo(s[0], s[1] - 7); ctx.lineTo(s[0] + 6, s[1]); ctx.lineTo(s[0], s[1] + 7); ctx.lineTo(s[0] - 6, s[1]);
        ctx.fill(); ctx.fillText("leader", s[0] + 8, s[1] + 4);
      }
    }
    const v = f.vehicles;
    if ($("show-trails").checked) {
      ctx.strokeStyle = "rgba(88,166,255,0.35)";
      for (const tr of view.trails.values()) { poly(tr); ctx.stroke(); }
    }
    const order = [];
    for (let k = 0; k < v.sysid.length; k++) {
      if (!v.pos[k]) continue;
      const s = project(v.pos[k]);
      if (s) order.push([s, k]);
    }
    order.sort((a, b) => b[0][2] - a[0][2]); // far first
    ctx.font = "12px system-ui, sans-serif";
    for (const [s, k] of order) {
      const r = Math.max(3, Math.min(9, 60 / s[2]));
      ctx.fillStyle = colour(v, k);
      ctx.beginPath(); ctx.arc(s[0], s[1], r, 0, 2 * Math.PI); ctx.fill();
      ctx.fillStyle = "#d8dee6"; ctx.fillText(String(v.label ? v.label[k] : v.sysid[k]), s[0] + r + 2, s[1] - r);
      view.drawn.push({ sysid: v.sysid[k], x: s[0], y: s[1] });
    }
    axes();
    view.drawnT = f.t; // the frame time of what the canvas shows (tests wait on it)
    view.draws += 1;
  }
  function axes() { // east, north, up at the bottom left
    const o = [40, canvas.height - 40];
    const dirs = [[[1, 0, 0], "E", "#ff7b72"], [[0, 1, 0], "N", "#7fd88f"], [[0, 0, 1], "U", "#79c0ff"]];
    for (const [d, name, col] of dirs) {
      const x = d[0] * basis.r[0] + d[1] * basis.r[1] + d[2] * basis.r[2];
      const y = d[0] * basis.u[0] + d[1] * basis.u[1] + d[2] * basis.u[2];
      ctx.strokeStyle = col; ctx.fillStyle = col;
      ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(o[0] + 25 * x, o[1] - 25 * y); ctx.stroke();
      ctx.fillText(name, o[0] + 30 * x - 3, o[1] - 30 * y + 4);
    }
  }
  function fit() { // look at the leader from far enough to see every vehicle
    const f = view.frame;
    if (!f) return;
    const c = f.leader || [0, 0, 0];
    let far = f.scene.sphere_radius;
    for (const p of f.vehicles.pos) if (p) far = Math.max(far, Math.hypot(p[0] - c[0], p[1] - c[1], p[2] - c[2]));
    cam.target = c.slice(); cam.dist = 2.6 * far + 4;
  }

  let drag = null;
  canvas.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    cam.yaw -= (e.clientX - drag[0]) * 0.01;
    cam.pitch = Math.max(-1.5, Math.min(1.5, cam.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY]; dirty = true;
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault(); cam.dist = Math.max(1, cam.dist * Math.exp(e.deltaY * 0.001)); dirty = true;
  }, { passive: false });
  $("reset").onclick = () => { cam.yaw = -0.9; cam.pitch = 0.45; fit(); dirty = true; };
  $("follow").onchange = () => { dirty = true; };
  $("show-trails").onchange = () => { dirty = true; };
  window.addEventListener("resize", () => { dirty = true; });

  function tick() {
    if (dirty) { dirty = false; draw(); }
    requestAnimationFrame(tick);
  }
  window.addEventListener("beforeunload", () => { closedOnPurpose = true; });
  connect();
  requestAnimationFrame(tick);
})();
