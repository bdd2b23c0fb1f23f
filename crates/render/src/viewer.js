// diffkfc's motion viewer: stick figures in 3D on a 2D canvas, no libraries, no network.
// Reads the JSON in #motion-data (written by viewer.rs). Drag to orbit, wheel to zoom, space to
// play/pause. `#frame=N` in the address opens paused at frame N (used by the page test).
(function () {
  "use strict";
  const D = JSON.parse(document.getElementById("motion-data").textContent);
  const cv = document.getElementById("view");
  const ctx = cv.getContext("2d");
  const slider = document.getElementById("frame");
  const playBtn = document.getElementById("play");
  const followBox = document.getElementById("follow");
  const frameLabel = document.getElementById("frame-label");
  const timeline = document.getElementById("timeline");
  const tctx = timeline.getContext("2d");
  const status = document.getElementById("status");
  const J = D.parents.length;
  const T = Math.max(...D.motions.map((m) => m.frames));
  const LANE = 1.3;
  const S = DiffkfcScene;
  const COLORS = S.COLORS;
  const side = D.parents.map((_, j) => (D.left.includes(j) ? "left" : D.right.includes(j) ? "right" : "centre"));
  D.motions.forEach((m, i) => { m.dx = (i - (D.motions.length - 1) / 2) * LANE; });
  const cam = { yaw: 0.6, pitch: 0.25, dist: 2.2 + 0.8 * D.motions.length, zoom: 1, target: [0, 0.9, 0] };
  let frame = 0, playing = true, last = null, acc = 0;
  slider.max = String(T - 1);

  const sub = S.sub;

  function joint(m, flat, f, j) {
    const o = (Math.min(f, m.frames - 1) * J + j) * 3;
    return [flat[o] + m.dx, flat[o + 1], flat[o + 2]];
  }

  function draw() {
    const { w, h, dpr } = S.fit(cv, ctx);
    ctx.fillStyle = "#f8fafc";
    ctx.fillRect(0, 0, w, h);
    if (followBox.checked) {
      // Look at the middle of the figures, from far enough to keep them all in view (motions
      // that travel apart, as long ones do, zoom the view out).
      const ps = D.motions.map((m) => joint(m, m.joints, frame, 0));
      const lo = [0, 2].map((k) => Math.min(...ps.map((p) => p[k]))), hi = [0, 2].map((k) => Math.max(...ps.map((p) => p[k])));
      cam.target = [(lo[0] + hi[0]) / 2, 0.9, (lo[1] + hi[1]) / 2];
      cam.dist = Math.max(2.2 + 0.8 * D.motions.length, 1.3 * Math.max(hi[0] - lo[0], hi[1] - lo[1]) + 2) * cam.zoom;
    }
    const proj = S.camera(cam, w, h).proj;
    S.grid(ctx, proj, cam);
    const segs = [];
    D.motions.forEach((m) => {
      // The root's path on the ground, up to this frame.
      ctx.strokeStyle = "#cbd5e1";
      ctx.beginPath();
      for (let f = 0; f <= Math.min(frame, m.frames - 1); f++) {
        const p = joint(m, m.joints, f, 0);
        const s = proj([p[0], 0, p[2]]);
        if (s) { f === 0 ? ctx.moveTo(s[0], s[1]) : ctx.lineTo(s[0], s[1]); }
      }
      ctx.stroke();
      // The root path the motion was asked to follow (track fit), whole and dashed.
      if (m.root_path) {
        ctx.strokeStyle = COLORS.path;
        ctx.lineWidth = 2.5;
        ctx.setLineDash([6, 4]);
        ctx.beginPath();
        for (let f = 0; 2 * f + 1 < m.root_path.length; f++) {
          const s = proj([m.root_path[2 * f] + (m.dx || 0), 0, m.root_path[2 * f + 1]]);
          if (s) { f === 0 ? ctx.moveTo(s[0], s[1]) : ctx.lineTo(s[0], s[1]); }
        }
        ctx.stroke();
        ctx.setLineDash([]);
        ctx.lineWidth = 1;
      }
      // Planted toes: a green disc on the ground under each toe while its span lasts.
      (m.planted || []).filter(([, s, e]) => s <= frame && frame <= e).forEach(([toe]) => {
        const p = joint(m, m.joints, frame, toe);
        const s = proj([p[0], 0, p[2]]);
        if (s) { ctx.fillStyle = COLORS.planted; ctx.beginPath(); ctx.arc(s[0], s[1], Math.max(3, 0.05 * s[3] / s[2]), 0, 2 * Math.PI); ctx.fill(); }
      });
      // The nearest keyed pose, drawn in orange at and near its frame (fading over 4 frames):
      // one ghost at a time, also where every frame is keyed.
      const near = (m.key_poses || []).reduce((b, k) => (!b || Math.abs(k[0] - frame) < Math.abs(b[0] - frame) ? k : b), null);
      if (near) {
        const [kf, pose] = near;
        const a = 1 - Math.abs(kf - frame) / 4;
        const flat = { frames: 1, dx: m.dx };
        for (let j = 1; j < J; j++) {
          if (m.key_joints && !(m.key_joints.includes(j) && m.key_joints.includes(D.parents[j]))) continue;
          if (a > 0) segs.push({ a: joint(flat, pose, 0, D.parents[j]), b: joint(flat, pose, 0, j), color: COLORS.key, alpha: 0.55 * a, width: 0.06 });
        }
      }
      S.figure(segs, D.parents, side, D.head, (j) => joint(m, m.joints, frame, j), { alpha: frame < m.frames ? 1 : 0.35 });
    });
    S.draw(ctx, proj, segs);
    ctx.fillStyle = "#0f172a";
    ctx.font = "13px sans-serif";
    ctx.textAlign = "center";
    D.motions.forEach((m) => {
      const p = proj(sub(joint(m, m.joints, frame, 0), [0, -1.0, 0]));
      if (p) ctx.fillText(m.label + (m.keyframes.includes(frame) ? "  \u25c6 key" : ""), p[0], p[1]);
    });
    const seg = (D.segments || []).filter(([s]) => s <= frame).pop();
    if (seg) {
      ctx.textAlign = "left";
      ctx.font = "15px sans-serif";
      ctx.fillText(`\u25b8 ${seg[1]}`, 12, 22);
    }
    slider.value = String(frame);
    frameLabel.textContent = `frame ${frame} / ${T - 1} (${(frame / D.fps).toFixed(2)} s)`;
    drawTimeline();
    if (!playing) report(w, h, dpr);
  }

  function drawTimeline() {
    const dpr = window.devicePixelRatio || 1;
    const w = timeline.clientWidth, h = timeline.clientHeight;
    if (timeline.width !== Math.round(w * dpr)) { timeline.width = Math.round(w * dpr); timeline.height = Math.round(h * dpr); }
    tctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    tctx.clearRect(0, 0, w, h);
    const x = (f) => 6 + (w - 12) * f / Math.max(1, T - 1);
    const rowH = (h - 4) / D.motions.length;
    D.motions.forEach((m, i) => {
      const y = 2 + i * rowH;
      tctx.fillStyle = "#e2e8f0";
      tctx.fillRect(x(0), y + rowH / 2 - 1, x(m.frames - 1) - x(0), 2);
      tctx.fillStyle = COLORS.key;
      tctx.fillStyle = COLORS.planted;
      (m.planted || []).forEach(([, s, e]) => tctx.fillRect(x(s), y + rowH / 2 - 2, Math.max(1, x(e) - x(s)), 4));
      tctx.fillStyle = COLORS.key;
      m.keyframes.forEach((k) => tctx.fillRect(x(k) - 1.5, y + 2, 3, rowH - 4));
    });
    (D.segments || []).forEach(([s]) => { tctx.fillStyle = "#64748b"; if (s > 0) tctx.fillRect(x(s) - 1, 0, 2, h); });
    tctx.fillStyle = "#0f172a";
    tctx.fillRect(x(frame) - 1, 0, 2, h);
  }

  // What the page test reads: the frame shown and how many pixels the figures cover.
  function report(w, h, dpr) {
    const img = ctx.getImageData(0, 0, Math.round(w * dpr), Math.round(h * dpr)).data;
    let n = 0, path = 0, planted = 0;
    for (let i = 0; i < img.length; i += 4) {
      const [r, g, b] = [img[i], img[i + 1], img[i + 2]];
      if (b > 150 && r < 120) n++; // blue: left limbs
      else if (r > 100 && r < 150 && g < 90 && b > 200) path++; // violet: the followed root path
      else if (g > 130 && r < 60 && b < 110) planted++; // green: planted toes
    }
    status.textContent = `frame ${frame}; root-path pixels ${path}; planted-foot pixels ${planted}; left-limb pixels ${n}`;
  }

  function setFrame(f) { frame = Math.max(0, Math.min(T - 1, f | 0)); draw(); }
  function setPlaying(p) { playing = p; playBtn.textContent = p ? "\u275a\u275a pause" : "\u25b6 play"; last = null; }
  function tick(ts) {
    if (playing) {
      if (last !== null) {
        acc += (ts - last) / 1000;
        const n = Math.floor(acc * D.fps);
        if (n > 0) { acc -= n / D.fps; frame = (frame + n) % T; }
      }
      last = ts;
      draw();
    }
    requestAnimationFrame(tick);
  }

  slider.addEventListener("input", () => { const v = Number(slider.value); playing = false; setPlaying(false); setFrame(v); });
  playBtn.addEventListener("click", () => { setPlaying(!playing); draw(); });
  followBox.addEventListener("change", draw);
  timeline.addEventListener("pointerdown", (e) => {
    const r = timeline.getBoundingClientRect();
    setPlaying(false);
    setFrame(Math.round((e.clientX - r.left - 6) / (r.width - 12) * (T - 1)));
  });
  let drag = null;
  cv.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; cv.setPointerCapture(e.pointerId); });
  cv.addEventListener("pointerup", () => { drag = null; });
  cv.addEventListener("pointermove", (e) => {
    if (!drag) return;
    cam.yaw -= (e.clientX - drag[0]) * 0.01;
    cam.pitch = Math.max(-0.1, Math.min(1.45, cam.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
    draw();
  });
  cv.addEventListener("wheel", (e) => {
    e.preventDefault();
    const f = Math.exp(e.deltaY * 0.001);
    cam.zoom = Math.max(0.2, Math.min(5, cam.zoom * f));
    cam.dist = Math.max(1.2, Math.min(60, cam.dist * f));
    draw();
  }, { passive: false });
  document.addEventListener("keydown", (e) => {
    if (e.code === "Space") { e.preventDefault(); setPlaying(!playing); draw(); }
    if (e.code === "ArrowRight") { setPlaying(false); setFrame(frame + 1); }
    if (e.code === "ArrowLeft") { setPlaying(false); setFrame(frame - 1); }
  });
  window.addEventListener("resize", draw);

  const m = /frame=(\d+)/.exec(location.hash);
  if (m) {
    slider.value = m[1];
    slider.dispatchEvent(new Event("input"));
  } else {
    draw();
  }
  requestAnimationFrame(tick);
})();
