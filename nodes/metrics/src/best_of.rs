//! The best of K draws: how close the world model's samples come when a user may pick among
//! them, beside the one point forecast.
//!
//! Trajectory forecasting scores a multi-modal forecast by its best mode (minADE over K); a
//! sampled world model is scored the same way here. For each (context, horizon) the K draws of
//! the model are scored one by one against the same logged sweep, then, for each K' of
//! `best_of_counts(K)`, among the first K' draws:
//!
//! - the whole-scene Chamfer is the smallest of theirs;
//! - the agent-level sums are those of the draw that recalls most true points on moving
//!   vehicles within 1 m (ties: more within 0.5 m, then the smaller Chamfer, then the earlier
//!   draw), so that a row's agent columns all describe one draw, the one best for the agents.
//!
//! Each metric picks its own best draw: the two may differ, as minADE and minFDE may.

use crate::agents::AgentSums;
use bevworld_types::PointClass;

/// One draw of the model scored against its logged sweep.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DrawScore {
    /// Whole-scene Chamfer, m²; `None` when the ROI left a cloud empty.
    pub chamfer: Option<f64>,
    /// The agent-level sums; `None` when the dataset annotates nothing there.
    pub agents: Option<AgentSums>,
}

/// The K' the best-of rows are reported for, given K draws: 4, 8, 16, 32 below K, and K
/// itself; none for one draw, which is the point forecast's own row.
pub fn best_of_counts(draws: usize) -> Vec<usize> {
    if draws < 2 {
        return Vec::new();
    }
    let mut counts: Vec<usize> = [4, 8, 16, 32].into_iter().filter(|&k| k < draws).collect();
    counts.push(draws);
    counts
}

/// The smallest Chamfer of `draws`; `None` when none was scored.
pub fn best_chamfer(draws: &[DrawScore]) -> Option<f64> {
    draws
        .iter()
        .filter_map(|d| d.chamfer)
        .min_by(f64::total_cmp)
}

/// The agent sums of the draw best for the moving vehicles (module docs); `None` when no
/// draw was annotated.
pub fn best_for_agents(draws: &[DrawScore]) -> Option<&AgentSums> {
    let mut best: Option<(&DrawScore, &AgentSums)> = None;
    for draw in draws {
        let Some(agents) = &draw.agents else { continue };
        let better = match best {
            None => true,
            Some((held, held_agents)) => {
                let key = |a: &AgentSums| {
                    let moving = a.class(PointClass::MovingVehicle);
                    (moving.within_far, moving.within_near)
                };
                match key(agents).cmp(&key(held_agents)) {
                    std::cmp::Ordering::Greater => true,
                    std::cmp::Ordering::Less => false,
                    // Equal on the moving vehicles: the smaller Chamfer, else the earlier draw.
                    std::cmp::Ordering::Equal => matches!(
                        (draw.chamfer, held.chamfer),
                        (Some(c), Some(h)) if c < h
                    ),
                }
            }
        };
        if better {
            best = Some((draw, agents));
        }
    }
    best.map(|(_, agents)| agents)
}

#[cfg(test)]
mod tests {
    use super::{DrawScore, best_chamfer, best_for_agents, best_of_counts};
    use crate::agents::{AgentSums, ClassSums};

    fn draw(chamfer: Option<f64>, moving_far: u64, moving_near: u64) -> DrawScore {
        let mut agents = AgentSums::default();
        agents.classes[0] = ClassSums {
            points: 10,
            within_near: moving_near,
            within_far: moving_far,
            ..ClassSums::default()
        };
        DrawScore {
            chamfer,
            agents: Some(agents),
        }
    }

    #[test]
    fn the_counts_reported_are_the_powers_below_k_and_k() {
        assert!(best_of_counts(0).is_empty());
        assert!(
            best_of_counts(1).is_empty(),
            "one draw is the point forecast"
        );
        assert_eq!(best_of_counts(2), vec![2]);
        assert_eq!(best_of_counts(4), vec![4]);
        assert_eq!(best_of_counts(8), vec![4, 8]);
        assert_eq!(best_of_counts(10), vec![4, 8, 10]);
        assert_eq!(best_of_counts(64), vec![4, 8, 16, 32, 64]);
    }

    #[test]
    fn the_best_chamfer_is_the_smallest_scored_one() {
        let draws = [
            draw(Some(0.9), 0, 0),
            draw(None, 0, 0),
            draw(Some(0.7), 0, 0),
        ];
        assert_eq!(best_chamfer(&draws), Some(0.7));
        assert_eq!(best_chamfer(&draws[..2]), Some(0.9), "the first two");
        assert_eq!(
            best_chamfer(&draws[1..2]),
            None,
            "an empty cloud is no score"
        );
    }

    #[test]
    fn the_draw_best_for_the_agents_recalls_most_moving_points_then_is_closest() {
        // Draw 1 recalls 6 of 10 moving points within 1 m, draws 0 and 2 only 4.
        let draws = [
            draw(Some(0.5), 4, 1),
            draw(Some(0.9), 6, 0),
            draw(Some(0.4), 4, 3),
        ];
        let best = best_for_agents(&draws).expect("annotated");
        assert_eq!(
            best.classes[0].within_far, 6,
            "not the smallest Chamfer's draw"
        );
        // Among draws 0 and 2 (4 within 1 m each), more within 0.5 m wins.
        let pair = [draws[0].clone(), draws[2].clone()];
        let best = best_for_agents(&pair).expect("annotated");
        assert_eq!(best.classes[0].within_near, 3);
        // Equal on both: the smaller Chamfer; equal on everything: the earlier draw.
        let tied = [draw(Some(0.8), 4, 1), draw(Some(0.6), 4, 1)];
        assert_eq!(best_for_agents(&tied), tied[1].agents.as_ref());
        let same = [draw(Some(0.8), 4, 1), draw(Some(0.8), 4, 1)];
        assert!(std::ptr::eq(
            best_for_agents(&same).expect("annotated"),
            same[0].agents.as_ref().expect("annotated")
        ));
        let unannotated = [DrawScore {
            chamfer: Some(0.1),
            agents: None,
        }];
        assert_eq!(best_for_agents(&unannotated), None);
    }
}
