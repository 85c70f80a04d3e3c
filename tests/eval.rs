//! `flyd eval`: the labelled real recordings of `eval/fixtures.toml` (the project's KITTI
//! copies: pairs, single frames of sequences, the first 20 frames of a drive at 43 km/h with
//! its poses) replayed over seeds, as a user validates flyd on their own rig; and a label that
//! is not met fails the command.
//!
//! Every item without an obstacle ("clear", "no-stop") must meet its label on every seed;
//! an item with a car in the lane ("stop") on at least 2 of the 3 seeds. Measured over 40
//! seeds, the crossing car of seq12 frame 11 is stopped for on ~85 % of them
//! (docs/results.md: the figures; docs/perception.md: what stands in the way of 100 %).

use std::process::Command;

const SEEDS: u32 = 3;

fn flyd_eval(args: &[&str]) -> (std::process::Output, serde_json::Value) {
    let root = env!("CARGO_MANIFEST_DIR");
    let work = tempfile::tempdir().expect("tempdir");
    let json = work.path().join("eval.json");
    let out = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .current_dir(root)
        .arg("eval")
        .args(args)
        .arg("--json")
        .arg(&json)
        .output()
        .expect("flyd eval runs");
    println!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let report = std::fs::read(&json)
        .map(|b| serde_json::from_slice(&b).expect("JSON"))
        .unwrap_or(serde_json::Value::Null);
    (out, report)
}

#[test]
fn labelled_real_recordings_meet_their_labels_over_seeds() {
    let (out, report) = flyd_eval(&[
        "eval/fixtures.toml",
        "--seeds",
        &SEEDS.to_string(),
        "--jobs",
        "2",
    ]);
    let table = String::from_utf8_lossy(&out.stdout);
    let items = report["items"].as_array().expect("items");
    assert!(
        items.len() >= 14,
        "every fixture is labelled: {}",
        items.len()
    );
    let mut failures = Vec::new();
    for item in items {
        let name = item["name"].as_str().expect("name");
        let ok = item["ok"].as_u64().expect("ok");
        let expect = item["label"]["expect"].as_str().expect("label");
        let runs = item["runs"].as_array().expect("runs");
        assert_eq!(runs.len(), SEEDS as usize, "{name}");
        for run in runs {
            assert!(run.get("error").is_none(), "{name}: {run}");
            // Every real recording is rectified: flyd measured and corrected its rows.
            assert_eq!(run["row_correction"], "measured", "{name}: {run}");
        }
        if name.starts_with("odom06") {
            assert!(
                runs.iter().all(|r| r["speed_source"] == "feed"),
                "the drive is decided at its poses' speed"
            );
        }
        let needed = if expect == "stop" {
            2
        } else {
            u64::from(SEEDS)
        };
        if ok < needed {
            failures.push(format!("{name} ({expect}): {ok} of {SEEDS} seeds"));
        }
    }
    assert!(failures.is_empty(), "labels not met: {failures:?}\n{table}");
    // The exit status says whether every run met its label.
    assert_eq!(
        out.status.success(),
        items
            .iter()
            .all(|i| i["ok"].as_u64() == Some(u64::from(SEEDS))),
        "{table}"
    );
}

#[test]
fn a_label_not_met_fails_the_command_and_says_why() {
    let dir = tempfile::tempdir().expect("tempdir");
    let manifest = dir.path().join("wrong.toml");
    // hw-mock's pedestrian 4 m ahead of a vehicle at 30 km/h labelled as a clear road: every
    // run must fail it.
    std::fs::write(
        &manifest,
        "[[item]]\nname = \"pedestrian\"\nscenario = \"pedestrian-4m\"\nsize = \"320x240\"\n\
         flies = 1000\nspeed_kmh = 30\nexpect = \"clear\"\n\n\
         [[item]]\nname = \"empty\"\nscenario = \"empty-road\"\nsize = \"320x240\"\n\
         flies = 1000\nexpect = \"no-stop\"\n",
    )
    .expect("manifest");
    let path = manifest.display().to_string();
    let (out, report) = flyd_eval(&[&path, "--seeds", "2"]);
    assert_eq!(out.status.code(), Some(1), "a failed label exits 1");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("pedestrian: seed 1: false alarm"),
        "{stdout}"
    );
    let items = report["items"].as_array().expect("items");
    assert_eq!(items[0]["ok"], 0);
    assert!(items[0]["false_stop_rate"].as_f64().expect("rate") > 0.5);
    assert_eq!(items[1]["ok"], 2, "the empty road meets its label");
    // A manifest that cannot be used says which item and key.
    std::fs::write(
        &manifest,
        "[[item]]\nname = \"car\"\nscenario = \"pedestrian-4m\"\nexpect = \"stop\"\n",
    )
    .expect("manifest");
    let (out, _) = flyd_eval(&[&path]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("item 'car': expect = \"stop\" needs `distance`"),
        "{stderr}"
    );
}

/// `flyd eval --out DIR`: every run that braked leaves the picture of the frame it decided on
/// (the corridor drawn on the road, the obstacle's flies marked) and its numbers, and
/// `DIR/index.html` links them. The picture is read by OpenCV (a real image reader) and the
/// page by Python's HTML parser; both from target/py (scripts/prereqs).
#[test]
fn eval_out_shows_why_each_run_braked() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = tempfile::tempdir().expect("tempdir");
    let dir = out.path().display().to_string();
    // A car 12.4 m ahead (KITTI 2015 #151): STOP on every seed; a clear road: none.
    let (status, report) = flyd_eval(&[
        "eval/fixtures.toml",
        "--seeds",
        "2",
        "--only",
        "aanet_000151,kitti2012_train_000001",
        "--out",
        &dir,
    ]);
    assert!(status.status.success(), "{report}");
    let index = std::fs::read_to_string(out.path().join("index.html")).expect("index.html");
    for seed in [1, 2] {
        let run = out.path().join(format!("aanet_000151/seed{seed}"));
        let numbers: serde_json::Value = serde_json::from_slice(
            &std::fs::read(run.join("decided.json")).expect("decided.json of a run that braked"),
        )
        .expect("JSON");
        assert_eq!(numbers["command"], "STOP", "{numbers}");
        let d = numbers["obstacle_distance_m"].as_f64().expect("distance");
        assert!((11.0..14.0).contains(&d), "{numbers}");
        assert!(
            index.contains(&format!("aanet_000151/seed{seed}/decided.png")),
            "{index}"
        );
    }
    assert!(
        !out.path()
            .join("kitti2012_train_000001/seed1/decided.png")
            .exists(),
        "a run that did not brake has no picture"
    );
    let py = std::env::var_os("FLYD_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| root.join("target/py/bin/python3"));
    let check = r#"
import sys, os, html.parser, cv2, numpy as np
d = sys.argv[1]
class P(html.parser.HTMLParser):
    srcs = []
    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.srcs.append(dict(attrs)["src"])
p = P(); p.feed(open(os.path.join(d, "index.html")).read())
assert p.srcs, "no picture on the page"
for s in p.srcs:
    img = cv2.imread(os.path.join(d, s))
    assert img is not None, s
    b, g, r = img[..., 0].astype(int), img[..., 1].astype(int), img[..., 2].astype(int)
    yellow = ((r > 240) & (g > 200) & (b < 30)).sum()
    red = ((r > 240) & (g < 20) & (b < 20)).sum()
    assert yellow > 200 and red > 20, (s, yellow, red)
    print(s, img.shape, "corridor px", yellow, "obstacle px", red)
"#;
    match Command::new(&py).args(["-c", "import cv2"]).status() {
        Ok(s) if s.success() => {
            let o = Command::new(&py)
                .args(["-c", check, &dir])
                .output()
                .expect("python runs");
            println!("{}", String::from_utf8_lossy(&o.stdout));
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        _ if std::env::var_os("FLYD_ALLOW_NO_PY").is_some() => {
            println!("SKIP: OpenCV not in target/py: the picture is not read back");
        }
        _ => panic!("OpenCV not found in target/py: run scripts/prereqs (or FLYD_ALLOW_NO_PY=1)"),
    }
}
