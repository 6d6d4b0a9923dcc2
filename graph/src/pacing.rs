//! Source pacing: as fast as possible, at recorded timestamps times a speed factor, or at a fixed
//! rate. Deadlines are absolute, so a slow item does not push every later one back.

use std::time::{Duration, Instant};

use crate::schema::PacingDecl;

/// A pacing declaration that cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum PacingError {
    #[error("pacing takes either speed or rate_hz, not both")]
    Both,
    #[error(
        "pacing speed must be 0 (as fast as possible) or from {MIN_SPEED} to {MAX_SPEED}, got {0}"
    )]
    Speed(f64),
    #[error("pacing rate_hz must be from {MIN_RATE_HZ} to {MAX_RATE_HZ}, got {0}")]
    Rate(f64),
}

/// The slowest and fastest fixed rates, so that every deadline is a time the clock can hold.
pub const MIN_RATE_HZ: f64 = 1e-6;
pub const MAX_RATE_HZ: f64 = 1e9;
/// The slowest and fastest replay speeds.
pub const MIN_SPEED: f64 = 1e-6;
pub const MAX_SPEED: f64 = 1e6;

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pacing {
    /// As fast as downstream takes items.
    Unpaced,
    /// Item k is released at `start + (tov_k - tov_0) / speed`.
    Recorded { speed: f64 },
    /// Item k is released at `start + k / rate_hz`.
    Fixed { rate_hz: f64 },
}

impl Pacing {
    pub fn from_decl(decl: &PacingDecl) -> Result<Self, PacingError> {
        match (decl.speed, decl.rate_hz) {
            (Some(_), Some(_)) => Err(PacingError::Both),
            (Some(0.0), None) => Ok(Self::Unpaced),
            (Some(speed), None) if !(MIN_SPEED..=MAX_SPEED).contains(&speed) => {
                Err(PacingError::Speed(speed))
            }
            (Some(speed), None) => Ok(Self::Recorded { speed }),
            (None, Some(rate)) if !(MIN_RATE_HZ..=MAX_RATE_HZ).contains(&rate) => {
                Err(PacingError::Rate(rate))
            }
            (None, Some(rate_hz)) => Ok(Self::Fixed { rate_hz }),
            (None, None) => Ok(Self::Unpaced),
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Self::Unpaced => "as fast as possible".into(),
            Self::Recorded { speed } => format!("recorded timestamps x {speed}"),
            Self::Fixed { rate_hz } => format!("{rate_hz} Hz"),
        }
    }
}

/// Tracks one source's release schedule.
#[derive(Debug)]
pub struct Pacer {
    pacing: Pacing,
    start: Option<(Instant, i64)>,
    released: u64,
}

impl Pacer {
    pub fn new(pacing: Pacing) -> Self {
        Self {
            pacing,
            start: None,
            released: 0,
        }
    }

    /// When the item with this time of validity may be released; `None` means now.
    pub fn deadline(&mut self, time_of_validity_us: i64, now: Instant) -> Option<Instant> {
        let (start, first_tov) = *self.start.get_or_insert((now, time_of_validity_us));
        let index = self.released;
        self.released += 1;
        match self.pacing {
            Pacing::Unpaced => None,
            Pacing::Recorded { speed } => {
                let elapsed_us = (time_of_validity_us - first_tov).max(0) as f64 / speed;
                Some(start + Duration::from_secs_f64(elapsed_us / 1e6))
            }
            Pacing::Fixed { rate_hz } => {
                Some(start + Duration::from_secs_f64(index as f64 / rate_hz))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_rate_deadlines_are_absolute() {
        let mut pacer = Pacer::new(Pacing::Fixed { rate_hz: 12.0 });
        let t0 = Instant::now();
        assert_eq!(pacer.deadline(0, t0), Some(t0));
        // Whatever the item's own timestamp, the 13th item is due one second in.
        for k in 1..12 {
            pacer.deadline(k * 999, t0);
        }
        assert_eq!(
            pacer.deadline(5, t0 + Duration::from_millis(500)),
            Some(t0 + Duration::from_secs(1))
        );
    }

    #[test]
    fn recorded_pacing_scales_by_speed() {
        let mut pacer = Pacer::new(Pacing::Recorded { speed: 2.0 });
        let t0 = Instant::now();
        pacer.deadline(1_000_000, t0);
        let due = pacer.deadline(3_000_000, t0).unwrap();
        assert_eq!(due - t0, Duration::from_secs(1));
    }

    #[test]
    fn bad_pacing_is_rejected() {
        assert!(
            Pacing::from_decl(&PacingDecl {
                speed: Some(-1.0),
                rate_hz: None
            })
            .is_err()
        );
        assert!(
            Pacing::from_decl(&PacingDecl {
                speed: None,
                rate_hz: Some(0.0)
            })
            .is_err()
        );
        assert!(
            Pacing::from_decl(&PacingDecl {
                speed: Some(1.0),
                rate_hz: Some(1.0)
            })
            .is_err()
        );
        assert_eq!(
            Pacing::from_decl(&PacingDecl {
                speed: Some(0.0),
                rate_hz: None
            }),
            Ok(Pacing::Unpaced)
        );
    }
}
