// bsjax live view: a small canvas renderer (painter's algorithm, Lambert shading), no libraries.
// Messages from /ws: {type: "scene", surface, surfaces, curves, tool_radius, title, replay}
// then {type: "frame", tool, force, gain, servo_hz, ticks, physics_updates, max_force, surface?}.
// window.bsjaxView lets a page built on this renderer (studio.js) take pointer presses (grab),
// draw on top (overlay), receive its own message types (onMessage) and send over the socket.
"use strict";
(function () {
  const canvas = document.getElementById("view");
  const ctx = canvas.getContext("2d");
  const panel = document.getElementById("panel");
  const status = document.getElementById("status");
  const stats = { frames: 0, scenes: 0, connects: 0, drawn: 0, connected: false, fps: 0, lastFrame: null };
  window.bsjax = stats;
  let scene = null, frame = null, replayIndex = 0, playing = false, playStart = 0;
  const cam = { yaw: 0.6, pitch: 0.35, dist: 4.0, target: [0, 0, 0] };
  const fpsWindow = [];
  const view = { grab: null, overlay: null, onMessage: null, send: null, cam, canvas, project, basis,
    scene: () => scene, setScene: (s, refit) => { scene = s; if (refit) fit(); schedule(); }, schedule: () => schedule() };
  window.bsjaxView = view;
  let physicsRate = 0, lastPhys = null;

  // --- math ----------------------------------------------------------------------------------
  function basis() {
    const cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw), cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch);
    const fwd = [-cp * cy, -cp * sy, -sp];             // camera looks at the target along fwd
    const right = [-sy, cy, 0];                         // z is up on the screen
    const up = [right[1] * fwd[2] - right[2] * fwd[1], right[2] * fwd[0] - right[0] * fwd[2], right[0] * fwd[1] - right[1] * fwd[0]];
    const eye = [cam.target[0] - fwd[0] * cam.dist, cam.target[1] - fwd[1] * cam.dist, cam.target[2] - fwd[2] * cam.dist];
    return { fwd, right, up, eye };
  }
  function project(b, p, out) {
    const d = [p[0] - b.eye[0], p[1] - b.eye[1], p[2] - b.eye[2]];
    const z = d[0] * b.fwd[0] + d[1] * b.fwd[1] + d[2] * b.fwd[2];
    const f = 0.9 * Math.min(canvas.width, canvas.height) / Math.max(z, 1e-3);
    out[0] = canvas.width / 2 + f * (d[0] * b.right[0] + d[1] * b.right[1] + d[2] * b.right[2]);
    out[1] = canvas.height / 2 - f * (d[0] * b.up[0] + d[1] * b.up[1] + d[2] * b.up[2]);
    out[2] = z; out[3] = f;
    return out;
  }
  const finite = (v) => v && v.every((x) => x !== null && Number.isFinite(x));

  // --- drawing -------------------------------------------------------------------------------
  function tris(grid, b, tool, radius, list) {
    const [m, n] = grid.shape, P = grid.points;
    const scr = new Float64Array(m * n * 4), tmp = [0, 0, 0, 0];
    for (let i = 0; i < m * n; i++) {
      project(b, [P[3 * i], P[3 * i + 1], P[3 * i + 2]], tmp);
      scr.set(tmp, 4 * i);
    }
    const reach = radius * 1.25;
    const light = [b.fwd[0] * -0.6 + b.up[0] * 0.5 + b.right[0] * 0.4, b.fwd[1] * -0.6 + b.up[1] * 0.5 + b.right[1] * 0.4, b.fwd[2] * -0.6 + b.up[2] * 0.5 + b.right[2] * 0.4];
    const ln = Math.hypot(...light);
    for (let i = 0; i + 1 < m; i++) for (let j = 0; j + 1 < n; j++) {
      const q = [i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j];
      for (const t of [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]) {
        const a = t[0] * 3, c = t[1] * 3, e = t[2] * 3;
        const u = [P[c] - P[a], P[c + 1] - P[a + 1], P[c + 2] - P[a + 2]];
        const v = [P[e] - P[a], P[e + 1] - P[a + 1], P[e + 2] - P[a + 2]];
        const nx = u[1] * v[2] - u[2] * v[1], ny = u[2] * v[0] - u[0] * v[2], nz = u[0] * v[1] - u[1] * v[0];
        const nn = Math.hypot(nx, ny, nz) || 1;
        const shade = 0.25 + 0.75 * Math.abs((nx * light[0] + ny * light[1] + nz * light[2]) / (nn * ln));
        const cx = (P[a] + P[c] + P[e]) / 3, cyy = (P[a + 1] + P[c + 1] + P[e + 1]) / 3, cz = (P[a + 2] + P[c + 2] + P[e + 2]) / 3;
        let contact = false;
        if (tool && reach > 0) contact = Math.hypot(cx - tool[0], cyy - tool[1], cz - tool[2]) < reach;
        const depth = (scr[4 * t[0] + 2] + scr[4 * t[1] + 2] + scr[4 * t[2] + 2]) / 3;
        if (depth <= 0.01) continue;
        list.push({ depth, shade, contact, pts: t.map((k) => [scr[4 * k], scr[4 * k + 1]]) });
      }
    }
  }
  function draw() {
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    ctx.fillStyle = "#14171c"; ctx.fillRect(0, 0, w, h);
    if (!scene) return;
    const b = basis();
    const tool = currentTool(), force = currentForce();
    const list = [];
    const radius = scene.tool_radius || 0;
    for (const g of allSurfaces()) tris(g, b, tool, radius, list);
    let tp = null;
    if (tool) {
      tp = project(b, tool, [0, 0, 0, 0]);
      if (tp[2] > 0.01) list.push({ depth: tp[2], tool: true });  // hidden behind nearer triangles
    }
    list.sort((p, q) => q.depth - p.depth);
    for (const t of list) {
      if (t.tool) { sphere(tp, radius); if (force) arrow(b, tool, force, tp); continue; }
      const s = t.shade;
      const rgb = t.contact ? [235 * s, 110 * s, 70 * s] : [120 * s, 150 * s, 200 * s];
      ctx.fillStyle = `rgb(${rgb[0] | 0},${rgb[1] | 0},${rgb[2] | 0})`;
      ctx.strokeStyle = ctx.fillStyle;
      ctx.beginPath(); ctx.moveTo(...t.pts[0]); ctx.lineTo(...t.pts[1]); ctx.lineTo(...t.pts[2]); ctx.closePath();
      ctx.fill(); ctx.stroke();
    }
    for (const c of scene.curves || []) {
      if (Array.isArray(c)) polyline(b, c, "#e5c07b", 2); else polyline(b, c.points, c.color || "#e5c07b", c.width || 2);
    }
    if (scene.replay) polyline(b, scene.replay.position, "rgba(198,120,221,0.6)", 1);
    if (view.overlay) view.overlay(ctx, b);
    stats.drawn += 1;
  }
  function sphere(p, radius) {
    const r = Math.max(3, p[3] * Math.max(radius, 0.02));
    const g = ctx.createRadialGradient(p[0] - r / 3, p[1] - r / 3, r / 8, p[0], p[1], r);
    g.addColorStop(0, "rgba(240,240,240,0.85)"); g.addColorStop(1, "rgba(120,130,140,0.55)");
    ctx.fillStyle = g; ctx.beginPath(); ctx.arc(p[0], p[1], r, 0, 2 * Math.PI); ctx.fill();
  }
  function polyline(b, flat, color, width) {
    const tmp = [0, 0, 0, 0];
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.beginPath();
    let started = false;
    for (let i = 0; i + 2 < flat.length; i += 3) {
      project(b, [flat[i], flat[i + 1], flat[i + 2]], tmp);
      if (tmp[2] <= 0.01) { started = false; continue; }
      if (!started) { ctx.moveTo(tmp[0], tmp[1]); started = true; } else ctx.lineTo(tmp[0], tmp[1]);
    }
    ctx.stroke(); ctx.lineWidth = 1;
  }
  function arrow(b, tool, force, p) {
    const mag = Math.hypot(...force);
    if (!(mag > 1e-9)) return;
    const scale = 0.6 / Math.max((frame && frame.max_force) || mag, 1e-9);
    const tip = project(b, [tool[0] + force[0] * scale, tool[1] + force[1] * scale, tool[2] + force[2] * scale], [0, 0, 0, 0]);
    if (tip[2] <= 0.01) return;
    ctx.strokeStyle = "#98c379"; ctx.fillStyle = "#98c379"; ctx.lineWidth = 3;
    ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(tip[0], tip[1]); ctx.stroke();
    const ang = Math.atan2(tip[1] - p[1], tip[0] - p[0]);
    ctx.beginPath(); ctx.moveTo(tip[0], tip[1]);
    ctx.lineTo(tip[0] - 12 * Math.cos(ang - 0.4), tip[1] - 12 * Math.sin(ang - 0.4));
    ctx.lineTo(tip[0] - 12 * Math.cos(ang + 0.4), tip[1] - 12 * Math.sin(ang + 0.4));
    ctx.closePath(); ctx.fill(); ctx.lineWidth = 1;
  }
  function allSurfaces() {
    const out = [];
    if (scene.surface) out.push(scene.surface);
    for (const s of scene.surfaces || []) out.push(s);
    return out;
  }
  function currentTool() {
    if (scene && scene.replay) { const p = scene.replay.position, k = 3 * replayIndex; return [p[k], p[k + 1], p[k + 2]]; }
    return frame && finite(frame.tool) ? frame.tool : null;
  }
  function currentForce() {
    if (scene && scene.replay) { const f = scene.replay.force, k = 3 * replayIndex; return [f[k], f[k + 1], f[k + 2]]; }
    return frame && finite(frame.force) ? frame.force : null;
  }

  // --- telemetry panel -----------------------------------------------------------------------
  function telemetry() {
    const lines = [scene ? scene.title : "bsjax view"];
    if (scene && scene.replay) {
      const f = currentForce();
      lines.push(`replay  t ${scene.replay.time[replayIndex].toFixed(2)} s of ${scene.replay.time.at(-1).toFixed(2)} s`);
      lines.push(`force   |F| ${Math.hypot(...f).toFixed(3)} N`);
    } else if (frame) {
      const f = finite(frame.force) ? Math.hypot(...frame.force) : 0;
      lines.push(`servo   ${(frame.servo_hz || 0).toFixed(1)} Hz (${frame.mode || "?"}), ${frame.ticks} ticks`);
      lines.push(`physics ${physicsRate > 0 ? physicsRate.toFixed(1) + " Hz, " : ""}${frame.physics_updates} updates`);
      lines.push(`force   |F| ${f.toFixed(3)} N of ${frame.max_force} N, watchdog gain ${(frame.gain ?? 0).toFixed(2)}`);
      lines.push(`view    ${stats.fps.toFixed(1)} frames/s`);
    }
    panel.textContent = lines.join("\n");
  }

  // --- connection ----------------------------------------------------------------------------
  function fit() {
    const pts = [];
    for (const g of allSurfaces()) pts.push(g.points);
    for (const c of scene.curves || []) pts.push(Array.isArray(c) ? c : c.points);
    if (scene.replay) pts.push(scene.replay.position);
    let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (const P of pts) for (let i = 0; i + 2 < P.length; i += 3) for (let k = 0; k < 3; k++) {
      if (P[i + k] === null) continue;
      lo[k] = Math.min(lo[k], P[i + k]); hi[k] = Math.max(hi[k], P[i + k]);
    }
    if (!Number.isFinite(lo[0])) { lo = [-1, -1, -1]; hi = [1, 1, 1]; }
    cam.target = [0, 1, 2].map((k) => (lo[k] + hi[k]) / 2);
    cam.dist = 1.8 * Math.max(Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]), 1e-6);
  }
  function onMessage(ev) {
    const msg = JSON.parse(ev.data);
    if (msg.type === "scene") {
      scene = msg; stats.scenes += 1; fit();
      const box = document.getElementById("replay");
      if (scene.replay) {
        box.style.display = "flex";
        const slider = document.getElementById("slider");
        slider.max = String(scene.replay.time.length - 1); slider.value = "0"; replayIndex = 0;
      } else box.style.display = "none";
    } else if (msg.type === "frame") {
      frame = msg; stats.frames += 1; stats.lastFrame = msg;
      if (msg.surface && scene) scene.surface = msg.surface;
      const now = performance.now();
      fpsWindow.push(now);
      while (fpsWindow.length && now - fpsWindow[0] > 1000) fpsWindow.shift();
      stats.fps = fpsWindow.length;
      if (lastPhys && now > lastPhys[0] + 500) {
        physicsRate = (msg.physics_updates - lastPhys[1]) / ((now - lastPhys[0]) / 1000); lastPhys = [now, msg.physics_updates];
      } else if (!lastPhys) lastPhys = [now, msg.physics_updates];
    }
    if (view.onMessage) view.onMessage(msg);  // every message, after the renderer's own handling
    schedule();
  }
  // drawing follows the display (requestAnimationFrame), receiving never waits on it
  let pending = false;
  function schedule() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => { pending = false; draw(); telemetry(); });
  }
  function connect() {
    const ws = new WebSocket(`ws://${location.host}/ws`);
    view.send = (obj) => ws.send(JSON.stringify(obj));
    ws.onopen = () => { stats.connected = true; stats.connects += 1; status.textContent = "live"; status.className = "on"; };
    ws.onmessage = onMessage;
    ws.onclose = () => {
      stats.connected = false; status.textContent = "offline"; status.className = "off";
      setTimeout(connect, 300);     // the server may be restarting: try again
    };
  }

  // --- mouse: orbit (drag), zoom (wheel); replay slider ---------------------------------------
  let drag = null;
  canvas.addEventListener("mousedown", (e) => {
    if (view.grab && view.grab(e)) return;  // the page on top of the renderer took this press
    drag = [e.clientX, e.clientY]; canvas.style.cursor = "grabbing"; });
  window.addEventListener("mouseup", () => { drag = null; canvas.style.cursor = "grab"; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    cam.yaw -= (e.clientX - drag[0]) * 0.01;
    cam.pitch = Math.max(-1.5, Math.min(1.5, cam.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY]; schedule();
  });
  canvas.addEventListener("wheel", (e) => { e.preventDefault(); cam.dist *= Math.exp(e.deltaY * 0.001); schedule(); }, { passive: false });
  window.addEventListener("resize", schedule);
  const slider = document.getElementById("slider"), play = document.getElementById("play"), clock = document.getElementById("clock");
  function setIndex(i) {
    replayIndex = Math.max(0, Math.min(i, scene.replay.time.length - 1)); slider.value = String(replayIndex);
    clock.textContent = `${scene.replay.time[replayIndex].toFixed(2)} s`; draw(); telemetry();
  }
  slider.addEventListener("input", () => setIndex(Number(slider.value)));
  play.addEventListener("click", () => {
    playing = !playing; play.textContent = playing ? "pause" : "play";
    playStart = performance.now() / 1000 - scene.replay.time[replayIndex];
    if (playing) requestAnimationFrame(step);
  });
  function step() {
    if (!playing || !scene || !scene.replay) return;
    const t = performance.now() / 1000 - playStart, T = scene.replay.time;
    let i = replayIndex;
    while (i + 1 < T.length && T[i + 1] <= t) i++;
    setIndex(i);
    if (i + 1 >= T.length) { playing = false; play.textContent = "play"; return; }
    requestAnimationFrame(step);
  }
  window.bsjaxCamera = { get: () => ({ ...cam }), set: (c) => { Object.assign(cam, c); schedule(); } };
  window.bsjaxReplay = { setIndex: (i) => setIndex(i), play: () => play.click() };
  draw(); connect();
})();
