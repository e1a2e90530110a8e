//! The real app binary under Xvfb: the demo peer talks through the whole pipeline and its head
//! moves its mouth; a `lipcall send` into the app is shown and animated.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_lipcall");

/// None (skip) when Xvfb is missing outside CI; a failure in CI.
fn xvfb_available() -> bool {
    let ok = ["xvfb-run", "import"].iter().all(|tool| {
        Command::new("sh")
            .arg("-c")
            .arg(format!("command -v {tool}"))
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "xvfb-run and import (packages xvfb, xauth, imagemagick) are required in CI"
        );
        eprintln!("skipped: xvfb-run or import missing");
    }
    ok
}

/// Runs `script` (sh) under a 1280x720 Xvfb with `$LIPCALL` set to the binary.
fn under_xvfb(dir: &Path, script: &str) -> std::process::Output {
    let out = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 1280x720x24", "sh", "-c", script])
        .current_dir(dir)
        .env("LIPCALL", BIN)
        .env("XDG_CONFIG_HOME", dir)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("xvfb-run runs");
    if !out.status.success() {
        panic!(
            "script failed: {}\nstdout:\n{}\nstderr:\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    out
}

fn is_skin(p: &image::Rgb<u8>) -> bool {
    let [r, g, b] = p.0.map(i32::from);
    r > 110 && r > g + 15 && g > b && r - b > 35
}

/// Skin pixels in the head area (right of the peer list, between the top and bottom bars).
fn skin_box(img: &image::RgbImage) -> Option<(u32, u32, u32, u32, usize)> {
    let (mut x0, mut y0, mut x1, mut y1, mut n) = (u32::MAX, u32::MAX, 0, 0, 0);
    for (x, y, p) in img.enumerate_pixels() {
        if x > 260 && y > 40 && y + 60 < img.height() && is_skin(p) {
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
            n += 1;
        }
    }
    (n > 0).then_some((x0, y0, x1, y1, n))
}

fn mouth_difference(a: &image::RgbImage, b: &image::RgbImage, bx: (u32, u32, u32, u32)) -> f64 {
    // The mouth sits in the lower half of the face, around its middle.
    let (x0, y0, x1, y1) = bx;
    let (w, h) = (x1 - x0, y1 - y0);
    let (mx0, mx1) = (x0 + w * 3 / 10, x0 + w * 7 / 10);
    let (my0, my1) = (y0 + h / 2, y0 + h * 9 / 10);
    let mut sum = 0u64;
    let mut count = 0u64;
    for y in my0..my1 {
        for x in mx0..mx1 {
            let (p, q) = (a.get_pixel(x, y).0, b.get_pixel(x, y).0);
            sum += (0..3).map(|c| u64::from(p[c].abs_diff(q[c]))).sum::<u64>();
            count += 1;
        }
    }
    sum as f64 / count.max(1) as f64
}

fn shots(dir: &Path, n: usize) -> Vec<PathBuf> {
    (0..n).map(|i| dir.join(format!("shot{i}.png"))).collect()
}

#[test]
fn a_direct_call_to_a_dead_address_is_calling_then_failed_in_the_status_file() {
    if !xvfb_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let dead = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let dead = dead.local_addr().unwrap();
    let script = format!(
        r#"
        "$LIPCALL" --no-audio --no-demo --listen 127.0.0.1:0 --call {dead} --quit-after 60 \
            --status status.txt --settings s.json 2>app.log &
        pid=$!
        call() {{ sed -n 's/.* call=\([a-z_]*\).*/\1/p' status.txt 2>/dev/null | head -1; }}
        i=0
        while [ $i -lt 250 ] && [ "$(call)" != failed ]; do
            call >> seen.txt
            sleep 0.1; i=$((i+1))
        done
        cp status.txt final.txt
        kill $pid; wait $pid
        true
        "#
    );
    let started = Instant::now();
    under_xvfb(dir.path(), &script);
    let read = |n: &str| std::fs::read_to_string(dir.path().join(n)).unwrap_or_default();
    let (seen, last) = (read("seen.txt"), read("final.txt"));
    assert!(
        seen.lines().any(|l| l == "calling"),
        "never calling: {seen}"
    );
    let first = last.lines().next().unwrap_or_default();
    assert!(
        first.contains(" call=failed"),
        "{first}\n{}",
        read("app.log")
    );
    assert!(started.elapsed() < Duration::from_secs(60));
}

#[test]
fn demo_peer_talks_and_its_mouth_moves() {
    if !xvfb_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Wait until the tile has shown weights of heard audio, then take shots 0.25 s apart.
    let script = r#"
        "$LIPCALL" --no-audio --quit-after 60 --status status.txt --settings s.json 2>app.log &
        pid=$!
        i=0
        while [ $i -lt 400 ]; do
            if grep -Eq 'demo=true.*shown=([3-9][0-9]|[0-9]{3,}) ' status.txt 2>/dev/null; then break; fi
            sleep 0.1; i=$((i+1))
        done
        for k in 0 1 2 3 4 5; do import -window root shot$k.png; sleep 0.25; done
        cp status.txt status-final.txt
        kill $pid; wait $pid
        true
    "#;
    let out = under_xvfb(dir.path(), script);
    let status = std::fs::read_to_string(dir.path().join("status-final.txt"))
        .unwrap_or_else(|_| panic!("no status; {}", String::from_utf8_lossy(&out.stderr)));
    assert!(
        status.contains("demo=true"),
        "no demo peer in the status:\n{status}\n{}",
        std::fs::read_to_string(dir.path().join("app.log")).unwrap_or_default()
    );
    let images: Vec<image::RgbImage> = shots(dir.path(), 6)
        .iter()
        .map(|p| image::open(p).expect("screenshot").to_rgb8())
        .collect();
    let (x0, y0, x1, y1, n) = skin_box(&images[0]).expect("no skin-coloured head in the window");
    assert!(
        n > 5000 && x1 - x0 > 80 && y1 - y0 > 80,
        "head too small: {n} skin pixels in {x0},{y0}..{x1},{y1}"
    );
    let most = images
        .windows(2)
        .map(|w| mouth_difference(&w[0], &w[1], (x0, y0, x1, y1)))
        .fold(0.0, f64::max);
    eprintln!("head: {n} skin pixels in {x0},{y0}..{x1},{y1}; largest mouth change {most:.2}");
    assert!(
        most > 1.0,
        "the mouth did not move between screenshots (largest mean difference {most:.3})"
    );
}

#[test]
fn a_sender_into_the_app_is_shown_and_animated() {
    if !xvfb_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let wav = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
    // The app listens on a port of its own choosing and says which in its status file; each
    // step waits (up to 30 s) for what it needs rather than for a fixed time.
    let script = format!(
        r#"
        "$LIPCALL" --no-audio --no-demo --listen 127.0.0.1:0 --quit-after 60 \
            --status status.txt --settings s.json 2>app.log &
        pid=$!
        field() {{ sed -n "$1" status.txt 2>/dev/null | head -1; }}
        listening() {{ field 's/.* listening=\(127[^ ]*\).*/\1/p'; }}
        alice() {{ field 's/.*name="Alice".* '"$1"'=\([0-9]*\).*/\1/p'; }}
        wait_until() {{
            i=0
            while [ $i -lt 300 ] && ! eval "$1"; do sleep 0.1; i=$((i+1)); done
        }}
        wait_until '[ -n "$(listening)" ]'
        "$LIPCALL" send '{wav}' --to "$(listening)" --name Alice 2>send.log &
        spid=$!
        wait_until '[ "$(alice animated)" -gt 0 ] 2>/dev/null'
        cp status.txt early.txt
        first=$(alice animated)
        wait_until '[ "$(alice animated)" -gt $((first + 25)) ] && [ "$(alice shown)" -gt 0 ] 2>/dev/null'
        cp status.txt late.txt
        kill $spid 2>/dev/null; kill $pid; wait $pid
        true
        "#,
        wav = wav.display()
    );
    let started = Instant::now();
    under_xvfb(dir.path(), &script);
    assert!(started.elapsed() < Duration::from_secs(120));
    let read = |n: &str| std::fs::read_to_string(dir.path().join(n)).unwrap_or_default();
    let animated = |text: &str| -> Option<(u64, u64)> {
        let line = text.lines().find(|l| l.contains("name=\"Alice\""))?;
        let field = |k: &str| {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(k))
                .and_then(|v| v.parse::<u64>().ok())
        };
        Some((field("animated=")?, field("shown=")?))
    };
    let (early, late) = (read("early.txt"), read("late.txt"));
    let log = read("app.log") + &read("send.log");
    let (a0, _) = animated(&early).unwrap_or_else(|| panic!("no Alice in {early}\n{log}"));
    let (a1, s1) = animated(&late).unwrap_or_else(|| panic!("no Alice in {late}\n{log}"));
    assert!(!early.contains("demo=true"), "demo peer with --no-demo");
    // A caller into the listening app rings until answered, in the status file's first line.
    let first = early.lines().next().unwrap_or_default();
    assert!(first.contains(" call=ringing"), "{first}");
    assert!(
        a1 > a0 && a0 > 0,
        "animation frames do not advance: {a0} -> {a1}"
    );
    assert!(s1 > 0, "the tile never showed weights of heard audio");
    // The tile's head is drawn at the level of detail its size needs: exact to half a pixel in
    // a tile some 450 pixels high takes fewer triangles than the full head has.
    let counter = |k: &str| {
        late.split_whitespace()
            .find_map(|w| w.strip_prefix(k))
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or_else(|| panic!("no {k} in {late}"))
    };
    let (renders, triangles) = (counter("tiles_drawn="), counter("triangles_drawn="));
    let full = lipcall::render::default_head().unwrap().triangle_count() as u64;
    assert!(renders > 0, "no head render");
    assert!(
        triangles < renders * full && triangles > renders * full / 10,
        "{triangles} triangles in {renders} renders of a {full}-triangle head"
    );
}
