//! The results page's figures: a box plot per summary variable, by compensator and seat,
//! titled and scaled for what it shows, and the learning curve.

use sqlx::AnyPool;

use super::learning::learning_curve;
use super::plots::{Group, box_plot_svg, learning_curve_svg, png};
use super::stats::group_values;
use super::study_data::SUMMARY_VARIABLES;
use crate::error::{AppError, Result};
use crate::store;

/// A figure's file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Svg,
    Png,
}

impl Format {
    pub fn mime(self) -> &'static str {
        match self {
            Self::Svg => "image/svg+xml",
            Self::Png => "image/png",
        }
    }
}

/// A figure of the results page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plot {
    /// The box plot of a summary variable (index in `SUMMARY_VARIABLES`).
    Box(usize),
    /// Tracking error against test position (`learning_curve`).
    LearningCurve,
}

/// The learning curve's file name, without the extension.
pub const LEARNING_CURVE: &str = "learning_curve";

/// Parses a plot file name `name.svg|png`, the name a summary variable or `learning_curve`.
pub fn parse_file(file: &str) -> Result<(Plot, Format)> {
    let (name, ext) = file
        .rsplit_once('.')
        .ok_or_else(|| AppError::BadRequest("plot: name.svg or name.png".into()))?;
    let plot = if name == LEARNING_CURVE {
        Plot::LearningCurve
    } else {
        Plot::Box(
            SUMMARY_VARIABLES
                .iter()
                .position(|v| *v == name)
                .ok_or_else(|| {
                    AppError::BadRequest(format!(
                        "plot: unknown plot {name:?}; valid: {}, {LEARNING_CURVE}",
                        SUMMARY_VARIABLES.join(", ")
                    ))
                })?,
        )
    };
    let format = match ext {
        "svg" => Format::Svg,
        "png" => Format::Png,
        _ => return Err(AppError::BadRequest("plot: .svg or .png".into())),
    };
    Ok((plot, format))
}

/// Title, axis label and fixed range (ratings) of each summary variable.
fn labels(index: usize, scale_points: u8) -> (&'static str, &'static str, Option<(f64, f64)>) {
    let ratings = Some((0.5, f64::from(scale_points) + 0.5));
    let higher = "rating (higher is better)";
    match SUMMARY_VARIABLES[index] {
        "mse_tracking_mm2" => ("Tracking error (mean square)", "MSE (mm²)", None),
        "ms_cab_accel" => (
            "Cab acceleration (mean square)",
            "mean-square acceleration ((mm/s²)²)",
            None,
        ),
        "rating_accuracy" => ("Rating: accuracy", higher, ratings),
        "rating_speed" => ("Rating: speed of response", higher, ratings),
        "rating_smoothness" => ("Rating: smoothness", higher, ratings),
        _ => ("Rating: overall controllability", higher, ratings),
    }
}

/// A figure of a study in `format`.
pub async fn plot(pool: &AnyPool, study_id: i64, plot: Plot, format: Format) -> Result<Vec<u8>> {
    let svg = match plot {
        Plot::Box(index) => box_plot(pool, study_id, index).await?,
        Plot::LearningCurve => {
            let study = store::studies::get(pool, study_id).await?;
            let curve = learning_curve(pool, study_id).await?;
            learning_curve_svg(
                &format!(
                    "Learning curve: tracking error by test position — study {}",
                    study.name
                ),
                &curve,
            )
        }
    };
    Ok(match format {
        Format::Svg => svg.into_bytes(),
        Format::Png => tokio::task::spawn_blocking(move || png(&svg))
            .await
            .map_err(anyhow::Error::from)??,
    })
}

/// The box plot of summary variable `index` for a study, as SVG.
async fn box_plot(pool: &AnyPool, study_id: i64, index: usize) -> Result<String> {
    let study = store::studies::get(pool, study_id).await?;
    let groups: Vec<Group> = group_values(pool, study_id)
        .await?
        .into_iter()
        .map(|((c, seat), vals)| (c, seat, vals.iter().filter_map(|v| v[index]).collect()))
        .collect();
    let compensators: Vec<String> = study
        .params
        .compensators
        .iter()
        .map(|c| c.kind().name().to_string())
        .collect();
    let (title, unit, range) = labels(index, study.params.survey.scale_points);
    Ok(box_plot_svg(
        &format!("{title} — study {}", study.name),
        unit,
        &compensators,
        &groups,
        range,
    ))
}
