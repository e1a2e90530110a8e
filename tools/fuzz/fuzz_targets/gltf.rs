//! Head loading from GLB or glTF bytes (`render::gltf_load::load_head_from_slice`: what
//! `--head` and the app's head picker go through), then what the renderer computes from a head
//! before it touches a GPU: the face frame, the neck pivot and the cameras. No panic, hang or
//! runaway allocation; a head that loads gives finite cameras.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lipcall::render::gltf_load::load_head_from_slice;
use lipcall::render::{Camera, Framing};

fuzz_target!(|data: &[u8]| {
    let Ok(head) = load_head_from_slice(data) else {
        return;
    };
    let frame = head.face_frame();
    assert!(frame.head_min.is_finite() && frame.head_max.is_finite() && frame.mouth.is_finite());
    assert!(frame.neck_pivot().is_finite());
    for framing in [Framing::Face, Framing::Mouth] {
        let camera = Camera::framing(&frame, framing);
        assert!(
            camera.view_proj(4.0 / 3.0).is_finite(),
            "a camera that is not finite: {camera:?}"
        );
    }
});
