// The editor's pictures: the generated motion at the current frame, every key as an orange
// ghost at its place (the selected one solid, with handles on its pelvis, wrists and ankles),
// each keyed place as a disc with a heading arrow, an uploaded motion in grey, and the
// timeline with the keys as handles. Records where every handle is drawn, for picking.
var DiffkfcEditorView = (function () {
  "use strict";
  const S = DiffkfcScene, P = DiffkfcPose, C = S.COLORS;
  const HEADING_ARM = 0.45; // metres from a keyed place to its heading handle

  // Joint j at frame f of a motion from the API ({length, joints: [T * J * 3]}).
  function motionJoint(m, f, j) {
    const J = m.joints.length / (3 * m.length);
    const o = (Math.min(f, m.length - 1) * J + j) * 3;
    return [m.joints[o], m.joints[o + 1], m.joints[o + 2]];
  }

  // The key's pose in the world (at its place, facing its heading).
  function keyWorld(k) {
    return P.toWorld(k.pose, k.place, k.heading);
  }

  function follow(E) {
    if (!E.follow || !E.motion) return;
    const p = motionJoint(E.motion, E.frame, 0);
    E.cam.target = [p[0], 0.9, p[2]];
    E.cam.dist = 4.2 * E.cam.zoom;
  }

  function drawPlace(ctx, proj, k, selected, handles, i) {
    const p = [k.place[0], 0, k.place[1]];
    const h = S.add(p, P.turn([0, 0, HEADING_ARM], k.heading));
    const sp = proj(p), sh = proj(h);
    if (!sp || !sh) return;
    ctx.strokeStyle = C.key;
    ctx.fillStyle = C.key;
    ctx.globalAlpha = selected ? 1 : 0.5;
    ctx.lineWidth = 2;
    S.line(ctx, sp, sh);
    ctx.beginPath();
    ctx.arc(sp[0], sp[1], selected ? 8 : 6, 0, 2 * Math.PI);
    ctx.fill();
    ctx.beginPath();
    ctx.arc(sh[0], sh[1], 5, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.globalAlpha = 1;
    handles.push({ kind: "place", key: i, x: sp[0], y: sp[1] });
    if (selected) handles.push({ kind: "heading", key: i, x: sh[0], y: sh[1] });
  }

  function drawView(E, cv, ctx) {
    const { w, h } = S.fit(cv, ctx);
    ctx.fillStyle = "#f8fafc";
    ctx.fillRect(0, 0, w, h);
    follow(E);
    const camera = S.camera(E.cam, w, h);
    const proj = camera.proj;
    E.camera = camera;
    S.grid(ctx, proj, E.cam);
    const I = E.info.index, handles = [], segs = [];
    const m = E.motion;
    if (m && m.root_path) {
      ctx.strokeStyle = C.path;
      ctx.setLineDash([6, 4]);
      ctx.lineWidth = 2;
      ctx.beginPath();
      for (let f = 0; 2 * f + 1 < m.root_path.length; f++) {
        const s = proj([m.root_path[2 * f], 0, m.root_path[2 * f + 1]]);
        if (s) { f === 0 ? ctx.moveTo(s[0], s[1]) : ctx.lineTo(s[0], s[1]); }
      }
      ctx.stroke();
      ctx.setLineDash([]);
    }
    E.keys.forEach((k, i) => {
      if (k.usePlace) drawPlace(ctx, proj, k, i === E.selected, handles, i);
      const near = Math.abs(k.frame - E.frame);
      if (k.usePose && (i === E.selected || near <= 4)) {
        const wp = keyWorld(k);
        S.figure(segs, E.info.parents, E.info.side, I.head, (j) => wp[j], { color: C.key, alpha: i === E.selected ? 0.9 : 0.5 * (1 - near / 5), width: 0.06 });
        if (i === E.selected) E.info.effectors.forEach((j) => { const s = proj(wp[j]); if (s) handles.push({ kind: "joint", key: i, joint: j, x: s[0], y: s[1], world: wp[j] }); });
      }
    });
    if (E.upload) {
      const u = E.upload;
      S.figure(segs, E.info.parents, E.info.side, I.head, (j) => motionJoint(u, E.frame, j), { color: "#94a3b8", alpha: 0.8 });
    }
    if (m) {
      (m.planted || []).filter(([, s, e]) => s <= E.frame && E.frame <= e).forEach(([toe]) => {
        const p = motionJoint(m, E.frame, toe), s = proj([p[0], 0, p[2]]);
        if (s) { ctx.fillStyle = C.planted; ctx.beginPath(); ctx.arc(s[0], s[1], 4, 0, 2 * Math.PI); ctx.fill(); }
      });
      S.figure(segs, E.info.parents, E.info.side, I.head, (j) => motionJoint(m, E.frame, j), { alpha: 1 });
    }
    S.draw(ctx, proj, segs);
    handles.filter((hd) => hd.kind === "joint").forEach((hd) => {
      ctx.strokeStyle = "#0f172a";
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(hd.x, hd.y, 6, 0, 2 * Math.PI);
      ctx.stroke();
    });
    E.handles = handles;
    ctx.fillStyle = "#0f172a";
    ctx.font = "13px sans-serif";
    ctx.fillText(`frame ${E.frame} / ${E.length - 1}` + (E.keys.some((k) => k.frame === E.frame) ? "  \u25c6 key" : ""), 10, 18);
  }

  // Timeline geometry: x of a frame and the frame at an x.
  const PAD = 8;
  function tx(E, w, f) { return PAD + (w - 2 * PAD) * f / Math.max(1, E.length - 1); }
  function frameAt(E, w, x) { return Math.max(0, Math.min(E.length - 1, Math.round((x - PAD) / (w - 2 * PAD) * (E.length - 1)))); }

  function drawTimeline(E, tl, tctx) {
    const { w, h } = S.fit(tl, tctx);
    tctx.clearRect(0, 0, w, h);
    tctx.fillStyle = "#e2e8f0";
    tctx.fillRect(tx(E, w, 0), h / 2 - 2, tx(E, w, E.length - 1) - tx(E, w, 0), 4);
    const m = E.motion;
    tctx.fillStyle = C.planted;
    if (m) (m.planted || []).forEach(([, s, e]) => tctx.fillRect(tx(E, w, s), h - 6, Math.max(1, tx(E, w, e) - tx(E, w, s)), 3));
    const large = new Set(((m && m.keys) || []).filter((k) => k.large).map((k) => k.frame));
    E.keys.forEach((k, i) => {
      const x = tx(E, w, k.frame);
      tctx.fillStyle = large.has(k.frame) ? "#b91c1c" : C.key;
      tctx.beginPath();
      tctx.moveTo(x, h / 2 - 10); tctx.lineTo(x + 7, h / 2); tctx.lineTo(x, h / 2 + 10); tctx.lineTo(x - 7, h / 2);
      tctx.fill();
      if (i === E.selected) { tctx.strokeStyle = "#0f172a"; tctx.lineWidth = 2; tctx.stroke(); }
    });
    tctx.fillStyle = "#0f172a";
    tctx.fillRect(tx(E, w, E.frame) - 1, 0, 2, h);
  }

  return { drawView, drawTimeline, tx, frameAt, keyWorld, motionJoint };
})();
