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
