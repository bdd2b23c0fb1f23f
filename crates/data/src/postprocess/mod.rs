//! After sampling: meeting keyframes without a seam (warp), one rigid skeleton (rigid), and
//! planted feet held still (foot lock).

pub mod contacts;
pub mod footlock;
pub mod rigid;
pub mod stride;
pub mod warp;
