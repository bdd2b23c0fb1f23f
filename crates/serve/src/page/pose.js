// Pose math of the keyframe editor: a key's pose is kept local (pelvis above the origin,
// facing +Z) and placed in the world by its place and heading; limbs are re-posed by
// two-bone IK that keeps every bone's length. Uses DiffkfcScene's vector helpers.
var DiffkfcPose = (function () {
  "use strict";
  const S = DiffkfcScene;
  const rad = (deg) => deg * Math.PI / 180;

  // Rotate p about +Y by `deg` (heading h turns +Z towards +X).
  function turn(p, deg) {
    const s = Math.sin(rad(deg)), c = Math.cos(rad(deg));
    return [p[0] * c + p[2] * s, p[1], -p[0] * s + p[2] * c];
  }

  // Heading (degrees) a pose faces, from its hips and shoulders (HumanML3D's facing rule).
  function facing(pose, I) {
    const across = S.add(S.sub(pose[I.r_hip], pose[I.l_hip]), S.sub(pose[I.r_shoulder], pose[I.l_shoulder]));
    const f = S.cross([0, 1, 0], across);
    return Math.atan2(f[0], f[2]) * 180 / Math.PI;
  }

  // World pose -> local (pelvis over the origin, facing +Z), given the heading it faces.
  function toLocal(world, heading) {
    const r = world[0];
    return world.map((p) => turn([p[0] - r[0], p[1], p[2] - r[2]], -heading));
  }

  // Local pose -> world at ground place [x, z] facing `heading`.
  function toWorld(local, place, heading) {
    return local.map((p) => { const q = turn(p, heading); return [q[0] + place[0], q[1], q[2] + place[1]]; });
  }

  // Move the end of chain [a, b, c] (joint indices of `pose`) towards `target`, keeping both
  // bone lengths and the knee or elbow bending the way it did; joints in `carry` (the foot of an
  // ankle) move with the end. Returns a new pose.
  function twoBone(pose, [a, b, c], target, carry) {
    const out = pose.map((p) => p.slice());
    const A = pose[a], B = pose[b], C = pose[c];
    const l1 = S.len(S.sub(B, A)), l2 = S.len(S.sub(C, B));
    const toT = S.sub(target, A);
    const d = Math.max(Math.abs(l1 - l2) + 1e-4, Math.min(l1 + l2 - 1e-4, S.len(toT)));
    const dir = S.norm(toT);
    // The bend's side: where the middle joint sat off the line from A to C (forward if straight).
    let pole = S.sub(S.sub(B, A), S.scale(dir, S.dot(S.sub(B, A), dir)));
    if (S.len(pole) < 1e-6) pole = S.sub([0, 0, 1], S.scale(dir, dir[2]));
    pole = S.norm(pole);
    const cosA = (l1 * l1 + d * d - l2 * l2) / (2 * l1 * d);
    const sinA = Math.sqrt(Math.max(0, 1 - cosA * cosA));
    out[b] = S.add(A, S.add(S.scale(dir, l1 * cosA), S.scale(pole, l1 * sinA)));
    out[c] = S.add(A, S.scale(dir, d));
    const moved = S.sub(out[c], C);
    (carry || []).forEach((j) => { out[j] = S.add(pose[j], moved); });
    return out;
  }

  // Raise or lower the pelvis by dy with the feet kept where they are (both legs re-solved).
  function movePelvis(pose, dy, I) {
    const legs = [[I.l_hip, I.l_knee, I.l_ankle, I.l_foot], [I.r_hip, I.r_knee, I.r_ankle, I.r_foot]];
    let out = pose.map((p) => [p[0], p[1] + dy, p[2]]);
    legs.forEach(([h, k, a, f]) => { out = twoBone(out, [h, k, a], pose[a], [f]); });
    return out;
  }

  return { turn, facing, toLocal, toWorld, twoBone, movePelvis };
})();
