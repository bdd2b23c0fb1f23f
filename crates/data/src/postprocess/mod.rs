//! After sampling: meeting keyframes without a seam (warp), one rigid skeleton (rigid), and
//! planted feet held still: contacts from the motion (contacts), stride warping (stride, pelvis),
//! pinning (pin, footlock), on one leg's machinery (leg).

pub mod contacts;
pub mod footlock;
pub(crate) mod leg;
pub mod pelvis;
pub mod pin;
pub mod rigid;
pub mod stride;
pub mod warp;

/// 3x² - 2x³ of x clamped to [0, 1]: a fade with zero slope at both ends.
pub(crate) fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}
