//! cyHair `.hair`: `parse_hair` on any bytes; whatever parses must encode and read back the same.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use twill_precompute::fabric::fiber_io::{encode_hair, parse_hair};

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz/fibers.hair");
    let Ok(fibers) = parse_hair(data, path) else { return };
    // Fibers of more than 65536 points cannot be written back (cyHair's u16 segment counts);
    // the reader cannot produce them either.
    let bytes = encode_hair(&fibers).expect("fibers read from cyHair encode as cyHair");
    let again = parse_hair(&bytes, path).expect("encoded fibers parse");
    assert_eq!(again.len(), fibers.len());
    for (a, b) in again.iter().zip(&fibers) {
        assert_eq!(a.points, b.points);
    }
});
