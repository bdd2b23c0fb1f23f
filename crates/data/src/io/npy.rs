//! `.npy` reading and writing (format versions 1.0, 2.0 and 3.0; little-endian f32 / f64;
//! C order; any number of dimensions).
//!
//! Every failure names the file and what is wrong with it, because users point diffkfc at
//! datasets with tens of thousands of files and need to find the bad one.
//!
//! Hand-written rather than npyz: npyz 0.8 writes `'shape': (3, 4, )` where numpy writes
//! `(3, 4)`, so every file we write would change bytes; ours equals `np.save` byte for byte and
//! reads numpy's files exactly (crates/data/tests/numpy.rs).

use std::path::{Path, PathBuf};

use crate::DataError;

const MAGIC: &[u8] = b"\x93NUMPY";

/// Element type stored in a `.npy` file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    F32,
    F64,
}

/// A dense C-order array read from (or to be written to) a `.npy` file.
#[derive(Clone, Debug, PartialEq)]
pub struct Array<T> {
    pub shape: Vec<usize>,
    pub data: Vec<T>,
}

impl<T: Copy> Array<T> {
    pub fn new(shape: Vec<usize>, data: Vec<T>) -> Self {
        assert_eq!(shape.iter().product::<usize>(), data.len(), "shape does not match data");
        Self { shape, data }
    }

    pub fn ndim(&self) -> usize {
        self.shape.len()
    }

    /// Convert elements, keeping the shape.
    pub fn map<U>(&self, f: impl Fn(T) -> U) -> Array<U> {
        Array { shape: self.shape.clone(), data: self.data.iter().map(|&x| f(x)).collect() }
    }
}

fn err(path: &Path, msg: impl Into<String>) -> DataError {
    DataError::Npy { path: PathBuf::from(path), msg: msg.into() }
}

/// Parsed header of a `.npy` file.
struct Header {
    dtype: DType,
    shape: Vec<usize>,
    data_offset: usize,
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header, DataError> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(err(path, "not a .npy file (bad magic bytes)"));
    }
    let major = bytes[6];
    let (len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(err(path, "truncated header"));
            }
            (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12)
        }
        v => return Err(err(path, format!("unsupported .npy format version {v}"))),
    };
    let end = start + len;
    if bytes.len() < end {
        return Err(err(path, "truncated header"));
    }
    let text = std::str::from_utf8(&bytes[start..end])
        .map_err(|_| err(path, "header is not valid text"))?;
    let descr = dict_value(text, "descr").ok_or_else(|| err(path, "header has no 'descr'"))?;
    let descr = descr.trim().trim_matches(|c| c == '\'' || c == '"');
    let dtype = match descr {
        "<f4" | "=f4" => DType::F32,
        "<f8" | "=f8" => DType::F64,
        other => return Err(err(path, format!("dtype '{other}' is not supported (expected little-endian float32 '<f4' or float64 '<f8')"))),
    };
    let order = dict_value(text, "fortran_order")
        .ok_or_else(|| err(path, "header has no 'fortran_order'"))?;
    if order.trim() != "False" {
        return Err(err(path, "Fortran-order arrays are not supported (save with C order)"));
    }
    let shape_txt = dict_value(text, "shape").ok_or_else(|| err(path, "header has no 'shape'"))?;
    let inner = shape_txt.trim().trim_start_matches('(').trim_end_matches(')');
    let mut shape = Vec::new();
    for part in inner.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        shape.push(
            part.parse::<usize>().map_err(|_| err(path, format!("bad shape entry '{part}'")))?,
        );
    }
    Ok(Header { dtype, shape, data_offset: end })
}

/// Value text of `key` in the Python dict literal of an npy header.
fn dict_value<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    let k1 = format!("'{key}'");
    let pos = text.find(&k1)? + k1.len();
    let rest = text[pos..].trim_start().strip_prefix(':')?.trim_start();
    // A value ends at the first top-level comma or closing brace.
    let mut depth = 0i32;
    for (i, c) in rest.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(&rest[..i]),
            _ => {}
        }
    }
    None
}

/// Decode a `.npy` byte buffer into f64 elements (exact for both f32 and f64 files).
pub fn decode_f64(path: &Path, bytes: &[u8]) -> Result<(Array<f64>, DType), DataError> {
    let h = parse_header(path, bytes)?;
    let width = match h.dtype {
        DType::F32 => 4,
        DType::F64 => 8,
    };
    // The header is untrusted: a shape whose size overflows is an error, not a wrapped number.
    let n = h
        .shape
        .iter()
        .try_fold(1usize, |a, &s| a.checked_mul(s))
        .filter(|n| n.checked_mul(width).is_some());
    let body = &bytes[h.data_offset..];
    let Some(n) = n.filter(|&n| body.len() >= n * width) else {
        let needs =
            n.map_or("more than 2^64".to_string(), |n| (n as u128 * width as u128).to_string());
        return Err(err(
            path,
            format!(
                "truncated data: shape {:?} needs {needs} bytes, file has {}",
                h.shape,
                body.len()
            ),
        ));
    };
    let data: Vec<f64> = match h.dtype {
        DType::F32 => body[..n * 4]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64)
            .collect(),
        DType::F64 => body[..n * 8]
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect(),
    };
    Ok((Array { shape: h.shape, data }, h.dtype))
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|e| DataError::Io { path: path.to_path_buf(), err: e })
}

/// Read any f32/f64 `.npy` file as f64.
pub fn read_f64(path: impl AsRef<Path>) -> Result<Array<f64>, DataError> {
    let path = path.as_ref();
    Ok(decode_f64(path, &read_bytes(path)?)?.0)
}

/// Read any f32/f64 `.npy` file as f32.
pub fn read_f32(path: impl AsRef<Path>) -> Result<Array<f32>, DataError> {
    Ok(read_f64(path)?.map(|x| x as f32))
}

/// Encode an array as `.npy` bytes (format 1.0, or 2.0 when the header needs it).
pub fn encode<T: NpyElem>(shape: &[usize], data: &[T]) -> Vec<u8> {
    let shape_txt = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!("({})", shape.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(", ")),
    };
    let dict =
        format!("{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}", T::DESCR, shape_txt);
    // Header (magic + version + len + dict + padding + '\n') is padded to a multiple of 64.
    let mut major = 1u8;
    let mut prefix = 10usize;
    let mut total = (prefix + dict.len() + 1).div_ceil(64) * 64;
    if total - prefix > u16::MAX as usize {
        major = 2;
        prefix = 12;
        total = (prefix + dict.len() + 1).div_ceil(64) * 64;
    }
    let hlen = total - prefix;
    let mut out = Vec::with_capacity(total + std::mem::size_of_val(data));
    out.extend_from_slice(MAGIC);
    out.push(major);
    out.push(0);
    if major == 1 {
        out.extend_from_slice(&(hlen as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&(hlen as u32).to_le_bytes());
    }
    out.extend_from_slice(dict.as_bytes());
    out.resize(total - 1, b' ');
    out.push(b'\n');
    for x in data {
        x.write_le(&mut out);
    }
    out
}

/// Element types diffkfc writes.
pub trait NpyElem: Copy {
    const DESCR: &'static str;
    fn write_le(&self, out: &mut Vec<u8>);
}

impl NpyElem for f32 {
    const DESCR: &'static str = "<f4";
    fn write_le(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

impl NpyElem for f64 {
    const DESCR: &'static str = "<f8";
    fn write_le(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

/// Write an array atomically: to a temporary name beside the target, then rename, so an
/// interrupted run never leaves a half-written file.
pub fn write<T: NpyElem>(
    path: impl AsRef<Path>,
    shape: &[usize],
    data: &[T],
) -> Result<(), DataError> {
    assert_eq!(shape.iter().product::<usize>(), data.len(), "shape does not match data");
    crate::write_atomic(path.as_ref(), &encode(shape, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_any_rank_and_dtype() {
        let p = Path::new("mem.npy");
        for shape in [vec![5], vec![2, 3], vec![2, 2, 3], vec![0, 263], vec![]] {
            let n: usize = shape.iter().product();
            let d32: Vec<f32> = (0..n).map(|i| i as f32 * 0.5 - 1.0).collect();
            let (a, t) = decode_f64(p, &encode(&shape, &d32)).unwrap();
            assert_eq!(t, DType::F32);
            assert_eq!(a.shape, shape);
            assert_eq!(a.data, d32.iter().map(|&x| x as f64).collect::<Vec<_>>());
            let d64: Vec<f64> = (0..n).map(|i| (i as f64).sqrt()).collect();
            let (b, t) = decode_f64(p, &encode(&shape, &d64)).unwrap();
            assert_eq!(t, DType::F64);
            assert_eq!(b.data, d64);
        }
    }

    #[test]
    fn header_is_aligned_to_64() {
        let bytes = encode(&[3, 22, 3], &[0f32; 198]);
        assert_eq!((bytes.len() - 198 * 4) % 64, 0);
        assert_eq!(bytes[6], 1);
    }

    /// A header written by numpy itself (version 1.0), with its exact spacing.
    #[test]
    fn reads_numpy_written_header() {
        let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 1), }";
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&[1, 0]);
        let hlen = 118usize;
        bytes.extend_from_slice(&(hlen as u16).to_le_bytes());
        let mut h = dict.as_bytes().to_vec();
        h.resize(hlen - 1, b' ');
        h.push(b'\n');
        bytes.extend_from_slice(&h);
        bytes.extend_from_slice(&1.5f64.to_le_bytes());
        bytes.extend_from_slice(&(-2.0f64).to_le_bytes());
        let (a, _) = decode_f64(Path::new("x.npy"), &bytes).unwrap();
        assert_eq!(a.shape, vec![2, 1]);
        assert_eq!(a.data, vec![1.5, -2.0]);
        // Version 2.0 with a 4-byte length.
        let mut v2 = MAGIC.to_vec();
        v2.extend_from_slice(&[2, 0]);
        v2.extend_from_slice(&(hlen as u32).to_le_bytes());
        v2.extend_from_slice(&h);
        v2.extend_from_slice(&bytes[10 + hlen..]);
        assert_eq!(decode_f64(Path::new("x.npy"), &v2).unwrap().0.data, vec![1.5, -2.0]);
    }

    #[test]
    fn malformed_files_name_the_problem() {
        let p = Path::new("bad.npy");
        let good = encode(&[4, 3], &[1f32; 12]);
        let e = decode_f64(p, &good[..good.len() - 5]).unwrap_err().to_string();
        assert!(e.contains("bad.npy") && e.contains("truncated data"), "{e}");
        let e = decode_f64(p, b"hello world").unwrap_err().to_string();
        assert!(e.contains("magic"), "{e}");
        let e = decode_f64(p, &good[..20]).unwrap_err().to_string();
        assert!(e.contains("truncated header"), "{e}");
        let patch = |from: &str, to: &str| -> Vec<u8> {
            let mut b = good.clone();
            let at = b.windows(from.len()).position(|w| w == from.as_bytes()).unwrap();
            b[at..at + to.len()].copy_from_slice(to.as_bytes());
            b
        };
        let e = decode_f64(p, &patch("<f4", "<i4")).unwrap_err().to_string();
        assert!(e.contains("'<i4' is not supported"), "{e}");
        let e = decode_f64(p, &patch("<f4", ">f4")).unwrap_err().to_string();
        assert!(e.contains("'>f4'"), "{e}");
        let e = decode_f64(p, &patch("False", "True ")).unwrap_err().to_string();
        assert!(e.contains("Fortran"), "{e}");
    }

    #[test]
    fn atomic_write_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("diffkfc-npy-{}", std::process::id()));
        let path = dir.join("sub/a.npy");
        write(&path, &[2, 2], &[1f32, 2., 3., 4.]).unwrap();
        assert_eq!(read_f32(&path).unwrap().data, vec![1., 2., 3., 4.]);
        let names: Vec<_> =
            std::fs::read_dir(dir.join("sub")).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "{names:?}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[cfg(test)]
mod overflow_tests {
    #[test]
    fn shapes_whose_size_overflows_are_errors() {
        for shape in [
            "(2305843009213693952, 22, 3)",
            "(4611686018427387904, 263)",
            "(18446744073709551615, 2)",
        ] {
            let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
            let mut header = dict.into_bytes();
            while (10 + header.len() + 1) % 64 != 0 {
                header.push(b' ');
            }
            header.push(b'\n');
            let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
            bytes.extend((header.len() as u16).to_le_bytes());
            bytes.extend(header);
            bytes.extend([0u8; 64]);
            let e =
                super::decode_f64(std::path::Path::new("big.npy"), &bytes).unwrap_err().to_string();
            assert!(
                e.contains("big.npy") && e.contains("truncated data") && e.contains("file has 64"),
                "{shape}: {e}"
            );
        }
    }
}
