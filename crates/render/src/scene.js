// Shared by diffkfc's pages (the 3D viewer and the keyframe editor): vector helpers, an orbit
// camera that projects world points onto a canvas and casts rays back into the world, the
// ground grid and depth-sorted stick figures. Plain canvas 2D, no libraries, no network.
var DiffkfcScene = (function () {
  "use strict";
  const COLORS = { left: "#2563eb", right: "#dc2626", centre: "#374151", key: "#f97316", path: "#7c3aed", planted: "#16a34a" };
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const len = (a) => Math.hypot(a[0], a[1], a[2]);
  const norm = (a) => { const l = len(a) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

  // The camera of orbit state `cam` ({yaw, pitch, dist, target}) for a w x h view: `proj(p)`
  // gives [x, y, depth, focal] (null behind the eye), `ray(x, y)` the world ray through a pixel.
  function camera(cam, w, h) {
    const c = Math.cos(cam.pitch);
    const eye = [cam.target[0] + cam.dist * c * Math.sin(cam.yaw), cam.target[1] + cam.dist * Math.sin(cam.pitch), cam.target[2] + cam.dist * c * Math.cos(cam.yaw)];
    const f = norm(sub(cam.target, eye));
    const r = norm(cross(f, [0, 1, 0]));
    const u = cross(r, f);
    const focal = 0.5 * h / Math.tan(0.45);
    const proj = (p) => {
      const d = sub(p, eye);
      const z = dot(d, f);
      return z < 0.05 ? null : [w / 2 + focal * dot(d, r) / z, h / 2 - focal * dot(d, u) / z, z, focal];
    };
    const ray = (x, y) => ({ o: eye, d: norm(add(f, add(scale(r, (x - w / 2) / focal), scale(u, -(y - h / 2) / focal)))) });
    return { proj, ray, eye, forward: f };
  }

  // Where ray `q` meets the plane through `p` with normal `n` (null if it never does ahead).
  function onPlane(q, p, n) {
    const den = dot(q.d, n);
    if (Math.abs(den) < 1e-9) return null;
    const t = dot(sub(p, q.o), n) / den;
    return t > 0 ? add(q.o, scale(q.d, t)) : null;
  }

  // Size the canvas's buffer to its box (device pixels); returns its CSS size.
  function fit(cv, ctx) {
    const dpr = window.devicePixelRatio || 1;
    const w = cv.clientWidth, h = cv.clientHeight;
    if (cv.width !== Math.round(w * dpr)) { cv.width = Math.round(w * dpr); cv.height = Math.round(h * dpr); }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return { w, h, dpr };
  }

  function line(ctx, a, b) {
    if (!a || !b) return;
    ctx.beginPath();
    ctx.moveTo(a[0], a[1]);
    ctx.lineTo(b[0], b[1]);
    ctx.stroke();
  }

  // A 0.5 m grid on the ground around the camera's target.
  function grid(ctx, proj, cam) {
    ctx.strokeStyle = "#e2e8f0";
    ctx.lineWidth = 1;
    const gx = Math.round(cam.target[0] * 2) / 2, gz = Math.round(cam.target[2] * 2) / 2, R = Math.max(6, Math.ceil(cam.dist));
    for (let k = -R; k <= R; k += 0.5) {
      line(ctx, proj([gx + k, 0, gz - R]), proj([gx + k, 0, gz + R]));
      line(ctx, proj([gx - R, 0, gz + k]), proj([gx + R, 0, gz + k]));
    }
  }

  // The bones of one pose as segments: `at(j)` gives joint j; `o.color` overrides the side
  // colours; a head disc at joint `head`.
  function figure(segs, parents, side, head, at, o) {
    for (let j = 1; j < parents.length; j++) {
      if (o.only && !o.only(j)) continue;
      segs.push({ a: at(parents[j]), b: at(j), color: o.color || COLORS[side[j]], alpha: o.alpha, width: o.width || 0.045 });
    }
    if (!o.only || o.only(head)) segs.push({ head: at(head), color: o.color || COLORS.centre, alpha: o.alpha });
  }

  // Segments and head discs, far ones first, widths in world units.
  function draw(ctx, proj, segs) {
    const pr = segs.map((s) => (s.head ? { s, p: proj(s.head) } : { s, p: proj(s.a), q: proj(s.b) })).filter((x) => x.p && (x.s.head || x.q));
    pr.sort((x, y) => (y.p[2] + (y.q ? y.q[2] : y.p[2])) - (x.p[2] + (x.q ? x.q[2] : x.p[2])));
    ctx.lineCap = "round";
    for (const { s, p, q } of pr) {
      ctx.globalAlpha = s.alpha;
      if (s.head) {
        ctx.fillStyle = s.color;
        ctx.beginPath();
        ctx.arc(p[0], p[1], Math.max(2, 0.09 * p[3] / p[2]), 0, 2 * Math.PI);
        ctx.fill();
      } else {
        ctx.strokeStyle = s.color;
        ctx.lineWidth = Math.max(1, s.width * p[3] / ((p[2] + q[2]) / 2));
        line(ctx, p, q);
      }
    }
    ctx.globalAlpha = 1;
  }

  return { COLORS, sub, add, scale, dot, cross, len, norm, camera, onPlane, fit, line, grid, figure, draw };
})();
