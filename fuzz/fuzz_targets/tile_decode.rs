//! Any bytes into the tile decoder: no panic, and a tile that decodes re-encodes to bytes that
//! decode and re-encode identically (compared as bytes, so NaN fields cannot fool it).
//!
//! Random bytes rarely pass the v4/v3 checksum or the v2 zstd frame check, so each input is also
//! tried behind a valid checksum (v4 and v3: it reaches the header, the range decoder and the
//! value checks) and as a v2 *decompressed* payload (framed and zstd-compressed here, it reaches the
//! postcard layout and the validation behind it).
#![no_main]

use common::grid::{
    decode_tile, encode_tile, TILE_CODEC_VERSION, TILE_CODEC_VERSION_V2, TILE_CODEC_VERSION_V3,
    TILE_MAGIC,
};
use libfuzzer_sys::fuzz_target;

fn check(bytes: &[u8]) {
    if let Ok(tile) = decode_tile(bytes) {
        let encoded = encode_tile(&tile);
        match decode_tile(&encoded) {
            Ok(again) => assert_eq!(encode_tile(&again), encoded, "re-encoding is not stable"),
            Err(e) => panic!("a decoded tile re-encodes to bytes that do not decode: {e}"),
        }
    }
}

fuzz_target!(|data: &[u8]| {
    check(data);
    for version in [TILE_CODEC_VERSION, TILE_CODEC_VERSION_V3] {
        let mut framed = vec![TILE_MAGIC, version];
        framed.extend(data);
        let crc = crc32fast::hash(&framed);
        framed.extend(crc.to_le_bytes());
        check(&framed);
    }
    if let Ok(compressed) = zstd::bulk::compress(data, 1) {
        let mut framed = vec![TILE_MAGIC, TILE_CODEC_VERSION_V2];
        framed.extend(compressed);
        check(&framed);
    }
});
