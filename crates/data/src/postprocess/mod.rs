//! After sampling: meeting keyframes without a seam (warp), one rigid skeleton (rigid) on the
//! floor it stood on (floor), and planted feet held still: contacts from the motion (contacts),
//! stride warping (stride, pelvis), pinning (pin, footlock), steps out of a shuffle (steps), on
//! one leg's machinery (leg).

pub mod contacts;
pub mod floor;
pub mod footlock;
pub(crate) mod leg;
pub mod pelvis;
pub mod pin;
pub mod rigid;
pub mod steps;
pub mod stride;
pub mod warp;

/// 3x² - 2x³ of x clamped to [0, 1]: a fade with zero slope at both ends.
pub fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// The frames of a window `width` wide (odd) centred on frame `f` of `t`, cut at the ends.
pub(crate) fn window(f: usize, width: usize, t: usize) -> std::ops::Range<usize> {
    f.saturating_sub(width / 2)..(f + width / 2 + 1).min(t)
}

/// Per frame, how much of a change may act there: nothing on a held frame, rising smoothly
/// to all of it `fade` frames away from the nearest one (all of it where nothing is held).
pub(crate) fn key_weights(hold: &[bool], fade: usize) -> Vec<f64> {
    let keys: Vec<usize> = (0..hold.len()).filter(|&f| hold[f]).collect();
    (0..hold.len())
        .map(|f| {
            let near = keys.iter().map(|&h| h.abs_diff(f)).min().unwrap_or(usize::MAX);
            smoothstep(near as f64 / fade as f64)
        })
        .collect()
}
