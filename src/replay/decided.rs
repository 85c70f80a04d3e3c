//! Why a replay braked: the frame its most severe alarm (the first STOP, else the first SLOW)
//! was decided on, drawn with the predicted path and its corridor on the road, the corridor's
//! unique flies and the obstacle's (`decided.png`), and the numbers beside it
//! (`decided.json`); `flyd eval --out` links every run's into an index page.

use std::path::Path;
use std::time::Duration;

use flyd_core::decision::Command;
use flyd_core::geometry::StereoRig;
use flyd_core::path::{PathEstimate, PredictedPath};
use flyd_core::perception::{Obstacle, Perception, PerceptionReport};
use flyd_core::road_plane::RoadPlane;
use image::{Rgb, RgbImage};
use nalgebra::Point3;

/// The frame an alarm was decided on, and what the decision saw.
#[derive(Debug, Clone)]
pub struct Decided {
    pub command: Command,
    pub frame: u64,
    pub frame_name: String,
    pub time: Duration,
    /// The speed decided at, m/s.
    pub speed: f64,
    /// The confirmed obstacle (distance along the path, offset from it).
    pub obstacle: Option<Obstacle>,
    /// The distance the decision judged (its near bound), metres.
    pub decision_distance: Option<f64>,
    /// The corridor's paths; `None`: straight ahead.
    pub path: Option<PathEstimate>,
    /// The fan of a motion fault, its largest curvature (1/m).
    pub fan: Option<f64>,
    pub road: RoadPlane,
    pub half_width: f64,
    pub search_far: f64,
    /// The unique corridor flies: left pixel and depth.
    pub flies: Vec<(f32, f32, f32)>,
    pub left: RgbImage,
    pub rig: StereoRig,
}

impl Decided {
    /// What `perception` saw when `command` was decided on `frame`.
    #[allow(clippy::too_many_arguments)]
    pub fn capture(
        command: Command,
        frame: u64,
        frame_name: String,
        time: Duration,
        speed: f64,
        perception: &Perception,
        report: &PerceptionReport,
        left: &RgbImage,
        rig: &StereoRig,
    ) -> Self {
        Self {
            command,
            frame,
            frame_name,
            time,
            speed,
            obstacle: report.tracked.confirmed(),
            decision_distance: report.tracked.decision_distance(),
            path: perception.path_estimate(),
            fan: perception.fan(),
            road: report.road.plane,
            half_width: perception.config().obstacle.corridor_half_width,
            search_far: perception.search_far(),
            flies: perception.corridor_pixels().collect(),
            left: left.clone(),
            rig: rig.clone(),
        }
    }

    /// The path the corridor followed.
    fn centre(&self) -> PredictedPath {
        self.path.map_or(PredictedPath::STRAIGHT, |p| p.held)
    }

    /// The picture: the left image, the corridor's edges (yellow) and centre line (cyan) on
    /// the road to the search's end, the unique corridor flies (green) and those at the
    /// obstacle's distance (red), a red bar across the corridor at the obstacle.
    pub fn picture(&self) -> RgbImage {
        let mut img = self.left.clone();
        let path = self.centre();
        let far = self.search_far.clamp(1.0, 200.0);
        let project = |path: PredictedPath, along: f64, offset: f64| {
            let (x, z) = path.point_at(along, offset);
            let y = self.road.road_y(x, z);
            self.rig
                .left
                .pixel_from_vehicle(&Point3::new(x, y, z))
                .map(|p| (p.x, p.y))
        };
        let polyline = |img: &mut RgbImage, path: PredictedPath, offset: f64, colour: Rgb<u8>| {
            let mut last = None;
            let mut s = 1.0;
            while s <= far {
                let p = project(path, s, offset);
                if let (Some(a), Some(b)) = (last, p) {
                    line(img, a, b, colour);
                }
                last = p;
                s += 0.5;
            }
        };
        // The arc of the moment, where the corridor must also hold a fly (magenta), when it
        // is not the centre line.
        if let Some(now) = self.path.map(|p| p.now).filter(|n| *n != path) {
            polyline(&mut img, now, 0.0, Rgb([255, 0, 255]));
        }
        let yellow = Rgb([255, 220, 0]);
        polyline(&mut img, path, -self.half_width, yellow);
        polyline(&mut img, path, self.half_width, yellow);
        polyline(&mut img, path, 0.0, Rgb([0, 220, 255]));
        let near = self.obstacle.map(|o| o.distance);
        for &(u, v, z) in &self.flies {
            let at_obstacle = near.is_some_and(|d| (f64::from(z) - d).abs() <= 1.0 + 0.05 * d);
            let colour = if at_obstacle {
                Rgb([255, 0, 0])
            } else {
                Rgb([0, 255, 0])
            };
            cross(&mut img, f64::from(u), f64::from(v), colour);
        }
        if let Some(o) = self.obstacle {
            let (a, b) = (
                project(path, o.distance, -self.half_width),
                project(path, o.distance, self.half_width),
            );
            if let (Some(a), Some(b)) = (a, b) {
                for dy in -1..=1 {
                    line(
                        &mut img,
                        (a.0, a.1 + f64::from(dy)),
                        (b.0, b.1 + f64::from(dy)),
                        Rgb([255, 0, 0]),
                    );
                }
            }
        }
        img
    }

    /// The numbers beside the picture.
    pub fn summary(&self) -> serde_json::Value {
        let path = self.centre();
        serde_json::json!({
            "command": self.command.name(),
            "frame": self.frame,
            "frame_name": self.frame_name,
            "time_s": self.time.as_secs_f64(),
            "speed_kmh": self.speed * 3.6,
            "obstacle_distance_m": self.obstacle.map(|o| o.distance),
            "obstacle_lateral_m": self.obstacle.map(|o| o.lateral),
            "obstacle_bottom_m": self.obstacle.map(|o| o.bottom),
            "obstacle_top_m": self.obstacle.map(|o| o.top),
            "obstacle_flies": self.obstacle.map(|o| o.flies),
            "decision_distance_m": self.decision_distance,
            "path_curvature": path.curvature,
            "path_curvature_rate": path.rate,
            "path_from_motion": self.path.is_some(),
            "path_spread_at_obstacle_m": self
                .path
                .zip(self.obstacle)
                .map(|(p, o)| p.spread(o.distance)),
            "fan_curvature": self.fan,
            "corridor_half_width_m": self.half_width,
            "search_far_m": self.search_far,
            "picture": "decided.png",
        })
    }

    /// Writes `decided.png` and `decided.json` into `dir`.
    pub fn write(&self, dir: &Path) -> Result<(), super::ReplayError> {
        let png = dir.join("decided.png");
        self.picture()
            .save(&png)
            .map_err(|source| super::ReplayError::Image {
                path: png.display().to_string(),
                source,
            })?;
        let json = dir.join("decided.json");
        let text = serde_json::to_string_pretty(&self.summary()).unwrap_or_default();
        std::fs::write(&json, text).map_err(|source| super::ReplayError::Io {
            path: json.display().to_string(),
            source,
        })
    }
}

/// A 2-pixel line from `a` to `b` (pixels), clipped to the image.
fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), colour: Rgb<u8>) {
    let steps = (b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil().min(4096.0) as u32;
    for i in 0..=steps {
        let t = if steps == 0 {
            0.0
        } else {
            f64::from(i) / f64::from(steps)
        };
        let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        put(img, x, y, colour);
        put(img, x + 1.0, y, colour);
    }
}

/// A 7-pixel cross at (u, v).
fn cross(img: &mut RgbImage, u: f64, v: f64, colour: Rgb<u8>) {
    for d in -3..=3 {
        put(img, u + f64::from(d), v, colour);
        put(img, u, v + f64::from(d), colour);
    }
}

fn put(img: &mut RgbImage, x: f64, y: f64, colour: Rgb<u8>) {
    if !(x.is_finite() && y.is_finite()) {
        return;
    }
    let (x, y) = (x.round(), y.round());
    if x >= 0.0 && y >= 0.0 && x < f64::from(img.width()) && y < f64::from(img.height()) {
        img.put_pixel(x as u32, y as u32, colour);
    }
}

/// `index.html` in `dir`: every `ITEM/seedN/decided.json` under it, a row each with its
/// picture and numbers, so that a person sees at a glance why each run braked.
pub fn write_index(dir: &Path) -> std::io::Result<usize> {
    let mut rows = Vec::new();
    let mut items: Vec<_> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    items.sort();
    for item in items {
        let mut seeds: Vec<_> = std::fs::read_dir(&item)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("decided.json").is_file())
            .collect();
        seeds.sort_by_key(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .and_then(|n| n.strip_prefix("seed"))
                .and_then(|n| n.parse::<u64>().ok())
                .unwrap_or(u64::MAX)
        });
        for seed in seeds {
            let text = std::fs::read_to_string(seed.join("decided.json"))?;
            let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) else {
                continue;
            };
            let rel = seed
                .strip_prefix(dir)
                .unwrap_or(&seed)
                .display()
                .to_string();
            rows.push((rel, v));
        }
    }
    let cell = |v: &serde_json::Value, key: &str, digits: usize| match v.get(key) {
        Some(serde_json::Value::Number(n)) => n
            .as_f64()
            .map_or_else(String::new, |f| format!("{f:.digits$}")),
        Some(serde_json::Value::String(s)) => escape(s),
        _ => "-".to_string(),
    };
    let mut html = String::from(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>flyd eval: why it braked</title><style>body{font-family:sans-serif}\
         td{vertical-align:top;padding:4px}img{max-width:640px}.STOP{color:#c00}\
         .SLOW{color:#c80}</style></head><body>\n<h1>Why it braked</h1>\n<p>Every run with \
         a SLOW or STOP: the frame its most severe alarm was decided on. Yellow: the \
         corridor's edges on the road, cyan: the predicted path, magenta: the arc of the \
         moment where it differs (a fly must be near both), green: the corridor's unique \
         flies, red: the obstacle's flies and its near face. A closed loop's run over time \
         beside it: speed, gap, deceleration requested and reached.</p>\n<table>\n",
    );
    for (rel, v) in &rows {
        let command = cell(v, "command", 0);
        html.push_str(&format!(
            "<tr><td><a href=\"{rel}/decided.png\"><img src=\"{rel}/decided.png\" \
             alt=\"{rel}\"></a></td><td><b>{rel}</b><br><span class=\"{command}\">{command}</span> \
             at frame {} ({} s), {} km/h<br>obstacle {} m along the path, {} m off it \
             (judged at {} m), {}-{} m above the road, {} flies<br>path curvature {} 1/m, \
             rate {} 1/m&sup2;{}, the plausible paths {} m apart there<br>corridor \
             &plusmn;{} m to {} m</td></tr>\n",
            cell(v, "frame", 0),
            cell(v, "time_s", 2),
            cell(v, "speed_kmh", 1),
            cell(v, "obstacle_distance_m", 2),
            cell(v, "obstacle_lateral_m", 2),
            cell(v, "decision_distance_m", 2),
            cell(v, "obstacle_bottom_m", 2),
            cell(v, "obstacle_top_m", 2),
            cell(v, "obstacle_flies", 0),
            cell(v, "path_curvature", 4),
            cell(v, "path_curvature_rate", 5),
            if v.get("path_from_motion") == Some(&serde_json::Value::Bool(true)) {
                ""
            } else {
                " (no motion: straight ahead)"
            },
            cell(v, "path_spread_at_obstacle_m", 2),
            cell(v, "corridor_half_width_m", 2),
            cell(v, "search_far_m", 1),
        ));
        // A closed loop's run over time beside it: how the vehicle braked.
        if dir.join(rel).join("closed_loop.svg").is_file() {
            let row = html.trim_end().trim_end_matches("</tr>").to_string();
            html = format!(
                "{row}<td><a href=\"{rel}/closed_loop.svg\"><img src=\"{rel}/closed_loop.svg\" \
                 alt=\"{rel}: the run over time\"></a></td></tr>\n"
            );
        }
    }
    if rows.is_empty() {
        html.push_str("<tr><td>No run braked.</td></tr>\n");
    }
    html.push_str("</table>\n</body></html>\n");
    std::fs::write(dir.join("index.html"), html)?;
    Ok(rows.len())
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}
