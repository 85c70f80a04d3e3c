//! An error and its causes on one line, the way a user reads them.
//!
//! flyd's errors name what failed in their own message and keep the cause as their
//! [`std::error::Error::source`]; [`Chain`] prints the message, then each cause after ": ".
//! A cause whose text the message before it already contains is printed once: some foreign
//! errors (the `image` crate's) put their cause into their own message as well.

use std::error::Error;
use std::fmt;

/// `error` and its causes, `a: b: c` (see the module docs); for logs: `error = %Chain(&e)`.
#[derive(Clone, Copy)]
pub struct Chain<'a>(pub &'a (dyn Error + 'static));

impl fmt::Display for Chain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut previous = String::new();
        let mut first = true;
        let mut next: Option<&(dyn Error + 'static)> = Some(self.0);
        while let Some(cause) = next {
            next = cause.source();
            let text = cause.to_string();
            if !previous.contains(&text) {
                if !first {
                    f.write_str(": ")?;
                }
                f.write_str(&text)?;
                first = false;
            }
            previous = text;
        }
        Ok(())
    }
}

impl fmt::Debug for Chain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

/// [`Chain`] as a `String`.
pub fn chain(error: &(dyn Error + 'static)) -> String {
    Chain(error).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Layer(&'static str, Option<Box<Layer>>);
    impl fmt::Display for Layer {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str(self.0)
        }
    }
    impl Error for Layer {
        fn source(&self) -> Option<&(dyn Error + 'static)> {
            self.1.as_deref().map(|l| l as _)
        }
    }

    #[test]
    fn a_chain_names_each_cause_once() {
        let repeated = Layer(
            "x.png: bad signature",
            Some(Box::new(Layer("bad signature", None))),
        );
        assert_eq!(chain(&repeated), "x.png: bad signature");
        let context = Layer(
            "cannot start the engine",
            Some(Box::new(Layer("parameter 'flies': too few", None))),
        );
        assert_eq!(
            chain(&context),
            "cannot start the engine: parameter 'flies': too few"
        );
        assert_eq!(chain(&Layer("alone", None)), "alone");
    }
}
