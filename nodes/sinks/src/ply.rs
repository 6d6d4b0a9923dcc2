//! PLY point clouds with fields `x y z intensity` (float32), binary little-endian by default or
//! ASCII. Open3D, CloudCompare and MeshLab read both.

use std::io::{BufReader, Read};
use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding, Ply, PropertyAccess, PropertyAccessResult, PropertyDef,
    PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;
use serde::{Deserialize, Serialize};
use thiserror::Error;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlyEncoding {
    #[default]
    BinaryLittleEndian,
    Ascii,
}

#[derive(Debug, Error)]
pub enum PlyError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: not a valid PLY file: {message}")]
    Format { path: String, message: String },
    #[error("{path}: PLY has no '{field}' property on its vertex element")]
    MissingField { path: String, field: &'static str },
}

/// One vertex: position and intensity.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlyPoint {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    pub intensity: f32,
    seen: u8,
}

impl PlyPoint {
    pub fn new(x: f32, y: f32, z: f32, intensity: f32) -> Self {
        Self {
            x,
            y,
            z,
            intensity,
            seen: 0,
        }
    }

    fn set(&mut self, name: &str, value: f32) -> PropertyAccessResult {
        let (slot, bit) = match name {
            "x" => (&mut self.x, 1),
            "y" => (&mut self.y, 2),
            "z" => (&mut self.z, 4),
            "intensity" | "scalar_intensity" | "reflectance" => (&mut self.intensity, 8),
            _ => return PropertyAccessResult::Ignored,
        };
        *slot = value;
        self.seen |= bit;
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for PlyPoint {
    fn new() -> Self {
        Self::default()
    }

    fn set_float(&mut self, name: &str, value: f32) -> PropertyAccessResult {
        self.set(name, value)
    }

    fn set_double(&mut self, name: &str, value: f64) -> PropertyAccessResult {
        self.set(name, value as f32)
    }

    fn set_uchar(&mut self, name: &str, value: u8) -> PropertyAccessResult {
        self.set(name, f32::from(value))
    }

    fn set_ushort(&mut self, name: &str, value: u16) -> PropertyAccessResult {
        self.set(name, f32::from(value))
    }

    fn get_float(&self, name: &str) -> Option<f32> {
        match name {
            "x" => Some(self.x),
            "y" => Some(self.y),
            "z" => Some(self.z),
            "intensity" => Some(self.intensity),
            _ => None,
        }
    }
}

/// Encodes points as a PLY file.
pub fn encode_ply(
    points: &[PlyPoint],
    encoding: PlyEncoding,
    comment: Option<&str>,
) -> Result<Vec<u8>, PlyError> {
    let mut ply = Ply::<PlyPoint>::new();
    ply.header.encoding = match encoding {
        PlyEncoding::BinaryLittleEndian => Encoding::BinaryLittleEndian,
        PlyEncoding::Ascii => Encoding::Ascii,
    };
    if let Some(comment) = comment {
        // A header comment is one line: a token or scene name holding a line break (they come
        // from datasets) must not end the header early or make the file unwritable.
        let one_line: String = comment
            .chars()
            .map(|c| if c.is_control() { ' ' } else { c })
            .collect();
        ply.header.comments.push(one_line);
    }
    let mut vertex = ElementDef::new("vertex".to_string());
    for name in ["x", "y", "z", "intensity"] {
        vertex.properties.add(PropertyDef::new(
            name.to_string(),
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    ply.header.elements.add(vertex);
    ply.payload.insert("vertex".to_string(), points.to_vec());
    let mut bytes = Vec::with_capacity(points.len() * 16 + 256);
    Writer::new()
        .write_ply(&mut bytes, &mut ply)
        .map_err(|error| PlyError::Format {
            path: "<memory>".into(),
            message: error.to_string(),
        })?;
    Ok(bytes)
}

/// Reads the vertices of a PLY file; `x`, `y`, `z` are required, intensity defaults to 0.
pub fn read_ply(path: &Path) -> Result<Vec<PlyPoint>, PlyError> {
    let name = path.display().to_string();
    let file = std::fs::File::open(path).map_err(|source| PlyError::Io {
        path: name.clone(),
        source,
    })?;
    decode_ply(BufReader::new(file), &name)
}

pub fn decode_ply(mut reader: impl Read, name: &str) -> Result<Vec<PlyPoint>, PlyError> {
    let ply = Parser::<PlyPoint>::new()
        .read_ply(&mut reader)
        .map_err(|error| PlyError::Format {
            path: name.to_string(),
            message: error.to_string(),
        })?;
    let vertex_def = ply
        .header
        .elements
        .get("vertex")
        .ok_or_else(|| PlyError::Format {
            path: name.to_string(),
            message: "no 'vertex' element".into(),
        })?;
    for field in ["x", "y", "z"] {
        if !vertex_def.properties.contains_key(field) {
            return Err(PlyError::MissingField {
                path: name.to_string(),
                field,
            });
        }
    }
    Ok(ply.payload.get("vertex").cloned().unwrap_or_default())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_and_ascii_round_trip() {
        let points = vec![
            PlyPoint::new(1.5, -2.0, 0.25, 7.0),
            PlyPoint::new(0.0, 3.0, -1.0, 0.5),
        ];
        for encoding in [PlyEncoding::BinaryLittleEndian, PlyEncoding::Ascii] {
            let bytes = encode_ply(&points, encoding, Some("test")).unwrap();
            let header = String::from_utf8_lossy(&bytes[..bytes.len().min(200)]).to_string();
            assert!(header.starts_with("ply\n"));
            assert!(header.contains("element vertex 2"));
            assert!(header.contains("property float intensity"));
            let back = decode_ply(&bytes[..], "mem").unwrap();
            let xyz: Vec<_> = back.iter().map(|p| (p.x, p.y, p.z, p.intensity)).collect();
            assert_eq!(xyz, vec![(1.5, -2.0, 0.25, 7.0), (0.0, 3.0, -1.0, 0.5)]);
        }
        let binary = encode_ply(&points, PlyEncoding::BinaryLittleEndian, None).unwrap();
        assert!(String::from_utf8_lossy(&binary).contains("format binary_little_endian 1.0"));
    }

    #[test]
    fn garbage_and_missing_fields_are_errors() {
        assert!(matches!(
            decode_ply(&b"not a ply"[..], "bad.ply"),
            Err(PlyError::Format { .. })
        ));
        let no_z = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
        let error = decode_ply(&no_z[..], "noz.ply").unwrap_err();
        assert!(error.to_string().contains("'z'"), "{error}");
    }
}
