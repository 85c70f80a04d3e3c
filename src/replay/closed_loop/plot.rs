//! A closed-loop run over time, at a glance (`closed_loop.svg`): the speed, the gap to the
//! nearest actor in the vehicle's width, and the deceleration requested and reached with
//! the command behind it (SLOW amber, STOP red).

use std::path::Path;

use flyd_core::decision::Command;
use plotters::prelude::*;

use super::{ClosedLoopReport, LoopSample};

/// Why the plot could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct PlotError {
    pub path: String,
    pub message: String,
}

/// Writes `report`'s run to `path` as SVG.
pub fn write_svg(report: &ClosedLoopReport, path: &Path) -> Result<(), PlotError> {
    let err = |e: &dyn std::fmt::Display| PlotError {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let root = SVGBackend::new(path, (900, 720)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let title = format!(
        "{}: {:.0} km/h, {}",
        report.case,
        report.start_kmh,
        headline(report)
    );
    let root = root
        .titled(&title, ("sans-serif", 18))
        .map_err(|e| err(&e))?;
    let panels = root.split_evenly((3, 1));
    let s = &report.samples;
    let end = s.last().map_or(1.0, |x| x.t).max(report.seconds).max(0.1);
    let speed_max = s
        .iter()
        .map(|x| x.speed_kmh)
        .fold(report.start_kmh, f64::max)
        * 1.1
        + 1.0;
    let gaps: Vec<(f64, f64)> = s.iter().filter_map(|x| x.gap_m.map(|g| (x.t, g))).collect();
    let gap_max = gaps.iter().map(|g| g.1).fold(5.0, f64::max) * 1.05;
    let gap_min = gaps.iter().map(|g| g.1).fold(0.0, f64::min) - 0.5;
    let decel_max = s
        .iter()
        .map(|x| x.requested_decel.max(x.decel))
        .fold(2.0, f64::max)
        * 1.15;

    let mut chart =
        panel(&panels[0], "speed, km/h", 0.0..end, 0.0..speed_max).map_err(|e| err(&e))?;
    chart
        .draw_series(LineSeries::new(
            s.iter().map(|x| (x.t, x.speed_kmh)),
            BLUE.stroke_width(2),
        ))
        .map_err(|e| err(&e))?;

    let mut chart = panel(
        &panels[1],
        "gap to the actor, m",
        0.0..end,
        gap_min..gap_max,
    )
    .map_err(|e| err(&e))?;
    chart
        .draw_series(LineSeries::new(gaps.iter().copied(), BLACK.stroke_width(2)))
        .map_err(|e| err(&e))?;
    chart
        .draw_series(LineSeries::new([(0.0, 0.0), (end, 0.0)], RED.mix(0.6)))
        .map_err(|e| err(&e))?;

    let mut chart =
        panel(&panels[2], "deceleration, m/s^2", 0.0..end, 0.0..decel_max).map_err(|e| err(&e))?;
    chart
        .draw_series(bands(s).map(|(a, b, c)| {
            let colour = if c == Command::Stop {
                RED.mix(0.15)
            } else {
                RGBColor(255, 170, 0).mix(0.2)
            };
            Rectangle::new([(a, 0.0), (b, decel_max)], colour.filled())
        }))
        .map_err(|e| err(&e))?;
    chart
        .draw_series(LineSeries::new(
            s.iter().map(|x| (x.t, x.requested_decel)),
            RED.stroke_width(2),
        ))
        .map_err(|e| err(&e))?
        .label("requested")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], RED.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            s.iter().map(|x| (x.t, x.decel)),
            GREEN.stroke_width(2),
        ))
        .map_err(|e| err(&e))?
        .label("reached")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], GREEN.stroke_width(2)));
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// What the run came to, in a few words.
fn headline(r: &ClosedLoopReport) -> String {
    if r.contact {
        format!("contact at {:.1} km/h", r.impact_kmh.unwrap_or_default())
    } else if let Some(g) = r.stopped_gap_m {
        format!("stopped {g:.1} m short")
    } else if r.activated() {
        format!("braked, {:.1} km/h lost", r.speed_lost_kmh)
    } else {
        "no SLOW, no STOP".into()
    }
}

type Chart<'a> = ChartContext<
    'a,
    SVGBackend<'a>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

fn panel<'a>(
    area: &DrawingArea<SVGBackend<'a>, plotters::coord::Shift>,
    label: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
) -> Result<Chart<'a>, DrawingAreaErrorKind<std::io::Error>> {
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .x_label_area_size(28)
        .y_label_area_size(48)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .x_desc("time, s")
        .y_desc(label)
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    Ok(chart)
}

/// The runs of SLOW and STOP: (from, to, command).
fn bands(s: &[LoopSample]) -> impl Iterator<Item = (f64, f64, Command)> {
    let mut out = Vec::new();
    let mut run: Option<(f64, Command)> = None;
    for x in s {
        if let Some((start, c)) = run
            && c != x.command
        {
            out.push((start, x.t, c));
            run = None;
        }
        if run.is_none() && x.command != Command::Clear {
            run = Some((x.t, x.command));
        }
    }
    if let (Some((start, c)), Some(last)) = (run, s.last()) {
        out.push((start, last.t, c));
    }
    out.into_iter()
}
