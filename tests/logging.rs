//! The command line installs a `tracing` subscriber: events reach stderr (warnings by default,
//! more through RUST_LOG). Before, none was installed and every warning was lost.

mod common;

use common::glb_write::write_glb;
use common::lipcall;
use lipcall::render::head::Expression;

/// `animate` with a head that cannot blink: loading it logs a debug event, then the missing
/// audio fails the command (before any rendering).
fn animate_blinkless_head(rust_log: Option<&str>) -> String {
    let dir = tempfile::tempdir().unwrap();
    let mut head = lipcall::render::load_head_or_default(None).unwrap();
    for p in &mut head.primitives {
        p.targets[Expression::Blink.slot()].clear();
    }
    let path = dir.path().join("blinkless.glb");
    std::fs::write(&path, write_glb(&head)).unwrap();
    let mut cmd = lipcall();
    cmd.arg("animate")
        .arg(dir.path().join("missing.wav"))
        .arg("--frames")
        .arg(dir.path().join("frames"))
        .arg("--head")
        .arg(&path)
        .env_remove("RUST_LOG");
    if let Some(spec) = rust_log {
        cmd.env("RUST_LOG", spec);
    }
    let out = cmd.output().unwrap();
    assert!(!out.status.success(), "the audio is missing");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

const EVENT: &str = "(or eyeBlink) morph target";

#[test]
fn rust_log_shows_tracing_events_on_stderr() {
    let stderr = animate_blinkless_head(Some("lipcall=debug"));
    let line = stderr
        .lines()
        .find(|l| l.contains(EVENT))
        .unwrap_or_else(|| panic!("the debug event is shown: {stderr}"));
    assert!(line.contains("DEBUG"), "{line}");
    assert!(
        !line.contains('\x1b'),
        "no colour codes off a terminal: {line:?}"
    );
}

#[test]
fn by_default_only_warnings_are_shown() {
    let stderr = animate_blinkless_head(None);
    assert!(!stderr.contains(EVENT), "{stderr}");
    assert!(stderr.contains("missing.wav"), "{stderr}");
}

#[test]
fn an_unreadable_rust_log_is_said_and_warnings_still_shown() {
    let stderr = animate_blinkless_head(Some("lipcall=loud"));
    assert!(stderr.contains("RUST_LOG"), "{stderr}");
    assert!(stderr.contains("WARN"), "{stderr}");
    assert!(!stderr.contains(EVENT), "{stderr}");
}
