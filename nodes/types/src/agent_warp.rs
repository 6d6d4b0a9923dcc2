//! Moving the other road users in a BEV latent, as the ego warp moves the static world: each
//! agent's cells are carried rigidly from its footprint now to its footprint at a future time,
//! and the cells it leaves take the mean of the ground around it. Where the agents' futures come
//! from is the caller's: the dataset's true boxes give the bound of what moving agents as rigid
//! latent patches can reach (`latent_box_warp`); a motion head's trajectories give a forecast.

use crate::bev_warp::{LatentGrid, PlanarMotion, taps_at};
use crate::object_box::ObjectBox;
use crate::pose::yaw_of;

/// An agent's box seen from above, in some ego frame: x along its length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    pub centre: [f64; 2],
    /// Heading about +z, rad.
    pub yaw: f64,
    pub length: f64,
    pub width: f64,
}

impl Footprint {
    /// The footprint of a box expressed in the ego frame wanted.
    pub fn of_box(object: &ObjectBox) -> Self {
        let centre = object.center();
        let [width, length, _] = object.size;
        Self {
            centre: [centre.x, centre.y],
            yaw: yaw_of(&object.global_from_box),
            length,
            width,
        }
    }

    /// `frame_from_box`.
    fn frame_from_box(&self) -> PlanarMotion {
        PlanarMotion {
            x: self.centre[0],
            y: self.centre[1],
            yaw: self.yaw,
        }
    }

    /// Whether `point` lies within the footprint grown by `margin` metres on every side.
    pub fn contains(&self, point: [f64; 2], margin: f64) -> bool {
        Rectangle::of(self).contains(point, margin)
    }
}

/// A footprint with its rotation worked out once: `move_agents` tests every cell against
/// every agent.
struct Rectangle {
    centre: [f64; 2],
    cos: f64,
    sin: f64,
    half: [f64; 2],
    /// Half the diagonal: no point farther along x or y (plus the margin) lies inside.
    reach: f64,
}

impl Rectangle {
    fn of(footprint: &Footprint) -> Self {
        let (sin, cos) = footprint.yaw.sin_cos();
        let half = [0.5 * footprint.length, 0.5 * footprint.width];
        Self {
            centre: footprint.centre,
            cos,
            sin,
            half,
            reach: half[0].hypot(half[1]),
        }
    }

    fn contains(&self, point: [f64; 2], margin: f64) -> bool {
        let (dx, dy) = (point[0] - self.centre[0], point[1] - self.centre[1]);
        let reach = self.reach + margin;
        if dx.abs() > reach || dy.abs() > reach {
            return false;
        }
        // The point in the box's own axes (the inverse rotation).
        let x = self.cos * dx + self.sin * dy;
        let y = -self.sin * dx + self.cos * dy;
        x.abs() <= self.half[0] + margin && y.abs() <= self.half[1] + margin
    }
}

/// One agent now and at a future time, both footprints in the current ego frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AgentMotion {
    pub now: Footprint,
    pub then: Footprint,
}

impl AgentMotion {
    /// Where a point near the agent's future footprint was now: `now_from_box · box_from_then`.
    fn source_of(&self, point: [f64; 2]) -> [f64; 2] {
        let now_from_then = self
            .now
            .frame_from_box()
            .then(&self.then.frame_from_box().inverse());
        now_from_then.apply(point)
    }
}

/// The ego-warped latent of a future frame with the agents moved: each cell of the future frame
/// whose centre (in the current ego frame, `current_from_future`) lies in an agent's future
/// footprint grown by `margin_m` reads the current latent bilinearly where that point was now;
/// a cell in an agent's footprint now that no agent fills takes the mean of the cells in a ring
/// of two cells around that agent that lie in no agent's footprint (the ground it leaves
/// behind); every other cell keeps `warped`, the ego warp. An agent that stands reads the same
/// cells as the ego warp, so it is left as the warp leaves it. Where footprints overlap, the
/// agent whose future centre is nearer takes the cell.
// current, warped: [C, H, W] -> [C, H, W]
pub fn move_agents(
    current: &[f32],
    warped: &[f32],
    grid: &LatentGrid,
    current_from_future: &PlanarMotion,
    agents: &[AgentMotion],
    margin_m: f64,
) -> Vec<f32> {
    let plane = grid.height * grid.width;
    let mut out = warped.to_vec();
    if agents.is_empty() {
        return out;
    }
    let [cell_x, cell_y] = grid.cell_size();
    let ring = 2.0 * cell_x.max(cell_y);
    let centres: Vec<[f64; 2]> = (0..grid.height)
        .flat_map(|i| (0..grid.width).map(move |j| (i, j)))
        .map(|(i, j)| grid.cell_centre(i, j))
        .collect();
    let now: Vec<Rectangle> = agents.iter().map(|a| Rectangle::of(&a.now)).collect();
    let then: Vec<Rectangle> = agents.iter().map(|a| Rectangle::of(&a.then)).collect();
    // Which cells some agent stands on now: computed once, as the ring of each agent leaves
    // them out.
    let taken: Vec<bool> = centres
        .iter()
        .map(|&c| now.iter().any(|r| r.contains(c, margin_m)))
        .collect();
    // The ground each agent leaves: per channel, the mean of its ring's free cells.
    let ground: Vec<Option<Vec<f32>>> = now
        .iter()
        .map(|rectangle| {
            let ring_cells: Vec<usize> = centres
                .iter()
                .enumerate()
                .filter(|&(k, c)| !taken[k] && rectangle.contains(*c, margin_m + ring))
                .map(|(k, _)| k)
                .collect();
            (!ring_cells.is_empty()).then(|| {
                (0..grid.channels)
                    .map(|channel| {
                        let values = &current[channel * plane..(channel + 1) * plane];
                        ring_cells.iter().map(|&k| values[k]).sum::<f32>() / ring_cells.len() as f32
                    })
                    .collect()
            })
        })
        .collect();
    let distance = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    for (cell, &centre) in centres.iter().enumerate() {
        let point = current_from_future.apply(centre);
        let arriving = agents
            .iter()
            .zip(&then)
            .filter(|(_, r)| r.contains(point, margin_m))
            .map(|(a, _)| a)
            .min_by(|a, b| {
                distance(a.then.centre, point).total_cmp(&distance(b.then.centre, point))
            });
        if let Some(agent) = arriving {
            let taps = taps_at(grid, agent.source_of(point));
            let inside: f32 = taps.iter().map(|&(_, w)| w).sum();
            for channel in 0..grid.channels {
                let values = &current[channel * plane..(channel + 1) * plane];
                let sampled: f32 = taps.iter().map(|&(k, w)| w * values[k as usize]).sum();
                let at = channel * plane + cell;
                out[at] = sampled + (1.0 - inside) * warped[at];
            }
            continue;
        }
        let left = agents
            .iter()
            .zip(&now)
            .zip(&ground)
            .filter(|((_, r), _)| r.contains(point, margin_m))
            .min_by(|((a, _), _), ((b, _), _)| {
                distance(a.now.centre, point).total_cmp(&distance(b.now.centre, point))
            });
        if let Some((_, Some(ground))) = left {
            for (channel, &value) in ground.iter().enumerate() {
                out[channel * plane + cell] = value;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bev_warp::warp_latent;

    /// 1 channel, 8 × 8 cells of 1 m over [-4, 4)².
    fn grid() -> LatentGrid {
        LatentGrid {
            channels: 1,
            height: 8,
            width: 8,
            x_range: [-4.0, 4.0],
            y_range: [-4.0, 4.0],
        }
    }

    /// Row `i`, column `j` of the one channel.
    fn at(values: &[f32], i: usize, j: usize) -> f32 {
        values[i * 8 + j]
    }

    fn car(x: f64, y: f64) -> Footprint {
        Footprint {
            centre: [x, y],
            yaw: 0.0,
            length: 0.8,
            width: 0.8,
        }
    }

    /// The ground at 1, one car of value 9 in the cell of centre (−1.5, 0.5): row 4, column 2.
    fn scene() -> Vec<f32> {
        let mut values = vec![1.0; 64];
        values[4 * 8 + 2] = 9.0;
        values
    }

    #[test]
    fn a_car_driving_two_cells_forward_is_drawn_there_and_leaves_ground_behind() {
        let current = scene();
        let still = PlanarMotion::default();
        let warped = warp_latent(&current, &grid(), &still, 0.0);
        let agent = AgentMotion {
            now: car(-1.5, 0.5),
            then: car(0.5, 0.5),
        };
        let out = move_agents(&current, &warped, &grid(), &still, &[agent], 0.0);
        // The cell of centre (0.5, 0.5) (row 4, column 4) reads (−1.5, 0.5): the car.
        assert_eq!(at(&out, 4, 4), 9.0);
        // Where it was, the ring's ground (all 1).
        assert_eq!(at(&out, 4, 2), 1.0);
        // Nothing else changes: 63 cells of ground, one car.
        assert_eq!(out.iter().filter(|&&v| v == 9.0).count(), 1);
        assert_eq!(out.iter().filter(|&&v| v == 1.0).count(), 63);
    }

    #[test]
    fn a_standing_car_is_left_as_the_ego_warp_leaves_it() {
        let current = scene();
        // The ego drove 1 m forward: the world shifts one cell back.
        let ego = PlanarMotion {
            x: 1.0,
            y: 0.0,
            yaw: 0.0,
        };
        let warped = warp_latent(&current, &grid(), &ego, 0.0);
        let agent = AgentMotion {
            now: car(-1.5, 0.5),
            then: car(-1.5, 0.5),
        };
        let out = move_agents(&current, &warped, &grid(), &ego, &[agent], 0.5);
        assert_eq!(out, warped);
        // The car now sits one column further back in the future ego frame.
        assert_eq!(at(&out, 4, 1), 9.0);
    }

    #[test]
    fn the_ego_and_the_car_moving_together_keep_the_car_in_its_cell() {
        // Both drive 2 m along +x: in the future ego frame the car is where it was.
        let current = scene();
        let ego = PlanarMotion {
            x: 2.0,
            y: 0.0,
            yaw: 0.0,
        };
        let warped = warp_latent(&current, &grid(), &ego, 0.0);
        let agent = AgentMotion {
            now: car(-1.5, 0.5),
            then: car(0.5, 0.5),
        };
        let out = move_agents(&current, &warped, &grid(), &ego, &[agent], 0.0);
        assert_eq!(at(&out, 4, 2), 9.0);
        // The ego warp alone lost it two cells back, at column 0.
        assert_eq!(at(&warped, 4, 0), 9.0);
        assert_eq!(at(&out, 4, 0), 1.0);
    }

    #[test]
    fn a_turning_car_is_read_through_its_own_rotation() {
        // A car three cells long on row 4 (y = 0.5): tail 5, middle 7, nose 9 at +x. It turns
        // 90° left about its centre (0.5, 0.5): nose up (row 5), tail down (row 3).
        let mut current = vec![1.0; 64];
        current[4 * 8 + 3] = 5.0;
        current[4 * 8 + 4] = 7.0;
        current[4 * 8 + 5] = 9.0;
        let still = PlanarMotion::default();
        let warped = warp_latent(&current, &grid(), &still, 0.0);
        let long = |yaw: f64| Footprint {
            centre: [0.5, 0.5],
            yaw,
            length: 2.8,
            width: 0.8,
        };
        let agent = AgentMotion {
            now: long(0.0),
            then: long(std::f64::consts::FRAC_PI_2),
        };
        let out = move_agents(&current, &warped, &grid(), &still, &[agent], 0.0);
        assert!((at(&out, 5, 4) - 9.0).abs() < 1e-5);
        assert!((at(&out, 4, 4) - 7.0).abs() < 1e-5);
        assert!((at(&out, 3, 4) - 5.0).abs() < 1e-5);
        // The cells it swept out of are ground again.
        assert_eq!(at(&out, 4, 3), 1.0);
        assert_eq!(at(&out, 4, 5), 1.0);
    }

    #[test]
    fn footprints_hold_what_their_rotated_box_holds() {
        let footprint = Footprint {
            centre: [10.0, -2.0],
            yaw: std::f64::consts::FRAC_PI_2,
            length: 4.0,
            width: 2.0,
        };
        // Along +y lies its length.
        assert!(footprint.contains([10.0, -0.1], 0.0));
        assert!(!footprint.contains([10.0, 0.1], 0.0));
        assert!(footprint.contains([10.0, 0.1], 0.2));
        assert!(!footprint.contains([11.1, -2.0], 0.0));
    }

    #[test]
    fn no_agents_give_the_ego_warp() {
        let current = scene();
        let warped = warp_latent(&current, &grid(), &PlanarMotion::default(), 0.0);
        assert_eq!(
            move_agents(
                &current,
                &warped,
                &grid(),
                &PlanarMotion::default(),
                &[],
                1.0
            ),
            warped
        );
    }
}
