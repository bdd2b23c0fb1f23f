//! `--device` and `--devices`: which Burn backend runs the model, and on which devices.

use anyhow::{anyhow, bail, Result};
use burn::prelude::Device;
use diffkfc_model::training::data_parallel::DataParallel;

/// A device name: flex (or cpu), ndarray, wgpu, cuda; a GPU's may carry an index (`cuda:1`,
/// `wgpu:1`: the second discrete GPU).
pub fn parse(name: &str) -> Result<Device> {
    let (kind, index) = match name.split_once(':') {
        Some((k, i)) => {
            let i: usize = i.parse().map_err(|_| {
                anyhow!("--device {name}: the index after ':' must be a number (e.g. cuda:1)")
            })?;
            if !is_gpu(k) {
                bail!("--device {name}: only wgpu and cuda devices take an index");
            }
            (k, Some(i))
        }
        None => (name, None),
    };
    let _ = index; // read only by the GPU arms of builds that have them
    match kind {
        "flex" | "cpu" => Ok(Device::flex()),
        #[cfg(feature = "ndarray")]
        #[allow(deprecated)]
        "ndarray" => Ok(Device::ndarray()),
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(Device::wgpu(match index {
            Some(i) => burn::tensor::DeviceKind::DiscreteGpu(i),
            None => burn::tensor::DeviceKind::DefaultDevice,
        })),
        #[cfg(feature = "cuda")]
        "cuda" => {
            cuda_driver(name)?;
            Ok(Device::cuda(index.unwrap_or(0)))
        }
        // A guard, not a pattern: in builds with a backend its name is matched above.
        n if matches!(n, "ndarray" | "wgpu" | "cuda") => bail!("--device {name}: this build lacks it; rebuild with `cargo build --release --features {n}`"),
        other => bail!("--device: unknown device '{other}' (flex, ndarray, wgpu, cuda; a GPU with an index: cuda:1)"),
    }
}

/// Whether a `--device` name (with or without its index) is a GPU's: wgpu or cuda.
pub fn is_gpu(name: &str) -> bool {
    matches!(name.split(':').next(), Some("wgpu" | "cuda"))
}

/// CubeCL's CUDA runtime loads the driver library on first use and panics on another thread
/// when it is missing; a machine without one gets this one-line error instead.
#[cfg(all(feature = "cuda", unix))]
fn cuda_driver(name: &str) -> Result<()> {
    let found = ["libcuda.so.1", "libcuda.so"].iter().any(|lib| {
        let c = std::ffi::CString::new(*lib).expect("no NUL");
        // SAFETY: dlopen with a valid C string; the handle is released at once.
        let h = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_LAZY | libc::RTLD_LOCAL) };
        if !h.is_null() {
            unsafe { libc::dlclose(h) };
        }
        !h.is_null()
    });
    if !found {
        bail!("--device {name}: no CUDA driver on this machine (libcuda.so.1 could not be loaded)");
    }
    Ok(())
}

#[cfg(all(feature = "cuda", not(unix)))]
fn cuda_driver(_: &str) -> Result<()> {
    Ok(())
}

/// `--devices cuda:0,cuda:1,...`: the devices of a data-parallel run, checked (two or more,
/// each one Burn can all-reduce gradients on, none twice).
pub fn parse_many(list: &str) -> Result<DataParallel> {
    let devices = list
        .split(',')
        .map(|n| parse(n.trim()).map_err(|e| anyhow!("--devices {list}: {e}")))
        .collect::<Result<Vec<_>>>()?;
    DataParallel::new(devices).map_err(|e| anyhow!("--devices {list}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_indices() {
        assert!(parse("flex").is_ok() && parse("cpu").is_ok());
        let e = parse("cuda:x").unwrap_err().to_string();
        assert!(e.contains("must be a number"), "{e}");
        let e = parse("flex:1").unwrap_err().to_string();
        assert!(e.contains("only wgpu and cuda"), "{e}");
        assert!(is_gpu("cuda") && is_gpu("cuda:1") && is_gpu("wgpu"));
        assert!(!is_gpu("flex") && !is_gpu("cpu") && !is_gpu("ndarray"));
        let e = parse("tpu").unwrap_err().to_string();
        assert!(e.contains("unknown device 'tpu'"), "{e}");
    }

    #[test]
    fn devices_name_the_list_and_the_problem() {
        let e = parse_many("flex,flex").unwrap_err().to_string();
        assert!(e.starts_with("--devices flex,flex: ") && e.contains("CUDA devices only"), "{e}");
        let e = parse_many("flex").unwrap_err().to_string();
        assert!(e.contains("two or more"), "{e}");
        #[cfg(not(feature = "cuda"))]
        {
            let e = parse_many("cuda:0,cuda:1").unwrap_err().to_string();
            assert!(e.contains("this build lacks it"), "{e}");
        }
    }
}
