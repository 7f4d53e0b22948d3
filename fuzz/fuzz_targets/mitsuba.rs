//! Mitsuba curve text: `parse_mitsuba` on any UTF-8 text, with and without a default radius.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::fabric::fiber_io::parse_mitsuba;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = Path::new("fuzz/fibers.txt");
    for default_radius in [None, Some(0.01)] {
        if let Ok(fibers) = parse_mitsuba(text, path, default_radius) {
            assert!(fibers.iter().all(|f| f.points.len() >= 2 && f.radius > 0.0 && f.radius.is_finite()));
        }
    }
});
