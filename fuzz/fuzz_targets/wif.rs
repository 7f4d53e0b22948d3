//! WIF weave drafts: `parse_wif` on the text, read as `read_wif` reads files (lossy UTF-8).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::fabric::wif::parse_wif;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let _ = parse_wif(&text, Path::new("fuzz/draft.wif"));
});
