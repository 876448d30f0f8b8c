//! The replay tape decoder on arbitrary bytes: the header, then every record until the first
//! error. It must return error values, never panic (the image decodes tapes on the rover CPU).
#![no_main]

use libfuzzer_sys::fuzz_target;
use rover_replay::tape::{SliceSource, TapeReader};

fuzz_target!(|data: &[u8]| {
    let Ok(mut reader) = TapeReader::open(SliceSource::new(data)) else {
        return;
    };
    let _ = reader.header().waypoints();
    let _ = reader.header().scenario_name();
    // Records are at least 2 bytes: the loop is bounded by the input length.
    for _ in 0..data.len() {
        if reader.next_record().is_err() {
            break;
        }
    }
});
