//! After sampling: meeting keyframes without a seam (warp), one rigid skeleton (rigid), and
//! planted feet held still: contacts from the motion (contacts), stride warping (stride),
//! pinning (pin, footlock), on one leg's machinery (leg).

pub mod contacts;
pub mod footlock;
pub(crate) mod leg;
pub mod pin;
pub mod rigid;
pub mod stride;
pub mod warp;
