//! Binary LiDAR files: nuScenes `.pcd.bin` (float32 x 5: x, y, z, intensity, ring) and KITTI
//! `.bin` (float32 x 4: x, y, z, reflectance). Little-endian, no header.

use std::path::Path;

use bevworld_types::LidarPoint;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SensorError};

/// What to do with a point whose coordinates are NaN or infinite.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NonFinitePolicy {
    /// Drop the point and count it (the default).
    #[default]
    Drop,
    /// Reject the whole sweep.
    Error,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LidarLayout {
    /// nuScenes: x, y, z, intensity, ring.
    NuScenes,
    /// KITTI: x, y, z, reflectance.
    Kitti,
}

impl LidarLayout {
    pub fn floats_per_point(self) -> usize {
        match self {
            LidarLayout::NuScenes => 5,
            LidarLayout::Kitti => 4,
        }
    }
}

/// Decodes a sweep's bytes; `path` names the file in errors. Returns the points and how many
/// non-finite points were dropped.
pub fn decode_points(
    bytes: &[u8],
    layout: LidarLayout,
    policy: NonFinitePolicy,
    path: &Path,
) -> Result<(Vec<LidarPoint>, usize)> {
    let stride = layout.floats_per_point() * 4;
    // A Velodyne scan always holds returns: an empty file is a failed copy or a crashed
    // writer, and read as a frame it would score as a scene with nothing in it.
    if bytes.is_empty() && layout == LidarLayout::Kitti {
        return Err(SensorError::file(
            path,
            "empty scan: 0 bytes (a KITTI scan holds at least one float32 x 4 point)",
        ));
    }
    if !bytes.len().is_multiple_of(stride) {
        return Err(SensorError::file(
            path,
            format!(
                "truncated point file: {} bytes is not a multiple of {stride} ({} float32 per point); {} trailing bytes",
                bytes.len(),
                layout.floats_per_point(),
                bytes.len() % stride
            ),
        ));
    }
    let mut points = Vec::with_capacity(bytes.len() / stride);
    let mut dropped = 0usize;
    for (index, record) in bytes.chunks_exact(stride).enumerate() {
        let f = |k: usize| {
            f32::from_le_bytes([
                record[4 * k],
                record[4 * k + 1],
                record[4 * k + 2],
                record[4 * k + 3],
            ])
        };
        let (x, y, z, intensity) = (f(0), f(1), f(2), f(3));
        let ring = match layout {
            LidarLayout::NuScenes => {
                let ring = f(4);
                if ring.is_finite() && ring >= 0.0 {
                    ring as u16
                } else {
                    0
                }
            }
            LidarLayout::Kitti => 0,
        };
        if !(x.is_finite() && y.is_finite() && z.is_finite() && intensity.is_finite()) {
            match policy {
                NonFinitePolicy::Drop => {
                    dropped += 1;
                    continue;
                }
                NonFinitePolicy::Error => {
                    return Err(SensorError::file(
                        path,
                        format!(
                            "point {index} has a non-finite value ({x}, {y}, {z}, {intensity})"
                        ),
                    ));
                }
            }
        }
        points.push(LidarPoint {
            x,
            y,
            z,
            intensity,
            ring,
        });
    }
    Ok((points, dropped))
}

/// Encodes points in a layout; used by the synthetic world's writer and tests.
pub fn encode_points(points: &[LidarPoint], layout: LidarLayout) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(points.len() * layout.floats_per_point() * 4);
    for p in points {
        for value in [p.x, p.y, p.z, p.intensity] {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
        if layout == LidarLayout::NuScenes {
            bytes.extend_from_slice(&f32::from(p.ring).to_le_bytes());
        }
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_truncation() {
        let points = vec![
            LidarPoint {
                x: 1.0,
                y: -2.0,
                z: 0.5,
                intensity: 7.0,
                ring: 3,
            },
            LidarPoint {
                x: 4.0,
                y: 5.0,
                z: 6.0,
                intensity: 0.0,
                ring: 31,
            },
        ];
        let bytes = encode_points(&points, LidarLayout::NuScenes);
        assert_eq!(bytes.len(), 40);
        let (back, dropped) = decode_points(
            &bytes,
            LidarLayout::NuScenes,
            NonFinitePolicy::Drop,
            Path::new("a.pcd.bin"),
        )
        .unwrap();
        assert_eq!((back, dropped), (points, 0));
        let error = decode_points(
            &bytes[..39],
            LidarLayout::NuScenes,
            NonFinitePolicy::Drop,
            Path::new("a.pcd.bin"),
        )
        .unwrap_err();
        let text = error.to_string();
        assert!(
            text.contains("a.pcd.bin")
                && text.contains("truncated")
                && text.contains("19 trailing"),
            "{text}"
        );
    }

    #[test]
    fn non_finite_points_are_dropped_or_rejected() {
        let points = vec![
            LidarPoint {
                x: f32::NAN,
                y: 0.0,
                z: 0.0,
                intensity: 1.0,
                ring: 0,
            },
            LidarPoint {
                x: 1.0,
                y: f32::INFINITY,
                z: 0.0,
                intensity: 1.0,
                ring: 0,
            },
            LidarPoint {
                x: 1.0,
                y: 2.0,
                z: 3.0,
                intensity: 1.0,
                ring: 0,
            },
        ];
        let bytes = encode_points(&points, LidarLayout::Kitti);
        let (kept, dropped) = decode_points(
            &bytes,
            LidarLayout::Kitti,
            NonFinitePolicy::Drop,
            Path::new("k.bin"),
        )
        .unwrap();
        assert_eq!((kept.len(), dropped), (1, 2));
        let error = decode_points(
            &bytes,
            LidarLayout::Kitti,
            NonFinitePolicy::Error,
            Path::new("k.bin"),
        )
        .unwrap_err();
        assert!(error.to_string().contains("point 0 has a non-finite value"));
    }
}
