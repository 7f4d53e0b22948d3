//! PNG pattern maps: `PatternMap::from_png_bytes` on the bytes as given, then again with every
//! chunk's CRC made to fit its contents, so that the fuzzer reaches the image data (almost every
//! mutation would otherwise stop at a CRC). A map that reads must be as large as the image says
//! and name only existing gray levels.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::bake::pattern::PatternMap;

/// The PNG signature's length; chunks follow it.
const SIGNATURE_LEN: usize = 8;

/// `bytes` with the CRC of every whole chunk (length, type, data, CRC) recomputed.
fn with_fitting_crcs(bytes: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    let mut at = SIGNATURE_LEN;
    while at + 12 <= out.len() {
        let len = u32::from_be_bytes(out[at..at + 4].try_into().expect("4 bytes")) as usize;
        let Some(crc_at) = (at + 8).checked_add(len).filter(|&c| c + 4 <= out.len()) else { break };
        let crc = crc32fast::hash(&out[at + 4..crc_at]);
        out[crc_at..crc_at + 4].copy_from_slice(&crc.to_be_bytes());
        at = crc_at + 4;
    }
    out
}

fn check(bytes: &[u8]) {
    let Ok((map, levels)) = PatternMap::from_png_bytes(bytes, Path::new("fuzz/map.png")) else { return };
    assert_eq!(map.exemplar_of_block.len(), map.width as usize * map.height as usize);
    assert!(map.exemplar_count() <= levels.len());
}

fuzz_target!(|data: &[u8]| {
    check(data);
    let fixed = with_fitting_crcs(data);
    if fixed != data {
        check(&fixed);
    }
});
