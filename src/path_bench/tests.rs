use super::*;
use nalgebra::Matrix3;

/// A drive at `speed` m/s on a curve of curvature `k(s)` (left positive), 10 Hz.
fn drive(speed: f64, seconds: f64, k: impl Fn(f64) -> f64) -> Drive {
    let (mut x, mut z, mut heading) = (0.0f64, 0.0f64, 0.0f64);
    let (mut poses, mut times) = (Vec::new(), Vec::new());
    let steps = (seconds * 10.0) as usize;
    let sub = 100;
    for i in 0..steps {
        let (s, c) = heading.sin_cos();
        // Turning left by `heading` about y (down): forward (-sin, 0, cos).
        let rotation = Matrix3::new(c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c);
        poses.push(Pose {
            rotation,
            position: Vector3::new(x, 0.0, z),
        });
        times.push(i as f64 / 10.0);
        let h = speed * 0.1 / f64::from(sub);
        for m in 0..sub {
            let travelled = (i * sub as usize + m as usize) as f64 * h;
            heading += k(travelled) * h;
            x -= heading.sin() * h;
            z += heading.cos() * h;
        }
    }
    Drive {
        name: "synthetic".into(),
        poses,
        times,
    }
}

fn config(model: PathModel) -> PathBenchConfig {
    PathBenchConfig {
        decision: DecisionConfig::default(),
        half_width: 1.2,
        model,
        yaw_noise: 0.0,
    }
}

fn all(report: &PathReport, stage: Stage) -> &Row {
    report
        .rows
        .iter()
        .find(|r| r.stage == stage && r.band == "all")
        .expect("an all row")
}

#[test]
fn a_constant_bend_is_predicted_by_its_arc_and_the_beside_objects_stay_out() {
    let d = drive(10.0, 30.0, |_| 1.0 / 80.0);
    let m = motion_at(&d, 5).expect("a moment");
    assert!((m.speed - 10.0).abs() < 0.01, "{m:?}");
    assert!((m.yaw_rate - 0.125).abs() < 1e-3, "{m:?}");
    let report = run(&[d], &config(PathModel::Clothoid { window: 0.0 }));
    for stage in Stage::ALL {
        let r = all(&report, stage);
        assert!(r.moments > 200, "{r:?}");
        assert_eq!(r.on_path_inside_pct, 100.0, "{r:?}");
        assert_eq!(r.beside_inside_pct, [0.0; 3], "{r:?}");
        assert!(r.offset_p99_m < 0.05, "{r:?}");
    }
    // The straight box misses the bend at the SLOW distance (36 m at 36 km/h: 8 m off).
    let straight = run(
        &[drive(10.0, 30.0, |_| 1.0 / 80.0)],
        &config(PathModel::Held { hold: 5.0 }),
    );
    let r = all(&straight, Stage::Slow);
    // The first 5 s the hold is straight: those moments miss.
    assert!(r.on_path_inside_pct < 95.0, "{r:?}");
}

#[test]
fn a_bend_opening_up_is_followed_by_the_clothoid_not_by_the_arc() {
    // An on-ramp as roads are built: a clothoid into a radius of 21 m over 20 m, then
    // opening linearly to straight over 60 m, at 10 m/s.
    let k = |s: f64| {
        let top = 1.0 / 21.0;
        if s < 100.0 {
            0.0
        } else if s < 120.0 {
            top * (s - 100.0) / 20.0
        } else {
            (top * (1.0 - (s - 120.0) / 60.0)).max(0.0)
        }
    };
    // At a gentle STOP's distance (4 m/s^2: 19.5 m at 36 km/h), where they differ.
    let stop = |model| {
        let gentle = PathBenchConfig {
            decision: DecisionConfig {
                slow_decel: 1.5,
                stop_decel: 4.0,
                ..DecisionConfig::default()
            },
            ..config(model)
        };
        let r = run(&[drive(10.0, 30.0, k)], &gentle);
        all(&r, Stage::Stop).clone()
    };
    let arc = stop(PathModel::Clothoid { window: 0.0 });
    let clothoid = stop(PathModel::Clothoid { window: 0.3 });
    assert!(
        clothoid.offset_p95_m < 0.85 * arc.offset_p95_m,
        "{clothoid:?} vs {arc:?}"
    );
    assert!(
        clothoid.beside_inside_pct[1] < 0.5 * arc.beside_inside_pct[1],
        "{clothoid:?} vs {arc:?}"
    );
    assert!(
        clothoid.on_path_inside_pct >= arc.on_path_inside_pct,
        "{clothoid:?} vs {arc:?}"
    );
}

#[test]
fn times_and_files_are_checked() {
    let dir = std::env::temp_dir().join(format!("flyd-path-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let line = "1 0 0 0 0 1 0 0 0 0 1 0\n";
    std::fs::write(dir.join("poses_01.txt"), line.repeat(3)).expect("write");
    std::fs::write(dir.join("times_01.txt"), "0\n0.1\n").expect("write");
    let err = Drive::load(&dir).expect_err("two times for three poses");
    assert!(err.to_string().contains("2 times for 3 poses"), "{err}");
    std::fs::write(dir.join("times_01.txt"), "0\n0.1\n0.1\n").expect("write");
    let err = Drive::load(&dir).expect_err("not increasing");
    assert!(err.to_string().contains("line 3"), "{err}");
    std::fs::remove_file(dir.join("times_01.txt")).expect("rm");
    let drives = Drive::load(&dir).expect("10 Hz without times");
    assert_eq!(drives[0].times, vec![0.0, 0.1, 0.2]);
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).expect("dir");
    assert!(matches!(Drive::load(&empty), Err(DriveError::Empty(_))));
    std::fs::remove_dir_all(&dir).ok();
}
