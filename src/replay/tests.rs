use super::*;
use flyd_core::perception::RoadEstimate;
use flyd_core::road_plane::RoadPlane;

fn trace(warnings: &[f64], frames_from: u64) -> Vec<TraceRow> {
    warnings
        .iter()
        .enumerate()
        .map(|(g, &w)| TraceRow {
            frame: frames_from + g as u64 / 3,
            frame_name: String::new(),
            time: Duration::ZERO,
            stats: GenerationStats {
                generation: g as u64 + 1,
                global_warning: w,
                ..GenerationStats::default()
            },
            road: RoadEstimate::prior(RoadPlane::FLAT),
            tracked: Tracked::NONE,
            watched: [Tracked::NONE; 2],
            corridor: CorridorCounts::default(),
            speed: 0.0,
            search_far: 40.0,
            command: if w >= 1.5 {
                Command::Stop
            } else {
                Command::Clear
            },
            reason: CommandReason::Perception,
            elapsed: Duration::ZERO,
            stage: Duration::ZERO,
            health: [ImageHealth::default(); 2],
            sensor: SensorVerdict::default(),
        })
        .collect()
}

#[test]
fn reaction_counts_generations_from_the_first_that_saw_the_obstacle() {
    // Frames 0..: 3 generations each; the obstacle at frame 2 = generation 7 (index 6).
    let mut w = vec![0.05; 6];
    w.extend([0.1, 0.6, 1.2, 2.0, 3.9, 4.0]);
    w.extend(std::iter::repeat_n(4.0, 60));
    let r = Reaction::of(&trace(&w, 0), 2, 0.5, 1.5).expect("long enough");
    assert_eq!(r.appears_at_generation, 7);
    assert_eq!(r.before, 0.05);
    assert_eq!(r.settled, 4.0);
    assert_eq!(r.slow_threshold_after, Some(2));
    assert_eq!(r.stop_threshold_after, Some(4));
    assert_eq!(r.stop_command_after, Some(4));
    assert_eq!(r.half_settled_after, Some(4), "2.0 is half of 4.0");
    assert!(
        Reaction::of(&trace(&w[..30], 0), 2, 0.5, 1.5).is_none(),
        "too short"
    );
    let never = Reaction::of(&trace(&[0.05; 80], 0), 2, 0.5, 1.5).expect("long enough");
    assert_eq!(never.stop_threshold_after, None);
    assert_eq!(never.stop_command_after, None);
}

#[test]
fn the_daemon_runs_a_burst_then_one_generation_a_period() {
    let e = EvolutionConfig::default();
    // 12 + 100 ms / 10 ms - 1 at 10 fps; 12 + 3 - 1 at 30 fps.
    assert_eq!(daemon_generations_per_frame(&e, 10.0), 21);
    assert_eq!(daemon_generations_per_frame(&e, 30.0), 14);
    let back_to_back = EvolutionConfig {
        generation_period: None,
        ..EvolutionConfig::default()
    };
    assert_eq!(daemon_generations_per_frame(&back_to_back, 10.0), 12);
}

#[test]
fn alarms_count_perception_commands_after_the_warm_up() {
    let mut t = trace(&[0.0, 2.0, 0.0, 2.0, 2.0, 0.0], 0);
    t[4].reason = CommandReason::FaultFallback;
    let a = Alarms::of(&t, 2);
    assert_eq!((a.stop_generations, a.first_generation), (1, Some(4)));
}
