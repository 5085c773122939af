//! Any bytes into the NMEA, Trimble and Orpheus parsers: no panic, and whatever parses must
//! format back into a sentence that parses again (the simulator's receiver relies on that).
#![no_main]

use common::geo::nmea::{format_gga, format_hdt, format_rmc, parse_sentence, Sentence};
use common::geo::orpheus::{format_orpheus, parse_orpheus};
use common::geo::trimble::{format_avr, format_ggk};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(s) = parse_sentence(text) {
        let again = match &s {
            Sentence::Gga(g) => Some(format_gga(g)),
            Sentence::Rmc(r) => Some(format_rmc(r)),
            Sentence::Hdt(h) => Some(format_hdt(&h.talker, h.heading_deg)),
            Sentence::Avr(a) => Some(format_avr(a)),
            Sentence::Ggk(g) => Some(format_ggk(g)),
            _ => None,
        };
        if let Some(line) = again {
            if let Err(e) = parse_sentence(&line) {
                panic!("{text:?} parsed, but its re-formatted {line:?} does not: {e}");
            }
        }
    }
    if let Ok(m) = parse_orpheus(text) {
        let line = format_orpheus(&m);
        if let Err(e) = parse_orpheus(&line) {
            panic!("{text:?} parsed, but its re-formatted {line:?} does not: {e}");
        }
    }
});
