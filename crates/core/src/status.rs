//! What flyd reports about itself in `FLYD_Status`: its [`State`] and its [`FaultBits`].

use std::fmt;
use std::ops::{BitAnd, BitAndAssign, BitOr, BitOrAssign, Not};

named_enum! {
    /// flyd's own state.
    pub enum State {
        Init = 0 => "INIT",
        Running = 1 => "RUNNING",
        /// Running with at least one fault bit set; commands fall back to the safe command.
        Degraded = 2 => "DEGRADED",
        /// Cannot produce perception at all.
        Fault = 3 => "FAULT",
        Shutdown = 4 => "SHUTDOWN",
    }
}

/// The `FaultBits` signal: one bit per fault, any combination (bitflags-like newtype; all 8 bits
/// are defined, so every `u8` is a valid value).
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct FaultBits(u8);

impl FaultBits {
    /// bit 0: no fresh frame from the left camera.
    pub const LEFT_CAMERA_STALE: Self = Self(1 << 0);
    /// bit 1: no fresh frame from the right camera.
    pub const RIGHT_CAMERA_STALE: Self = Self(1 << 1);
    /// bit 2: left and right frames too far apart in time to be a stereo pair.
    pub const STEREO_SKEW: Self = Self(1 << 2);
    /// bit 3: the evolution cannot keep its generation rate.
    pub const EVOLUTION_OVERRUN: Self = Self(1 << 3);
    /// bit 4: the newest perception snapshot is too old.
    pub const SNAPSHOT_STALE: Self = Self(1 << 4);
    /// bit 5: a camera reports a wrong format or a device error, or the stereo pair matches
    /// nowhere (perception blind: a camera delivering noise or covered).
    pub const CAMERA_ERROR: Self = Self(1 << 5);
    /// bit 6: CAN transmission errors.
    pub const CAN_TX_ERROR: Self = Self(1 << 6);
    /// bit 7: configuration or internal error.
    pub const INTERNAL: Self = Self(1 << 7);

    const NAMED: [(Self, &'static str); 8] = [
        (Self::LEFT_CAMERA_STALE, "LEFT_CAMERA_STALE"),
        (Self::RIGHT_CAMERA_STALE, "RIGHT_CAMERA_STALE"),
        (Self::STEREO_SKEW, "STEREO_SKEW"),
        (Self::EVOLUTION_OVERRUN, "EVOLUTION_OVERRUN"),
        (Self::SNAPSHOT_STALE, "SNAPSHOT_STALE"),
        (Self::CAMERA_ERROR, "CAMERA_ERROR"),
        (Self::CAN_TX_ERROR, "CAN_TX_ERROR"),
        (Self::INTERNAL, "INTERNAL"),
    ];

    pub const fn empty() -> Self {
        Self(0)
    }

    pub const fn all() -> Self {
        Self(0xFF)
    }

    pub const fn from_bits(bits: u8) -> Self {
        Self(bits)
    }

    pub const fn bits(self) -> u8 {
        self.0
    }

    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// All bits of `other` are set in `self`.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// At least one bit of `other` is set in `self`.
    pub const fn intersects(self, other: Self) -> bool {
        self.0 & other.0 != 0
    }

    pub fn insert(&mut self, other: Self) {
        self.0 |= other.0;
    }

    pub fn remove(&mut self, other: Self) {
        self.0 &= !other.0;
    }

    pub fn set(&mut self, other: Self, on: bool) {
        if on {
            self.insert(other);
        } else {
            self.remove(other);
        }
    }

    /// Names of the set bits, bit 0 first.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        Self::NAMED
            .into_iter()
            .filter(move |(flag, _)| self.contains(*flag))
            .map(|(_, name)| name)
    }
}

impl BitOr for FaultBits {
    type Output = Self;
    fn bitor(self, rhs: Self) -> Self {
        Self(self.0 | rhs.0)
    }
}

impl BitOrAssign for FaultBits {
    fn bitor_assign(&mut self, rhs: Self) {
        self.0 |= rhs.0;
    }
}

impl BitAnd for FaultBits {
    type Output = Self;
    fn bitand(self, rhs: Self) -> Self {
        Self(self.0 & rhs.0)
    }
}

impl BitAndAssign for FaultBits {
    fn bitand_assign(&mut self, rhs: Self) {
        self.0 &= rhs.0;
    }
}

impl Not for FaultBits {
    type Output = Self;
    fn not(self) -> Self {
        Self(!self.0)
    }
}

impl fmt::Display for FaultBits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_empty() {
            return f.write_str("none");
        }
        for (i, name) in self.names().enumerate() {
            if i > 0 {
                f.write_str("|")?;
            }
            f.write_str(name)?;
        }
        Ok(())
    }
}

impl fmt::Debug for FaultBits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FaultBits({self})")
    }
}
