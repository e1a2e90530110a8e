//! PulseAudio for the audio tests (the server `.ci/pulse-null-sink.sh` starts).

use std::process::Command;

/// A null sink of one test's own, unloaded when dropped.
pub struct NullSink {
    pub name: String,
    module: String,
}

impl NullSink {
    /// A sink named `lipcall_TAG_PID` at `rate` Hz (`tag` tells apart cases running at once).
    pub fn load(tag: &str, rate: u32) -> Self {
        let name = format!("lipcall_{tag}_{}", std::process::id());
        let out = Command::new("pactl")
            .args(["load-module", "module-null-sink"])
            .arg(format!("sink_name={name}"))
            .arg(format!("rate={rate}"))
            .output()
            .expect("pactl runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let module = String::from_utf8_lossy(&out.stdout).trim().to_owned();
        Self { name, module }
    }
}

impl Drop for NullSink {
    fn drop(&mut self) {
        let _ = Command::new("pactl")
            .args(["unload-module", &self.module])
            .status();
    }
}
