use super::*;
use flyd_core::frame::PreparedImage;

/// A car stopped `at` metres ahead on a straight road, the vehicle at `kmh`.
fn car_ahead(at: f64, kmh: f64) -> Case {
    let text = format!(
        "[[case]]\nname = \"car\"\nroad = \"straight\"\nspeed_kmh = {kmh}\n\
         expect = \"no-contact\"\n[[case.actor]]\nkind = \"car\"\nat = {at}\n"
    );
    let file: hw_mock::closed_loop::CaseFile = toml::from_str(&text).expect("parses");
    file.cases().expect("valid").remove(0)
}

fn decision(command: Command, reason: CommandReason, decel: f64) -> Decision {
    Decision {
        command,
        reason,
        requested_decel: decel,
        changed: true,
        previous: Command::Clear,
        fault: false,
    }
}

/// Loads frame `index` of `feed` (a small mock rig: the images do not matter here).
fn load(feed: &mut ClosedLoopFeed, index: u64) {
    let image = || PreparedImage::new(64, 48).expect("image");
    let mut frame = StereoFrame::new(image(), image(), index);
    let mut left = RgbImage::new(64, 48);
    feed.load(index, &mut frame, &mut left).expect("renders");
}

#[test]
fn the_vehicle_obeys_the_commands_and_flyd_is_given_its_measured_motion() {
    let mut feed = ClosedLoopFeed::new(car_ahead(60.0, 36.0), 64, 48, 7).expect("feed");
    load(&mut feed, 0);
    let start = feed.motion(0).expect("measured");
    assert!((start.speed - 10.0).abs() < 0.25, "{}", start.speed);
    // The start-up's safe command is the system not yet armed: not obeyed.
    let t = |s: f64| Duration::from_secs_f64(s);
    feed.obey(
        t(0.2),
        &decision(Command::Slow, CommandReason::FaultFallback, 1.5),
    );
    load(&mut feed, 15);
    assert!((feed.motion(15).expect("measured").speed - 10.0).abs() < 0.25);
    assert_eq!(feed.report().armed_s, None);
    // Armed by the perception's first decision; a STOP then brakes it.
    feed.obey(
        t(0.5),
        &decision(Command::Clear, CommandReason::Perception, 0.0),
    );
    feed.obey(
        t(0.6),
        &decision(Command::Stop, CommandReason::Perception, 6.0),
    );
    load(&mut feed, 60);
    let r = feed.report();
    assert_eq!((r.armed_s, r.first_stop_s), (Some(0.5), Some(0.6)));
    assert_eq!(r.peak_requested_decel, 6.0);
    // Acting from 0.8 s, rising over ~0.3 s: about 6 m/s^2 for 0.9 s of the 1.4 s left.
    let speed = feed.motion(60).expect("measured").speed;
    assert!(speed > 1.0 && speed < 5.5, "{speed}");
    assert!(
        r.peak_decel > 5.5 && r.peak_decel <= 6.0,
        "{}",
        r.peak_decel
    );
    assert!(r.peak_jerk <= 30.0 + 1e-9, "{}", r.peak_jerk);
    // The time to collision at the first STOP: the gap over the speed then.
    let ttc = r.first_stop_ttc_s.expect("closing");
    let want = (60.0 - 1.5 - 10.0 * 0.6) / 10.0;
    assert!((ttc - want).abs() < 0.05, "{ttc} vs {want}");
    // It stops, is held, and the run ends a second later, short of the car.
    for f in 61..200 {
        if feed.finished() {
            break;
        }
        load(&mut feed, f);
    }
    assert!(feed.finished());
    let r = feed.report();
    assert!(!r.contact);
    assert_eq!(r.end_kmh, 0.0);
    // 58.5 m at the start; 8 m to the brakes acting, 8.3 m at 6 m/s^2, at most 3.5 m of rise.
    let gap = r.stopped_gap_m.expect("stopped");
    assert!(gap > 38.5 && gap < 42.2, "{gap}");
    assert_eq!(r.speed_lost_kmh, 36.0);
}

#[test]
fn a_vehicle_never_braked_hits_the_car_at_its_speed_and_the_run_ends() {
    let mut feed = ClosedLoopFeed::new(car_ahead(25.0, 36.0), 64, 48, 1).expect("feed");
    let mut f = 0;
    while !feed.finished() && f < 300 {
        load(&mut feed, f);
        f += 1;
    }
    let r = feed.report();
    assert!(r.contact);
    let impact = r.impact_kmh.expect("an impact speed");
    assert!((impact - 36.0).abs() < 1e-9, "{impact}");
    // The bumper reached the car's rear (23.5 m away) at 2.35 s, checked every 5 ms.
    assert!((r.seconds - 2.35).abs() < 0.01, "{}", r.seconds);
    assert!(!r.activated());
}

#[test]
fn the_same_seed_gives_the_same_run() {
    let run = |seed| {
        let mut feed = ClosedLoopFeed::new(car_ahead(40.0, 30.0), 64, 48, seed).expect("feed");
        load(&mut feed, 0);
        feed.obey(
            Duration::from_millis(100),
            &decision(Command::Slow, CommandReason::Perception, 1.5),
        );
        load(&mut feed, 30);
        (feed.motion(30).map(|m| m.speed.to_bits()), feed.report())
    };
    assert_eq!(run(3), run(3));
    assert_ne!(run(3).0, run(4).0, "the sensor's noise follows the seed");
}
