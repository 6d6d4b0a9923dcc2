//! The timestamp aligner: groups messages from several inputs whose times of validity agree
//! within a tolerance. Cameras and LiDAR are not triggered together, so exact equality is too
//! strict for real sensors.
//!
//! Each input's stream is assumed to be in time order. A group is emitted when every input's
//! oldest message lies within `tolerance` of the newest of them. A message older than
//! `newest - tolerance` can never be matched (its partners have passed), so it is discarded
//! and counted.

use std::collections::VecDeque;

use crate::message::Message;

pub struct Aligner {
    queues: Vec<VecDeque<Message>>,
    /// Ports with an edge: an optional input left unconnected never holds a group back.
    connected: Vec<bool>,
    tolerance_us: i64,
    unmatched: u64,
}

impl Aligner {
    pub fn new(inputs: usize, tolerance_us: i64) -> Self {
        Self {
            queues: (0..inputs).map(|_| VecDeque::new()).collect(),
            connected: vec![true; inputs],
            tolerance_us: tolerance_us.max(0),
            unmatched: 0,
        }
    }

    /// An aligner over the ports in `connected` only, of `inputs`; groups hold `None` for the
    /// others.
    pub fn over(inputs: usize, connected: &[usize], tolerance_us: i64) -> Self {
        let mut aligner = Self::new(inputs, tolerance_us);
        aligner.connected = (0..inputs).map(|p| connected.contains(&p)).collect();
        aligner
    }

    pub fn push(&mut self, port: usize, message: Message) {
        if let Some(queue) = self.queues.get_mut(port) {
            queue.push_back(message);
        }
    }

    /// Takes the next complete group, if there is one.
    pub fn pop_group(&mut self) -> Option<Vec<Option<Message>>> {
        loop {
            let mut newest = i64::MIN;
            let active = || {
                self.queues
                    .iter()
                    .zip(&self.connected)
                    .filter(|(_, c)| **c)
                    .map(|(q, _)| q)
            };
            for queue in active() {
                let head = queue.front()?;
                newest = newest.max(head.header().time_of_validity_us);
            }
            let mut discarded = false;
            for queue in &mut self.queues {
                while queue
                    .front()
                    .is_some_and(|m| m.header().time_of_validity_us < newest - self.tolerance_us)
                {
                    queue.pop_front();
                    self.unmatched += 1;
                    discarded = true;
                }
            }
            if !discarded {
                return Some(self.queues.iter_mut().map(|q| q.pop_front()).collect());
            }
        }
    }

    /// Messages still waiting when the inputs closed are unmatched: count and release them.
    pub fn close(&mut self) {
        for queue in &mut self.queues {
            self.unmatched += queue.len() as u64;
            queue.clear();
        }
    }

    pub fn unmatched(&self) -> u64 {
        self.unmatched
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::message::Header;
    use crate::message::Instant;

    fn at(tov: i64) -> Message {
        Message::new(
            Header {
                seq: 0,
                time_of_validity_us: tov,
                entered_graph: Instant::now(),
            },
            tov,
        )
    }

    fn tovs(group: &[Option<Message>]) -> Vec<i64> {
        group
            .iter()
            .map(|m| *m.as_ref().unwrap().get::<i64>().unwrap())
            .collect()
    }

    #[test]
    fn pairs_within_tolerance_and_drops_stragglers() {
        let mut aligner = Aligner::new(2, 10_000);
        // Camera at 0, 83_333, 166_666; LiDAR at 5_000, 170_000 (one sweep missing).
        for t in [0, 83_333, 166_666] {
            aligner.push(0, at(t));
        }
        for t in [5_000, 170_000] {
            aligner.push(1, at(t));
        }
        assert_eq!(tovs(&aligner.pop_group().unwrap()), vec![0, 5_000]);
        assert_eq!(tovs(&aligner.pop_group().unwrap()), vec![166_666, 170_000]);
        assert_eq!(aligner.unmatched(), 1); // the camera frame at 83_333
        assert!(aligner.pop_group().is_none());
    }

    #[test]
    fn an_unconnected_port_does_not_hold_groups_back() {
        let mut aligner = Aligner::over(3, &[0, 2], 0);
        aligner.push(0, at(5));
        assert!(aligner.pop_group().is_none());
        aligner.push(2, at(5));
        let group = aligner.pop_group().unwrap();
        assert!(group[1].is_none());
        assert_eq!(*group[2].as_ref().unwrap().get::<i64>().unwrap(), 5);
    }

    #[test]
    fn exact_alignment_waits_for_all_inputs() {
        let mut aligner = Aligner::new(2, 0);
        aligner.push(0, at(7));
        assert!(aligner.pop_group().is_none());
        aligner.push(1, at(7));
        assert_eq!(tovs(&aligner.pop_group().unwrap()), vec![7, 7]);
        aligner.push(1, at(8));
        aligner.close();
        assert_eq!(aligner.unmatched(), 1);
    }
}
