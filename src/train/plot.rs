//! Learning curves as a PNG, drawn without text so no font is needed: top panel the training
//! (blue) and validation (red) loss, bottom panel the validation closure share (green) and
//! openness r (black), both on [0, 1]. The CSV beside it has the numbers.

use std::path::Path;

use plotters::prelude::*;

use crate::train::trainer::EpochStats;

type Series = Vec<(Vec<(f64, f64)>, RGBColor)>;

#[derive(Debug, thiserror::Error)]
#[error("cannot draw the learning curves: {0}")]
pub struct PlotError(String);

fn err(e: impl std::fmt::Display) -> PlotError {
    PlotError(e.to_string())
}

pub fn learning_curves(path: &Path, curve: &[EpochStats]) -> Result<(), PlotError> {
    if curve.is_empty() {
        return Err(PlotError("no epochs".into()));
    }
    let root = BitMapBackend::new(path, (800, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let (top, bottom) = root.split_vertically(300);
    let epochs = curve.len() as f64;
    let max_loss = curve
        .iter()
        .flat_map(|e| [e.train_loss, e.validation_loss])
        .filter(|v| v.is_finite())
        .fold(1e-6, f64::max);
    let panels: [(_, f64, Series); 2] = [
        (
            top,
            max_loss * 1.05,
            vec![
                (points(curve, |e| e.train_loss), BLUE),
                (points(curve, |e| e.validation_loss), RED),
            ],
        ),
        (
            bottom,
            1.0,
            vec![
                (points(curve, |e| e.validation_closure_share), GREEN),
                (points(curve, |e| e.validation_openness_r), BLACK),
            ],
        ),
    ];
    for (area, y_max, series) in panels {
        let area = area.margin(10, 10, 10, 10);
        let mut chart = ChartBuilder::on(&area)
            .build_cartesian_2d(1.0..epochs.max(2.0), 0.0..y_max)
            .map_err(err)?;
        // Grid lines only: ticks every tenth of the range, no labels.
        chart
            .configure_mesh()
            .x_labels(10)
            .y_labels(10)
            .x_label_formatter(&|_| String::new())
            .y_label_formatter(&|_| String::new())
            .disable_x_axis()
            .disable_y_axis()
            .draw()
            .map_err(err)?;
        area.draw(&Rectangle::new(
            [
                (0, 0),
                (
                    area.dim_in_pixel().0 as i32 - 1,
                    area.dim_in_pixel().1 as i32 - 1,
                ),
            ],
            BLACK.stroke_width(1),
        ))
        .map_err(err)?;
        for (data, colour) in series {
            chart
                .draw_series(LineSeries::new(data, colour.stroke_width(2)))
                .map_err(err)?;
        }
    }
    root.present().map_err(err)
}

fn points(curve: &[EpochStats], f: impl Fn(&EpochStats) -> f64) -> Vec<(f64, f64)> {
    curve
        .iter()
        .map(|e| (e.epoch as f64, f(e)))
        .filter(|(_, y)| y.is_finite())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plots_a_png() {
        let curve: Vec<EpochStats> = (1..=20)
            .map(|epoch| EpochStats {
                epoch,
                train_loss: 1.0 / epoch as f64,
                validation_loss: 1.2 / epoch as f64,
                validation_closure_share: 0.5,
                validation_openness_r: 0.7,
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("curves.png");
        learning_curves(&path, &curve).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(learning_curves(&path, &[]).is_err());
    }
}
