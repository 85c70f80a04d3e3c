//! Crate-internal macros.

/// An enum of named values with fixed raw numbers: `ALL`, `raw`, `from_raw`, `name` and
/// `Display` (the name). The raw numbers and names are those of `config/flyd.dbc`.
macro_rules! named_enum {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[$vmeta:meta])* $variant:ident = $raw:literal => $label:literal, )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        #[repr(u8)]
        pub enum $name {
            $( $(#[$vmeta])* $variant = $raw, )+
        }

        impl $name {
            /// Every value, in raw order.
            pub const ALL: &'static [Self] = &[$(Self::$variant),+];

            /// The raw value (on the bus, in `config/flyd.dbc`).
            pub const fn raw(self) -> u8 {
                self as u8
            }

            /// `None` for a raw value without a meaning.
            pub const fn from_raw(raw: u8) -> Option<Self> {
                match raw {
                    $( $raw => Some(Self::$variant), )+
                    _ => None,
                }
            }

            /// The name in logs and in the DBC value table (`VAL_`).
            pub const fn name(self) -> &'static str {
                match self {
                    $( Self::$variant => $label, )+
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        }
    };
}

/// A set of named bits in a `u8` (bitflags-like newtype): the flags, `empty`, `all`,
/// `from_bits` (undefined bits dropped), `bits`, `is_empty`, `contains`, `intersects`,
/// `insert`, `remove`, `set`, `names`, the bit operators, and `Display` as `A|B` (`none` when
/// empty). The names are those of `config/flyd.dbc`.
macro_rules! bit_set {
    (
        $(#[$meta:meta])*
        pub struct $name:ident(mask $mask:literal) {
            $( $(#[$fmeta:meta])* const $flag:ident = $bit:literal => $label:literal; )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
        pub struct $name(u8);

        impl $name {
            $( $(#[$fmeta])* pub const $flag: Self = Self(1 << $bit); )+

            const NAMED: &'static [(Self, &'static str)] = &[$((Self::$flag, $label)),+];

            pub const fn empty() -> Self {
                Self(0)
            }

            pub const fn all() -> Self {
                Self($mask)
            }

            /// The set of `bits`; bits without a meaning are dropped.
            pub const fn from_bits(bits: u8) -> Self {
                Self(bits & $mask)
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
                    .iter()
                    .filter(move |(flag, _)| self.contains(*flag))
                    .map(|(_, name)| *name)
            }
        }

        impl std::ops::BitOr for $name {
            type Output = Self;
            fn bitor(self, rhs: Self) -> Self {
                Self(self.0 | rhs.0)
            }
        }

        impl std::ops::BitOrAssign for $name {
            fn bitor_assign(&mut self, rhs: Self) {
                self.0 |= rhs.0;
            }
        }

        impl std::ops::BitAnd for $name {
            type Output = Self;
            fn bitand(self, rhs: Self) -> Self {
                Self(self.0 & rhs.0)
            }
        }

        impl std::ops::BitAndAssign for $name {
            fn bitand_assign(&mut self, rhs: Self) {
                self.0 &= rhs.0;
            }
        }

        impl std::ops::Not for $name {
            type Output = Self;
            fn not(self) -> Self {
                Self(!self.0 & $mask)
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
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

        impl std::fmt::Debug for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "{}({self})", stringify!($name))
            }
        }
    };
}
