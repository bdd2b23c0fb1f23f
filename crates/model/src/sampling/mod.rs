//! Generating motion: the reverse-diffusion loop and its request (`sampler`), keyframe,
//! transition and place guidance, the keyframe fits, and the pipeline that turns keyframes into
//! a fitted motion (the track fit's two stages), long motions from timelines and body-part prompts.

pub mod balance;
pub mod fit;
pub mod guidance;
pub mod interpolation;
pub mod parts;
pub mod pipeline;
pub mod place;
pub mod sampler;
pub mod session;
pub mod timeline;
pub(crate) mod transition;
