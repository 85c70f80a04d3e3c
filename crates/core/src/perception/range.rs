//! How far ahead the flies search and the obstacle stage looks, from the speed the decision
//! uses, and how well the rig resolves depth there.
//!
//! The configured ranges (`engine.max_depth`, `engine.roi.max_ahead`,
//! `perception.obstacle.max_distance`) are checked at start-up to reach the SLOW distance at
//! `vehicle.assumed_speed_kmh`. A vehicle that reports a higher speed needs more: with
//! [`SearchReach`] the ranges reach the SLOW distance at the measured speed, never less than
//! configured and never beyond what the rig searches ([`SearchReach::cap`]).
//!
//! **The resolution rule.** One pixel of disparity at depth `Z` is `Z^2 / (f B)` metres of
//! depth ([`depth_error_per_pixel`]); the rig resolves a distance when that error is within
//! the decision's margin, i.e. up to `sqrt(margin f B)` ([`resolved_distance`]). Beyond it an
//! obstacle is still found, but its distance is uncertain by more than the margin kept in
//! front of the vehicle. (hw-mock's 640x480 rig, f B = 156 px m: 17.7 m with the 2 m margin;
//! KITTI's, f B = 389: 27.9 m; the SLOW distance at 30 km/h is 29.3 m.)

use crate::decision::{Command, DecisionConfig};

/// Disparity, pixels, at the farthest depth searched: beyond `f B / 2 px` one pixel of
/// disparity is half the depth or more, and a fly's depth says little.
pub const MIN_SEARCH_DISPARITY_PX: f64 = 2.0;

/// The depth error of one pixel of disparity at `depth` metres, for a rig of `fb` (focal
/// length in pixels times baseline in metres): `Z^2 / (f B)`.
pub fn depth_error_per_pixel(fb: f64, depth: f64) -> f64 {
    depth * depth / fb
}

/// The farthest depth at which one pixel of disparity is at most `margin` metres of depth:
/// `sqrt(margin f B)`.
pub fn resolved_distance(fb: f64, margin: f64) -> f64 {
    (margin * fb).sqrt()
}

/// How well a rig resolves the SLOW distance at a speed (the rule in the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resolution {
    /// The speed, m/s.
    pub speed: f64,
    /// The SLOW distance at that speed, metres.
    pub slow_distance: f64,
    /// One pixel of disparity there, metres of depth.
    pub error_per_pixel: f64,
    /// The decision's margin, metres.
    pub margin: f64,
    /// The farthest distance resolved within the margin, metres.
    pub resolved: f64,
}

impl Resolution {
    /// The rule for a rig of `fb` (f B, pixel metres) at `speed` m/s under `decision`.
    pub fn at(decision: &DecisionConfig, fb: f64, speed: f64) -> Self {
        let slow_distance = decision.reach(Command::Slow, speed.abs());
        Self {
            speed,
            slow_distance,
            error_per_pixel: depth_error_per_pixel(fb, slow_distance),
            margin: decision.margin,
            resolved: resolved_distance(fb, decision.margin),
        }
    }

    /// Whether one pixel of disparity at the SLOW distance is within the margin.
    pub fn enough(&self) -> bool {
        self.error_per_pixel <= self.margin
    }
}

/// The search range as the speed asks for it: the SLOW distance at the speed the decision
/// uses, capped by what the rig searches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchReach {
    decision: DecisionConfig,
    cap: f64,
}

impl SearchReach {
    /// The reach the decision `decision` asks for on a rig of `fb` (f B, pixel metres).
    pub fn new(decision: DecisionConfig, fb: f64) -> Self {
        Self {
            decision,
            cap: fb / MIN_SEARCH_DISPARITY_PX,
        }
    }

    /// The farthest the flies may search on this rig, metres: the depth of
    /// [`MIN_SEARCH_DISPARITY_PX`] of disparity.
    pub fn cap(&self) -> f64 {
        self.cap
    }

    /// How far ahead to search at `speed` m/s (either direction's magnitude; a non-finite
    /// speed asks for nothing beyond the configured ranges): the SLOW distance, at most
    /// [`SearchReach::cap`].
    pub fn at(&self, speed: f64) -> f64 {
        if !speed.is_finite() {
            return 0.0;
        }
        self.decision
            .reach(Command::Slow, speed.abs())
            .min(self.cap)
    }

    /// Whether the SLOW distance at `speed` lies beyond what the rig searches.
    pub fn beyond_cap(&self, speed: f64) -> bool {
        self.decision.reach(Command::Slow, speed.abs()) > self.cap
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rule_on_the_mock_and_kitti_rigs() {
        // hw-mock 640x480: f = 520 px, B = 0.3 m.
        let mock = 520.0 * 0.3;
        assert!((resolved_distance(mock, 2.0) - 17.66).abs() < 0.01);
        assert!((depth_error_per_pixel(mock, resolved_distance(mock, 2.0)) - 2.0).abs() < 1e-9);
        // KITTI: f = 721.5 px, B = 0.54 m.
        assert!((resolved_distance(721.5 * 0.54, 2.0) - 27.9).abs() < 0.05);
        // The SLOW distance at 30 km/h with the defaults is beyond both.
        let d = DecisionConfig::default().reach(Command::Slow, 30.0 / 3.6);
        assert!(depth_error_per_pixel(mock, d) > 2.0 * 2.0, "{d}");
    }

    #[test]
    fn the_resolution_at_a_speed() {
        let decision = DecisionConfig::default();
        let mock = Resolution::at(&decision, 156.0, 30.0 / 3.6);
        assert!(!mock.enough(), "{mock:?}");
        assert!((mock.error_per_pixel - 29.3f64.powi(2) / 156.0).abs() < 0.1);
        // A rig of f B = 500 px m resolves 31.6 m: 30 km/h's SLOW distance within the margin.
        assert!(Resolution::at(&decision, 500.0, 30.0 / 3.6).enough());
        assert!(!Resolution::at(&decision, 500.0, 40.0 / 3.6).enough());
    }

    #[test]
    fn the_reach_follows_the_speed_up_to_the_cap() {
        let decision = DecisionConfig::default();
        let reach = SearchReach::new(decision, 520.0 * 0.3);
        assert_eq!(reach.cap(), 78.0);
        let at = |kmh: f64| reach.at(kmh / 3.6);
        // 30 km/h: the SLOW distance itself; 43 km/h (the KITTI drive): farther.
        assert!((at(30.0) - decision.reach(Command::Slow, 30.0 / 3.6)).abs() < 1e-9);
        assert!(at(43.0) > at(30.0) + 15.0, "{} {}", at(43.0), at(30.0));
        // Reversing asks as much as driving forward; a fast vehicle is capped.
        assert_eq!(at(-30.0), at(30.0));
        assert_eq!(at(120.0), 78.0);
        assert!(reach.beyond_cap(120.0 / 3.6) && !reach.beyond_cap(30.0 / 3.6));
        assert_eq!(reach.at(f64::NAN), 0.0);
    }
}
