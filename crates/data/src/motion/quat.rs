//! Quaternion (w, x, y, z; Hamilton product) and continuous-6D rotation math, the conventions
//! of HumanML3D's `common/quaternion.py`. The one home for rotation math on the CPU side.

pub type Vec3 = [f64; 3];
pub type Quat = [f64; 4];

pub const IDENTITY: Quat = [1.0, 0.0, 0.0, 0.0];

pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

/// `a` at unit length; a zero (or non-finite) vector has no direction and stays zero, so a
/// collapsed bone yields no NaN downstream.
pub fn normalize(a: Vec3) -> Vec3 {
    let n = norm(a);
    if n > TINY && n.is_finite() {
        scale(a, 1.0 / n)
    } else {
        [0.0; 3]
    }
}

/// Below this length a vector (or quaternion) is taken as having no direction.
const TINY: f64 = 1e-12;

/// Hamilton product q * r.
pub fn qmul(q: Quat, r: Quat) -> Quat {
    let [w0, x0, y0, z0] = r;
    let [w1, x1, y1, z1] = q;
    [
        w1 * w0 - x1 * x0 - y1 * y0 - z1 * z0,
        w1 * x0 + x1 * w0 + y1 * z0 - z1 * y0,
        w1 * y0 - x1 * z0 + y1 * w0 + z1 * x0,
        w1 * z0 + x1 * y0 - y1 * x0 + z1 * w0,
    ]
}

/// Conjugate (the inverse of a unit quaternion).
pub fn qinv(q: Quat) -> Quat {
    [q[0], -q[1], -q[2], -q[3]]
}

/// `q` at unit length; a zero quaternion (no rotation can be told) becomes the identity.
pub fn qnormalize(q: Quat) -> Quat {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n > TINY && n.is_finite()) {
        return IDENTITY;
    }
    [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
}

/// Rotate v by the unit quaternion q.
pub fn qrot(q: Quat, v: Vec3) -> Vec3 {
    let qv = [q[1], q[2], q[3]];
    let uv = cross(qv, v);
    let uuv = cross(qv, uv);
    add(v, scale(add(scale(uv, q[0]), uuv), 2.0))
}

/// The shortest-arc rotation taking direction v0 onto direction v1; the identity where either
/// is a zero vector (no direction to turn from or to).
pub fn qbetween(v0: Vec3, v1: Vec3) -> Quat {
    if !(norm(v0) > TINY && norm(v1) > TINY) {
        return IDENTITY;
    }
    let v = cross(v0, v1);
    let w = (dot(v0, v0) * dot(v1, v1)).sqrt() + dot(v0, v1);
    let q = [w, v[0], v[1], v[2]];
    if q.iter().map(|x| x * x).sum::<f64>() < 1e-24 {
        // Opposite directions: any half turn about an axis perpendicular to v0 (the formula
        // above gives 0/0 there).
        let axis =
            if v0[0].abs() < 0.9 { cross(v0, [1.0, 0.0, 0.0]) } else { cross(v0, [0.0, 1.0, 0.0]) };
        return qnormalize([0.0, axis[0], axis[1], axis[2]]);
    }
    qnormalize(q)
}

/// Rotation about +Y by `angle` in HumanML3D's convention for the root: (cos a, 0, sin a, 0).
/// Note it uses the angle itself, not its half, exactly as `recover_root_rot_pos` does.
pub fn root_yaw_quat(angle: f64) -> Quat {
    [angle.cos(), 0.0, angle.sin(), 0.0]
}

/// Row-major 3x3 rotation matrix of a (not necessarily unit) quaternion.
pub fn to_matrix(q: Quat) -> [[f64; 3]; 3] {
    let [r, i, j, k] = q;
    let two_s = 2.0 / (r * r + i * i + j * j + k * k);
    [
        [1.0 - two_s * (j * j + k * k), two_s * (i * j - k * r), two_s * (i * k + j * r)],
        [two_s * (i * j + k * r), 1.0 - two_s * (i * i + k * k), two_s * (j * k - i * r)],
        [two_s * (i * k - j * r), two_s * (j * k + i * r), 1.0 - two_s * (i * i + j * j)],
    ]
}

/// Continuous 6D representation (Zhou et al. 2019): the first two columns of the rotation
/// matrix, column 0 then column 1, as HumanML3D's `quaternion_to_cont6d`.
pub fn to_cont6d(q: Quat) -> [f64; 6] {
    let m = to_matrix(q);
    [m[0][0], m[1][0], m[2][0], m[0][1], m[1][1], m[2][1]]
}

/// Rotation matrix (row-major) from a 6D representation by Gram-Schmidt; the identity where the
/// two columns span no plane (zero or parallel), which has no rotation to tell.
pub fn cont6d_to_matrix(c: [f64; 6]) -> [[f64; 3]; 3] {
    let x = normalize([c[0], c[1], c[2]]);
    let z = normalize(cross(x, [c[3], c[4], c[5]]));
    if z == [0.0; 3] {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let y = cross(z, x);
    [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]]
}

/// Unit quaternion of a rotation matrix (Shepperd's method, w >= 0).
pub fn from_matrix(m: [[f64; 3]; 3]) -> Quat {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [(m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s]
    };
    let q = qnormalize(q);
    if q[0] < 0.0 {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    }
}

/// Quaternion from an axis (need not be unit) and an angle in radians.
pub fn from_axis_angle(axis: Vec3, angle: f64) -> Quat {
    let a = normalize(axis);
    let (s, c) = (angle / 2.0).sin_cos();
    [c, a[0] * s, a[1] * s, a[2] * s]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < tol)
    }

    #[test]
    fn rotation_about_y_by_quarter_turn() {
        // +90 degrees about +Y takes +Z to +X (right-handed).
        let q = from_axis_angle([0.0, 1.0, 0.0], std::f64::consts::FRAC_PI_2);
        assert!(close(&qrot(q, [0.0, 0.0, 1.0]), &[1.0, 0.0, 0.0], 1e-12));
        let m = to_matrix(q);
        let v = [0.0, 0.0, 1.0];
        let mv: Vec<f64> = (0..3).map(|r| dot(m[r], v)).collect();
        assert!(close(&mv, &[1.0, 0.0, 0.0], 1e-12));
    }

    #[test]
    fn product_composes_rotations() {
        let a = from_axis_angle([1.0, 2.0, 0.5], 0.7);
        let b = from_axis_angle([-0.3, 1.0, 2.0], -1.9);
        let v = [0.3, -1.2, 2.5];
        assert!(close(&qrot(qmul(a, b), v), &qrot(a, qrot(b, v)), 1e-12));
        assert!(close(&qrot(qinv(a), qrot(a, v)), &v, 1e-12));
    }

    #[test]
    fn between_maps_directions() {
        let v0 = [0.2, -1.0, 0.4];
        let v1 = [1.0, 0.5, -0.1];
        let q = qbetween(v0, v1);
        assert!(close(&normalize(qrot(q, v0)), &normalize(v1), 1e-12));
    }

    #[test]
    fn cont6d_round_trip_through_matrix() {
        let q = from_axis_angle([0.4, -1.0, 0.2], 2.4);
        let m = cont6d_to_matrix(to_cont6d(q));
        assert!(close(&from_matrix(m), &from_matrix(to_matrix(q)), 1e-12));
        for axis in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] {
            let q = from_axis_angle(axis, 3.0);
            let r = from_matrix(to_matrix(q));
            let v = [0.1, 0.7, -0.4];
            assert!(close(&qrot(q, v), &qrot(r, v), 1e-12));
        }
    }

    #[test]
    fn directionless_inputs_give_the_identity_not_nan() {
        // A collapsed bone (zero vector), a zero quaternion, a zero or rank-one 6D rotation.
        assert_eq!(normalize([0.0; 3]), [0.0; 3]);
        assert_eq!(normalize([f64::NAN, 0.0, 0.0]), [0.0; 3]);
        assert_eq!(qnormalize([0.0; 4]), IDENTITY);
        assert_eq!(qbetween([0.0; 3], [0.0, 1.0, 0.0]), IDENTITY);
        assert_eq!(qbetween([0.0, 1.0, 0.0], [0.0; 3]), IDENTITY);
        assert_eq!(from_matrix(cont6d_to_matrix([0.0; 6])), IDENTITY);
        assert_eq!(from_matrix(cont6d_to_matrix([1.0, 0.0, 0.0, 2.0, 0.0, 0.0])), IDENTITY);
        // Real directions are untouched: opposite vectors still give a half turn.
        let q = qbetween([0.0, 1.0, 0.0], [0.0, -1.0, 0.0]);
        assert!(close(&qrot(q, [0.0, 1.0, 0.0]), &[0.0, -1.0, 0.0], 1e-12));
    }
}
