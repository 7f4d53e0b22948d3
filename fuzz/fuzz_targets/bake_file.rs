//! Bake files: `BakeFile::parse` on the bytes as given, then again with the header's body length
//! and checksum made to fit the bytes, so that the fuzzer reaches the section directory (almost
//! every mutation would otherwise stop at the checksum).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::bake::file::{BakeFile, HEADER_LEN};

/// Where the header keeps the body length and the checksum.
const BODY_LEN_AT: usize = 48;
const CHECKSUM_AT: usize = 64;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz/bake.twillbake");
    let _ = BakeFile::parse(path, data);
    if data.len() < HEADER_LEN {
        return;
    }
    let mut fixed = data.to_vec();
    let body_len = (data.len() - HEADER_LEN) as u64;
    fixed[BODY_LEN_AT..BODY_LEN_AT + 8].copy_from_slice(&body_len.to_le_bytes());
    let mut hasher = blake3::Hasher::new();
    hasher.update(&fixed[..CHECKSUM_AT]);
    hasher.update(&fixed[HEADER_LEN..]);
    fixed[CHECKSUM_AT..HEADER_LEN].copy_from_slice(hasher.finalize().as_bytes());
    if let Ok(file) = BakeFile::parse(path, &fixed) {
        for section in file.sections() {
            let count: u64 = section.array.shape().iter().product();
            assert_eq!(count, section.array.data().len() as u64, "section {:?}", section.name);
        }
    }
});
