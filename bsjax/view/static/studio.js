// bsjax studio: input on top of the view's renderer (view.js). Every gesture becomes a command
// sent over the view's WebSocket; Python (bsjax/view/_studio.py) computes it and replies with
// the new scene, which is all this page draws. Nothing is computed here but pixels.
"use strict";
(function () {
  const view = window.bsjaxView, canvas = view.canvas;
  const message = document.getElementById("message"), info = document.getElementById("info");
  const list = document.getElementById("list"), timed = document.getElementById("timed");
  const KIND_COLOR = { line: "#88c0d0", circle: "#a3be8c", ellipse: "#b48ead", arc: "#8fbcbb", triangle: "#d08770",
    square: "#ebcb8b", rectangle: "#ebcb8b", diamond: "#d08770", polyline: "#81a1c1", spline: "#e5c07b" };
  const PLANES = { xy: [0, 0, 1], xz: [0, 1, 0], yz: [1, 0, 0] };
  const studio = { scene: null, replies: [], errors: [], selection: [], mode: "draw", stroke: null, seq: 0, sent: 0 };
  window.bsjaxStudio = studio;
  const waiting = new Map();
  studio.pending = () => waiting.size;

  // --- talking to Python --------------------------------------------------------------------
  studio.send = (command) => new Promise((resolve) => {
    const seq = ++studio.seq;
    waiting.set(seq, resolve);
    studio.sent += 1;
    view.send({ ...command, seq });
  });
  view.onMessage = (msg) => {
    if (msg.type === "scene") show(msg);
    else if (msg.type === "update") {
      studio.replies.push(msg); show(msg.scene);
      say(describe(msg), false);
    } else if (msg.type === "error") { studio.errors.push(msg); say(msg.error, true); }
    else return;
    const resolve = waiting.get(msg.seq);
    if (resolve) { waiting.delete(msg.seq); resolve(msg); }
  };
  function say(text, bad) { message.textContent = text; message.className = bad ? "error" : ""; }
  function describe(msg) {
    const r = msg.result || {};
    if (msg.command === "stroke") return `curve ${r.id}: ${r.kind} (score ${r.score.toFixed(3)})`;
    if (msg.command === "build") return `surface ${r.id}: ${r.op}`;
    return `${msg.command}: ok`;
  }

  // --- the scene as the renderer draws it ---------------------------------------------------
  function show(s) {
    studio.scene = s;
    const ids = new Set([...s.items.map((i) => i.id), ...s.surfaces.map((b) => b.id)]);
    studio.selection = studio.selection.filter((id) => ids.has(id));
    redraw();
  }
  function redraw() {
    const s = studio.scene;
    if (!s) return;
    const curves = planeGrid(s.plane);
    for (const it of s.items) {
      if (it.stroke) curves.push({ points: it.stroke, color: "rgba(216,222,233,0.35)", width: 1 });
      const sel = studio.selection.includes(it.id);
      curves.push({ points: it.outline, color: sel ? "#ffffff" : KIND_COLOR[it.kind] || "#e5c07b", width: sel ? 3 : 2 });
    }
    view.setScene({ ...s, curves }, false);
    list.innerHTML = "";
    for (const it of s.items) row(it.id, `curve ${it.id}  ${it.kind}${it.score === null ? "" : "  " + it.score.toFixed(2)}`);
    for (const b of s.surfaces) row(b.id, `surface ${b.id}  ${b.op}  ${b.spline.ctrl.length}×${b.spline.ctrl[0].length}`);
    info.textContent = details(s);
  }
  function row(id, text) {
    const div = document.createElement("div");
    div.textContent = text; div.dataset.id = String(id);
    if (studio.selection.includes(id)) div.className = "sel";
    div.onclick = () => { toggle(id); };
    list.appendChild(div);
  }
  function toggle(id) {
    const k = studio.selection.indexOf(id);
    if (k >= 0) studio.selection.splice(k, 1); else studio.selection.push(id);
    redraw();
  }
  studio.select = (ids) => { studio.selection = [...ids]; redraw(); };
  function details(s) {
    const last = s.items[s.items.length - 1];
    const lines = [`${s.items.length} curves, ${s.surfaces.length} surfaces   undo ${s.history.undo} / redo ${s.history.redo}`];
    if (last) {
      lines.push(`last: curve ${last.id} ${last.kind}`);
      for (const [k, v] of Object.entries(last.params)) lines.push(`  ${k} ${JSON.stringify(round(v))}`);
    }
    return lines.join("\n");
  }
  const round = (v) => (Array.isArray(v) ? v.map(round) : typeof v === "number" ? Math.round(v * 1000) / 1000 : v);
  function planeGrid(p) {
    const out = [], R = 1.5, k = 6;
    for (let i = -k; i <= k; i++) {
      const a = (i / k) * R;
      for (const [e, f] of [[p.e1, p.e2], [p.e2, p.e1]]) {
        const pts = [];
        for (const b of [-R, R]) for (let c = 0; c < 3; c++) pts.push(p.origin[c] + a * e[c] + b * f[c]);
        out.push({ points: pts, color: i === 0 ? "rgba(136,192,208,0.35)" : "rgba(136,192,208,0.12)", width: 1 });
      }
    }
    return out;
  }

  // --- the camera of eqs. 5-1/5-2, as view.js projects ---------------------------------------
  studio.camera = () => {
    const b = view.basis(), w = canvas.width, h = canvas.height;
    return { eye: b.eye, target: [...view.cam.target], up: [0, 0, 1],
      fov: 2 * Math.atan(h / (1.8 * Math.min(w, h))), aspect: w / h };
  };
  function local(e) { const r = canvas.getBoundingClientRect(); return [e.clientX - r.left, e.clientY - r.top]; }
  const toWindow = (p) => [p[0] / canvas.width, 1 - p[1] / canvas.height];
  studio.toWindow = toWindow;

  // --- pointer: draw, over-sketch, drag a surface point (the right button always orbits) -------
  view.grab = (e) => studio.mode !== "orbit" && e.button === 0;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => {
    if (!view.grab(e)) return;
    canvas.setPointerCapture(e.pointerId);
    if (studio.mode === "drag") return startDrag(local(e));
    studio.stroke = { px: [local(e)], times: [e.timeStamp / 1000] };
  });
  canvas.addEventListener("pointermove", (e) => {
    if (studio.drag) return moveDrag(local(e));
    if (!studio.stroke) return;
    const events = e.getCoalescedEvents ? e.getCoalescedEvents() : [e];
    for (const ev of events.length ? events : [e]) {
      const t = studio.stroke.times;
      studio.stroke.px.push(local(ev));
      t.push(Math.max(ev.timeStamp / 1000, t[t.length - 1] + 1e-4));  // equal stamps: 0.1 ms apart
    }
    view.schedule();
  });
  canvas.addEventListener("pointerup", () => {
    if (studio.drag) { studio.drag = null; return; }
    const s = studio.stroke;
    studio.stroke = null;
    if (!s || s.px.length < 3) return view.schedule();
    const command = { window: s.px.map(toWindow), camera: studio.camera() };
    if (studio.mode === "oversketch") {  // the last selected curve, else the last drawn
      const curve = studio.selection.filter(isItem).at(-1) ?? studio.scene.items.at(-1)?.id;
      studio.send({ cmd: "oversketch", curve, ...command });
      studio.lastCommand = command;
    } else studio.send({ cmd: "stroke", times: timed.checked ? s.times : null, ...command });
    studio.lastCommand = { ...command, times: timed.checked ? s.times : null };
  });
  view.overlay = (ctx, b) => {
    if (studio.stroke) {
      ctx.strokeStyle = "#eceff4"; ctx.lineWidth = 2; ctx.beginPath();
      studio.stroke.px.forEach((p, i) => (i ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1])));
      ctx.stroke(); ctx.lineWidth = 1;
    }
    if (!studio.scene) return;
    ctx.font = "12px monospace";
    for (const it of studio.scene.items) {  // the recognised kind beside each curve
      const o = it.outline, q = view.project(b, [o[0], o[1], o[2]], [0, 0, 0, 0]);
      if (q[2] <= 0.01) continue;
      ctx.fillStyle = KIND_COLOR[it.kind] || "#e5c07b";
      ctx.fillText(`${it.id}: ${it.kind}`, q[0] + 6, q[1] - 6);
    }
    if (studio.drag && studio.drag.handle) {
      const q = view.project(b, studio.drag.handle, [0, 0, 0, 0]);
      ctx.fillStyle = "#bf616a"; ctx.beginPath(); ctx.arc(q[0], q[1], 5, 0, 2 * Math.PI); ctx.fill();
    }
  };
  const isItem = (id) => studio.scene.items.some((i) => i.id === id);

  // a press picks the nearest sample of a surface on the screen; each move is one drag command
  function startDrag(p) {
    const b = view.basis(), q = [0, 0, 0, 0];
    let best = null;
    for (const s of studio.scene.surfaces) {
      const [m, n] = s.shape, P = s.points;
      for (let i = 0; i < m * n; i++) {
        view.project(b, [P[3 * i], P[3 * i + 1], P[3 * i + 2]], q);
        const d = Math.hypot(q[0] - p[0], q[1] - p[1]);
        if (q[2] > 0.01 && d < 15 && (!best || d < best.d))
          best = { d, surface: s.id, u: Math.floor(i / n) / (m - 1), v: (i % n) / (n - 1), handle: [P[3 * i], P[3 * i + 1], P[3 * i + 2]] };
      }
    }
    if (!best) return say("drag: no surface point under the pointer", true);
    studio.drag = { ...best, gesture: Date.now(), busy: false, next: null };
  }
  function moveDrag(p) {
    const d = studio.drag;
    const command = { cmd: "drag", surface: d.surface, u: d.u, v: d.v, gesture: d.gesture,
      window: [toWindow(p)], camera: studio.camera() };
    if (d.busy) { d.next = command; return; }  // one in flight; the newest waits
    const go = (c) => {
      d.busy = true; studio.lastDrag = c;
      studio.send(c).then((r) => {
        if (r.type === "update") d.handle = r.result.target;
        d.busy = false;
        if (d.next) { const n = d.next; d.next = null; go(n); }
      });
    };
    go(command);
  }

  // --- buttons ------------------------------------------------------------------------------
  const modeButtons = document.querySelectorAll("[data-mode]");
  studio.setMode = (mode) => {
    studio.mode = mode;
    modeButtons.forEach((x) => x.classList.toggle("on", x.dataset.mode === mode));
    canvas.style.cursor = mode === "orbit" ? "grab" : "crosshair";
  };
  modeButtons.forEach((btn) => (btn.onclick = () => studio.setMode(btn.dataset.mode)));
  document.querySelectorAll("[data-op]").forEach((btn) => (btn.onclick = () =>
    studio.send({ cmd: "build", op: btn.dataset.op, curves: studio.selection.filter(isItem) })));
  document.getElementById("plane").onchange = (e) =>
    studio.send({ cmd: "plane", point: [0, 0, 0], normal: PLANES[e.target.value] });
  document.getElementById("target").onclick = () => {
    const surface = studio.selection.find((id) => !isItem(id)), curve = studio.selection.filter(isItem).at(-1);
    studio.send({ cmd: "target", surface, curve, lam: Number(document.getElementById("lam").value) });
  };
  const selectedSurface = () => studio.selection.find((id) => !isItem(id));
  document.getElementById("drop").onclick = () => studio.send({ cmd: "drop", surface: selectedSurface() });
  document.getElementById("press").onclick = () =>
    studio.send({ cmd: "press", surface: selectedSurface(), u: 0.5, v: 0.5 });
  for (const name of ["undo", "redo", "clear"]) document.getElementById(name).onclick = () => studio.send({ cmd: name });
  document.getElementById("delete").onclick = () => {
    for (const id of studio.selection) studio.send({ cmd: "delete", id });
  };
  const fileName = () => document.getElementById("name").value;
  document.getElementById("save").onclick = () => studio.send({ cmd: "save", name: fileName() });
  document.getElementById("load").onclick = () => studio.send({ cmd: "load", name: fileName() });
  window.addEventListener("keydown", (e) => {
    if (!(e.ctrlKey || e.metaKey) || e.target.tagName === "INPUT") return;
    if (e.key === "z") { e.preventDefault(); studio.send({ cmd: e.shiftKey ? "redo" : "undo" }); }
    if (e.key === "y") { e.preventDefault(); studio.send({ cmd: "redo" }); }
  });
  view.cam.yaw = -Math.PI / 2; view.cam.pitch = 1.2;  // the drawing plane z = 0 seen from above
})();
