//! `--device`: which Burn backend runs the model.

use anyhow::{bail, Result};
use burn::prelude::Device;

pub fn parse(name: &str) -> Result<Device> {
    match name {
        "flex" | "cpu" => Ok(Device::flex()),
        #[cfg(feature = "ndarray")]
        #[allow(deprecated)]
        "ndarray" => Ok(Device::ndarray()),
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice)),
        #[cfg(feature = "cuda")]
        "cuda" => Ok(Device::cuda(0)),
        // A guard, not a pattern: in builds with a backend its name is matched above.
        n if matches!(n, "ndarray" | "wgpu" | "cuda") => bail!("--device {name}: this build lacks it; rebuild with `cargo build --release --features {name}`"),
        other => bail!("--device: unknown device '{other}' (flex, ndarray, wgpu, cuda)"),
    }
}
