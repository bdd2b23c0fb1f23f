//! `.npy` against numpy itself: files numpy writes (format 1.0 and 2.0, f32 and f64, rank 0 to 4,
//! empty arrays) read back with their values, and our writer's bytes equal `np.save`'s.

use diffkfc_data::{io::npy, testing::fixtures};

const SCRIPT: &str = r#"
import sys, json, numpy as np
from numpy.lib import format as fmt
out = sys.argv[1]
rng = np.random.default_rng(7)
cases = [("a", (3, 4), np.float32, (1, 0)), ("b", (2, 3, 5), np.float64, (1, 0)),
         ("c", (7,), np.float32, (1, 0)), ("d", (1, 1, 1, 2), np.float64, (1, 0)),
         ("e", (0, 3), np.float32, (1, 0)), ("f", (), np.float64, (1, 0)),
         ("g", (4, 263), np.float32, (2, 0)), ("h", (196, 22, 3), np.float32, (1, 0))]
meta = []
for name, shape, dt, ver in cases:
    a = rng.standard_normal(shape).astype(dt)
    with open(f"{out}/{name}.npy", "wb") as f:
        fmt.write_array(f, a, version=ver)
    meta.append({"name": name, "shape": list(shape), "f64": dt == np.float64, "v1": ver == (1, 0),
                 "values": [repr(float(x)) for x in a.ravel()]})
print(json.dumps(meta))
"#;

#[test]
fn numpy_files_read_back_and_our_bytes_are_np_save() {
    let dir = std::env::temp_dir().join(format!("diffkfc-numpy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let Some(out) = fixtures::python(&["numpy"], SCRIPT, &[&dir]) else {
        return;
    };
    // Values travel as Python's repr strings: Rust's parse rounds them exactly (serde_json's
    // default float parsing may not).
    let meta: Vec<serde_json::Value> = serde_json::from_str(&out).unwrap();
    for m in &meta {
        let name = m["name"].as_str().unwrap();
        let path = dir.join(format!("{name}.npy"));
        let shape: Vec<usize> =
            m["shape"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
        let want: Vec<f64> = m["values"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().parse().unwrap())
            .collect();
        let got = npy::read_f64(&path).unwrap();
        assert_eq!(got.shape, shape, "{name}");
        assert_eq!(got.data, want, "{name}: values differ");
        if !m["v1"].as_bool().unwrap() {
            continue; // numpy writes format 2.0 only when asked; ours writes 1.0
        }
        let numpy_bytes = std::fs::read(&path).unwrap();
        let ours = if m["f64"].as_bool().unwrap() {
            npy::encode(&shape, &want)
        } else {
            npy::encode(&shape, &want.iter().map(|&v| v as f32).collect::<Vec<_>>())
        };
        assert_eq!(ours, numpy_bytes, "{name}: our .npy bytes differ from np.save's");
    }
    std::fs::remove_dir_all(dir).unwrap();
}
