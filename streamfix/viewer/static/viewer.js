// streamfix view: raw vs cleaned skeletons in 3D (hand-written canvas renderer) and rolling plots.
//
// Data flow: the server sends {"type":"frames","records":[...]} over /ws; each record is one
// paired instant of a stream (raw, live and clean joints of every body, recovered flags,
// latencies) the page has not had yet, at most a few per stream. onmessage acknowledges
// (the server sends at most a couple of unacknowledged messages, so nothing queues), adds
// every record to the rolling plots and to a short per-stream playout queue. The service
// emits clean frames a window hop at a time; on requestAnimationFrame each stream's queue
// is played at the records' sensor timing, so bursts are shown as smooth motion, and a
// queue that lags more than MAX_LAG_S is skipped ahead (counted) rather than let grow. window.sfStatus is the page's own account of what it drew
// (read by tests through the DevTools protocol, and reported to the server's /status).
"use strict";

const HISTORY_S = 10;                 // seconds shown in the rolling plots
const MAX_LAG_S = 0.4;                // playout queue longer than this (sensor time): skip ahead
const COLORS = { raw: "#f0a030", live: "#8fbc8f", clean: "#4c9be8", rec: "#ff4d4d" };

const layouts = {};                   // stream -> {skeleton, joint_names, bones, rate_hz}
const latest = {};                    // stream -> record on screen
const playout = {};                   // stream -> {queue: [records], clock: sensor time (s) shown}
const history = {};                   // "stream#body" -> {t:[], raw:[], clean:[], rawBone:[], cleanBone:[]}
const latency = { t: [], live: [], clean: [], wire: [] };
let dirty = true;  // draw once at start ("waiting for frames")
let ws = null;

const status = window.sfStatus = {
  connected: false, messages: 0, records: 0, skipped: 0, framesDrawn: 0, rafTicks: 0, renderFps: 0, drawMs: 0, ageMs: null, maxAgeMs: 0,
  streams: 0, bodies: 0, expectedJoints: 0, jointsDrawn: { raw: 0, live: 0, clean: 0 }, recoveredDrawn: 0,
  lastSeq: {}, bridge: null, error: null,
};

const $ = (id) => document.getElementById(id);
const camera = { yaw: 0, pitch: 0.2, dist: 2.6, target: null, up: null, auto: true };  // auto: fit until zoomed

// ------------------------------------------------------------------ connection
function connect() {
  ws = new WebSocket(`ws://${location.host}/ws`);
  ws.onopen = () => { status.connected = true; $("conn").textContent = "connected"; dirty = true; };
  ws.onclose = () => {
    status.connected = false; $("conn").textContent = "disconnected, retrying...";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.type === "hello") { $("title").textContent = msg.title; document.title = msg.title; return; }
    if (msg.type !== "frames") return;
    ws.send('{"type":"ack"}');
    status.messages += 1;
    status.bridge = msg.bridge;
    Object.assign(layouts, msg.layouts);
    for (const rec of msg.records) take(rec);
  };
}

function take(rec) {
  status.records += 1;
  const p = playout[rec.stream] || (playout[rec.stream] = { queue: [], clock: null });
  p.queue.push(rec);
  const lay = layouts[rec.stream];
  const j = jointIndex(lay);
  const axis = +$("axis").value;
  for (const b of rec.bodies) {
    const key = `${rec.stream}#${b.id}`;
    const h = history[key] || (history[key] = { t: [], raw: [], clean: [], rawBone: [], cleanBone: [] });
    h.t.push(rec.t);
    h.raw.push(coord(b.raw, j, axis));
    h.clean.push(coord(b.clean, j, axis));
    const parent = lay ? parentOf(lay, j) : -1;
    h.rawBone.push(boneLen(b.raw, parent, j));
    h.cleanBone.push(boneLen(b.clean, parent, j));
    trim(h, rec.t);
  }
  const L = rec.latency_ms;
  latency.t.push(rec.t); latency.live.push(L.live); latency.clean.push(L.clean); latency.wire.push(L.wire);
  trim(latency, rec.t);
}

function trim(h, tNow) {
  let k = 0;
  while (k < h.t.length && (h.t[k] < tNow - HISTORY_S || h.t[k] > tNow)) k++;  // old, or before a loop restart
  if (k > 0) for (const name in h) h[name].splice(0, k);
}

const coord = (joints, j, axis) => (joints && joints[j] ? joints[j][axis] : null);
function boneLen(joints, a, b) {
  if (!joints || a < 0 || !joints[a] || !joints[b]) return null;
  const d = [0, 1, 2].map((i) => joints[a][i] - joints[b][i]);
  return 100 * Math.hypot(d[0], d[1], d[2]);  // cm
}
function parentOf(lay, j) {
  for (const [p, c] of lay.bones) if (c === j) return p;
  for (const [p, c] of lay.bones) if (p === j) return c;  // a root joint: its first child
  return -1;
}
// The joint select lists the plotted body's skeleton; other skeletons plot the joint of the same name.
function fillJoints(lay) {
  const sel = $("joint"), keep = sel.selectedOptions[0] ? sel.selectedOptions[0].text : null;
  sel.innerHTML = lay.joint_names.map((n, i) => `<option value="${i}">${n}</option>`).join("");
  let j = keep === null ? -1 : lay.joint_names.indexOf(keep);
  if (j < 0) j = lay.joint_names.findIndex((n) => /hand.?right|rwrist|wristright|right.?hand/i.test(n));
  sel.value = String(Math.max(j, 0));
  sel.dataset.skeleton = lay.skeleton;
}
function jointIndex(lay) {
  if (!lay) return 0;
  const sel = $("joint");
  if (!sel.options.length) fillJoints(lay);
  if (sel.dataset.skeleton === lay.skeleton) return +sel.value;
  return Math.max(0, lay.joint_names.indexOf(sel.selectedOptions[0].text));
}
function resetHistory() { for (const k in history) delete history[k]; }

// Advance every stream's playout clock by the real time elapsed; show the newest due record.
function play(dt) {
  for (const s in playout) {
    const p = playout[s], q = p.queue;
    if (!q.length) continue;
    const last = q[q.length - 1].t;
    if (p.clock === null || p.clock < q[0].t - 1 || p.clock > last + 1) p.clock = q[0].t;  // start, or a jump
    else p.clock = Math.min(p.clock + dt, last);  // never ahead of the data: a burst then plays smoothly
    if (last - p.clock > MAX_LAG_S) {  // fallen behind: skip to near the newest
      p.clock = last - MAX_LAG_S / 4;
    }
    let shown = null;
    while (q.length && q[0].t <= p.clock + 1e-6) {
      if (shown) status.skipped += 1;  // more than one due in this animation frame
      shown = q.shift();
    }
    if (shown) {
      latest[s] = shown;
      status.lastSeq[s] = shown.seq;
      dirty = true;
    }
  }
}

// ------------------------------------------------------------------ 3D scene
function upAxis(rec) {
  // y is up for Kinect / BVH; C3D worlds are z up: take the axis along which a body is tallest
  for (const b of rec.bodies) {
    const pts = (b.clean || b.raw || []).filter(Boolean);
    if (pts.length < 3) continue;
    const ext = [0, 1, 2].map((i) => Math.max(...pts.map((p) => p[i])) - Math.min(...pts.map((p) => p[i])));
    return ext.indexOf(Math.max(...ext));
  }
  return 1;
}
function toYUp(p, up) {
  if (up === 2) return [p[0], p[2], -p[1]];
  if (up === 0) return [p[1], p[0], p[2]];
  return p;
}

function project(p, view) {
  const x0 = p[0] - view.c[0], y0 = p[1] - view.c[1], z0 = p[2] - view.c[2];
  const cy = Math.cos(camera.yaw), sy = Math.sin(camera.yaw), cp = Math.cos(camera.pitch), sp = Math.sin(camera.pitch);
  const x1 = cy * x0 - sy * z0, z1 = sy * x0 + cy * z0;          // yaw about y
  const y2 = cp * y0 - sp * z1, z2 = sp * y0 + cp * z1;          // pitch about x
  const zc = camera.dist + z2;
  if (zc < 0.05) return null;
  // camera looks along +z (as the sensor does): +x is to the left on screen
  return [view.w / 2 - view.f * (x1 + view.shift) / zc, view.h / 2 - view.f * y2 / zc, zc];
}

function drawScene() {
  const cv = $("scene"), ctx = cv.getContext("2d");
  fit(cv);
  const w = cv.width, h = cv.height;
  ctx.clearRect(0, 0, w, h);
  const streams = Object.keys(latest);
  const counts = { raw: 0, live: 0, clean: 0 };
  let recovered = 0, bodies = 0, expected = 0;
  // the orbit target follows the bodies' centroid, smoothed
  const pts = [];
  for (const s of streams) {
    const rec = latest[s];
    if (camera.up === null) camera.up = upAxis(rec);
    for (const b of rec.bodies) for (const p of (b.clean || b.raw || [])) if (p) pts.push(toYUp(p, camera.up));
  }
  if (pts.length) {
    const c = [0, 1, 2].map((i) => pts.reduce((a, p) => a + p[i], 0) / pts.length);
    camera.target = camera.target ? camera.target.map((v, i) => v + 0.1 * (c[i] - v)) : c;
    if (camera.auto) {  // frame every body: distance from the extent of what is drawn
      const ext = Math.max(...[0, 1, 2].map((i) => Math.max(...pts.map((p) => p[i])) - Math.min(...pts.map((p) => p[i]))));
      camera.dist += 0.1 * (Math.min(15, Math.max(1.5, 1.5 * ext)) - camera.dist);
    }
  }
  if (!camera.target) {
    ctx.fillStyle = "#8a93a6"; ctx.font = "16px system-ui"; ctx.textAlign = "center";
    ctx.fillText(status.connected ? "waiting for frames..." : "connecting to the viewer...", w / 2, h / 2);
    ctx.textAlign = "left";
    return counts;
  }
  const view = { c: camera.target, w, h, f: 0.9 * Math.min(w, h), shift: 0 };
  drawGrid(ctx, view, pts);
  const layoutSide = $("layout").value === "side";
  // clean first and thick, raw and live over it thinner, so both stay visible when overlaid
  const kinds = ["clean", "live", "raw"].filter((k) => $("show" + k[0].toUpperCase() + k.slice(1)).checked);
  for (const s of streams) {
    const rec = latest[s], lay = layouts[s];
    if (!lay) continue;
    for (const b of rec.bodies) {
      bodies += 1;
      expected += lay.joint_names.length;
      for (const kind of kinds) {
        const joints = b[kind];
        if (!joints) continue;
        view.shift = layoutSide ? (kind === "clean" ? -0.5 : 0.5) : 0;
        const P = joints.map((p) => (p ? project(toYUp(p, camera.up), view) : null));
        ctx.strokeStyle = COLORS[kind];
        ctx.globalAlpha = kind === "clean" ? 1 : 0.9;
        ctx.lineWidth = kind === "clean" ? 4 : 1.5;
        ctx.beginPath();
        for (const [a, c] of lay.bones) {
          if (P[a] && P[c]) { ctx.moveTo(P[a][0], P[a][1]); ctx.lineTo(P[c][0], P[c][1]); }
        }
        ctx.stroke();
        ctx.fillStyle = COLORS[kind];
        for (let j = 0; j < P.length; j++) {
          if (!P[j]) continue;
          counts[kind] += 1;
          const isRec = kind === "clean" && b.rec && b.rec[j];
          const r = isRec ? 5 : kind === "clean" ? 3.5 : 2.5;
          ctx.beginPath(); ctx.arc(P[j][0], P[j][1], r, 0, 2 * Math.PI);
          if (isRec) { ctx.fillStyle = COLORS.rec; ctx.fill(); ctx.fillStyle = COLORS[kind]; recovered += 1; }
          else ctx.fill();
        }
      }
      ctx.globalAlpha = 1;
    }
  }
  status.bodies = bodies; status.expectedJoints = expected; status.recoveredDrawn = recovered;
  return counts;
}

function drawGrid(ctx, view, pts) {
  const floor = pts.length ? Math.min(...pts.map((p) => p[1])) : view.c[1] - 1;
  ctx.strokeStyle = "#2b313c"; ctx.lineWidth = 1; ctx.beginPath();
  for (let k = -4; k <= 4; k++) {
    for (const [a, b] of [[[k * 0.5, floor, -2], [k * 0.5, floor, 2]], [[-2, floor, k * 0.5], [2, floor, k * 0.5]]]) {
      const A = project([view.c[0] + a[0], a[1], view.c[2] + a[2]], view);
      const B = project([view.c[0] + b[0], b[1], view.c[2] + b[2]], view);
      if (A && B) { ctx.moveTo(A[0], A[1]); ctx.lineTo(B[0], B[1]); }
    }
  }
  ctx.stroke();
}

function fit(cv) {
  const r = cv.getBoundingClientRect(), d = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(r.width * d)), h = Math.max(1, Math.round(r.height * d));
  if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
}

// ------------------------------------------------------------------ plots
function drawPlot(id, title, ylabel, series) {
  const cv = $(id), ctx = cv.getContext("2d");
  fit(cv);
  const w = cv.width, h = cv.height, m = { l: 52, r: 8, t: 20, b: 30 };
  ctx.clearRect(0, 0, w, h);
  let tMax = -Infinity, lo = Infinity, hi = -Infinity;
  for (const s of series) for (let i = 0; i < s.t.length; i++) {
    if (s.v[i] === null || s.v[i] === undefined) continue;
    tMax = Math.max(tMax, s.t[i]); lo = Math.min(lo, s.v[i]); hi = Math.max(hi, s.v[i]);
  }
  ctx.fillStyle = "#d8dee9"; ctx.font = "12px system-ui"; ctx.fillText(title, m.l, 14);
  ctx.save(); ctx.translate(12, h / 2); ctx.rotate(-Math.PI / 2); ctx.textAlign = "center"; ctx.fillText(ylabel, 0, 0); ctx.restore();
  ctx.textAlign = "center"; ctx.fillText("time (s, newest at right)", (w + m.l) / 2, h - 6); ctx.textAlign = "left";
  ctx.strokeStyle = "#4c566a"; ctx.strokeRect(m.l, m.t, w - m.l - m.r, h - m.t - m.b);
  if (!isFinite(tMax)) return;
  if (hi - lo < 1e-6) { hi += 0.5; lo -= 0.5; }
  const pad = 0.08 * (hi - lo); lo -= pad; hi += pad;
  if (series.every((s) => s.nonNegative)) lo = Math.max(lo, 0);
  const X = (t) => m.l + (w - m.l - m.r) * (1 - (tMax - t) / HISTORY_S);
  const Y = (v) => m.t + (h - m.t - m.b) * (hi - v) / (hi - lo);
  ctx.fillStyle = "#8a93a6"; ctx.font = "11px system-ui";
  ctx.fillText(hi.toPrecision(4), 2, m.t + 10); ctx.fillText(lo.toPrecision(4), 2, h - m.b);
  ctx.fillText(`-${HISTORY_S}`, m.l, h - m.b + 12); ctx.fillText("0", w - m.r - 8, h - m.b + 12);
  let lx = m.l + 6;
  for (const s of series) {
    ctx.strokeStyle = s.color; ctx.lineWidth = 1.5; ctx.beginPath();
    let pen = false;
    for (let i = 0; i < s.t.length; i++) {
      const v = s.v[i];
      if (v === null || v === undefined) { pen = false; continue; }
      if (pen) ctx.lineTo(X(s.t[i]), Y(v)); else ctx.moveTo(X(s.t[i]), Y(v));
      pen = true;
    }
    ctx.stroke();
    ctx.fillStyle = s.color; ctx.fillText(s.label, lx, m.t + 12); lx += ctx.measureText(s.label).width + 12;
  }
}

function drawPlots() {
  const sel = $("body");
  const keys = Object.keys(history).sort();
  if (sel.options.length !== keys.length) {
    const keep = sel.value;
    sel.innerHTML = keys.map((k) => `<option>${k}</option>`).join("");
    if (keys.includes(keep)) sel.value = keep;
  }
  const h = history[sel.value];
  const jname = $("joint").selectedOptions[0] ? $("joint").selectedOptions[0].text : "joint";
  const axis = "xyz"[+$("axis").value];
  if (h) {
    drawPlot("plotTraj", `${jname} ${axis} (m): raw vs clean`, `${axis} (m)`,
      [{ t: h.t, v: h.raw, color: COLORS.raw, label: "raw" }, { t: h.t, v: h.clean, color: COLORS.clean, label: "clean" }]);
    drawPlot("plotBone", `bone length at ${jname} (cm): raw vs clean`, "length (cm)",
      [{ t: h.t, v: h.rawBone, color: COLORS.raw, label: "raw" }, { t: h.t, v: h.cleanBone, color: COLORS.clean, label: "clean" }]);
  }
  drawPlot("plotLat", "latency (ms): service delay live / clean, wire", "ms", [
    { t: latency.t, v: latency.live, color: COLORS.live, label: "live", nonNegative: true },
    { t: latency.t, v: latency.clean, color: COLORS.clean, label: "clean", nonNegative: true },
    { t: latency.t, v: latency.wire, color: "#b48ead", label: "wire", nonNegative: true },
  ]);
}

// ------------------------------------------------------------------ render loop
let fpsFrames = 0, fpsSince = performance.now(), lastReport = 0, ageWindow = 0, lastTick = null;
function frame(now) {
  status.rafTicks += 1;
  try {
    play(lastTick === null ? 0 : Math.min(0.25, (now - lastTick) / 1000));
    lastTick = now;
    if (dirty) {
      dirty = false;
      const t0 = performance.now();
      status.jointsDrawn = drawScene();
      drawPlots();
      status.drawMs = 0.9 * status.drawMs + 0.1 * (performance.now() - t0);  // smoothed cost of one draw
      // age of the newest clean frame on screen: wall clock now minus the service's publish time
      const pubs = Object.values(latest).map((r) => r.t_publish_ms).filter((v) => v);
      if (pubs.length) {
        status.ageMs = Math.round(Date.now() - Math.min(...pubs));
        ageWindow = Math.max(ageWindow, status.ageMs);
      }
      status.framesDrawn += 1;
      fpsFrames += 1;
    }
    if (now - fpsSince >= 1000) {
      status.renderFps = Math.round((1000 * fpsFrames) / (now - fpsSince));
      fpsFrames = 0; fpsSince = now;
      status.maxAgeMs = ageWindow; ageWindow = 0;  // the oldest frame shown in the last second
      status.streams = Object.keys(latest).length;
      const br = status.bridge || {};
      $("stats").textContent = `streams ${status.streams} bodies ${status.bodies} drawn ${status.framesDrawn} ` +
        `(${status.renderFps}/s) dropped ${br.dropped || 0} queue ${br.queue || 0}`;
    }
    if (now - lastReport >= 500 && ws && ws.readyState === 1) {
      lastReport = now;
      ws.send(JSON.stringify(Object.assign({ type: "status" }, status)));
    }
  } catch (e) {
    status.error = String(e && e.stack || e);
  }
  requestAnimationFrame(frame);
}

// ------------------------------------------------------------------ controls
function controls() {
  const cv = $("scene");
  let drag = null;
  cv.addEventListener("mousedown", (e) => { drag = [e.clientX, e.clientY]; cv.style.cursor = "grabbing"; });
  window.addEventListener("mouseup", () => { drag = null; $("scene").style.cursor = "grab"; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    camera.yaw += 0.01 * (e.clientX - drag[0]);
    camera.pitch = Math.max(-1.5, Math.min(1.5, camera.pitch + 0.01 * (e.clientY - drag[1])));
    drag = [e.clientX, e.clientY]; dirty = true;
  });
  cv.addEventListener("wheel", (e) => { e.preventDefault(); camera.auto = false; camera.dist = Math.max(0.5, camera.dist * Math.exp(0.001 * e.deltaY)); dirty = true; });
  cv.addEventListener("dblclick", () => { camera.yaw = 0; camera.pitch = 0.2; camera.auto = true; camera.up = null; dirty = true; });
  for (const id of ["joint", "axis"]) $(id).addEventListener("change", () => { resetHistory(); dirty = true; });
  $("body").addEventListener("change", () => {  // another body may have another skeleton
    const lay = layouts[$("body").value.split("#")[0]];
    if (lay && lay.skeleton !== $("joint").dataset.skeleton) { fillJoints(lay); resetHistory(); }
    dirty = true;
  });
  for (const id of ["layout", "showRaw", "showLive", "showClean"]) $(id).addEventListener("change", () => { dirty = true; });
}

controls();
connect();
requestAnimationFrame(frame);
