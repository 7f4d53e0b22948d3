//! Yarn colour orders: which palette colour each warp end or weft pick of a repeat carries.
//!
//! How it works: an order is written the way a designer says it, `"2 navy, 2 cream, 1 red"`:
//! comma-separated runs of `COUNT NAME` (the count may be left out for 1), names from the
//! palette. [`ColourOrder::parse`] turns it into one palette index per thread. The colour
//! repeat and the weave repeat together set the exemplar's repeat: the least common multiple of
//! the two, per direction ([`exemplar_repeat`]), refused past [`MAX_REPEAT_THREADS`] with the
//! numbers that gave it.

use std::fmt;

use crate::params::ParamError;

/// The most threads an exemplar repeat holds in one direction (the weave draft's own limit).
pub const MAX_REPEAT_THREADS: usize = super::weave::WeaveDraft::MAX_SIZE;

/// One colour order: a palette index per thread of the colour repeat.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ColourOrder {
    threads: Vec<u32>,
}

impl ColourOrder {
    /// Parses `text` against the palette's names (`names[k]` is palette index `k`). `what`
    /// names the order in errors (`warp_order`).
    ///
    /// # Errors
    /// An empty order or run, a count that is not a whole number in `1..=MAX_REPEAT_THREADS`,
    /// a name not in the palette (the known ones are listed), or more than
    /// `MAX_REPEAT_THREADS` threads in all.
    pub fn parse(what: &str, text: &str, names: &[&str]) -> Result<Self, ParamError> {
        let mut threads = Vec::new();
        for (k, run) in text.split(',').enumerate() {
            let run = run.trim();
            let bad =
                |reason: String| ParamError::new(format!("{what} run {}", k + 1), format!("{run:?}"), reason);
            if run.is_empty() {
                return Err(bad("a run `COUNT NAME`, e.g. \"2 navy\" (runs are separated by commas)".into()));
            }
            let (count, name) = match run.split_once(char::is_whitespace) {
                Some((count, name)) if count.chars().all(|c| c.is_ascii_digit()) => {
                    let count: usize =
                        count.parse().map_err(|_| bad(format!("1 <= count <= {MAX_REPEAT_THREADS}")))?;
                    (count, name.trim())
                }
                _ => (1, run),
            };
            if !(1..=MAX_REPEAT_THREADS).contains(&count) {
                return Err(bad(format!("1 <= count <= {MAX_REPEAT_THREADS}")));
            }
            let Some(index) = names.iter().position(|n| *n == name) else {
                return Err(bad(format!("a palette colour: one of {}", names.join(", "))));
            };
            threads.extend(std::iter::repeat_n(index as u32, count));
            if threads.len() > MAX_REPEAT_THREADS {
                return Err(ParamError::new(
                    what,
                    format!("{text:?} ({}+ threads)", threads.len()),
                    format!("at most {MAX_REPEAT_THREADS} threads in one colour repeat"),
                ));
            }
        }
        Ok(Self { threads })
    }

    /// An order of one colour per thread, as given (`threads` not empty, at most
    /// `MAX_REPEAT_THREADS`).
    ///
    /// # Errors
    /// An empty or too long list.
    pub fn from_threads(what: &str, threads: Vec<u32>) -> Result<Self, ParamError> {
        if threads.is_empty() || threads.len() > MAX_REPEAT_THREADS {
            return Err(ParamError::new(what, threads.len(), format!("1 to {MAX_REPEAT_THREADS} threads")));
        }
        Ok(Self { threads })
    }

    /// The palette index of each thread of the colour repeat.
    #[must_use]
    pub fn threads(&self) -> &[u32] {
        &self.threads
    }

    /// The palette index of thread `i` of the cloth (the order repeats).
    #[must_use]
    pub fn colour_of(&self, i: usize) -> u32 {
        self.threads[i % self.threads.len()]
    }

    /// The order written back as runs, with the palette's names (`"2 navy, 1 red"`).
    #[must_use]
    pub fn display<'a>(&'a self, names: &'a [&'a str]) -> impl fmt::Display + 'a {
        struct Runs<'a>(&'a [u32], &'a [&'a str]);
        impl fmt::Display for Runs<'_> {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                let mut first = true;
                for run in self.0.chunk_by(|a, b| a == b) {
                    if !first {
                        f.write_str(", ")?;
                    }
                    first = false;
                    let name = self.1.get(run[0] as usize).copied().unwrap_or("?");
                    write!(f, "{} {name}", run.len())?;
                }
                Ok(())
            }
        }
        Runs(&self.threads, names)
    }
}

/// Threads in the exemplar repeat along one direction: the least common multiple of the
/// weave's repeat `weave` and the colour repeat `colours`.
///
/// # Errors
/// When it exceeds `MAX_REPEAT_THREADS`, naming `what` (`warp_order`) and both repeats.
pub fn exemplar_repeat(what: &str, weave: usize, colours: usize) -> Result<usize, ParamError> {
    let repeat = weave / gcd(weave, colours) * colours;
    if repeat > MAX_REPEAT_THREADS {
        return Err(ParamError::new(
            what,
            format!("{colours} threads against the weave's {weave} (they repeat together every {repeat})"),
            format!(
                "a joint repeat of at most {MAX_REPEAT_THREADS} threads: choose a colour repeat that \
                 divides or shares factors with {weave}"
            ),
        ));
    }
    Ok(repeat)
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAMES: [&str; 3] = ["navy", "cream", "red"];

    #[test]
    fn orders_parse_into_one_colour_per_thread_and_print_back() {
        let order = ColourOrder::parse("warp_order", "2 navy, 2 cream, red", &NAMES).unwrap();
        assert_eq!(order.threads(), &[0, 0, 1, 1, 2]);
        assert_eq!(order.colour_of(7), 1);
        assert_eq!(order.display(&NAMES).to_string(), "2 navy, 2 cream, 1 red");
        let spaced = ColourOrder::parse("weft_order", "  3   red ,1 navy", &NAMES).unwrap();
        assert_eq!(spaced.threads(), &[2, 2, 2, 0]);
    }

    #[test]
    fn bad_orders_name_the_run_the_value_and_what_is_valid() {
        for (text, expect) in [
            ("2 navy, , 1 red", "warp_order run 2"),
            ("2 teal", "one of navy, cream, red"),
            ("0 navy", "1 <= count <= 64"),
            ("99999999999999999999999 navy", "1 <= count <= 64"),
            ("40 navy, 40 red", "at most 64 threads"),
            ("", "warp_order run 1"),
        ] {
            let message = ColourOrder::parse("warp_order", text, &NAMES).unwrap_err().to_string();
            assert!(message.contains(expect), "{text:?}: {message}");
        }
    }

    #[test]
    fn the_exemplar_repeat_is_the_least_common_multiple_within_the_limit() {
        assert_eq!(exemplar_repeat("warp_order", 4, 6).unwrap(), 12);
        assert_eq!(exemplar_repeat("warp_order", 4, 2).unwrap(), 4);
        assert_eq!(exemplar_repeat("warp_order", 3, 1).unwrap(), 3);
        assert_eq!(exemplar_repeat("warp_order", 8, 64).unwrap(), 64);
        let message = exemplar_repeat("weft_order", 4, 17).unwrap_err().to_string();
        assert!(
            message.contains("weft_order") && message.contains("every 68") && message.contains("64"),
            "{message}"
        );
    }
}
