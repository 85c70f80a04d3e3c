//! What `flyd replay` writes: flies.csv, trace.csv, frames.csv, overlay.png, warnings.png.

use std::io::Write;
use std::path::Path;

use flyd_core::engine::Population;
use image::{GrayImage, Luma, Rgb, RgbImage};

use super::{OVERLAY_FLIES, Replay, ReplayError, TraceRow, io_err};

/// Writes `flies.csv`.
pub fn write_flies_csv(
    pop: &Population,
    ambiguity: &[f32],
    path: &Path,
) -> Result<(), ReplayError> {
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = std::io::BufWriter::new(file);
    let write = |w: &mut std::io::BufWriter<std::fs::File>| -> std::io::Result<()> {
        writeln!(
            w,
            "x,y,z,fitness,warning,u_left,v_left,u_right,v_right,raw_fitness,ambiguity"
        )?;
        let px = |v: f32| {
            if v.is_finite() {
                format!("{v:.3}")
            } else {
                String::new()
            }
        };
        for i in 0..pop.len() {
            writeln!(
                w,
                "{:.5},{:.5},{:.5},{:e},{:e},{},{},{},{},{:e},{}",
                pop.x[i],
                pop.y[i],
                pop.z[i],
                pop.fitness[i],
                pop.warning[i],
                px(pop.u_left[i]),
                px(pop.v_left[i]),
                px(pop.u_right[i]),
                px(pop.v_right[i]),
                pop.raw_fitness[i],
                ambiguity
                    .get(i)
                    .map_or(String::new(), |a| format!("{a:.4}")),
            )?;
        }
        w.flush()
    };
    write(&mut w).map_err(io_err(path))
}

/// Writes `road_points.csv`: the road measurement's points on the last new frame; `used` = the
/// fit took it (unique match), `residual` = its height above the final estimate, metres.
fn write_road_points(replay: &Replay, path: &Path) -> Result<(), ReplayError> {
    let road = replay.perception.report().road.plane;
    let max_ambiguity = replay.perception.config().road.max_ambiguity;
    let mut out = String::from("x,y,z,fitness,ambiguity,u_left,v_left,used,residual\n");
    for p in replay.perception.road().swept() {
        let [x, y, z] = p.point;
        let used = p.fitness > 0.0 && f64::from(p.ambiguity) <= max_ambiguity;
        out.push_str(&format!(
            "{x:.4},{y:.4},{z:.4},{:e},{:.4},{:.2},{:.2},{},{:.4}\n",
            p.fitness,
            p.ambiguity,
            p.u,
            p.v,
            used as u8,
            road.height_above(f64::from(x), f64::from(y), f64::from(z)),
        ));
    }
    std::fs::write(path, out).map_err(io_err(path))
}

/// The header of `trace.csv` and `frames.csv`.
pub const TRACE_HEADER: &str = "generation,frame,frame_name,new_frame,time_s,global_warning,danger,\
visible,road_source,road_height,road_pitch_deg,road_roll_deg,road_inliers,corridor_flies,\
unique_flies,obstacle,obstacle_confirmed,obstacle_distance,obstacle_near,obstacle_lateral,\
obstacle_bottom,obstacle_top,obstacle_flies,obstacle_confidence,command,reason,time_us,matched,sensor_faults,\
left_contrast,right_contrast,left_textured,right_textured,left_unchanged,right_unchanged,speed_kmh,\
search_far_m,obstacle_speed,obstacle_speed_sigma,obstacle_motion_established,obstacle_credited_speed,\
obstacle_lateral_speed,obstacle_entering_s,watch_left_distance,watch_left_lateral,\
watch_left_lateral_speed,watch_right_distance,watch_right_lateral,watch_right_lateral_speed,\
obstacle_centre";

/// One row of `trace.csv` (no newline).
fn trace_line(r: &TraceRow) -> String {
    let road = &r.road;
    let o = r.tracked.obstacle;
    let [left, right] = r.watched;
    let num = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.3}"));
    let [l, rh] = r.health;
    let frac = |v: Option<f32>| v.map_or(String::new(), |v| format!("{v:.4}"));
    format!(
        "{},{},{},{},{:.4},{:e},{:e},{},{},{:.4},{:.3},{:.3},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.1},\
         {:.4},{},{:.2},{:.2},{:.4},{:.4},{},{},{:.2},{:.1},{},{},{},{:.3},{},{},{},{},{},{},{},{},{}",
        r.stats.generation,
        r.frame,
        r.frame_name,
        r.stats.new_frame as u8,
        r.time.as_secs_f64(),
        r.stats.global_warning,
        r.stats.danger,
        r.stats.visible,
        road.source,
        road.plane.height,
        road.plane.pitch_deg(),
        road.plane.roll_deg(),
        road.inliers,
        r.corridor.candidates,
        r.corridor.unique,
        o.is_some() as u8,
        r.tracked.confirmed as u8,
        num(o.map(|o| o.distance)),
        num(o.map(|o| o.near)),
        num(o.map(|o| o.lateral)),
        num(o.map(|o| o.bottom)),
        num(o.map(|o| o.top)),
        o.map_or(String::new(), |o| o.flies.to_string()),
        num(o.map(|o| o.confidence)),
        r.command,
        r.reason,
        r.elapsed.as_secs_f64() * 1e6,
        r.stats.matched,
        r.sensor.faults,
        l.contrast,
        rh.contrast,
        l.textured,
        rh.textured,
        frac(l.unchanged),
        frac(rh.unchanged),
        r.speed * 3.6,
        r.search_far,
        num(r.tracked.motion.map(|m| m.speed)),
        num(r.tracked.motion.map(|m| m.speed_sigma)),
        r.tracked
            .motion
            .map_or(String::new(), |m| (m.established as u8).to_string()),
        r.tracked.decision_speed(),
        num(r.tracked.motion.map(|m| m.lateral_speed)),
        num(r.tracked.entering),
        num(left.confirmed().map(|o| o.near)),
        num(left.confirmed().map(|o| o.lateral)),
        num(left.motion.map(|m| m.lateral_speed)),
        num(right.confirmed().map(|o| o.near)),
        num(right.confirmed().map(|o| o.lateral)),
        num(right.motion.map(|m| m.lateral_speed)),
        num(o.map(|o| o.centre)),
    )
}

/// Writes `rows` as `trace.csv`-style lines to `path`.
pub fn write_trace_csv<'a>(
    rows: impl IntoIterator<Item = &'a TraceRow>,
    path: &Path,
) -> Result<(), ReplayError> {
    let mut out = String::from(TRACE_HEADER);
    out.push('\n');
    for r in rows {
        out.push_str(&trace_line(r));
        out.push('\n');
    }
    std::fs::write(path, out).map_err(io_err(path))
}

/// The left image with the best `n` flies drawn as crosses.
pub fn overlay(left: &RgbImage, pop: &Population, n: usize) -> RgbImage {
    let mut img = left.clone();
    let (w, h) = (img.width() as i64, img.height() as i64);
    for i in pop.best(n) {
        let (u, v) = (pop.u_left[i], pop.v_left[i]);
        if !(u.is_finite() && v.is_finite()) {
            continue;
        }
        let (cx, cy) = (u.round() as i64, v.round() as i64);
        for d in -3i64..=3 {
            for (x, y) in [(cx + d, cy), (cx, cy + d)] {
                if (0..w).contains(&x) && (0..h).contains(&y) {
                    img.put_pixel(x as u32, y as u32, Rgb([0, 255, 0]));
                }
            }
        }
    }
    img
}

/// A white image where each fly is a 3x3 spot at its left projection, as dark as its warning
/// (scaled to the largest warning of the population).
pub fn warning_map(width: u32, height: u32, pop: &Population) -> GrayImage {
    let mut img = GrayImage::from_pixel(width, height, Luma([255]));
    let max = pop.warning.iter().copied().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return img;
    }
    // Draw the weakest first so strong warnings stay visible where spots overlap.
    let mut order: Vec<usize> = (0..pop.len()).collect();
    order.sort_by(|&a, &b| pop.warning[a].total_cmp(&pop.warning[b]));
    for i in order {
        let (u, v) = (pop.u_left[i], pop.v_left[i]);
        if !(u.is_finite() && v.is_finite()) || pop.warning[i] <= 0.0 {
            continue;
        }
        let shade = (255.0 * (1.0 - (pop.warning[i] / max).sqrt())).round() as u8;
        let (cx, cy) = (u.round() as i64, v.round() as i64);
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (x, y) = (cx + dx, cy + dy);
                if (0..width as i64).contains(&x) && (0..height as i64).contains(&y) {
                    let p = img.get_pixel_mut(x as u32, y as u32);
                    p.0[0] = p.0[0].min(shade);
                }
            }
        }
    }
    img
}

/// Writes flies.csv, road_points.csv, trace.csv, frames.csv (the last generation of each frame), overlay.png
/// and warnings.png of `replay` into `dir` (created if needed).
pub fn write_outputs(dir: &Path, replay: &Replay) -> Result<(), ReplayError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let pop = replay.perception.engine().population();
    write_flies_csv(pop, &replay.ambiguity, &dir.join("flies.csv"))?;
    write_road_points(replay, &dir.join("road_points.csv"))?;
    write_trace_csv(&replay.trace, &dir.join("trace.csv"))?;
    write_trace_csv(replay.frame_ends(), &dir.join("frames.csv"))?;
    let save_err = |path: &Path| {
        let path = path.display().to_string();
        move |source| ReplayError::Image { path, source }
    };
    let left = &replay.left;
    let p = dir.join("overlay.png");
    overlay(left, pop, OVERLAY_FLIES)
        .save(&p)
        .map_err(save_err(&p))?;
    let p = dir.join("warnings.png");
    warning_map(left.width(), left.height(), pop)
        .save(&p)
        .map_err(save_err(&p))?;
    if let Some(decided) = &replay.decided {
        decided.write(dir)?;
    }
    if let Some(run) = &replay.closed_loop {
        run.write(dir)?;
    }
    Ok(())
}
