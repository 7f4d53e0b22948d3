//! Scene TOML: `SceneFile::parse` on any UTF-8 text. A scene that parses must also write back
//! out (`to_toml`) as text that parses again to the same scene.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::scene::SceneFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = Path::new("fuzz/scene.toml");
    let Ok(scene) = SceneFile::parse(text, path) else { return };
    let written = scene.to_toml().expect("a parsed scene writes back out");
    let again = SceneFile::parse(&written, path).expect("a written scene parses");
    // NaN is not equal to itself; compare the text instead, which keeps every bit.
    assert_eq!(again.to_toml().expect("writes"), written, "the scene changed on a round trip");
});
