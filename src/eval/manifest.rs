//! The manifest `flyd eval` reads: labelled recordings, one `[[item]]` each.
//!
//! ```toml
//! data = "../tests/fixtures/kitti"   # where the items' folders are (relative to this file)
//!
//! [[item]]
//! name = "seq12_frame11"
//! pair = "kitti_raw_2011_09_26_seq12" # a folder: im0.png + im1.png, or left/ + right/ with `frame`
//! frame = "000011.png"
//! mount = [-0.06, 1.65, 0.0]          # the folder's calib.txt, the left camera placed there
//! expect = "stop"
//! distance = 13.8
//! tolerance = 0.7
//! ```
//!
//! An item is a still `pair`, a `sequence` folder (with its `poses.txt` as the vehicle's
//! motion) or a hw-mock `scenario`. Its rig is `rig` (any calibration flyd reads, relative to
//! the item's folder) or the folder's `calib.txt` placed on the vehicle at `mount`. Labels
//! (`expect`), judged on the frames after the warm-up (within `frames = [first, last]` when
//! given):
//! - `clear`: no SLOW and no STOP from the perception, CLEAR at the end;
//! - `no-stop`: no STOP from the perception;
//! - `nothing-nearer`: no confirmed obstacle nearer than `distance` m;
//! - `stop`: STOP at the end, the confirmed obstacle at `distance` m within `tolerance`;
//! - `stop-within`: the first STOP at most `generations` generations after the scenario's
//!   obstacle appears;
//! - `stop-before`: the first STOP while the obstacle, `from` m ahead at frame 0 with the
//!   vehicle at `kmh`, is still farther than `stopping` m.
//!
//! Closed-loop cases (hw-mock's vehicle obeys the commands: [`crate::replay::closed_loop`])
//! come from case files the manifest names, `cases = ["closed-loop/stationary.toml"]`
//! (relative to it; the format is hw-mock's [`hw_mock::closed_loop`], documented in
//! docs/closed-loop.md), each case an item with its own label, judged by outcome:
//! - `no-contact`: the vehicle never touched an actor;
//! - `impact-below`: no contact, or one slower than `impact_kmh`;
//! - `no-activation`: no SLOW and no STOP once the system was armed;
//! - `peak-decel-below`: the brakes never gave `decel` m/s^2 or more.

use serde::Deserialize;
use std::path::{Path, PathBuf};

/// A manifest as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Where the items' folders are, relative to the manifest (`--data` overrides it).
    pub data: Option<PathBuf>,
    /// Closed-loop case files, relative to the manifest: each case an item.
    #[serde(default)]
    pub cases: Vec<PathBuf>,
    #[serde(rename = "item", default)]
    pub items: Vec<Item>,
}

/// One labelled recording.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Item {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pair: Option<String>,
    /// With `pair`: the file name in the folder's left/ and right/.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sequence: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scenario: Option<String>,
    /// A calibration file, relative to the item's folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rig: Option<String>,
    /// Where the left camera of the folder's `calib.txt` sits on the vehicle, metres (x right,
    /// y up, z ahead).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mount: Option<[f64; 3]>,
    /// A disparity map of the left image (PFM, relative to the item's folder: KITTI's and
    /// Middlebury's `disp0.pfm`): each run then reports how many of the flies obstacles are
    /// built from agree with it ([`super::outcome::Accuracy`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub truth: Option<String>,
    /// A sequence's motion from this candump log of the vehicle's bus, relative to its
    /// folder (default: the folder's poses.txt, if any).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub can_input: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speed_kmh: Option<f64>,
    /// A sequence's frame rate (default 10).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    /// A scenario's image size, `WxH` (default 640x480).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flies: Option<usize>,
    pub expect: Expect,
    /// The frames judged, first and last (inclusive; default: all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<[u64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generations: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kmh: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopping: Option<f64>,
    /// `impact-below`: the impact speed a contact must stay under, km/h.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub impact_kmh: Option<f64>,
    /// `peak-decel-below`: the deceleration the brakes must stay under, m/s^2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decel: Option<f64>,
    /// A closed-loop case (from the manifest's `cases`, not written in an item).
    #[serde(skip)]
    pub case: Option<Box<hw_mock::closed_loop::Case>>,
}

/// What an item must show.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Expect {
    Clear,
    NoStop,
    NothingNearer,
    Stop,
    StopWithin,
    StopBefore,
    NoContact,
    ImpactBelow,
    NoActivation,
    PeakDecelBelow,
}

impl Expect {
    pub fn name(self) -> &'static str {
        match self {
            Self::Clear => "clear",
            Self::NoStop => "no-stop",
            Self::NothingNearer => "nothing-nearer",
            Self::Stop => "stop",
            Self::StopWithin => "stop-within",
            Self::StopBefore => "stop-before",
            Self::NoContact => "no-contact",
            Self::ImpactBelow => "impact-below",
            Self::NoActivation => "no-activation",
            Self::PeakDecelBelow => "peak-decel-below",
        }
    }

    /// The label of this name.
    pub fn named(name: &str) -> Option<Self> {
        [
            Self::Clear,
            Self::NoStop,
            Self::NothingNearer,
            Self::Stop,
            Self::StopWithin,
            Self::StopBefore,
            Self::NoContact,
            Self::ImpactBelow,
            Self::NoActivation,
            Self::PeakDecelBelow,
        ]
        .into_iter()
        .find(|e| e.name() == name)
    }

    /// Whether the label judges a closed loop's outcome.
    pub fn closed_loop(self) -> bool {
        matches!(
            self,
            Self::NoContact | Self::ImpactBelow | Self::NoActivation | Self::PeakDecelBelow
        )
    }

    /// Whether the item holds an obstacle the vehicle must stop for (the others hold none
    /// that it must brake for: every SLOW or STOP there is a false one).
    pub fn wants_stop(self) -> bool {
        matches!(
            self,
            Self::Stop | Self::StopWithin | Self::StopBefore | Self::NoContact | Self::ImpactBelow
        )
    }
}

/// A manifest that cannot be used, with the item and key at fault.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    #[error("{path}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Parse { path: String, message: String },
    #[error("{path}: item '{item}': {message}")]
    Item {
        path: String,
        item: String,
        message: String,
    },
}

impl Manifest {
    /// Reads and checks `path`.
    pub fn load(path: &Path) -> Result<Self, ManifestError> {
        let text = std::fs::read_to_string(path).map_err(|source| ManifestError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let mut manifest: Self = toml::from_str(&text).map_err(|e| ManifestError::Parse {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        for file in manifest.cases.clone() {
            let items = case_items(&base.join(&file))?;
            manifest.items.extend(items);
        }
        manifest.check(path)?;
        Ok(manifest)
    }

    fn check(&self, path: &Path) -> Result<(), ManifestError> {
        let error = |item: &Item, message: String| ManifestError::Item {
            path: path.display().to_string(),
            item: item.name.clone(),
            message,
        };
        if self.items.is_empty() {
            return Err(ManifestError::Parse {
                path: path.display().to_string(),
                message: "no [[item]]".into(),
            });
        }
        for (i, item) in self.items.iter().enumerate() {
            if self.items[..i].iter().any(|o| o.name == item.name) {
                return Err(error(item, "a second item of that name".into()));
            }
            let sources = [&item.pair, &item.sequence, &item.scenario]
                .iter()
                .filter(|s| s.is_some())
                .count()
                + usize::from(item.case.is_some());
            if sources != 1 {
                return Err(error(
                    item,
                    "needs exactly one of pair, sequence, scenario".into(),
                ));
            }
            if item.expect.closed_loop() != item.case.is_some() {
                return Err(error(
                    item,
                    format!(
                        "expect = \"{}\" {}",
                        item.expect.name(),
                        if item.case.is_some() {
                            "judges no closed loop's outcome"
                        } else {
                            "belongs to a closed-loop case (a manifest's `cases`)"
                        }
                    ),
                ));
            }
            if item.scenario.is_none()
                && item.case.is_none()
                && item.rig.is_none() == item.mount.is_none()
            {
                return Err(error(
                    item,
                    "needs its rig: `rig` (a calibration file) or `mount` (the folder's \
                     calib.txt placed on the vehicle), not both"
                        .into(),
                ));
            }
            if item.frame.is_some() && item.pair.is_none() {
                return Err(error(item, "`frame` belongs to a pair".into()));
            }
            if item.truth.is_some() && item.pair.is_none() {
                return Err(error(item, "`truth` belongs to a pair".into()));
            }
            if let Some(size) = &item.size {
                parse_size(size)
                    .ok_or_else(|| error(item, format!("size '{size}': expected WIDTHxHEIGHT")))?;
            }
            if let Some([first, last]) = item.frames
                && first > last
            {
                return Err(error(
                    item,
                    format!("frames [{first}, {last}]: first > last"),
                ));
            }
            let needs: &[(&str, bool)] = match item.expect {
                Expect::Clear | Expect::NoStop => &[],
                Expect::NothingNearer => &[("distance", item.distance.is_some())],
                Expect::Stop => &[
                    ("distance", item.distance.is_some()),
                    ("tolerance", item.tolerance.is_some()),
                ],
                Expect::StopWithin => &[
                    ("generations", item.generations.is_some()),
                    ("scenario", item.scenario.is_some()),
                ],
                Expect::StopBefore => &[
                    ("from", item.from.is_some()),
                    ("kmh", item.kmh.is_some()),
                    ("stopping", item.stopping.is_some()),
                ],
                Expect::NoContact | Expect::NoActivation => &[],
                Expect::ImpactBelow => &[("impact_kmh", item.impact_kmh.is_some())],
                Expect::PeakDecelBelow => &[("decel", item.decel.is_some())],
            };
            if let Some((key, _)) = needs.iter().find(|(_, given)| !given) {
                return Err(error(
                    item,
                    format!("expect = \"{}\" needs `{key}`", item.expect.name()),
                ));
            }
        }
        Ok(())
    }
}

/// The items of a closed-loop case file: each case one, its label its own.
fn case_items(path: &Path) -> Result<Vec<Item>, ManifestError> {
    let text = std::fs::read_to_string(path).map_err(|source| ManifestError::Read {
        path: path.display().to_string(),
        source,
    })?;
    let parse = |message: String| ManifestError::Parse {
        path: path.display().to_string(),
        message,
    };
    let file: hw_mock::closed_loop::CaseFile =
        toml::from_str(&text).map_err(|e| parse(e.to_string()))?;
    let cases = file.cases().map_err(|e| parse(e.to_string()))?;
    cases
        .into_iter()
        .map(|case| {
            let expect = Expect::named(&case.expect)
                .ok_or_else(|| parse(format!("case '{}': unknown label", case.name)))?;
            Ok(Item {
                name: case.name.clone(),
                expect,
                impact_kmh: case.impact_kmh,
                decel: case.decel,
                case: Some(Box::new(case)),
                ..Item::empty()
            })
        })
        .collect()
}

impl Item {
    /// An item of no source and the label `clear`, to be filled in.
    fn empty() -> Self {
        Self {
            name: String::new(),
            pair: None,
            frame: None,
            sequence: None,
            scenario: None,
            rig: None,
            mount: None,
            truth: None,
            can_input: None,
            speed_kmh: None,
            fps: None,
            size: None,
            flies: None,
            expect: Expect::Clear,
            frames: None,
            distance: None,
            tolerance: None,
            generations: None,
            from: None,
            kmh: None,
            stopping: None,
            impact_kmh: None,
            decel: None,
            case: None,
        }
    }
}

/// `WxH` as numbers.
pub fn parse_size(size: &str) -> Option<(u32, u32)> {
    let (w, h) = size.split_once('x')?;
    let (w, h) = (w.trim().parse().ok()?, h.trim().parse().ok()?);
    (w > 0 && h > 0).then_some((w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Manifest, ManifestError> {
        let m: Manifest = toml::from_str(text).map_err(|e| ManifestError::Parse {
            path: "m.toml".into(),
            message: e.to_string(),
        })?;
        m.check(Path::new("m.toml"))?;
        Ok(m)
    }

    #[test]
    fn a_label_without_its_values_names_the_item_and_key() {
        let e = parse(
            "[[item]]\nname = \"car\"\npair = \"p\"\nmount = [0.0, 1.65, 0.0]\nexpect = \"stop\"\ndistance = 12.0\n",
        )
        .expect_err("no tolerance");
        assert_eq!(
            e.to_string(),
            "m.toml: item 'car': expect = \"stop\" needs `tolerance`"
        );
    }

    #[test]
    fn an_item_needs_one_source_and_one_rig() {
        let e = parse("[[item]]\nname = \"a\"\npair = \"p\"\nsequence = \"s\"\nmount = [0.0, 1.6, 0.0]\nexpect = \"clear\"\n")
            .expect_err("two sources");
        assert!(e.to_string().contains("exactly one of"), "{e}");
        let e = parse("[[item]]\nname = \"a\"\npair = \"p\"\nexpect = \"clear\"\n")
            .expect_err("no rig");
        assert!(e.to_string().contains("needs its rig"), "{e}");
        let e = parse("[[item]]\nname = \"a\"\nscenario = \"driving\"\nexpect = \"maybe\"\n")
            .expect_err("unknown label");
        assert!(e.to_string().contains("maybe"), "{e}");
        parse("[[item]]\nname = \"a\"\nscenario = \"driving\"\nsize = \"320x240\"\nexpect = \"clear\"\n")
            .expect("a scenario needs no rig");
    }

    #[test]
    fn shipped_manifests_are_valid() {
        for m in [
            "eval/real.toml",
            "eval/fixtures.toml",
            "eval/hw-mock.toml",
            "eval/closed-loop.toml",
            "eval/traffic.toml",
        ] {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(m);
            let manifest = Manifest::load(&path).unwrap_or_else(|e| panic!("{m}: {e}"));
            assert!(manifest.items.len() >= 10, "{m}");
        }
    }
}
