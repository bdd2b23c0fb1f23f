// The keyframe editor: its state (prompt, length, keys, sampler settings), the API calls
// (every edit samples again; one request in flight, the newest edit wins), pointer editing in
// the view and on the timeline, undo and redo, import and export. `window.diffkfcEditor`
// exposes the state and handle positions to the browser test.
(function () {
  "use strict";
  const info = JSON.parse(document.getElementById("editor-info").textContent);
  const P = DiffkfcPose, V = DiffkfcEditorView;
  const $ = (id) => document.getElementById(id);
  const cv = $("view"), ctx = cv.getContext("2d"), tl = $("timeline"), tctx = tl.getContext("2d");
  const E = {
    info, text: $("text").value, length: 120, keys: [], selected: -1, frame: 0, playing: true,
    seed: 0, motion: null, upload: null, handles: [], follow: true,
    cam: { yaw: 0.6, pitch: 0.3, dist: 4.2, zoom: 1, target: [0, 0.9, 0] },
    history: [], future: [], inFlight: false, dirty: false, editAt: null,
    generation: 0, latencyMs: null, serverMs: null, error: null, drawn: 0,
  };
  const I = info.index;

  // ---- state, undo and redo -------------------------------------------------------------
  const snapshot = () => JSON.stringify({ text: E.text, length: E.length, keys: E.keys });
  function restore(s) { const o = JSON.parse(s); E.text = o.text; E.length = o.length; E.keys = o.keys; $("text").value = E.text; $("length").value = E.length; E.selected = Math.min(E.selected, E.keys.length - 1); }
  function remember() { E.history.push(snapshot()); if (E.history.length > 200) E.history.shift(); E.future = []; }
  function undo() { if (!E.history.length) return; E.future.push(snapshot()); restore(E.history.pop()); edited(); }
  function redo() { if (!E.future.length) return; E.history.push(snapshot()); restore(E.future.pop()); edited(); }

  // ---- the request ----------------------------------------------------------------------
  function spec() {
    return {
      length: E.length,
      keyframes: E.keys.slice().sort((a, b) => a.frame - b.frame).map((k) => {
        const o = { frame: k.frame };
        const r = (v) => Math.round(v * 1e4) / 1e4;
        if (k.usePose) o.joints = V.keyWorld(k).map((p) => p.map(r));
        if (k.usePlace) { o.root = [r(k.place[0]), r(k.pose[0][1]), r(k.place[1])]; o.heading = r(k.heading); }
        return o;
      }),
    };
  }
  function request() {
    if (!$("lock-seed").checked) { E.seed = Math.floor(Math.random() * 2 ** 31); $("seed").value = E.seed; }
    return {
      text: E.text, keyframes: spec(), seed: Number($("seed").value) || 0, steps: Number($("steps").value),
      kf_guidance: Number($("kf-guidance").value), transition_guidance: Number($("transition").value),
      fit: $("fit").value, foot_lock: $("foot-lock").checked,
    };
  }
  async function api(path, body, type) {
    const r = await fetch(path, { method: "POST", headers: { "Content-Type": type || "application/json" }, body: type ? body : JSON.stringify(body) });
    if (!r.ok) {
      let msg = `${r.status} ${r.statusText}`;
      try { msg = (await r.json()).error || msg; } catch (_) { /* not JSON */ }
      throw new Error(msg);
    }
    return r;
  }
  function showError(e) { E.error = e ? String(e.message || e) : null; $("error").textContent = E.error || ""; }

  // Sample again with the current keys; an edit during a request runs once it returns.
  async function generate() {
    if (E.inFlight) { E.dirty = true; return; }
    E.inFlight = true; E.dirty = false;
    $("busy").textContent = "generating\u2026";
    const editAt = E.editAt;
    try {
      const m = await (await api("/api/sample", request())).json();
      E.motion = m; E.serverMs = m.server_ms; E.generation++;
      E.frame = Math.min(E.frame, m.length - 1);
      showError(null);
      requestAnimationFrame(() => { draw(); if (editAt !== null) E.latencyMs = performance.now() - editAt; E.drawn = E.generation; report(); });
    } catch (e) { showError(e); }
    E.inFlight = false;
    $("busy").textContent = "";
    if (E.dirty) generate();
  }
  function edited() {
    E.editAt = performance.now();
    draw();
    renderKeys();
    if ($("auto").checked) generate();
  }

  // ---- keys ------------------------------------------------------------------------------
  function keyFromMotion(m, f, frame) {
    const row = m.root[Math.min(f, m.length - 1)];
    const world = info.parents.map((_, j) => V.motionJoint(m, f, j));
    return { frame, pose: P.toLocal(world, row[3]), place: [row[0], row[2]], heading: row[3], usePose: true, usePlace: true };
  }
  function addKey(from) {
    const src = from === "upload" ? E.upload : E.motion;
    if (!src) return;
    const at = E.keys.findIndex((k) => k.frame === E.frame);
    remember();
    const k = keyFromMotion(src, Math.min(E.frame, src.length - 1), E.frame);
    if (at >= 0) E.keys[at] = k; else E.keys.push(k);
    E.selected = at >= 0 ? at : E.keys.length - 1;
    edited();
  }
  function deleteKey() { if (E.selected < 0) return; remember(); E.keys.splice(E.selected, 1); E.selected = -1; edited(); }
  function setMode(mode) {
    const k = E.keys[E.selected];
    if (!k) return;
    remember();
    k.usePose = mode !== "place"; k.usePlace = mode !== "pose";
    edited();
  }
  // A key read from a keyframe file: its pose made local, its place and heading from the file
  // or from the pose.
  function keyFromFile(k) {
    if (!k.joints) return { frame: k.frame, pose: null, place: k.root ? [k.root[0], k.root[2]] : [0, 0], heading: k.heading || 0, usePose: false, usePlace: true };
    const heading = k.heading !== undefined ? k.heading : P.facing(k.joints, I);
    const place = k.root ? [k.root[0], k.root[2]] : [k.joints[0][0], k.joints[0][2]];
    return { frame: k.frame, pose: P.toLocal(k.joints, heading), place, heading, usePose: true, usePlace: !!(k.root || k.heading !== undefined) };
  }
  function loadKeys(doc) {
    if (!doc || !Array.isArray(doc.keyframes)) throw new Error("keyframe file: no \"keyframes\" list");
    remember();
    E.length = Math.max(1, Math.min(info.limits.max_frames, doc.length || E.length));
    $("length").value = E.length;
    E.keys = doc.keyframes.filter((k) => k.frame < E.length).map(keyFromFile);
    E.keys.forEach((k) => { if (!k.pose) k.pose = E.motion ? keyFromMotion(E.motion, k.frame, k.frame).pose : info.rest; });
    if (doc.source && doc.source.text) { E.text = doc.source.text; $("text").value = E.text; }
    E.selected = E.keys.length ? 0 : -1;
    edited();
  }
  function renderKeys() {
    const rows = E.keys.map((k, i) => {
      const r = ((E.motion && E.motion.keys) || []).find((x) => x.frame === k.frame);
      const cm = (v) => (v === null || v === undefined ? "-" : (100 * v).toFixed(1) + " cm");
      const mode = k.usePose && k.usePlace ? "pose + place" : k.usePose ? "pose" : "place";
      return `<tr class="${i === E.selected ? "sel" : ""}${r && r.large ? " large" : ""}" data-i="${i}"><td>${k.frame}</td><td>${mode}</td><td>${r ? cm(r.pose_err_m) : "-"}</td><td>${r ? cm(r.place_err_m) : "-"}</td><td>${r && r.large ? "needed a large correction" : ""}</td></tr>`;
    });
    $("keys").innerHTML = "<tr><th>frame</th><th>observes</th><th>pose error</th><th>place error</th><th></th></tr>" + rows.join("");
    const k = E.keys[E.selected];
    $("mode").value = k ? (k.usePose && k.usePlace ? "both" : k.usePose ? "pose" : "place") : "both";
  }
  function report() {
    const m = E.motion && E.motion.metrics;
    const f = (v, d, u) => (v === null || v === undefined ? "-" : v.toFixed(d) + (u || ""));
    $("metrics").textContent = m ? `K-Err ${f(m.k_err_m && 100 * m.k_err_m, 2, " cm")} \u00b7 place ${f(m.place_err_m && 100 * m.place_err_m, 2, " cm")} \u00b7 heading ${f(m.heading_err_deg, 1, "\u00b0")} \u00b7 K-TranS ${f(m.k_trans, 4)} \u00b7 foot skating ${f(m.foot_skating, 3)} \u00b7 server ${f(E.serverMs, 0, " ms")} \u00b7 edit to picture ${f(E.latencyMs, 0, " ms")}` + (m.large_corrections ? ` \u00b7 ${m.large_corrections} key(s) needed a large correction` : "") : "";
    renderKeys();
  }

  // ---- drawing and playback --------------------------------------------------------------
  function draw() { V.drawView(E, cv, ctx); V.drawTimeline(E, tl, tctx); $("frame").max = E.length - 1; $("frame").value = E.frame; }
  let last = null, acc = 0;
  function tick(ts) {
    if (E.playing && E.motion && !drag) {
      if (last !== null) { acc += (ts - last) / 1000; const n = Math.floor(acc * info.fps); if (n > 0) { acc -= n / info.fps; E.frame = (E.frame + n) % E.length; draw(); } }
      last = ts;
    } else last = null;
    requestAnimationFrame(tick);
  }
  function setPlaying(p) { E.playing = p; $("play").textContent = p ? "\u275a\u275a pause" : "\u25b6 play"; }

  // ---- pointer editing in the view ---------------------------------------------------------
  let drag = null;
  function pick(x, y) {
    let best = null, bd = 14;
    E.handles.forEach((h) => { const d = Math.hypot(h.x - x, h.y - y); if (d < bd) { bd = d; best = h; } });
    return best;
  }
  function dragTo(h, x, y) {
    const k = E.keys[h.key], ray = E.camera.ray(x, y);
    if (h.kind === "place" || h.kind === "heading") {
      const g = DiffkfcScene.onPlane(ray, [0, 0, 0], [0, 1, 0]);
      if (!g) return;
      if (h.kind === "place") { k.place = [g[0], g[2]]; k.usePlace = true; }
      else k.heading = Math.atan2(g[0] - k.place[0], g[2] - k.place[1]) * 180 / Math.PI;
      return;
    }
    const t = DiffkfcScene.onPlane(ray, h.world, E.camera.forward);
    if (!t) return;
    const local = P.toLocal([[k.place[0], 0, k.place[1]], t], k.heading)[1];
    local[1] = t[1];
    const j = h.joint;
    if (j === 0) k.pose = P.movePelvis(k.pose, t[1] - k.pose[0][1], I);
    else k.pose = P.twoBone(k.pose, info.chains[j], local, info.carry[j] || []);
    k.usePose = true;
  }
  cv.addEventListener("pointerdown", (e) => {
    const r = cv.getBoundingClientRect(), x = e.clientX - r.left, y = e.clientY - r.top;
    const h = pick(x, y);
    cv.setPointerCapture(e.pointerId);
    if (h) { remember(); E.selected = h.key; E.frame = E.keys[h.key].frame; setPlaying(false); drag = { handle: h, moved: false }; }
    else drag = { orbit: [e.clientX, e.clientY] };
    draw(); renderKeys();
  });
  cv.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const r = cv.getBoundingClientRect();
    if (drag.handle) { dragTo(drag.handle, e.clientX - r.left, e.clientY - r.top); drag.moved = true; }
    else { E.cam.yaw -= (e.clientX - drag.orbit[0]) * 0.01; E.cam.pitch = Math.max(-0.1, Math.min(1.45, E.cam.pitch + (e.clientY - drag.orbit[1]) * 0.01)); drag.orbit = [e.clientX, e.clientY]; }
    draw();
  });
  cv.addEventListener("pointerup", () => { const d = drag; drag = null; if (d && d.handle) { if (d.moved) edited(); else E.history.pop(); } });
  cv.addEventListener("wheel", (e) => { e.preventDefault(); E.cam.zoom = Math.max(0.2, Math.min(5, E.cam.zoom * Math.exp(e.deltaY * 0.001))); E.cam.dist = 4.2 * E.cam.zoom; draw(); }, { passive: false });

  // ---- the timeline: click to seek, drag a key in time --------------------------------------
  let tdrag = null;
  tl.addEventListener("pointerdown", (e) => {
    const r = tl.getBoundingClientRect(), x = e.clientX - r.left;
    tl.setPointerCapture(e.pointerId);
    setPlaying(false);
    const i = E.keys.findIndex((k) => Math.abs(V.tx(E, r.width, k.frame) - x) < 8);
    if (i >= 0) { remember(); E.selected = i; tdrag = { i, moved: false }; E.frame = E.keys[i].frame; }
    else E.frame = V.frameAt(E, r.width, x);
    draw(); renderKeys();
  });
  tl.addEventListener("pointermove", (e) => {
    if (!tdrag) return;
    const r = tl.getBoundingClientRect(), f = V.frameAt(E, r.width, e.clientX - r.left);
    if (E.keys.some((k, j) => j !== tdrag.i && k.frame === f)) return;
    E.keys[tdrag.i].frame = f; E.frame = f; tdrag.moved = true;
    draw();
  });
  tl.addEventListener("pointerup", () => { const d = tdrag; tdrag = null; if (d) { if (d.moved) edited(); else E.history.pop(); } });

  // ---- controls ---------------------------------------------------------------------------
  const on = (id, ev, f) => $(id).addEventListener(ev, f);
  on("generate", "click", () => { E.editAt = performance.now(); generate(); });
  on("text", "change", () => { remember(); E.text = $("text").value; edited(); });
  on("length", "change", () => {
    const last = Math.max(0, ...E.keys.map((k) => k.frame));
    const n = Math.max(last + 1, Math.min(info.limits.max_frames, Math.round(Number($("length").value)) || E.length));
    remember(); E.length = n; $("length").value = n; E.frame = Math.min(E.frame, n - 1); edited();
  });
  on("play", "click", () => setPlaying(!E.playing));
  on("frame", "input", () => { setPlaying(false); E.frame = Number($("frame").value); draw(); });
  on("add-key", "click", () => addKey("motion"));
  on("add-upload-key", "click", () => addKey("upload"));
  on("delete-key", "click", deleteKey);
  on("mode", "change", () => setMode($("mode").value));
  on("undo", "click", undo);
  on("redo", "click", redo);
  on("follow", "change", () => { E.follow = $("follow").checked; draw(); });
  ["steps", "kf-guidance", "transition", "fit", "foot-lock", "seed"].forEach((id) => on(id, "change", edited));
  $("keys").addEventListener("click", (e) => { const tr = e.target.closest("tr[data-i]"); if (tr) { E.selected = Number(tr.dataset.i); E.frame = E.keys[E.selected].frame; setPlaying(false); draw(); renderKeys(); } });
  document.addEventListener("keydown", (e) => {
    if (e.target.tagName === "INPUT" || e.target.tagName === "SELECT") return;
    const mod = e.ctrlKey || e.metaKey;
    if (mod && e.key.toLowerCase() === "z") { e.preventDefault(); e.shiftKey ? redo() : undo(); }
    else if (mod && e.key.toLowerCase() === "y") { e.preventDefault(); redo(); }
    else if (e.code === "Space") { e.preventDefault(); setPlaying(!E.playing); }
    else if (e.key === "k") addKey("motion");
    else if (e.key === "Delete" || e.key === "Backspace") deleteKey();
    else if (e.code === "ArrowRight" || e.code === "ArrowLeft") { setPlaying(false); E.frame = Math.max(0, Math.min(E.length - 1, E.frame + (e.code === "ArrowRight" ? 1 : -1))); draw(); }
  });

  function download(name, blob) {
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob); a.download = name; document.body.appendChild(a); a.click(); a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  }
  const exportName = { bvh: "motion.bvh", glb: "motion.glb", features: "motion_features.npy", joints: "motion_joints.npy" };
  ["bvh", "glb", "features", "joints"].forEach((f) => on("export-" + f, "click", async () => {
    try { const r = await api("/api/export?format=" + f, request()); download(exportName[f], await r.blob()); showError(null); } catch (e) { showError(e); }
  }));
  on("export-keys", "click", () => {
    const doc = Object.assign(spec(), { source: { text: E.text, seed: Number($("seed").value) || 0, editor: "diffkfc serve" } });
    download("keys.json", new Blob([JSON.stringify(doc, null, 1)], { type: "application/json" }));
  });
  on("import-keys", "change", async (e) => {
    const file = e.target.files[0]; e.target.value = "";
    if (!file) return;
    try { loadKeys(JSON.parse(await file.text())); showError(null); } catch (err) { showError(`${file.name}: ${err.message}`); }
  });
  on("upload", "change", async (e) => {
    const file = e.target.files[0]; e.target.value = "";
    if (!file) return;
    try {
      const u = await (await api("/api/import?name=" + encodeURIComponent(file.name), await file.arrayBuffer(), "application/octet-stream")).json();
      E.upload = u;
      $("upload-name").textContent = `${u.name}: ${u.length} frames (grey)`; $("add-upload-key").disabled = false;
      showError(null); draw();
    } catch (err) { showError(err); }
  });
  on("suggest", "click", async () => {
    try { loadKeys(await (await api("/api/suggest", { request: request(), count: Number($("suggest-count").value), strategy: $("suggest-strategy").value })).json()); showError(null); } catch (e) { showError(e); }
  });

  window.addEventListener("resize", draw);
  window.diffkfcEditor = {
    state: E, addKey, generate,
    // Where a key's handle is drawn (CSS pixels in the view), for the browser test.
    handle: (kind, key, joint) => { draw(); const h = E.handles.find((x) => x.kind === kind && x.key === key && (joint === undefined || x.joint === joint)); return h ? [h.x, h.y] : null; },
    pixelsChanged: () => cv.toDataURL(),
  };
  $("length").value = E.length;
  setPlaying(true);
  renderKeys();
  draw();
  generate();
  requestAnimationFrame(tick);
})();
