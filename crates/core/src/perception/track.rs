//! Debounce over frames: an obstacle is *confirmed* once it was seen on `trigger_frames`
//! consecutive frames, and released once it was missing from `release_frames` consecutive
//! ones (as Nav2's collision monitor and Autoware's AEB debounce their detections).
//!
//! A frame is new evidence; another generation on the same frame is not: the estimates of
//! one frame count once. A frame saw the obstacle when any of its estimates did (each is a
//! different sample of flies looking at the same images, and what makes one an obstacle, a
//! verified cluster of unique matches over several cells, is the same on all of them); the
//! obstacle it reports is its latest sighting. Counting a frame as its latest estimate
//! instead released a pedestrian 24 m ahead of hw-mock's 40 km/h drive that every frame's
//! first estimate found and the later ones missed (flies bred off it between two frames'
//! evidence), and the STOP came 3 m late. A frame's verdict counts as soon as it is made, so
//! an obstacle seen on two frames is confirmed on the first estimate of the second one.
//! While a confirmed obstacle is missing, the last one seen is held until release.

use serde::{Deserialize, Serialize};

use super::motion::{History, ObstacleMotion};
use super::obstacle::{Obstacle, PerceptionParamError};
use crate::decision::DecisionInput;

/// Frames to confirm and to release an obstacle, and what a sighting must agree with.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackConfig {
    /// Consecutive frames with an obstacle that confirm it (1: the first sighting).
    pub trigger_frames: u32,
    /// Consecutive frames without one that release a confirmed obstacle.
    pub release_frames: u32,
    /// The fastest an obstacle moves over the road, m/s: a sighting continues a track when it
    /// is where the track's last sighting would be after the vehicle's own motion, give or
    /// take this speed over the frame interval (and the depth resolution).
    pub max_object_speed: f64,
}

impl Default for TrackConfig {
    fn default() -> Self {
        Self {
            trigger_frames: 2,
            release_frames: 3,
            max_object_speed: 15.0,
        }
    }
}

impl TrackConfig {
    pub fn validate(&self) -> Result<(), PerceptionParamError> {
        // More than a few frames to confirm is a pedestrian reached before it is believed.
        PerceptionParamError::check(
            "track.trigger_frames",
            (1..=5).contains(&self.trigger_frames),
            || format!("must be within 1..=5, got {}", self.trigger_frames),
        )?;
        PerceptionParamError::check(
            "track.max_object_speed",
            self.max_object_speed.is_finite() && (2.0..=40.0).contains(&self.max_object_speed),
            || format!("must be within 2..=40 m/s, got {}", self.max_object_speed),
        )?;
        PerceptionParamError::check(
            "track.release_frames",
            (1..=100).contains(&self.release_frames),
            || format!("must be within 1..=100, got {}", self.release_frames),
        )
    }
}

/// The tracker's verdict after an estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Tracked {
    /// The obstacle of the latest estimate, or, while a confirmed obstacle is missing but not
    /// yet released, the last one seen.
    pub obstacle: Option<Obstacle>,
    /// `obstacle` is confirmed: what the decision acts on.
    pub confirmed: bool,
    /// Consecutive frames with an obstacle, this one included (0 when it has none).
    pub seen_frames: u32,
    /// How `obstacle` moves over the ground, from its track's sightings
    /// ([`super::motion`]; none before three).
    pub motion: Option<ObstacleMotion>,
    /// `obstacle` is beside the corridor, predicted to enter it in this many seconds, before
    /// the vehicle has passed ([`super::crossing`]); none: it is in the corridor.
    pub entering: Option<f64>,
}

impl Tracked {
    /// Nothing seen.
    pub const NONE: Self = Self {
        obstacle: None,
        confirmed: false,
        seen_frames: 0,
        motion: None,
        entering: None,
    };

    /// The confirmed obstacle, if any.
    pub fn confirmed(&self) -> Option<Obstacle> {
        self.obstacle.filter(|_| self.confirmed)
    }

    /// Where the decision judges the confirmed obstacle, metres: its [`Obstacle::near`].
    pub fn decision_distance(&self) -> Option<f64> {
        self.confirmed().map(|o| o.near)
    }

    /// The speed along the path the decision may credit the confirmed obstacle with, m/s
    /// ([`crate::decision::DecisionInput::obstacle_speed`]): its speed over the ground less
    /// [`CREDIT_SIGMAS`] standard errors, once its motion is established; 0 (still) before,
    /// for an oncoming obstacle, or one whose speed is not surely positive.
    pub fn decision_speed(&self) -> f64 {
        self.credited(CREDIT_SIGMAS)
    }

    /// The speed SLOW is judged with ([`crate::decision::DecisionInput::obstacle_speed_slow`]):
    /// as [`Tracked::decision_speed`], less [`SLOW_CREDIT_SIGMAS`] standard errors.
    pub fn slow_speed(&self) -> f64 {
        self.credited(SLOW_CREDIT_SIGMAS)
    }

    /// `input` with the speeds the decision may credit the confirmed obstacle: STOP's
    /// ([`Tracked::decision_speed`]) and SLOW's ([`Tracked::slow_speed`]).
    pub fn credit(&self, input: DecisionInput) -> DecisionInput {
        DecisionInput {
            obstacle_speed: self.decision_speed(),
            obstacle_speed_slow: self.slow_speed(),
            obstacle_entering: self.confirmed().is_some() && self.entering.is_some(),
            ..input
        }
    }

    fn credited(&self, sigmas: f64) -> f64 {
        match (self.confirmed(), self.motion) {
            (Some(_), Some(m)) if m.established => {
                let credit = m.speed - sigmas * m.speed_sigma;
                if credit.is_finite() && credit > 0.0 {
                    credit
                } else {
                    0.0
                }
            }
            _ => 0.0,
        }
    }
}

/// How far `track`'s obstacle drives ahead over `dt` seconds as its established motion says,
/// metres (0 before, or for a motion beyond any obstacle's).
fn own_travel(track: &Track, dt: f64) -> f64 {
    track
        .history
        .motion()
        .filter(|m| m.established && m.speed.abs() <= super::motion::MAX_SPEED)
        .map_or(0.0, |m| m.speed * dt)
}

/// Standard errors a moving obstacle's speed is credited less by ([`Tracked::decision_speed`]):
/// two, so that the decision overrates an obstacle's speed on about one sighting in forty.
pub const CREDIT_SIGMAS: f64 = 2.0;
/// ... for SLOW ([`Tracked::slow_speed`]): one. SLOW is the early, gentle level (1.5 m/s^2);
/// overrating the obstacle's speed there delays it while STOP, judged at two, still stands
/// guard. Judged at two, a car followed 17 m ahead at 40 km/h on hw-mock's rig (a standard
/// error of 0.8 m/s: a pixel of disparity is 2 m there) was SLOWed for on one frame in a few
/// seconds, as its measured speed wandered by half a metre a second.
pub const SLOW_CREDIT_SIGMAS: f64 = 1.0;

/// A run of consistent sightings on consecutive frames.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Track {
    /// Its latest sighting, moved with the vehicle since (distance less the travel).
    last: Obstacle,
    /// Frames it was seen on in a row, and frames missed since (a confirmed track only).
    hits: u32,
    misses: u32,
    /// One of its sightings was at or beyond the judgeable distance.
    judged: bool,
    /// Its sightings in the ground frame ([`super::motion`]).
    history: History,
    /// When it was first seen (the tracker's clock, seconds; a resumed track keeps its own):
    /// a track seen over [`LONG_TRACK`] is held longer ([`LONG_HOLD`]).
    since: f64,
}

/// Both tracks after the frames before the current one.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct State {
    /// The confirmed obstacle (held while missing, until released).
    confirmed: Option<Track>,
    /// A run of sightings not yet confirmed.
    candidate: Option<Track>,
    /// The confirmed track last released, for [`RESUME_WITHIN`] seconds after its newest
    /// sighting: a new run where its motion carries it resumes its sightings.
    lost: Option<Track>,
}

/// The debounce state (see the module docs).
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackConfig,
    /// Nearer than this, an obstacle cannot be judged from one sighting (see
    /// [`Tracker::new`]).
    judgeable: f64,
    /// Disparity (pixels) per m^-1: f B, for the depth resolution of the gate.
    pixels_per_inverse_depth: f64,
    frame: Option<u64>,
    /// The best sighting on `frame` so far (none: no estimate of it saw the obstacle).
    current: Option<Obstacle>,
    /// Before `frame`.
    state: State,
    /// The vehicle's travel ahead (metres) and the time (seconds) from the previous frame to
    /// `frame`, and from `frame` to the next (what [`Tracker::moved`] said since).
    interval: (f64, f64),
    pending: (f64, f64),
    /// The vehicle's travel (metres) and the time (seconds) from the first frame to `frame`:
    /// where a sighting is in the ground frame.
    odometer: (f64, f64),
}

/// The frame interval assumed when no motion says it, seconds (10 fps: the slowest camera a
/// rig runs at, so the gate is never tighter than the truth).
const DEFAULT_INTERVAL: f64 = 0.1;
/// A sighting's lateral offset may wander this much from its track's on a still object,
/// metres (a cluster's median moves with the flies it is built from).
const LATERAL_SLACK: f64 = 1.0;
/// ... and its distance at least this much, metres, besides the depth of
/// [`DEPTH_SLACK_PX`] pixels of disparity.
const DEPTH_SLACK: f64 = 0.5;
const DEPTH_SLACK_PX: f64 = 2.0;
/// A sighting's distance is uncertain by this much disparity, pixels ([`super::motion`]):
/// the flies' sub-pixel matches, persisting from frame to frame.
const DISPARITY_NOISE_PX: f64 = 0.25;
/// A released track's sightings are resumed by a new run within this many seconds of its
/// newest one, where its motion carries it ([`Tracker::resumes`]). The flies on a car followed
/// on hw-mock lose it for a few frames now and then, and for up to 2.6 s (a cluster too thin
/// to verify); each loss started its motion again, as still, and the STOP that rule asks for
/// was obeyed. A car that braked or sped up meanwhile is not where its motion carries it (the
/// gate grows by two standard errors of its speed a second), or its sightings no longer fit
/// one line (its motion's error grows): it counts as still again.
const RESUME_WITHIN: f64 = 3.0;
/// ... and within this many metres across of its newest sighting: a car's width (the median
/// of the flies found on a car ahead moves from one of its halves to the other, 1.5 m, from
/// one sighting to another). The confirmed track, held while missing, is resumed the same
/// way: on hw-mock's car followed at 30 km/h the cluster jumped from 0.81 m right to 0.85 m
/// left (beyond [`LATERAL_SLACK`]) at the same distance, started a new run that was confirmed
/// two frames later as still, and the STOP that rule asks for was obeyed.
const RESUME_LATERAL: f64 = 2.0;

/// A confirmed track seen over at least this many seconds is held while missing for up to
/// [`LONG_HOLD`] seconds after its newest sighting, not `release_frames`: what was there for a
/// second does not vanish between two frames. hw-mock's car stopped across the left half of
/// the path (`car-stationary-minus-50`, 20 km/h): SLOWed for to 8 km/h, its track released
/// when its flies missed it 5 m ahead at the corridor's edge for 1 s, the driver drove on, and
/// the STOP came 2.2 m ahead: contact at 12.5 km/h.
pub const LONG_TRACK: f64 = 1.0;
pub const LONG_HOLD: f64 = 1.0;

/// A track that ends (released, replaced, or a run that broke off) is kept as `lost` to be
/// resumed when it has a motion to carry it on ([`History::motion`]: three sightings) and its
/// newest sighting is no older than the one kept.
fn bury(lost: &mut Option<Track>, ended: Option<Track>) {
    let Some(t) = ended.filter(|t| t.history.motion().is_some()) else {
        return;
    };
    let newest = |t: &Track| {
        t.history
            .newest()
            .map_or(f64::NEG_INFINITY, |(time, _, _)| time)
    };
    if lost.is_none_or(|l| newest(&t) >= newest(&l)) {
        *lost = Some(t);
    }
}

impl Tracker {
    /// A tracker for a rig of `pixels_per_inverse_depth` = f B that judges obstacles from
    /// `judgeable` metres on: nearer, part of the corridor is outside one camera's view or
    /// beyond the disparities searched, and the few pixels both cameras share there match
    /// anything (KITTI's odometry 06 drive: "obstacles" 1-2 m ahead from pixels matched
    /// 200-400 px apart). An obstacle there is confirmed only as the continuation of a track
    /// one of whose sightings was at or beyond `judgeable`: one seen coming, as the vehicle's
    /// motion predicts.
    pub fn new(config: TrackConfig, judgeable: f64, pixels_per_inverse_depth: f64) -> Self {
        Self {
            config,
            judgeable: if judgeable.is_finite() {
                judgeable
            } else {
                0.0
            },
            pixels_per_inverse_depth,
            frame: None,
            current: None,
            state: State::default(),
            interval: (0.0, DEFAULT_INTERVAL),
            pending: (0.0, 0.0),
            odometer: (0.0, 0.0),
        }
    }

    /// The judgeable distance, metres (see [`Tracker::new`]).
    pub fn judgeable(&self) -> f64 {
        self.judgeable
    }

    /// The vehicle moved `travel` metres ahead in `dt` seconds since the previous call (or the
    /// current frame): the next frame's sightings are compared with the tracks moved by it.
    pub fn moved(&mut self, travel: f64, dt: f64) {
        if travel.is_finite() && dt.is_finite() && dt >= 0.0 {
            self.pending.0 += travel;
            self.pending.1 += dt;
        }
    }

    /// Takes the estimate `seen` made on frame `frame`.
    pub fn update(&mut self, frame: u64, seen: Option<Obstacle>) -> Tracked {
        if self.frame != Some(frame) {
            if self.frame.is_some() {
                // The previous frame's verdict is final.
                self.state = self.next(self.current);
            }
            self.frame = Some(frame);
            self.current = None;
            let (travel, dt) = std::mem::take(&mut self.pending);
            self.interval = (travel, if dt > 0.0 { dt } else { DEFAULT_INTERVAL });
            self.odometer.0 += self.interval.0;
            self.odometer.1 += self.interval.1;
        }
        // The frame's best sighting: one that continues the confirmed track, else the
        // candidate, else the latest.
        self.current = match (seen, self.current) {
            (Some(s), Some(c)) if self.rank(&c) < self.rank(&s) => Some(c),
            (Some(s), _) => Some(s),
            (None, c) => c,
        };
        let state = self.next(self.current);
        let shown = state.confirmed.or(state.candidate);
        let seen_here = self.current.is_some();
        Tracked {
            obstacle: if seen_here || state.confirmed.is_some() {
                shown.map(|t| t.last)
            } else {
                None
            },
            confirmed: state.confirmed.is_some(),
            seen_frames: match (self.current, shown) {
                (Some(_), Some(t)) if t.misses == 0 => t.hits,
                _ => 0,
            },
            motion: shown.and_then(|t| t.history.motion()),
            entering: None,
        }
    }

    /// How uncertain a sighting's depth is at `distance`: [`DISPARITY_NOISE_PX`] of
    /// disparity there, metres.
    fn depth_noise(&self, distance: f64) -> f64 {
        DISPARITY_NOISE_PX * self.depth_per_px(distance)
    }

    /// The depth a pixel of disparity spans at `distance`, metres: Z^2 / (f B).
    fn depth_per_px(&self, distance: f64) -> f64 {
        distance * distance / self.pixels_per_inverse_depth.max(1e-9)
    }

    /// `o`, seen on the current frame, in the ground frame: (time, along, lateral).
    fn sample(&self, o: &Obstacle) -> (f64, f64, f64) {
        (self.odometer.1, o.centre + self.odometer.0, o.lateral)
    }

    /// 0: continues the confirmed track; 1: the candidate; 2: neither.
    fn rank(&self, o: &Obstacle) -> u8 {
        if self.state.confirmed.is_some_and(|t| self.continues(&t, o)) {
            0
        } else if self.state.candidate.is_some_and(|t| self.continues(&t, o)) {
            1
        } else {
            2
        }
    }

    /// Whether `o`, seen on the current frame, is where `track` is after the vehicle's travel
    /// since its last sighting, give or take an object's motion over the interval and the
    /// depth resolution.
    fn continues(&self, track: &Track, o: &Obstacle) -> bool {
        let (travel, dt) = self.interval;
        let expected = track.last.distance - travel + own_travel(track, dt);
        let resolution = DEPTH_SLACK_PX * self.depth_per_px(expected.max(o.distance));
        let moving = self.config.max_object_speed * dt;
        (o.distance - expected).abs() <= DEPTH_SLACK.max(resolution) + moving
            && (o.lateral - track.last.lateral).abs() <= LATERAL_SLACK + moving
    }

    /// The state after the current frame, had it ended with sighting `seen`.
    fn next(&self, seen: Option<Obstacle>) -> State {
        let State {
            mut confirmed,
            mut candidate,
            mut lost,
        } = self.state;
        let now = self.odometer.1;
        lost = lost.filter(|l| {
            l.history
                .newest()
                .is_some_and(|(t, _, _)| now - t <= RESUME_WITHIN)
        });
        let judged = |o: &Obstacle| o.distance >= self.judgeable;
        let with = |h: History, o: &Obstacle| {
            let (t, a, l) = self.sample(o);
            h.with(t, a, l, self.depth_noise(o.distance))
        };
        let continues = |t: &Option<Track>, o: &Obstacle| t.is_some_and(|t| self.continues(&t, o));
        match seen {
            Some(o) if continues(&confirmed, &o) => {
                confirmed = confirmed.map(|t| Track {
                    last: o,
                    // Consecutive frames: a run broken by a miss starts again.
                    hits: if t.misses > 0 {
                        1
                    } else {
                        t.hits.saturating_add(1)
                    },
                    misses: 0,
                    judged: t.judged || judged(&o),
                    history: with(t.history, &o),
                    since: t.since,
                });
                bury(&mut lost, candidate.take());
            }
            Some(o) => {
                // Released first: a new run may resume it.
                confirmed = self.missed_or_lost(confirmed, &mut lost);
                candidate = Some(match candidate {
                    Some(t) if self.continues(&t, &o) => Track {
                        last: o,
                        hits: t.hits.saturating_add(1),
                        misses: 0,
                        judged: t.judged || judged(&o),
                        history: with(t.history, &o),
                        since: t.since,
                    },
                    previous => {
                        // A new run where a track's motion carries it is that track seen
                        // again, or from elsewhere on it (see `RESUME_LATERAL`): the held
                        // one, the run it replaces, or the one lost last.
                        let held = confirmed.filter(|c| self.resumes(c, &o));
                        let before = previous.filter(|p| self.resumes(p, &o));
                        let resumed = held
                            .or(before)
                            .or_else(|| lost.take_if(|l| self.resumes(l, &o)));
                        if held.is_some() || before.is_none() {
                            bury(&mut lost, previous);
                        }
                        Track {
                            last: o,
                            hits: 1,
                            misses: 0,
                            judged: resumed.is_some_and(|l| l.judged) || judged(&o),
                            history: with(resumed.map_or_else(History::default, |l| l.history), &o),
                            since: resumed.map_or(now, |l| l.since),
                        }
                    }
                });
            }
            None => {
                bury(&mut lost, candidate.take());
                confirmed = self.missed_or_lost(confirmed, &mut lost);
            }
        }
        if let Some(t) = candidate
            && t.judged
            && t.hits >= self.config.trigger_frames
            && confirmed.is_none_or(|c| t.last.distance <= c.last.distance || c.misses > 0)
        {
            // A new obstacle confirmed: it replaces a farther one, or one not seen now.
            bury(&mut lost, confirmed.replace(t));
            candidate = None;
        }
        State {
            confirmed,
            candidate,
            lost,
        }
    }

    /// Whether `o`, seen on the current frame, is where the released track `lost`'s motion
    /// carries it: along the path within the depth resolution and its speed's uncertainty
    /// over the time since, across within [`RESUME_LATERAL`].
    fn resumes(&self, lost: &Track, o: &Obstacle) -> bool {
        let (t, along, lateral) = self.sample(o);
        let (Some((_, _, was_lateral)), Some((expected, spread))) =
            (lost.history.newest(), lost.history.along_at(t))
        else {
            return false;
        };
        let resolution = DEPTH_SLACK_PX * self.depth_per_px(o.distance);
        (along - expected).abs() <= DEPTH_SLACK.max(resolution) + spread
            && (lateral - was_lateral).abs() <= RESUME_LATERAL
    }

    /// `o` moved `by` metres along the path (negative: nearer), its near bound the same
    /// disparity nearer than its distance.
    fn shifted(&self, o: &Obstacle, by: f64) -> Obstacle {
        let f_b = self.pixels_per_inverse_depth;
        let distance = o.distance + by;
        let extra = f_b * (1.0 / o.near - 1.0 / o.distance);
        let near = if distance > 0.0 && f_b > 0.0 && extra.is_finite() {
            f_b / (f_b / distance + extra)
        } else {
            distance
        };
        Obstacle {
            distance,
            near,
            centre: o.centre + by,
            ..*o
        }
    }

    /// [`Tracker::missed`] of `confirmed`; a track it releases becomes `lost`.
    fn missed_or_lost(&self, confirmed: Option<Track>, lost: &mut Option<Track>) -> Option<Track> {
        let held = confirmed.and_then(|t| self.missed(t));
        if held.is_none() {
            bury(lost, confirmed);
        }
        held
    }

    /// A confirmed track that missed the current frame: held where the vehicle's travel
    /// (and its own motion) brought it, or released: after `release_frames` misses, or for
    /// a track seen over [`LONG_TRACK`], [`LONG_HOLD`] seconds after its newest sighting
    /// (sooner once the vehicle has reached it).
    fn missed(&self, t: Track) -> Option<Track> {
        let misses = t.misses.saturating_add(1);
        let last = self.shifted(&t.last, own_travel(&t, self.interval.1) - self.interval.0);
        let now = self.odometer.1;
        let long = t.history.newest().is_some_and(|(seen, _, _)| {
            seen - t.since >= LONG_TRACK && now - seen <= LONG_HOLD && last.distance > 0.0
        });
        (misses < self.config.release_frames || long).then_some(Track { misses, last, ..t })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// KITTI's f B (px m), judging from 4.8 m on.
    const FB: f64 = 389.0;
    const JUDGEABLE: f64 = 4.8;

    fn tracker() -> Tracker {
        Tracker::new(TrackConfig::default(), JUDGEABLE, FB)
    }

    fn beside(distance: f64, lateral: f64) -> Option<Obstacle> {
        at(distance).map(|o| Obstacle { lateral, ..o })
    }

    fn at(distance: f64) -> Option<Obstacle> {
        Some(Obstacle {
            distance,
            near: distance,
            centre: distance,
            lateral: 0.0,
            bottom: 0.3,
            top: 1.7,
            flies: 20,
            cells: 9,
            confidence: 60.0,
        })
    }

    /// A car 20 m ahead driving at 5 m/s while the vehicle drives at 8: its sightings close
    /// by 3 m/s, the vehicle's travel says 8, so it moves at 5 over the ground; established
    /// after eight frames at 30 fps, counted from the track's first sighting (a confirmed
    /// track keeps its candidate's sightings).
    #[test]
    fn a_track_measures_how_its_obstacle_moves_over_the_ground() {
        let mut t = tracker();
        let dt = 1.0 / 30.0;
        let mut last = None;
        for f in 0..12u64 {
            if f > 0 {
                t.moved(8.0 * dt, dt);
            }
            let d = 20.0 - 3.0 * dt * f as f64;
            let r = t.update(f, beside(d, 0.2 + 0.01 * f as f64));
            // Several estimates of one frame are one sighting.
            let again = t.update(f, beside(d, 0.2 + 0.01 * f as f64));
            assert_eq!(r.motion, again.motion);
            last = Some((f, r));
        }
        let (f, r) = last.expect("frames");
        let m = r.motion.expect("a motion");
        assert!(r.confirmed);
        assert_eq!(m.samples as u64, f + 1);
        assert!((m.speed - 5.0).abs() < 1e-6, "{m:?}");
        assert!((m.lateral_speed - 0.3).abs() < 1e-6, "{m:?}");
        assert!(m.established);
        // Fewer than three sightings: none yet.
        let mut fresh = tracker();
        assert_eq!(fresh.update(0, at(20.0)).motion, None);
        // A sighting elsewhere starts a candidate of its own: the confirmed track, held,
        // keeps its motion.
        let r = t.update(12, at(8.0));
        assert_eq!(r.motion.map(|m| m.samples), Some(12), "{r:?}");
    }

    /// A car followed at 8 m/s, 12 m ahead, lost for five frames (released after three): seen
    /// again where its motion carries it, its track resumes with its sightings and its motion
    /// is established at once; seen 4 m off, a new track starts from nothing.
    #[test]
    fn a_track_lost_for_a_few_frames_resumes_where_its_motion_carries_it() {
        let dt = 1.0 / 30.0;
        let run = |offset: f64| {
            let mut t = tracker();
            let mut r = None;
            for f in 0..20u64 {
                if f > 0 {
                    t.moved(8.0 * dt, dt);
                }
                let seen = if (10..15).contains(&f) {
                    None
                } else if f >= 15 {
                    beside(12.0 + offset, 0.3)
                } else {
                    beside(12.0, 0.3)
                };
                r = Some(t.update(f, seen));
                if f == 14 {
                    assert!(r.is_some_and(|r| !r.confirmed), "released: {r:?}");
                }
            }
            r.expect("frames")
        };
        let resumed = run(0.0);
        let m = resumed.motion.expect("a motion");
        // The sightings of the last 0.6 s (motion::MAX_AGE): 14 of the 15.
        assert!(
            resumed.confirmed && m.samples == 14 && m.established,
            "{resumed:?}"
        );
        assert!((m.speed - 8.0).abs() < 0.01, "{m:?}");
        assert!(resumed.decision_speed() > 7.0, "{resumed:?}");
        let other = run(4.0);
        let m = other.motion.expect("a motion");
        assert!(
            other.confirmed && m.samples == 5 && !m.established,
            "{other:?}"
        );
        assert_eq!(other.decision_speed(), 0.0);
        // Lost for longer than RESUME_WITHIN: a new track.
        let mut t = tracker();
        for f in 0..120u64 {
            if f > 0 {
                t.moved(8.0 * dt, dt);
            }
            let seen = if (10..110).contains(&f) {
                None
            } else {
                beside(12.0, 0.3)
            };
            let r = t.update(f, seen);
            if f == 117 {
                assert_eq!(r.motion.map(|m| m.samples), Some(8), "{r:?}");
            }
            if f == 112 {
                assert!(r.motion.is_some_and(|m| m.samples == 3), "{r:?}");
            }
        }
    }

    #[test]
    fn a_followed_car_seen_on_its_other_half_keeps_its_motion() {
        // Followed at the vehicle's 8 m/s, 12 m ahead; the cluster found on it is its right
        // half, then its left one (1.7 m across: not a continuation).
        let dt = 1.0 / 30.0;
        let mut t = tracker();
        let mut last = None;
        for f in 0..30u64 {
            if f > 0 {
                t.moved(8.0 * dt, dt);
            }
            let lateral = if f < 15 { 0.85 } else { -0.85 };
            let r = t.update(f, beside(12.0, lateral));
            if f >= 12 {
                assert!(r.decision_speed() > 7.0, "frame {f}: {r:?}");
            }
            last = Some(r);
        }
        let m = last.and_then(|r| r.motion).expect("a motion");
        assert_eq!(
            m.samples as usize,
            crate::perception::motion::WINDOW,
            "{m:?}"
        );
        // Another obstacle at another distance is not the followed car.
        let mut t = tracker();
        for f in 0..20u64 {
            if f > 0 {
                t.moved(8.0 * dt, dt);
            }
            let seen = if f < 15 {
                beside(12.0, 0.85)
            } else {
                beside(9.0, -0.85)
            };
            let r = t.update(f, seen);
            if f == 19 {
                assert_eq!(r.decision_speed(), 0.0, "{r:?}");
            }
        }
    }

    #[test]
    fn a_car_seen_on_one_frame_in_three_keeps_its_motion() {
        // Followed at 8 m/s, 12 m ahead; after 20 frames seen on one frame in three only
        // (released, and every new run broken off after one frame), then again on each.
        let dt = 1.0 / 30.0;
        let mut t = tracker();
        for f in 0..56u64 {
            if f > 0 {
                t.moved(8.0 * dt, dt);
            }
            let seen = (!(20..50).contains(&f) || f % 3 == 0)
                .then(|| beside(12.0, 0.3))
                .flatten();
            let r = t.update(f, seen);
            // Confirmed again on the second frame of the run, with the sightings before it
            // (the last 0.6 s of them: motion::MAX_AGE), and established on the third.
            if f == 51 {
                assert!(
                    r.confirmed && r.motion.is_some_and(|m| m.samples > 2),
                    "{r:?}"
                );
            }
            if f >= 52 {
                assert!(r.confirmed && r.decision_speed() > 7.0, "frame {f}: {r:?}");
            }
        }
    }

    #[test]
    fn two_frames_confirm_three_release() {
        let mut t = tracker();
        // Several estimates on frame 1: one frame, however many generations.
        for _ in 0..5 {
            let r = t.update(1, at(14.0));
            assert!(!r.confirmed && r.seen_frames == 1, "{r:?}");
        }
        let r = t.update(2, at(13.9));
        assert!(r.confirmed && r.seen_frames == 2, "{r:?}");
        assert_eq!(r.confirmed().map(|o| o.distance), Some(13.9));
        // Missing on frames 3 and 4: held at the last distance seen.
        for f in [3, 4] {
            let r = t.update(f, None);
            assert!(r.confirmed, "frame {f}: {r:?}");
            assert_eq!(r.obstacle.map(|o| o.distance), Some(13.9));
        }
        let r = t.update(5, None);
        assert!(!r.confirmed && r.obstacle.is_none(), "{r:?}");
    }

    #[test]
    fn a_frame_saw_the_obstacle_when_one_of_its_estimates_did() {
        let mut t = tracker();
        t.update(1, at(14.0));
        // Frame 1's later estimates miss it: the frame still saw it, at its latest sighting.
        let r = t.update(1, None);
        assert!(!r.confirmed && r.seen_frames == 1, "{r:?}");
        assert_eq!(r.obstacle.map(|o| o.distance), Some(14.0));
        let r = t.update(2, None);
        assert!(r.obstacle.is_none() && r.seen_frames == 0, "{r:?}");
        let r = t.update(2, at(13.9));
        // Frames 1 and 2 both saw it: confirmed.
        assert!(r.confirmed && r.seen_frames == 2, "{r:?}");
    }

    #[test]
    fn a_sighting_on_a_frame_keeps_a_confirmed_obstacle_through_its_later_estimates() {
        // Confirmed on frames 1-2, missed on 3 and 4, seen on 5's first estimate only: held.
        let mut t = tracker();
        t.update(1, at(25.0));
        assert!(t.update(2, at(24.6)).confirmed);
        for f in [3, 4] {
            assert!(t.update(f, None).confirmed, "frame {f}");
        }
        let r = t.update(5, at(24.0));
        assert!(r.confirmed, "{r:?}");
        for _ in 0..3 {
            let r = t.update(5, None);
            assert!(r.confirmed && r.seen_frames == 1, "{r:?}");
            assert_eq!(r.obstacle.map(|o| o.distance), Some(24.0));
        }
        // Frames 6-8 see nothing at all: released on the third.
        assert!(t.update(6, None).confirmed);
        assert!(t.update(7, None).confirmed);
        let r = t.update(8, None);
        assert!(!r.confirmed && r.obstacle.is_none(), "{r:?}");
    }

    #[test]
    fn a_near_obstacle_out_of_nowhere_is_not_confirmed_one_seen_coming_is() {
        // KITTI odometry 06: "obstacles" 1.0-1.9 m ahead on frame after frame, at 43 km/h.
        let mut t = tracker();
        for f in 0..10 {
            t.moved(1.2, 0.1);
            let r = t.update(f, beside(1.0 + 0.1 * (f % 9) as f64, 0.6));
            assert!(!r.confirmed, "frame {f}: {r:?}");
            assert!(r.obstacle.is_some(), "still reported, as seen");
        }
        // A car seen from 9 m on as the vehicle closes in at 1.2 m a frame: confirmed, and
        // kept below the judgeable distance.
        let mut t = tracker();
        for (f, d) in [9.0, 7.8, 6.6, 5.4, 4.2, 3.0, 1.8].into_iter().enumerate() {
            t.moved(1.2, 0.1);
            let r = t.update(f as u64, at(d));
            assert_eq!(r.confirmed, f >= 1, "frame {f} at {d} m: {r:?}");
        }
        // The same car first seen at 4.2 m: never judged.
        let mut t = tracker();
        for (f, d) in [4.2, 3.0, 1.8].into_iter().enumerate() {
            t.moved(1.2, 0.1);
            assert!(!t.update(f as u64, at(d)).confirmed, "frame {f}");
        }
    }

    #[test]
    fn sightings_that_disagree_with_the_motion_confirm_nothing() {
        // A repeated structure matched a period off here, then the truth there: one frame at
        // 8 m, the next at 30 m, and so on; or jumping across the corridor.
        let mut t = tracker();
        for f in 0..12 {
            let d = if f % 2 == 0 { 8.1 } else { 30.0 };
            assert!(!t.update(f, at(d)).confirmed, "frame {f}");
        }
        let mut t = tracker();
        for f in 0..12 {
            let x = if f % 2 == 0 { -1.1 } else { 1.1 };
            t.moved(0.0, 1.0 / 30.0);
            assert!(!t.update(f, beside(12.0, x)).confirmed, "frame {f}");
        }
        // A car 20 m ahead standing still while the vehicle drives at 12 m/s: 1.2 m nearer a
        // frame. Seen 1.2 m nearer each frame it is confirmed; at the same distance (a car
        // driving away at the vehicle's speed) it is too, within max_object_speed.
        for step in [1.2, 0.0] {
            let mut t = tracker();
            t.update(0, at(20.0));
            t.moved(1.2, 0.1);
            assert!(t.update(1, at(20.0 - step)).confirmed, "{step}");
        }
        // 5 m nearer in 0.1 s (50 m/s faster than a still object): another obstacle.
        let mut t = tracker();
        t.update(0, at(20.0));
        t.moved(1.2, 0.1);
        assert!(!t.update(1, at(13.8)).confirmed);
    }

    #[test]
    fn a_held_obstacle_comes_nearer_with_the_vehicle() {
        let mut t = tracker();
        t.update(0, at(20.0));
        t.moved(1.0, 0.1);
        assert!(t.update(1, at(19.0)).confirmed);
        t.moved(1.0, 0.1);
        let r = t.update(2, None);
        assert!(r.confirmed);
        assert_eq!(r.obstacle.map(|o| o.distance), Some(18.0));
        // Its near bound stays half a pixel of disparity nearer.
        let half_px = |d: f64| FB / (FB / d + 0.5);
        let mut t = tracker();
        let seen = |d: f64| {
            at(d).map(|o| Obstacle {
                near: half_px(d),
                ..o
            })
        };
        t.update(0, seen(20.0));
        t.moved(1.0, 0.1);
        assert!(t.update(1, seen(19.0)).confirmed);
        t.moved(1.0, 0.1);
        let held = t.update(2, None).obstacle.expect("held");
        assert!((held.near - half_px(18.0)).abs() < 1e-9, "{held:?}");
    }

    /// A car stopped 20 m ahead, approached at 5 m/s and seen on every frame for 1.2 s, then
    /// missed: held where the vehicle's travel brings it for a second after its last
    /// sighting, then released; one seen for 0.3 s is released after three misses.
    #[test]
    fn a_long_seen_obstacle_is_held_for_a_second_after_its_last_sighting() {
        let run = |seen_frames: u64| {
            let mut t = tracker();
            let dt = 0.1;
            let mut d = 20.0;
            let mut held = Vec::new();
            for f in 0..seen_frames + 15 {
                if f > 0 {
                    t.moved(5.0 * dt, dt);
                    d -= 5.0 * dt;
                }
                let r = t.update(f, (f < seen_frames).then(|| at(d)).flatten());
                if f >= seen_frames {
                    held.push(r.confirmed().map(|o| o.distance));
                }
            }
            held
        };
        let long = run(13);
        // About ten frames after the last sighting (1.0 s) held, coming nearer; then released.
        assert!(long[..9].iter().all(Option::is_some), "{long:?}");
        let first = long[0].expect("held");
        assert!((first - 13.5).abs() < 1e-9, "{long:?}");
        assert!(long[11..].iter().all(Option::is_none), "{long:?}");
        let short = run(4);
        assert!(short[..2].iter().all(Option::is_some), "{short:?}");
        assert!(short[2..].iter().all(Option::is_none), "{short:?}");
    }

    #[test]
    fn one_stray_frame_confirms_nothing() {
        let mut t = tracker();
        for f in 0..20 {
            let seen = if f % 2 == 0 { at(10.0) } else { None };
            assert!(!t.update(f, seen).confirmed, "frame {f}");
        }
    }
}
