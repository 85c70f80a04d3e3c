//! The vehicle's motion into the threaded daemon: decisions at the measured speed, the
//! MotionFault bit and the assumed speed when the motion stops or cannot be trusted, bad
//! frames counted and never trusted.
//!
//! The scene's obstacle stands 3 m ahead (tests/mock_daemon). At a standstill the stopping
//! distance is the 2 m margin: no reason to brake (CLEAR). At 30 km/h it is 14.9 m: STOP. The
//! vehicle's frames are pushed by a thread every 20 ms, as a VCU sends them.

mod mock_daemon;

use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use flyd::bus::MemoryRx;
use flyd_core::can::crc::e2e_crc;
use flyd_core::can::messages::{AliveCounter, CanMessage, MotionMsg};
use flyd_core::decision::Command;
use mock_daemon::*;

/// What the mock VCU sends each period.
const SEND_SPEED: u32 = 0;
const SEND_NOTHING: u32 = 1;
/// Only bad frames: bad CRC, repeated counter, 300 m/s, DLC 7, counter 15.
const SEND_GARBAGE: u32 = 2;

struct Vcu {
    mode: Arc<AtomicU32>,
    /// Target speed in cm/s.
    speed: Arc<AtomicU32>,
    /// Periods of garbage sent.
    garbage: Arc<AtomicU32>,
    stop: Shutdown,
    handle: Option<JoinHandle<()>>,
}

use flyd::daemon::Shutdown;

impl Vcu {
    fn start(rx: MemoryRx) -> Self {
        let mode = Arc::new(AtomicU32::new(SEND_SPEED));
        let speed = Arc::new(AtomicU32::new(0));
        let stop = Shutdown::new();
        let garbage = Arc::new(AtomicU32::new(0));
        let (m, v, s, g) = (mode.clone(), speed.clone(), stop.clone(), garbage.clone());
        let handle = flyd::daemon::spawn_named("test-vcu", move || {
            let mut counter = AliveCounter::ZERO;
            let id = MotionMsg::DEFAULT_ID;
            // The vehicle's speed follows the target at 5 m/s^2 (0.1 m/s a period), as a real
            // one does: the monitor rejects jumps no vehicle makes.
            let mut speed = 0.0f64;
            while !s.sleep(Duration::from_millis(20)) {
                let target = f64::from(v.load(Ordering::Relaxed)) / 100.0;
                speed += (target - speed).clamp(-0.1, 0.1);
                // Turning as it goes: a constant curvature at any speed.
                let msg = MotionMsg {
                    valid: true,
                    speed,
                    yaw_rate: CURVATURE * speed,
                };
                match m.load(Ordering::Relaxed) {
                    SEND_SPEED => rx.push(id, &msg.encode(counter.advance())),
                    SEND_GARBAGE => {
                        let mut crc = msg.encode(counter.advance());
                        crc[0] ^= 0x55;
                        rx.push(id, &crc);
                        let fast = MotionMsg {
                            speed: 300.0,
                            ..msg
                        }
                        .encode(counter.advance());
                        rx.push(id, &fast);
                        rx.push(id, &fast); // a repeated counter
                        rx.push(id, &msg.encode(counter.advance())[..7]);
                        let mut c15 = msg.encode(counter.advance());
                        c15[1] |= 0x0F;
                        c15[0] = e2e_crc(MotionMsg::DEFAULT_DATA_ID, &c15[1..]);
                        rx.push(id, &c15);
                        g.fetch_add(1, Ordering::Relaxed);
                    }
                    _ => {}
                }
            }
        })
        .expect("spawn");
        Self {
            mode,
            speed,
            garbage,
            stop,
            handle: Some(handle),
        }
    }

    fn send(&self, mode: u32, speed_mps: f64) {
        self.speed
            .store((speed_mps * 100.0).round() as u32, Ordering::Relaxed);
        self.mode.store(mode, Ordering::Relaxed);
    }
}

impl Drop for Vcu {
    fn drop(&mut self) {
        self.stop.request();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// The arc the VCU's vehicle drives on, 1/m (left).
const CURVATURE: f64 = 0.01;

fn last_command(frames: &[Frame]) -> Option<Command> {
    commands(frames).last().map(|c| c.command)
}

fn last_motion_fault(frames: &[Frame]) -> Option<bool> {
    statuses(frames).last().map(|s| s.motion_fault)
}

#[test]
fn decisions_follow_the_measured_speed_and_fall_back_to_the_assumed_one() {
    let control = Arc::new(SceneControl::default());
    control.obstacle.store(true, Ordering::Relaxed);
    let rx = MemoryRx::default();
    let vcu = Vcu::start(rx.clone());
    // The scene stands still whatever the VCU says: flies moved with its speed would test
    // prediction against a contradiction, not the motion input.
    let mut config = config();
    config.vehicle.predict_flies = false;
    let daemon = start_receiving(config, control, Some(rx));

    // Standing 3 m before the obstacle: known motion, CLEAR once warmed up.
    daemon.wait_for("the motion known, at a standstill", |f| {
        last_motion_fault(f) == Some(false)
    });
    daemon.wait_for("CLEAR at a standstill 3 m before the obstacle", |f| {
        is_running_clear(f) && last_command(f) == Some(Command::Clear)
    });

    // Driving off towards it: STOP once the stopping distance reaches 3 m (1.7 m/s).
    vcu.send(SEND_SPEED, 2.5);
    let frames = daemon.wait_for("STOP driving off", |f| {
        last_command(f) == Some(Command::Stop)
    });
    assert_eq!(
        last_motion_fault(&frames),
        Some(false),
        "{}",
        summary(&frames)
    );
    // FLYD_Path: the arc of the moment once moving, the corridor's centre line once it has
    // been held for perception.obstacle.path_hold_s (2 s).
    let on_arc = |k: f64| (k - CURVATURE).abs() < 2e-4;
    let frames = daemon.wait_for("FLYD_Path with the held curvature", |f| {
        paths(f)
            .last()
            .is_some_and(|p| p.valid && on_arc(p.curvature) && on_arc(p.curvature_now))
    });
    assert!(
        paths(&frames).iter().all(|p| p.curvature >= 0.0
            && p.curvature <= CURVATURE + 2e-4
            && (!p.valid || p.curvature == 0.0 || on_arc(p.curvature_now))),
        "{:?}",
        paths(&frames)
    );

    // Back to a standstill: STOP is held, then released (the obstacle is beyond reach).
    vcu.send(SEND_SPEED, 0.0);
    daemon.wait_for("CLEAR again at a standstill", |f| {
        last_command(f) == Some(Command::Clear)
    });

    // The VCU goes silent: MotionFault within 3 periods (and a turn), STOP at the assumed
    // 30 km/h.
    vcu.send(SEND_NOTHING, 0.0);
    let frames = daemon.wait_for("MotionFault once the motion stops", |f| {
        last_motion_fault(f) == Some(true)
    });
    let faulted_at = frames.len();
    let frames = daemon.wait_for("STOP at the assumed speed", |f| {
        last_command(f) == Some(Command::Stop)
    });
    assert!(
        statuses(&frames[faulted_at..])
            .iter()
            .all(|s| s.motion_fault),
        "MotionFault stays while nothing arrives"
    );

    // Only bad frames, saying "standing still": never trusted.
    vcu.send(SEND_GARBAGE, 0.0);
    while vcu.garbage.load(Ordering::Relaxed) < 20 {
        std::thread::sleep(Duration::from_millis(10));
    }
    // Then silence, and five more FLYD_Status: five turns of the control loop after the last
    // bad frame, each reading up to 64 frames, so every bad frame was read however busy the
    // machine (judged by what the daemon sent, not by the clock).
    vcu.send(SEND_NOTHING, 0.0);
    let periods = u64::from(vcu.garbage.load(Ordering::Relaxed));
    let sent = statuses(&daemon.wait_for("the VCU silent", |_| true)).len();
    daemon.wait_for("five FLYD_Status after the bad frames", |f| {
        statuses(f).len() >= sent + 5
    });
    let (report, frames) = daemon.stop();
    let garbage: Vec<_> = statuses(&frames[faulted_at..]).to_vec();
    assert!(
        garbage.iter().all(|s| s.motion_fault),
        "a bad frame cleared MotionFault"
    );
    let stops = commands(&frames[faulted_at..]);
    let after_stop = stops
        .iter()
        .skip_while(|c| c.command != Command::Stop)
        .collect::<Vec<_>>();
    assert!(
        after_stop.iter().all(|c| c.command == Command::Stop),
        "the assumed speed keeps STOP 3 m before the obstacle: {}",
        summary(&frames[faulted_at..])
    );
    // 5 bad frames a period, every one rejected.
    assert!(
        report.control.motion_rejected >= 5 * periods,
        "{periods} periods: {:?}",
        report.control
    );
    assert!(report.control.motion_lost, "the loss was reported");
    // The decision judges the obstacle at its near bound, 3 m with `disparity_error_px` more
    // disparity (2.89 m on this rig); the stopping distance reaches it at 1.33 m/s. The ramp
    // adds 0.1 m/s a period and the measured distance wanders by a few centimetres, so the
    // first STOP comes a period before that speed or a few periods later.
    let (config, rig) = (self::config(), rig());
    let f_b = rig.left.intrinsics().fx * rig.baseline();
    let e = config.perception.obstacle.disparity_error_px;
    let near = f_b / (f_b / OBSTACLE_Z + e);
    let d = &config.decision;
    let (t, a) = (d.reaction_time.as_secs_f64(), d.stop_decel);
    // v t + v^2 / (2 a) + margin = near
    let v_stop = a * (-t + (t * t + 2.0 * (near - d.margin) / a).sqrt());
    let v = report.control.first_stop_speed.expect("a STOP was sent");
    assert!(
        (v_stop - 0.1..=v_stop + 0.5).contains(&v),
        "first STOP at {v} m/s, the near bound {near:.2} m is reached at {v_stop:.2} m/s"
    );
}
