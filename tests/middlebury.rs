//! Accuracy of the fly engine on real stereo pairs with ground truth (tests/fixtures, Middlebury).
//!
//! Runs the real `flyd replay` binary (50 generations of 5000 flies, default seed) and checks:
//! at least 85 % of the 250 fittest flies have a disparity `u_left - u_right` within 1 px of the
//! ground truth at their left pixel (pixels of unknown truth excluded), and those 250 flies
//! occupy at least 50 distinct 16x16-pixel cells of the left image.

mod flyd_cli;

use flyd_core::dataset::read_pfm;
use std::path::{Path, PathBuf};

const BEST: usize = 250;
const MIN_WITHIN_1PX: f64 = 0.85;
const MIN_CELLS: usize = 50;

struct Fly {
    fitness: f64,
    u_left: f64,
    v_left: f64,
    u_right: f64,
}

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn replay(set: &str, calib: &str) -> Vec<Fly> {
    let dir = fixtures().join(set);
    let out = tempfile::tempdir().expect("tempdir");
    let mut args: Vec<std::ffi::OsString> = ["replay", "--generations", "50", "--flies", "5000"]
        .map(Into::into)
        .into();
    for (flag, path) in [
        ("--left", dir.join("im0.png")),
        ("--right", dir.join("im1.png")),
        ("--calib", dir.join(calib)),
        ("--out", out.path().to_path_buf()),
    ] {
        args.extend([flag.into(), path.into()]);
    }
    let summary = flyd_cli::flyd_json(args);
    for file in ["flies.csv", "overlay.png", "warnings.png", "trace.csv"] {
        assert!(out.path().join(file).exists(), "{file} missing");
    }
    assert_eq!(summary["generations"], 50);
    let csv = std::fs::read_to_string(out.path().join("flies.csv")).expect("flies.csv");
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("x,y,z,fitness,warning,u_left,v_left,u_right,v_right,raw_fitness,ambiguity")
    );
    let flies: Vec<Fly> = lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let num = |i: usize| f.get(i).and_then(|s| s.parse::<f64>().ok());
            Some(Fly {
                fitness: num(3)?,
                u_left: num(5)?,
                v_left: num(6)?,
                u_right: num(7)?,
            })
        })
        .collect();
    assert!(
        flies.len() > 4000,
        "{} flies inside the images",
        flies.len()
    );
    flies
}

/// (fraction of the best flies within 1 px, distinct 16x16 cells, flies with known truth).
fn accuracy(set: &str, calib: &str) -> (f64, usize, usize) {
    let mut flies = replay(set, calib);
    flies.sort_by(|a, b| b.fitness.total_cmp(&a.fitness));
    flies.truncate(BEST);
    let truth = read_pfm(&fixtures().join(set).join("disp0.pfm")).expect("ground truth");
    let (mut good, mut known) = (0, 0);
    let mut cells = std::collections::HashSet::new();
    for f in &flies {
        let (x, y) = (f.u_left.round() as usize, f.v_left.round() as usize);
        cells.insert((x / 16, y / 16));
        let Some(d) = truth.get(x, y) else { continue };
        known += 1;
        if ((f.u_left - f.u_right) - d as f64).abs() <= 1.0 {
            good += 1;
        }
    }
    let fraction = good as f64 / known as f64;
    println!(
        "{set}: {good}/{known} of the {BEST} fittest flies within 1 px ({:.1} %), {} distinct 16x16 cells",
        fraction * 100.0,
        cells.len()
    );
    (fraction, cells.len(), known)
}

fn check(set: &str, calib: &str, min_within_1px: f64) {
    let (fraction, cells, known) = accuracy(set, calib);
    assert!(
        known >= BEST / 2,
        "only {known} flies on pixels with known truth"
    );
    assert!(
        fraction >= min_within_1px,
        "{set}: {:.1} % within 1 px",
        fraction * 100.0
    );
    assert!(cells >= MIN_CELLS, "{set}: {cells} cells");
}

#[test]
fn motorcycle_disparities_within_one_pixel() {
    check("middlebury-motorcycle", "calib.txt", MIN_WITHIN_1PX);
}

/// The issue sets the 85 % bound on Motorcycle and asks for Cones' figures to be reported (they
/// are printed). Cones measured 84.6 % at the default seed (85-89 % on other seeds); this test
/// guards against a regression below 80 %.
#[test]
fn cones_disparities_within_one_pixel() {
    check("middlebury-cones", "rig.toml", 0.80);
}
