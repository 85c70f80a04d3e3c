//! "No allocation per generation": a counting allocator watches `Engine::step` and
//! `Perception::step` (the road, the obstacle stage, the debounce).

use flyd::mock::MockStereo;
use flyd_core::engine::{Engine, EngineParams};
use flyd_core::frame::{PixelFormat, PreparedImage, StereoFrame};
use flyd_core::perception::{Perception, PerceptionConfig};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The counter is global: the tests of this file take turns.
static TURN: Mutex<()> = Mutex::new(());

struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Frames `ids` of `pedestrian-steps-in` at 320x240.
fn frames(ids: &[u32]) -> (MockStereo, Vec<StereoFrame>) {
    let scenario = hw_mock::Scenario::by_name("pedestrian-steps-in").expect("scenario");
    let mut mock = MockStereo::new(scenario, 320, 240).expect("mock");
    let mut frames = Vec::new();
    for &i in ids {
        let (l, r) = mock.frame(i).expect("render");
        frames.push(StereoFrame::new(
            PreparedImage::from_pixels(320, 240, PixelFormat::Rgb8, l).expect("left"),
            PreparedImage::from_pixels(320, 240, PixelFormat::Rgb8, r).expect("right"),
            u64::from(i),
        ));
    }
    (mock, frames)
}

#[test]
fn perception_steps_do_not_allocate() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    // The pedestrian stands in the lane on these frames: clusters are found and verified.
    let (mock, frames) = frames(&[60, 61, 62]);
    let params = EngineParams {
        flies: 2000,
        ..EngineParams::default()
    };
    let mut perception =
        Perception::new(mock.rig(), params, PerceptionConfig::default()).expect("perception");
    for g in 0..60 {
        perception.step(&frames[(g / 3) % 3]).expect("warm-up");
    }
    COUNTING.store(true, Ordering::SeqCst);
    ALLOCATIONS.store(0, Ordering::SeqCst);
    let (mut estimates, mut seen, mut roads) = (0, 0, 0);
    for g in 0..30 {
        let r = perception.step(&frames[(g / 3) % 3]).expect("step");
        estimates += usize::from(r.estimated);
        seen += usize::from(r.tracked.obstacle.is_some());
        roads += usize::from(r.stats.new_frame);
    }
    COUNTING.store(false, Ordering::SeqCst);
    assert_eq!(
        ALLOCATIONS.load(Ordering::SeqCst),
        0,
        "Perception::step allocated"
    );
    assert_eq!(
        estimates, 30,
        "the obstacle stage did not run every generation"
    );
    assert!(roads >= 9, "the road was measured on {roads} new frames");
    assert!(seen > 0, "no obstacle seen: the cluster paths did not run");
}

#[test]
fn generations_do_not_allocate() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let scenario = hw_mock::Scenario::by_name("pedestrian-steps-in").expect("scenario");
    let mut mock = MockStereo::new(scenario, 320, 240).expect("mock");
    let mut frames = Vec::new();
    // Frames 29 and 30: the pedestrian appears, so the change map and guided immigration work.
    for i in [29u32, 30] {
        let (l, r) = mock.frame(i).expect("render");
        frames.push(StereoFrame::new(
            PreparedImage::from_pixels(320, 240, PixelFormat::Rgb8, l).expect("left"),
            PreparedImage::from_pixels(320, 240, PixelFormat::Rgb8, r).expect("right"),
            i as u64,
        ));
    }
    let params = EngineParams {
        flies: 2000,
        local_mating: 0.5,
        ..EngineParams::default()
    };
    let mut engine = Engine::new(mock.rig(), params).expect("engine");
    engine.step(&frames[0]).expect("first generation");
    COUNTING.store(true, Ordering::SeqCst);
    ALLOCATIONS.store(0, Ordering::SeqCst);
    let (mut probes, mut refreshed) = (0, 0);
    for g in 0..30 {
        let s = engine.step(&frames[(g / 3) % 2]).expect("step");
        probes += s.probes;
        refreshed += s.refreshed;
    }
    COUNTING.store(false, Ordering::SeqCst);
    assert_eq!(
        ALLOCATIONS.load(Ordering::SeqCst),
        0,
        "Engine::step allocated"
    );
    assert!(
        probes > 0,
        "the depth probes of guided immigrants did not run"
    );
    assert!(
        refreshed > 0,
        "no fly was re-evaluated before selection where the image changed"
    );
}
