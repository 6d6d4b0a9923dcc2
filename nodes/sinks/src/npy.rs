//! NumPy `.npy` files (format version 1.0), as `numpy.load` reads them:
//! the magic `\x93NUMPY`, version bytes 1 0, a little-endian u16 header length, and a Python
//! dict literal `{'descr': '<f4', 'fortran_order': False, 'shape': (..), }` padded with spaces
//! and a newline so the data starts on a 64-byte boundary; then the data in C order.

/// Element types this project writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NpyDtype {
    F32,
    U8,
    U32,
}

impl NpyDtype {
    pub fn descr(self) -> &'static str {
        match self {
            NpyDtype::F32 => "<f4",
            NpyDtype::U8 => "|u1",
            NpyDtype::U32 => "<u4",
        }
    }

    pub fn size(self) -> usize {
        match self {
            NpyDtype::F32 | NpyDtype::U32 => 4,
            NpyDtype::U8 => 1,
        }
    }
}

/// The header of an array of `shape`, padded to the 64-byte alignment the format asks for.
pub fn npy_header(dtype: NpyDtype, shape: &[usize]) -> Vec<u8> {
    let shape_text = match shape.len() {
        0 => "()".to_string(),
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut dict = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}",
        dtype.descr(),
        shape_text
    );
    // magic (6) + version (2) + length (2) + dict + padding + '\n' is a multiple of 64.
    let unpadded = 10 + dict.len() + 1;
    let padding = (64 - unpadded % 64) % 64;
    dict.push_str(&" ".repeat(padding));
    dict.push('\n');
    let mut header = Vec::with_capacity(10 + dict.len());
    header.extend_from_slice(b"\x93NUMPY");
    header.extend_from_slice(&[1, 0]);
    header.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    header.extend_from_slice(dict.as_bytes());
    header
}

/// An f32 array as a complete `.npy` file. `data.len()` must equal the product of `shape`.
pub fn npy_f32(shape: &[usize], data: &[f32]) -> Result<Vec<u8>, String> {
    let expected: usize = shape.iter().product();
    if data.len() != expected {
        return Err(format!(
            "array has {} values but shape {shape:?} needs {expected}",
            data.len()
        ));
    }
    let mut bytes = npy_header(NpyDtype::F32, shape);
    bytes.reserve(data.len() * 4);
    for value in data {
        bytes.extend_from_slice(&value.to_le_bytes());
    }
    Ok(bytes)
}

/// Parses a version-1.0 `.npy` f32 file back: (shape, data). For tests and tools.
pub fn read_npy_f32(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f32>), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy file (bad magic)".into());
    }
    if bytes[6] != 1 {
        return Err(format!(
            "unsupported .npy version {}.{}",
            bytes[6], bytes[7]
        ));
    }
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(bytes.get(10..10 + header_len).ok_or("truncated header")?)
        .map_err(|_| "header is not text")?;
    if !header.contains("'descr': '<f4'") || !header.contains("'fortran_order': False") {
        return Err(format!("not a C-order float32 array: {}", header.trim()));
    }
    let shape_text = header
        .split("'shape': (")
        .nth(1)
        .and_then(|rest| rest.split(')').next())
        .ok_or("header has no shape")?;
    let shape: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| t.parse().map_err(|_| format!("bad dimension '{t}'")))
        .collect::<Result<_, _>>()?;
    let data_bytes = &bytes[10 + header_len..];
    let count: usize = shape.iter().product();
    if data_bytes.len() != count * 4 {
        return Err(format!(
            "data has {} bytes, shape {shape:?} needs {}",
            data_bytes.len(),
            count * 4
        ));
    }
    let data = data_bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((shape, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_follows_the_specification() {
        let header = npy_header(NpyDtype::F32, &[4, 96, 96]);
        assert_eq!(&header[..8], b"\x93NUMPY\x01\x00");
        assert_eq!(header.len() % 64, 0, "data starts 64-byte aligned");
        let len = u16::from_le_bytes([header[8], header[9]]) as usize;
        assert_eq!(len + 10, header.len());
        let dict = std::str::from_utf8(&header[10..]).unwrap();
        assert!(
            dict.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 96, 96), }")
        );
        assert!(dict.ends_with('\n'));
        // One-dimensional shapes need the trailing comma of a Python 1-tuple.
        assert!(
            String::from_utf8_lossy(&npy_header(NpyDtype::U8, &[7])).contains("'shape': (7,), ")
        );
    }

    #[test]
    fn round_trip_and_bad_input() {
        let data: Vec<f32> = (0..24).map(|k| k as f32 * 0.5 - 3.0).collect();
        let bytes = npy_f32(&[2, 3, 4], &data).unwrap();
        assert_eq!(read_npy_f32(&bytes).unwrap(), (vec![2, 3, 4], data.clone()));
        assert!(
            npy_f32(&[5, 5], &data)
                .unwrap_err()
                .contains("shape [5, 5] needs 25")
        );
        assert!(
            read_npy_f32(&bytes[..bytes.len() - 1])
                .unwrap_err()
                .contains("needs 96")
        );
        assert!(
            read_npy_f32(b"not numpy at all")
                .unwrap_err()
                .contains("bad magic")
        );
    }
}

#[cfg(test)]
mod numpy_interop {
    use super::*;

    /// numpy.load reads what we write: dtype, shape and values. Uses python3's numpy when present
    /// and skips with a message otherwise, so the Rust tests do not depend on it.
    #[test]
    fn numpy_loads_our_files() {
        let has_numpy = std::process::Command::new("python3")
            .args(["-c", "import numpy"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false);
        if !has_numpy {
            eprintln!("skipped: python3 with numpy is not available");
            return;
        }
        let dir = std::env::temp_dir().join(format!("bevworld-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.npy");
        let data: Vec<f32> = (0..2 * 3 * 5).map(|k| k as f32 * 0.25 - 1.0).collect();
        std::fs::write(&path, npy_f32(&[2, 3, 5], &data).unwrap()).unwrap();
        let script = format!(
            "import numpy as np; a = np.load(r'{}'); assert a.dtype == np.float32, a.dtype; assert a.shape == (2, 3, 5), a.shape; \
             assert float(a[1, 2, 4]) == {}, a[1, 2, 4]; print('ok')",
            path.display(),
            data[29]
        );
        let output = std::process::Command::new("python3")
            .args(["-c", &script])
            .output()
            .unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        assert_eq!(String::from_utf8_lossy(&output.stdout).trim(), "ok");
    }
}
