//! `RUN/curves.png`: a run's curves from its `metrics.csv`, read by column name, one panel per
//! curve (`bevworld_plot`).

use std::path::Path;

use bevworld_plot::{Panel, PlotError, Series, panels_png};

use crate::metrics_log::{MetricsLogError, read_series};

/// One panel: column `column` of the rows of phase `phase`.
#[derive(Clone, Copy, Debug)]
pub struct Curve {
    pub title: &'static str,
    pub phase: &'static str,
    pub column: &'static str,
    pub log_scale: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum CurvesError {
    #[error(transparent)]
    Log(#[from] MetricsLogError),
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// Draws the curves of the log at `csv` into `png`, side by side.
pub fn plot_curves(csv: &Path, png: &Path, curves: &[Curve]) -> Result<(), CurvesError> {
    let series: Vec<Vec<(f64, f64)>> = curves
        .iter()
        .map(|c| read_series(csv, c.phase, c.column))
        .collect::<Result<_, _>>()?;
    let panels: Vec<Panel> = curves
        .iter()
        .zip(&series)
        .map(|(curve, points)| Panel {
            title: curve.title,
            x_label: "step",
            log_y: curve.log_scale,
            series: vec![Series {
                label: curve.column,
                points,
            }],
        })
        .collect();
    Ok(panels_png(png, &panels)?)
}
