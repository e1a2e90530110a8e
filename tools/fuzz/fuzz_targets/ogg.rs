//! Ogg files as `animate` and `decode` take them: the Ogg Speex and Ogg Opus readers, then the
//! whole decode of whichever the file holds (libspeex or libopus, the bitstream walkers and the
//! feature rows). No panic; every feature row holds what `FrameFeatures` promises: LSPs strictly
//! increasing in (0, pi) and a finite energy.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::codec::opus;
use lipcall::codec::speex::bitstream::Walker;
use lipcall::codec::speex::{ogg_file, stream};

fuzz_target!(|data: &[u8]| {
    if let Ok(file) = ogg_file::read(data) {
        let mut walker = Walker::new();
        for packet in file.pages.iter().flat_map(|p| &p.packets) {
            let _ = walker.walk_packet(packet);
        }
    }
    let _ = opus::ogg_file::read(data);
    let features = if opus::ogg_file::holds_opus(data) {
        let Ok(decoded) = opus::stream::decode(data) else {
            return;
        };
        opus::features::stream_features(&decoded)
    } else {
        let Ok(decoded) = stream::decode(data, true) else {
            return;
        };
        decoded.features
    };
    for row in &features {
        let inside = row.lsp.iter().all(|&v| v > 0.0 && v < std::f32::consts::PI);
        let increasing = row.lsp.windows(2).all(|w| w[0] < w[1]);
        assert!(
            inside && increasing && row.energy_db.is_finite(),
            "a feature row breaking its promise: {row:?}"
        );
    }
});
