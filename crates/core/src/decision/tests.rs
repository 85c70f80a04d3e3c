use super::*;
use Command::{Clear, Slow, Stop};

const NONE: FaultBits = FaultBits::empty();
const STALE: FaultBits = FaultBits::SNAPSHOT_STALE;

/// Thresholds 0.3 / 0.6, ratio 0.5 (release below 0.15 / 0.3), holds 200 / 500 ms.
fn cfg() -> DecisionConfig {
    DecisionConfig {
        slow_threshold: 0.3,
        stop_threshold: 0.6,
        release_ratio: 0.5,
        slow_hold: Duration::from_millis(200),
        stop_hold: Duration::from_millis(500),
        safe_command: Slow,
        fault_mask: FaultBits::all(),
        slow_decel: 1.5,
        stop_decel: 4.0,
        mode: DecisionMode::GlobalWarning,
        ..DecisionConfig::default()
    }
}

/// Runs `steps` of (ms, warning, faults) through a fresh decider and compares the commands;
/// on mismatch, prints the whole trace.
fn check_with(
    config: DecisionConfig,
    steps: &[(u64, f64, FaultBits)],
    expected: &[Command],
) -> Vec<Decision> {
    assert_eq!(steps.len(), expected.len(), "test table is malformed");
    let mut decider = Decider::new(config).expect("valid config");
    let decisions: Vec<Decision> = steps
        .iter()
        .map(|&(ms, w, faults)| {
            decider.update(
                DecisionInput {
                    faults,
                    ..DecisionInput::healthy(w)
                },
                Duration::from_millis(ms),
            )
        })
        .collect();
    let got: Vec<Command> = decisions.iter().map(|d| d.command).collect();
    if got != expected {
        let trace: Vec<String> = steps
            .iter()
            .zip(&got)
            .zip(expected)
            .map(|((s, g), e)| {
                format!(
                    "t={:>5} w={:<6} faults={:<20} got {:<5} want {}{}",
                    s.0,
                    s.1,
                    s.2.to_string(),
                    g.name(),
                    e.name(),
                    if g == e { "" } else { "   <--" }
                )
            })
            .collect();
        panic!("command sequence differs:\n{}", trace.join("\n"));
    }
    decisions
}

fn check(steps: &[(u64, f64, FaultBits)], expected: &[Command]) -> Vec<Decision> {
    check_with(cfg(), steps, expected)
}

/// Three calm snapshots that take a fresh decider from its start-up SLOW to CLEAR.
const WARM: [(u64, f64, FaultBits); 3] = [(0, 0.0, NONE), (100, 0.0, NONE), (200, 0.0, NONE)];
const WARM_CMDS: [Command; 3] = [Slow, Slow, Clear];

fn warm_then(steps: &[(u64, f64, FaultBits)], expected: &[Command]) -> Vec<Decision> {
    let all_steps: Vec<_> = WARM.iter().chain(steps).copied().collect();
    let all_expected: Vec<_> = WARM_CMDS.iter().chain(expected).copied().collect();
    check(&all_steps, &all_expected)[WARM.len()..].to_vec()
}

#[test]
fn starts_safe_and_clears_only_after_the_hold() {
    let d = check(
        &[
            (0, 0.0, NONE),
            (100, 0.0, NONE),
            (199, 0.0, NONE),
            (200, 0.0, NONE),
        ],
        &[Slow, Slow, Slow, Clear],
    );
    assert_eq!(d[0].reason, CommandReason::FaultFallback);
    assert_eq!(d[2].reason, CommandReason::FaultFallback);
    assert!(!d[2].changed);
    assert_eq!(d[3].reason, CommandReason::Perception);
    assert!(d[3].changed);
    assert_eq!(d[3].requested_decel, 0.0);
}

#[test]
fn escalates_only_above_the_current_command() {
    let mut d = Decider::new(cfg()).expect("valid");
    let ms = Duration::from_millis;
    // Start-up SLOW: only a STOP-level warning escalates.
    assert!(
        !d.escalates(&DecisionInput::healthy(0.4)) && d.escalates(&DecisionInput::healthy(0.6))
    );
    for t in [0, 100, 200] {
        d.update(DecisionInput::healthy(0.0), ms(t));
    }
    assert_eq!(d.command(), Clear);
    assert!(!d.escalates(&DecisionInput::healthy(0.29)), "below SLOW");
    assert!(d.escalates(&DecisionInput::healthy(0.3)) && d.escalates(&DecisionInput::healthy(5.0)));
    assert!(
        !d.escalates(&DecisionInput::healthy(f64::NAN))
            && !d.escalates(&DecisionInput::healthy(-1.0)),
        "faults are not escalations"
    );
    d.update(DecisionInput::healthy(0.7), ms(300));
    assert_eq!(d.command(), Stop);
    assert!(
        !d.escalates(&DecisionInput::healthy(9.0)),
        "nothing above STOP"
    );
    d.shutdown();
    assert!(
        !d.escalates(&DecisionInput::healthy(9.0)),
        "latched after shutdown"
    );
}

#[test]
fn rise_to_slow() {
    let d = warm_then(
        &[(300, 0.29, NONE), (400, 0.3, NONE), (500, 0.59, NONE)],
        &[Clear, Slow, Slow],
    );
    assert!(d[1].changed && d[1].previous == Clear);
    assert_eq!(d[1].reason, CommandReason::Perception);
    assert_eq!(d[1].requested_decel, 1.5);
}

#[test]
fn rise_to_stop_directly_and_through_slow() {
    warm_then(&[(300, 0.6, NONE)], &[Stop]);
    let d = warm_then(
        &[(300, 0.4, NONE), (400, 0.7, NONE), (500, 5.0, NONE)],
        &[Slow, Stop, Stop],
    );
    assert_eq!(d[1].requested_decel, 4.0);
    assert!(d[1].changed && !d[2].changed);
}

#[test]
fn hysteresis_keeps_stop_and_slow_between_release_level_and_threshold() {
    // STOP, then w just under the STOP threshold (0.59) and just above its release level
    // (0.3) for a long time: STOP stays. Then SLOW band above SLOW release (0.15): SLOW
    // stays.
    let mut steps = vec![(300, 0.8, NONE)];
    let mut want = vec![Stop];
    for t in (400..=3000).step_by(100) {
        steps.push((t, if t % 200 == 0 { 0.59 } else { 0.3 }, NONE));
        want.push(Stop);
    }
    steps.extend([(3100, 0.29, NONE), (3600, 0.29, NONE)]);
    want.extend([Stop, Slow]);
    for t in (3700..=6000).step_by(100) {
        steps.push((t, if t % 200 == 0 { 0.29 } else { 0.15 }, NONE));
        want.push(Slow);
    }
    let d = warm_then(&steps, &want);
    assert!(d.iter().all(|d| d.reason == CommandReason::Perception));
}

#[test]
fn stop_needs_continuous_calm_for_the_whole_hold() {
    warm_then(
        &[
            (300, 0.9, NONE),  // STOP
            (400, 0.0, NONE),  // one good snapshot: no release
            (800, 0.0, NONE),  // 400 ms < 500 ms hold
            (850, 0.45, NONE), // above release level 0.3: hold restarts
            (900, 0.1, NONE),  // calm again from 900
            (1300, 0.1, NONE), // 400 ms
            (1399, 0.1, NONE), // 499 ms
            (1400, 0.1, NONE), // 500 ms: STOP released; SLOW calm since 900 too -> CLEAR
        ],
        &[Stop, Stop, Stop, Stop, Stop, Stop, Stop, Clear],
    );
}

#[test]
fn stop_releases_to_slow_when_warning_is_still_in_the_slow_band() {
    warm_then(
        &[
            (300, 0.9, NONE),
            (400, 0.2, NONE),  // below STOP release (0.3), above SLOW release (0.15)
            (900, 0.2, NONE),  // STOP hold done -> SLOW
            (1000, 0.1, NONE), // below SLOW release from 1000
            (1199, 0.1, NONE),
            (1200, 0.1, NONE), // 200 ms -> CLEAR
        ],
        &[Stop, Stop, Slow, Slow, Slow, Clear],
    );
}

#[test]
fn slow_hold() {
    warm_then(
        &[
            (300, 0.35, NONE),
            (350, 0.1, NONE),
            (500, 0.1, NONE),
            (520, 0.2, NONE), // back into the SLOW band: hold restarts
            (600, 0.1, NONE),
            (799, 0.1, NONE),
            (800, 0.1, NONE),
        ],
        &[Slow, Slow, Slow, Slow, Slow, Slow, Clear],
    );
}

#[test]
fn fault_gives_safe_command_and_recovery_needs_the_hold() {
    let d = warm_then(
        &[
            (300, 0.0, STALE),
            (
                400,
                0.0,
                FaultBits::LEFT_CAMERA_STALE | FaultBits::STEREO_SKEW,
            ),
            (500, 0.0, NONE), // healthy again: calm counted from here
            (600, 0.0, NONE),
            (699, 0.0, NONE),
            (700, 0.0, NONE), // 200 ms of healthy calm -> CLEAR
        ],
        &[Slow, Slow, Slow, Slow, Slow, Clear],
    );
    assert!(d[0].fault && d[0].changed);
    assert_eq!(d[0].reason, CommandReason::FaultFallback);
    assert!(!d[2].fault);
    assert_eq!(
        d[4].reason,
        CommandReason::FaultFallback,
        "still held because of the fault"
    );
    assert_eq!(d[5].reason, CommandReason::Perception);
}

#[test]
fn calm_before_a_fault_does_not_count_after_it() {
    warm_then(
        &[
            (300, 0.35, NONE), // SLOW
            (400, 0.0, NONE),  // calm from 400
            (550, 0.0, STALE), // fault resets the hold
            (600, 0.0, NONE),  // calm from 600
            (700, 0.0, NONE),  // would be 300 ms since 400, but only 100 since 600
            (800, 0.0, NONE),
        ],
        &[Slow, Slow, Slow, Slow, Slow, Clear],
    );
}

#[test]
fn fault_while_stopping_keeps_stop() {
    let d = warm_then(
        &[
            (300, 0.9, NONE),
            (400, 0.0, STALE),
            (500, f64::NAN, FaultBits::CAMERA_ERROR),
            (600, 0.0, NONE),
            (1000, 0.0, NONE),
            (1100, 0.0, NONE), // 500 ms of healthy calm since 600 -> CLEAR
        ],
        &[Stop, Stop, Stop, Stop, Stop, Clear],
    );
    assert_eq!(d[1].reason, CommandReason::FaultFallback);
    assert_eq!(d[1].requested_decel, 4.0);
}

#[test]
fn high_warning_during_a_fault_still_escalates() {
    warm_then(&[(300, 0.0, STALE), (400, 0.9, STALE)], &[Slow, Stop]);
}

#[test]
fn fault_stop_as_safe_command() {
    let config = DecisionConfig {
        safe_command: Stop,
        ..cfg()
    };
    check_with(
        config,
        &[
            (0, 0.0, NONE),
            (500, 0.0, NONE),
            (600, 0.0, STALE),
            (700, 0.0, NONE),
        ],
        &[Stop, Clear, Stop, Stop],
    );
}

#[test]
fn non_finite_or_negative_warning_is_a_fault() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.1] {
        let d = warm_then(&[(300, bad, NONE), (400, 0.0, NONE)], &[Slow, Slow]);
        assert!(d[0].fault, "{bad}");
        assert_eq!(d[0].reason, CommandReason::FaultFallback, "{bad}");
        assert!(!d[1].fault);
    }
    // -0.0 is a valid (zero) warning.
    let d = warm_then(&[(300, -0.0, NONE)], &[Clear]);
    assert!(!d[0].fault);
}

#[test]
fn faults_outside_the_mask_are_ignored() {
    let config = DecisionConfig {
        fault_mask: FaultBits::all() & !FaultBits::CAN_TX_ERROR,
        ..cfg()
    };
    check_with(
        config,
        &[
            (0, 0.0, NONE),
            (200, 0.0, FaultBits::CAN_TX_ERROR),
            (300, 0.0, FaultBits::CAN_TX_ERROR | STALE),
        ],
        &[Slow, Clear, Slow],
    );
}

#[test]
fn time_going_backwards_never_shortens_a_hold() {
    warm_then(
        &[
            (1000, 0.9, NONE),
            (1100, 0.0, NONE),
            (900, 0.0, NONE),
            (1599, 0.0, NONE),
        ],
        &[Stop, Stop, Stop, Stop],
    );
}

#[test]
fn shutdown_latches_the_safe_command() {
    let mut decider = Decider::new(cfg()).expect("valid");
    for ms in [0, 100, 200] {
        decider.update(DecisionInput::healthy(0.0), Duration::from_millis(ms));
    }
    assert_eq!(decider.command(), Clear);
    let d = decider.shutdown();
    assert_eq!(
        (d.command, d.reason, d.changed),
        (Slow, CommandReason::Shutdown, true)
    );
    let later = decider.update(DecisionInput::healthy(0.0), Duration::from_secs(10));
    assert_eq!(
        (later.command, later.reason),
        (Slow, CommandReason::Shutdown)
    );

    // A STOP stays a STOP at shutdown.
    let mut decider = Decider::new(cfg()).expect("valid");
    decider.update(DecisionInput::healthy(0.9), Duration::ZERO);
    assert_eq!(decider.shutdown().command, Stop);
}

#[test]
fn config_validation() {
    let bad = [
        DecisionConfig {
            slow_threshold: 0.7,
            ..cfg()
        },
        DecisionConfig {
            stop_threshold: f64::NAN,
            ..cfg()
        },
        DecisionConfig {
            slow_threshold: 0.0,
            ..cfg()
        },
        DecisionConfig {
            release_ratio: 1.5,
            ..cfg()
        },
        DecisionConfig {
            release_ratio: 0.0,
            ..cfg()
        },
        DecisionConfig {
            stop_hold: Duration::ZERO,
            ..cfg()
        },
        DecisionConfig {
            safe_command: Clear,
            ..cfg()
        },
        DecisionConfig {
            stop_decel: -1.0,
            ..cfg()
        },
        DecisionConfig {
            slow_decel: 5.0,
            ..cfg()
        },
        DecisionConfig {
            margin: f64::NAN,
            ..cfg()
        },
    ];
    for config in bad {
        assert!(Decider::new(config).is_err(), "{config:?}");
    }
    assert!(Decider::new(DecisionConfig::default()).is_ok());
}

/// Invariants over a long pseudo-random run, checked against the history directly:
/// - never below the warning's own level while healthy,
/// - never below the safe command while faulty,
/// - any release from STOP (or SLOW) is preceded by `hold` of healthy snapshots all below
///   that command's release level.
#[test]
fn invariants_hold_on_a_random_run() {
    let config = cfg();
    let mut decider = Decider::new(config).expect("valid");
    let mut rnd = crate::test_support::xorshift64(0x9E37_79B9_7F4A_7C15);
    let mut history: Vec<(Duration, f64, bool)> = Vec::new();
    let mut t = Duration::ZERO;
    let mut previous = decider.command();
    for _ in 0..20_000 {
        t += Duration::from_millis(10 + rnd() % 90);
        let r = rnd();
        let w = match r % 10 {
            0 => 0.7,
            1..=2 => 0.2 + (r % 100) as f64 / 1000.0,
            _ => (r % 140) as f64 / 1000.0,
        };
        let faults = if rnd().is_multiple_of(50) {
            STALE
        } else {
            NONE
        };
        let input = DecisionInput {
            faults,
            ..DecisionInput::healthy(w)
        };
        let d = decider.update(input, t);
        let fault = !faults.is_empty();
        history.push((t, w, fault));

        if fault {
            assert!(d.command >= config.safe_command, "fault at {t:?}");
        } else {
            assert!(d.command >= decider.level(&input), "below level at {t:?}");
        }
        for (released, threshold, hold) in [
            (Stop, config.stop_threshold, config.stop_hold),
            (Slow, config.slow_threshold, config.slow_hold),
        ] {
            if previous >= released && d.command < released {
                // The calm streak: the newest snapshots, all healthy and below the release
                // level. The release is legal only if the streak began `hold` ago or more.
                let release = threshold * config.release_ratio;
                let streak_start = history
                    .iter()
                    .rev()
                    .take_while(|(_, hw, hf)| *hw < release && !hf)
                    .last()
                    .map(|(ht, _, _)| *ht);
                assert!(
                    streak_start.is_some_and(|s| t - s >= hold),
                    "{released} released at {t:?}, calm only since {streak_start:?}"
                );
            }
        }
        previous = d.command;
    }
}

/// 30 km/h in m/s.
const KMH30: f64 = 30.0 / 3.6;

#[test]
fn stopping_distances_at_30_kmh() {
    let c = DecisionConfig::default();
    // 8.33 * 0.5 + 8.33^2 / 8 + 2 = 14.85 m; with 1.5 m/s^2, 29.31 m.
    assert!((c.reach(Stop, KMH30) - 14.8472).abs() < 1e-3);
    assert!((c.reach(Slow, KMH30) - 29.3148).abs() < 1e-3);
    assert_eq!(c.reach(Stop, 0.0), c.margin);
    assert_eq!(c.reach(Clear, KMH30), 0.0);
}

#[test]
fn the_obstacle_is_judged_where_it_will_be_when_the_next_evidence_comes() {
    let c = DecisionConfig::default();
    let d = Decider::new(c).expect("valid");
    // 15.2 m ahead at 30 km/h: beyond STOP's 14.85 m now, within it after 50 ms of
    // evidence age and a 33 ms frame (0.69 m nearer).
    let now = DecisionInput::at_speed(Some(15.2), KMH30);
    assert_eq!(d.level(&now), Slow);
    let later = DecisionInput {
        latency: 0.083,
        ..now
    };
    assert_eq!(d.level(&later), Stop);
    // Standing still, latency changes nothing.
    let still = DecisionInput {
        latency: 10.0,
        ..DecisionInput::at_speed(Some(2.5), 0.0)
    };
    assert_eq!(d.level(&still), Clear);
    for bad in [f64::NAN, -0.1, f64::INFINITY] {
        let input = DecisionInput {
            latency: bad,
            ..now
        };
        assert_eq!(d.level(&input), Clear, "latency {bad}: a fault, no level");
        assert!(d.clone().update(input, Duration::ZERO).fault);
    }
    // Nearer than the travel within the latency: STOP.
    let passed = DecisionInput {
        latency: 1.0,
        ..DecisionInput::at_speed(Some(5.0), KMH30)
    };
    assert_eq!(d.level(&passed), Stop);
}

/// Runs (ms, obstacle distance) at 30 km/h through an obstacle-mode decider, warmed up
/// with no obstacle for the default holds, and returns the commands.
fn obstacle_run(steps: &[(u64, Option<f64>)]) -> Vec<Command> {
    let mut d = Decider::new(DecisionConfig::default()).expect("valid");
    let ms = Duration::from_millis;
    for t in (0..=600).step_by(100) {
        d.update(DecisionInput::at_speed(None, KMH30), ms(t));
    }
    assert_eq!(d.command(), Clear);
    steps
        .iter()
        .map(|&(t, o)| {
            d.update(DecisionInput::at_speed(o, KMH30), ms(1000 + t))
                .command
        })
        .collect()
}

#[test]
fn an_obstacle_within_the_stopping_distance_stops() {
    let commands = obstacle_run(&[
        (0, Some(40.0)),
        (100, Some(29.0)),
        (200, Some(14.8)),
        (300, Some(14.0)),
        // Beyond STOP's reach / release_ratio = 18.6 m for the 1 s hold: SLOW.
        (1200, Some(19.0)),
        (2199, Some(19.0)),
        (2300, Some(19.0)),
        // Beyond SLOW's reach / 0.8 = 36.6 m for 0.5 s: CLEAR.
        (2400, Some(37.0)),
        (2950, Some(37.0)),
    ]);
    assert_eq!(
        commands,
        [Clear, Slow, Stop, Stop, Stop, Stop, Slow, Slow, Clear]
    );
}

#[test]
fn a_late_stop_asks_for_what_the_distance_left_needs() {
    let c = DecisionConfig::default();
    let stop = |distance: f64| {
        let mut d = Decider::new(c).expect("valid");
        d.update(DecisionInput::at_speed(None, KMH30), Duration::ZERO);
        d.update(
            DecisionInput::at_speed(Some(distance), KMH30),
            Duration::from_millis(700),
        )
    };
    // At the STOP distance (14.85 m at 30 km/h): stop_decel.
    let in_time = stop(14.8);
    assert_eq!(in_time.command, Stop);
    assert!((in_time.requested_decel - 4.0).abs() < 0.05, "{in_time:?}");
    // 11 m: 8.33^2 / (2 (11 - 8.33 * 0.5 - 2)) = 7.18 m/s^2.
    let late = stop(11.0);
    assert!((late.requested_decel - 7.18).abs() < 0.01, "{late:?}");
    // No room left: the most it asks for.
    assert_eq!(stop(5.0).requested_decel, c.max_decel);
    // A fault's STOP asks for stop_decel, whatever the distance.
    let mut d = Decider::new(DecisionConfig {
        safe_command: Stop,
        ..c
    })
    .expect("valid");
    let fault = d.update(
        DecisionInput {
            faults: STALE,
            ..DecisionInput::at_speed(Some(5.0), KMH30)
        },
        Duration::ZERO,
    );
    assert_eq!((fault.command, fault.requested_decel), (Stop, 4.0));
    // max_decel below stop_decel is refused.
    assert!(matches!(
        DecisionConfig {
            max_decel: 3.0,
            ..c
        }
        .validate(),
        Err(DecisionConfigError::MaxDecel { .. })
    ));
}

#[test]
fn at_standstill_only_the_margin_counts() {
    let mut d = Decider::new(DecisionConfig::default()).expect("valid");
    let at = |o| DecisionInput::at_speed(o, 0.0);
    assert!(d.escalates(&at(Some(1.9))), "inside the 2 m margin");
    d.update(at(None), Duration::ZERO);
    assert_eq!(d.level(&at(Some(2.1))), Clear);
    assert_eq!(d.level(&at(Some(2.0))), Stop);
}

#[test]
fn an_obstacle_or_speed_that_cannot_be_true_is_a_fault() {
    let d = Decider::new(DecisionConfig::default()).expect("valid");
    for input in [
        DecisionInput::at_speed(Some(f64::NAN), KMH30),
        DecisionInput::at_speed(Some(-1.0), KMH30),
        DecisionInput::at_speed(None, f64::NAN),
        DecisionInput::at_speed(None, -3.0),
    ] {
        let mut d = d.clone();
        let out = d.update(input, Duration::ZERO);
        assert!(out.fault && out.command == Slow, "{input:?}: {out:?}");
    }
    // The warning is not what this mode decides on: a NaN there is no fault.
    let mut d = d.clone();
    let input = DecisionInput {
        global_warning: f64::NAN,
        ..DecisionInput::at_speed(None, KMH30)
    };
    assert!(!d.update(input, Duration::ZERO).fault);
}

#[test]
fn the_worst_of_two_snapshots_keeps_the_nearest_obstacle() {
    let a = DecisionInput {
        global_warning: 0.2,
        ..DecisionInput::at_speed(Some(12.0), 5.0)
    };
    let b = DecisionInput {
        global_warning: 0.9,
        faults: STALE,
        ..DecisionInput::at_speed(Some(20.0), 6.0)
    };
    let w = a.worst(b);
    assert_eq!(
        (w.global_warning, w.obstacle, w.speed, w.faults),
        (0.9, Some(12.0), 6.0, STALE)
    );
    assert_eq!(
        a.worst(DecisionInput::at_speed(None, 5.0)).obstacle,
        Some(12.0)
    );
    assert!(
        a.worst(DecisionInput::at_speed(Some(f64::NAN), 5.0))
            .obstacle
            .is_some_and(f64::is_nan)
    );
    assert!(
        a.worst(DecisionInput::healthy(f64::NAN))
            .global_warning
            .is_nan()
    );
}

/// A snapshot of an obstacle `d` metres ahead moving at `u` m/s along the path, the vehicle
/// at `v`, with a 67 ms latency (a 30 fps frame's age and the next frame).
fn behind(d: f64, v: f64, u: f64) -> DecisionInput {
    DecisionInput {
        obstacle_speed: u,
        latency: 0.067,
        ..DecisionInput::at_speed(Some(d), v)
    }
}

const KMH50: f64 = 50.0 / 3.6;

#[test]
fn a_car_followed_at_a_second_is_neither_slow_nor_stop() {
    let d = Decider::new(DecisionConfig::default()).expect("valid");
    for (v, gap_s) in [
        (KMH30, 1.0),
        (KMH30, 1.5),
        (40.0 / 3.6, 1.0),
        (KMH50, 1.0),
        (KMH50, 2.0),
    ] {
        // Credited half a metre a second slower than it drives (two standard errors).
        let input = behind(v * gap_s, v, v - 0.5);
        assert_eq!(d.level(&input), Clear, "{v} m/s at {gap_s} s");
        // The same car standing: today's rule, a STOP or a SLOW.
        assert!(
            d.level(&behind(v * gap_s, v, 0.0)) > Clear,
            "{v} m/s at {gap_s} s"
        );
    }
    // Tailgating: STOP within what the vehicle closes in while it reacts to the car's
    // braking, plus the margin; the same at 30 and 50 km/h.
    let c = DecisionConfig::default();
    for v in [KMH30, KMH50] {
        let (stop, slow) = (c.reach_behind(Stop, v, v), c.reach_behind(Slow, v, v));
        assert!(
            (stop - 3.5).abs() < 0.01 && (slow - 2.56).abs() < 0.01,
            "{stop} {slow}"
        );
        assert_eq!(d.level(&behind(stop - 0.05, v, v)), Stop);
        assert_eq!(d.level(&behind(stop + 0.05, v, v)), Clear);
    }
}

#[test]
fn a_still_obstacle_is_decided_as_before_whatever_is_credited_to_nothing() {
    let d = Decider::new(DecisionConfig::default()).expect("valid");
    // 0, NaN, negative (oncoming) and infinite credit: a still obstacle, bit for bit.
    for u in [0.0, f64::NAN, -5.0, f64::NEG_INFINITY, f64::INFINITY] {
        for distance in [5.0, 14.0, 15.2, 20.0, 29.0, 40.0] {
            let still = DecisionInput {
                latency: 0.067,
                ..DecisionInput::at_speed(Some(distance), KMH30)
            };
            let credited = DecisionInput {
                obstacle_speed: u,
                ..still
            };
            let (mut a, mut b) = (d.clone(), d.clone());
            let (x, y) = (
                a.update(still, Duration::ZERO),
                b.update(credited, Duration::ZERO),
            );
            let inf = u == f64::INFINITY;
            assert!(x == y || inf, "{u} at {distance}: {x:?} vs {y:?}");
            assert!(
                !y.fault,
                "a speed that cannot be true is taken as still, not a fault"
            );
        }
    }
}

#[test]
fn a_slower_car_ahead_asks_slow_then_stop_as_the_gap_closes() {
    let d = Decider::new(DecisionConfig::default()).expect("valid");
    let (v, u) = (KMH50, 20.0 / 3.6);
    // SLOW from 59.5 m (the car stops in 13.7 m were it to brake at 1.1 m/s^2; the vehicle
    // needs 71.2 m at SLOW's 1.5), STOP from 28 m (at 3 and 4 m/s^2: 5.1 and 31 m).
    let levels: Vec<Command> = [75.0, 60.5, 58.0, 29.0, 27.0, 8.0]
        .iter()
        .map(|&gap| d.level(&behind(gap, v, u)))
        .collect();
    assert_eq!(levels, [Clear, Clear, Slow, Slow, Stop, Stop], "{levels:?}");
    // Its STOP asks for what keeps the margin were it to brake at lead_decel: less than the
    // still obstacle's rule at the same distance, it drives on.
    let mut a = d.clone();
    a.update(DecisionInput::at_speed(None, v), Duration::ZERO);
    let moving = a.update(behind(20.0, v, u), Duration::from_millis(100));
    let mut b = d.clone();
    b.update(DecisionInput::at_speed(None, v), Duration::ZERO);
    let still = b.update(behind(20.0, v, 0.0), Duration::from_millis(100));
    assert_eq!((moving.command, still.command), (Stop, Stop));
    assert!(
        moving.requested_decel < still.requested_decel,
        "{moving:?} vs {still:?}"
    );
    assert!(moving.requested_decel >= 4.0);
}

#[test]
fn a_car_that_brakes_ahead_is_a_stop_as_soon_as_its_speed_drops() {
    let d = Decider::new(DecisionConfig::default()).expect("valid");
    let v = KMH50;
    // Followed at 12 m (0.86 s): clear while it drives at the vehicle's speed.
    assert_eq!(d.level(&behind(12.0, v, v - 0.4)), Clear);
    // 2 m/s slower (a third of a second at 6 m/s^2): SLOW; 3 m/s (half a second, 1.3 m
    // nearer): STOP.
    assert_eq!(d.level(&behind(10.7, v, v - 2.0)), Slow);
    assert_eq!(d.level(&behind(10.7, v, v - 3.0)), Stop);
    // lead_decel is validated.
    for bad in [0.0, 0.5, 11.0, f64::NAN] {
        let c = DecisionConfig {
            lead_decel: bad,
            ..DecisionConfig::default()
        };
        assert!(c.validate().is_err(), "{bad}");
    }
}

#[test]
fn the_worst_of_two_snapshots_credits_the_slower_obstacle() {
    let a = behind(12.0, 10.0, 8.0);
    let b = behind(20.0, 10.0, 5.0);
    assert_eq!(a.worst(b).obstacle_speed, 5.0);
    assert_eq!(
        a.worst(DecisionInput::at_speed(None, 10.0)).obstacle_speed,
        8.0
    );
    assert_eq!(
        DecisionInput::at_speed(None, 10.0).worst(a).obstacle_speed,
        8.0
    );
    let nan = DecisionInput {
        obstacle_speed: f64::NAN,
        ..a
    };
    assert_eq!(a.worst(nan).obstacle_speed, 0.0);
}

/// SLOW is judged with the obstacle's speed less one standard error, STOP with two: a car
/// followed 16.5 m ahead at 40 km/h, measured at its speed give or take 1.3 m/s.
#[test]
fn slow_credits_one_standard_error_and_stop_two() {
    let d = Decider::new(DecisionConfig::default()).expect("valid");
    let v = 40.0 / 3.6;
    let stop_only = behind(16.5, v, v - 2.6);
    assert_eq!(d.level(&stop_only), Slow);
    let both = DecisionInput {
        obstacle_speed_slow: v - 1.3,
        ..stop_only
    };
    assert_eq!(d.level(&both), Clear);
    // The same car nearer: STOP stands on its own credit.
    let near = DecisionInput {
        obstacle: Some(5.0),
        ..both
    };
    assert_eq!(d.level(&near), Stop);
    // SLOW's speed never below STOP's, and the worst of two takes the lower of each.
    let low = DecisionInput {
        obstacle_speed_slow: 1.0,
        ..stop_only
    };
    assert_eq!(low.credited_for(Slow), v - 2.6);
    let w = both.worst(DecisionInput {
        obstacle_speed: v - 3.0,
        obstacle_speed_slow: v - 1.5,
        ..both
    });
    assert_eq!(
        (w.obstacle_speed, w.obstacle_speed_slow),
        (v - 3.0, v - 1.5)
    );
}

#[test]
fn one_only_predicted_to_walk_in_is_acted_on_a_stage_later_than_one_in_the_path() {
    let c = DecisionConfig::default();
    let d = Decider::new(c).expect("valid");
    // At 30 km/h: STOP's reach 14.85 m; at max_decel (9 m/s^2) 4.17 + 3.86 + 2 = 10.02 m.
    let late = c.reach_at(c.max_decel, KMH30);
    assert!((late - 10.0247).abs() < 1e-3, "{late}");
    let entering = |at: f64| DecisionInput {
        obstacle_entering: true,
        ..DecisionInput::at_speed(Some(at), KMH30)
    };
    let standing = |at: f64| DecisionInput::at_speed(Some(at), KMH30);
    // Between the two reaches: a STOP for one in the corridor, a SLOW for one who may enter.
    assert_eq!(d.level(&standing(12.0)), Stop);
    assert_eq!(d.level(&entering(12.0)), Slow);
    // Within the latest moment: a STOP either way, and what the distance needs is asked.
    assert_eq!(d.level(&entering(9.9)), Stop);
    let asked = d
        .clone()
        .update(entering(9.9), Duration::ZERO)
        .requested_decel;
    assert!(asked > c.stop_decel, "{asked}");
    // SLOW where one in the path would be STOPped for: within 14.85 m, not beyond.
    assert_eq!(d.level(&standing(29.0)), Slow);
    assert_eq!(d.level(&entering(14.7)), Slow);
    assert_eq!(d.level(&entering(15.0)), Clear);
    assert_eq!(d.level(&entering(29.0)), Clear);
    // The worst of two snapshots is only entering when both obstacles are.
    assert!(entering(12.0).worst(entering(14.0)).obstacle_entering);
    assert!(!entering(12.0).worst(standing(14.0)).obstacle_entering);
    assert!(
        entering(12.0)
            .worst(DecisionInput::at_speed(None, KMH30))
            .obstacle_entering
    );
}
