//! PNG pattern maps: `PatternMap::from_png_bytes` on any bytes. A map that reads must be as
//! large as the image says and name only existing gray levels.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::bake::pattern::PatternMap;

fuzz_target!(|data: &[u8]| {
    let Ok((map, levels)) = PatternMap::from_png_bytes(data, Path::new("fuzz/map.png")) else { return };
    assert_eq!(map.exemplar_of_block.len(), map.width as usize * map.height as usize);
    assert!(map.exemplar_count() <= levels.len());
});
