//! The desktop app: an eframe/egui window with one head tile per remote peer.
//!
//! Threads: the UI thread (egui, wgpu) reads the engine's snapshot once per frame and looks up
//! each peer's weights at the audio position heard now; the engine thread ([`engine`]) runs
//! the sessions, the microphone and the per-peer animation at 20 ms.

pub mod counters;
pub mod engine;
pub mod peer;
pub mod roster;
pub mod settings;
pub mod tiles;

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Context;
use eframe::egui;

use crate::audio::{DeviceChoice, DeviceInfo};
use crate::codec::any::Codec;
use crate::render::Framing;
use crate::vocab::FacePose;
use crate::vocab::VisemeWeights;
use engine::{CallSpec, Command, Engine, EngineConfig};
use peer::{FaceRow, PeerView};
use settings::{PeerPrefs, Settings};
use tiles::{HeadTile, HeadTiles, RenderCounters};

/// How the app starts (the command line's top-level flags).
#[derive(Debug, Clone, Default)]
pub struct AppOptions {
    /// Listen for calls on this address (otherwise a loopback port for the demo peer).
    pub listen: Option<String>,
    /// No demo peer.
    pub no_demo: bool,
    /// Close the window after this many seconds (tests, screenshots).
    pub quit_after: Option<f64>,
    /// Write a status line per peer to this file twice a second.
    pub status: Option<PathBuf>,
    /// Use no audio device (silent playback, no microphone).
    pub no_audio: bool,
    /// Settings file instead of the XDG one.
    pub settings: Option<PathBuf>,
}

/// Opens the window and runs until it is closed.
pub fn run(options: AppOptions) -> anyhow::Result<()> {
    let listen = match &options.listen {
        Some(a) => Some(
            a.parse::<SocketAddr>()
                .with_context(|| format!("--listen {a}: expected IP:PORT"))?,
        ),
        None => None,
    };
    let settings_path = options.settings.clone().or_else(settings::default_path);
    let (settings, settings_note) = match &settings_path {
        Some(p) => Settings::load(p),
        None => (Settings::default(), None),
    };
    let choice = |id: &str| DeviceChoice::from_option((!id.is_empty()).then_some(id));
    let engine = Engine::start(EngineConfig {
        listen,
        demo: !options.no_demo,
        name: settings.name.clone(),
        input: choice(&settings.input_device),
        output: choice(&settings.output_device),
        no_audio: options.no_audio,
    })?;
    if let Some(addr) = engine::lock(&engine.shared).call.local_addr {
        eprintln!("lipcall: listening on {addr}");
    }

    let mut wgpu_options = eframe::egui_wgpu::WgpuConfiguration::default();
    if let eframe::egui_wgpu::WgpuSetup::CreateNew(create) = &mut wgpu_options.wgpu_setup {
        create.device_descriptor = Arc::new(|adapter| wgpu::DeviceDescriptor {
            label: Some("lipcall device"),
            required_limits: crate::render::HeadRenderer::required_limits()
                .using_resolution(adapter.limits()),
            ..Default::default()
        });
    }
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("lipcall")
            .with_inner_size([1280.0, 720.0])
            .with_min_inner_size([480.0, 320.0]),
        renderer: eframe::Renderer::Wgpu,
        // Heads are drawn in their own targets (tiles.rs), so egui's pass needs no depth buffer;
        // dithering is noise for egui's flat panels and, on a software adapter, a cost per pixel.
        depth_buffer: 0,
        dithering: false,
        wgpu_options,
        ..Default::default()
    };
    let counters = Arc::new(RenderCounters::default());
    let result = eframe::run_native(
        "lipcall",
        native,
        Box::new(move |cc| {
            let mut notes: Vec<String> = settings_note.into_iter().collect();
            let heads = match &cc.wgpu_render_state {
                Some(state) => HeadTiles::new(state, counters.clone())
                    .map_err(|e| notes.push(format!("heads cannot be drawn: {e:#}")))
                    .ok(),
                None => {
                    notes.push("heads cannot be drawn: no wgpu renderer".into());
                    None
                }
            };
            Ok(Box::new(LipcallApp::new(
                engine,
                settings,
                settings_path,
                options,
                counters,
                heads,
                notes,
            )))
        }),
    );
    result.map_err(|e| anyhow::anyhow!("the window failed: {e}"))
}

/// The call form's fields.
#[derive(Debug, Clone, Default)]
pub struct CallForm {
    pub address: String,
    pub room: String,
    pub passphrase: String,
}

pub struct LipcallApp {
    engine: Engine,
    settings: Settings,
    settings_path: Option<PathBuf>,
    options: AppOptions,
    form: CallForm,
    notes: Vec<String>,
    started: Instant,
    last_status: Instant,
    last_save: Instant,
    counters: Arc<RenderCounters>,
    /// The head renderer and the tiles' textures (none without a wgpu renderer).
    heads: Option<HeadTiles>,
    /// UI frames drawn.
    frames: u64,
    inputs: Vec<DeviceInfo>,
    outputs: Vec<DeviceInfo>,
}

impl LipcallApp {
    fn new(
        engine: Engine,
        settings: Settings,
        settings_path: Option<PathBuf>,
        options: AppOptions,
        counters: Arc<RenderCounters>,
        heads: Option<HeadTiles>,
        notes: Vec<String>,
    ) -> Self {
        let form = CallForm {
            address: settings.last_address.clone(),
            room: settings.last_room.clone(),
            passphrase: String::new(),
        };
        let (inputs, outputs) = if options.no_audio {
            (Vec::new(), Vec::new())
        } else {
            (
                crate::audio::input_devices().unwrap_or_default(),
                crate::audio::output_devices().unwrap_or_default(),
            )
        };
        if let Some(mic) = &engine::lock(&engine.shared).mic {
            mic.set_push_to_talk(settings.push_to_talk);
        }
        Self {
            engine,
            settings,
            settings_path,
            options,
            form,
            notes,
            started: Instant::now(),
            last_status: Instant::now(),
            last_save: Instant::now(),
            counters,
            heads,
            frames: 0,
            inputs,
            outputs,
        }
    }

    fn save_settings(&self) {
        if let Some(p) = &self.settings_path
            && let Err(e) = self.settings.save(p)
        {
            eprintln!("lipcall: cannot save settings to {}: {e}", p.display());
        }
    }

    /// `shown[i]`: the UI frames that showed weights for `peers[i]`; `listening`: the call's
    /// local address (so a script can call an app started on port 0).
    fn write_status(&self, peers: &[PeerView], shown: &[u64], listening: Option<SocketAddr>) {
        let Some(path) = &self.options.status else {
            return;
        };
        let c = &self.engine.counters;
        let mut text = format!(
            "time_s={:.2} ui_frames={} network_ms={:.1} frames_animated={} record_ms={:.1} \
             tiles_drawn={} tiles_shown={} weights_sent={} weights_fallback={} weights_late={} late_ms={:.1} \
             listening={}\n",
            self.started.elapsed().as_secs_f64(),
            self.frames,
            c.network_ns.load(Ordering::Relaxed) as f64 / 1e6,
            c.frames_animated.load(Ordering::Relaxed),
            self.counters.record_ns.load(Ordering::Relaxed) as f64 / 1e6,
            self.counters.tiles_drawn.load(Ordering::Relaxed),
            self.counters.tiles_shown.load(Ordering::Relaxed),
            c.weights_sent.load(Ordering::Relaxed),
            c.weights_fallback.load(Ordering::Relaxed),
            c.weights_late.load(Ordering::Relaxed),
            c.late_samples.load(Ordering::Relaxed) as f64 / 8.0,
            listening.map_or("-".to_owned(), |a| a.to_string()),
        );
        for (p, shown) in peers.iter().zip(shown) {
            text += &format!(
                "peer ssrc={:08x} name={:?} demo={} talking={} animated={} shown={} received={} \
                 codec={} recovered={} unknown_pt={}\n",
                p.ssrc,
                p.name,
                p.is_demo,
                p.talking,
                p.frames_animated,
                shown,
                p.frames_received,
                p.codec.map_or("-", Codec::name),
                p.frames_recovered,
                p.unknown_payload,
            );
        }
        let tmp = path.with_extension("tmp");
        let ok = std::fs::File::create(&tmp)
            .and_then(|mut f| f.write_all(text.as_bytes()))
            .and_then(|()| std::fs::rename(&tmp, path));
        if let Err(e) = ok {
            eprintln!("lipcall: cannot write {}: {e}", path.display());
        }
    }

    /// Keyboard shortcuts: M toggles the microphone's mute; Space talks in push-to-talk mode.
    fn shortcuts(&mut self, ctx: &egui::Context) {
        let typing = ctx.egui_wants_keyboard_input();
        let (m, space) = ctx.input(|i| (i.key_pressed(egui::Key::M), i.key_down(egui::Key::Space)));
        let s = engine::lock(&self.engine.shared);
        if let Some(mic) = &s.mic {
            if m && !typing {
                mic.set_muted(!mic.muted());
            }
            mic.set_talk_pressed(space && !typing);
        }
    }
}

impl eframe::App for LipcallApp {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        self.frames += 1;
        self.shortcuts(&ctx);
        let now = Instant::now();

        // One lock: the snapshot, each peer's choices, and its weights for the audio heard now.
        let (peers, call, output_status, input_status, mic, weights, mut prefs, shown) = {
            let mut guard = engine::lock(&self.engine.shared);
            let s = &mut *guard;
            if let Some(status) = s.playback.poll() {
                s.output_status = engine::describe_output(status);
            }
            let (mut peers, mut weights, mut prefs, mut shown) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for peer in s.peers.iter_mut() {
                let Some(view) = peer.view.clone() else {
                    continue;
                };
                // A peer's saved choices apply once its name (SDES) is known.
                if !peer.saved_prefs_applied
                    && let Some(saved) = self.settings.peers.get(&view.name)
                {
                    peer.prefs = saved.clone();
                    peer.saved_prefs_applied = true;
                }
                let w = s
                    .playback
                    .weights_now(&mut peer.schedule, view.feed, now)
                    .copied();
                if w.is_some() {
                    peer.frames_shown += 1;
                }
                peers.push(view);
                weights.push(w);
                prefs.push(peer.prefs.clone());
                shown.push(peer.frames_shown);
            }
            (
                peers,
                s.call.clone(),
                s.output_status.clone(),
                s.input_status.clone(),
                s.mic.clone(),
                weights,
                prefs,
                shown,
            )
        };
        let before = prefs.clone();

        // Panels are the window's clear colour (see `clear_color`) rather than filled rectangles:
        // on a software adapter every pixel egui fills costs.
        let side = egui::Frame::side_top_panel(ui.style()).fill(egui::Color32::TRANSPARENT);
        egui::Panel::top("call").frame(side).show(ui, |ui| {
            call_ui(ui, &mut self.form, &mut self.settings, &call, &self.engine);
        });
        egui::Panel::bottom("audio").frame(side).show(ui, |ui| {
            audio_ui(
                ui,
                &mut self.settings,
                mic.as_ref(),
                &output_status,
                &input_status,
                &self.inputs,
                &self.outputs,
                &self.engine,
            );
            for n in &self.notes {
                ui.colored_label(egui::Color32::YELLOW, n);
            }
        });
        egui::Panel::left("peers")
            .frame(side)
            .resizable(true)
            .default_size(240.0)
            .min_size(200.0)
            .show(ui, |ui| peer_list_ui(ui, &peers));
        let central = egui::Frame::central_panel(ui.style()).fill(egui::Color32::TRANSPARENT);
        egui::CentralPanel::default().frame(central).show(ui, |ui| {
            tiles_ui(ui, &peers, &weights, &mut prefs, self.heads.as_mut());
        });
        if let Some(heads) = &mut self.heads {
            heads.end_frame();
        }

        if prefs != before {
            let mut s = engine::lock(&self.engine.shared);
            for (p, pr) in peers.iter().zip(&prefs) {
                if let Some(peer) = s.peers.get_mut(p.ssrc) {
                    peer.prefs = pr.clone();
                }
                if !p.is_demo && p.named {
                    self.settings.peers.insert(p.name.clone(), pr.clone());
                }
            }
        }

        if self.last_status.elapsed() >= Duration::from_millis(500) {
            self.last_status = Instant::now();
            self.write_status(&peers, &shown, call.local_addr);
        }
        if self.last_save.elapsed() >= Duration::from_secs(5) {
            self.last_save = Instant::now();
            self.save_settings();
        }
        if self
            .options
            .quit_after
            .is_some_and(|s| self.started.elapsed().as_secs_f64() >= s)
        {
            self.write_status(&peers, &shown, call.local_addr);
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        ctx.request_repaint_after(Duration::from_millis(20));
    }

    fn on_exit(&mut self) {
        self.save_settings();
        engine::lock(&self.engine.shared).call.in_call = false;
        self.engine.send(Command::Leave);
    }
}

/// Join a room on a relay or call a peer directly; leave; the encryption indicator.
fn call_ui(
    ui: &mut egui::Ui,
    form: &mut CallForm,
    settings: &mut Settings,
    call: &engine::CallStatus,
    engine: &Engine,
) {
    ui.horizontal_wrapped(|ui| {
        ui.strong("lipcall");
        ui.separator();
        ui.label("Name");
        ui.add(egui::TextEdit::singleline(&mut settings.name).desired_width(90.0));
        ui.label("Address");
        ui.add(
            egui::TextEdit::singleline(&mut form.address)
                .hint_text("host:port or Janus URL")
                .desired_width(150.0),
        );
        ui.label("Room");
        ui.add(
            egui::TextEdit::singleline(&mut form.room)
                .hint_text("(direct call)")
                .desired_width(90.0),
        );
        ui.label("Passphrase");
        ui.add(
            egui::TextEdit::singleline(&mut form.passphrase)
                .password(true)
                .desired_width(90.0),
        );
        codec_picker_ui(ui, &mut settings.codec);
        let label = if form.room.trim().is_empty() {
            "Call"
        } else {
            "Join room"
        };
        if ui
            .add_enabled(!form.address.trim().is_empty(), egui::Button::new(label))
            .clicked()
        {
            settings.last_address = form.address.clone();
            settings.last_room = form.room.clone();
            engine.send(Command::Call(CallSpec {
                address: form.address.clone(),
                room: Some(form.room.clone()),
                passphrase: Some(form.passphrase.clone()),
                name: settings.name.clone(),
                codec: settings.codec,
            }));
        }
        if ui
            .add_enabled(call.in_call, egui::Button::new("Leave"))
            .clicked()
        {
            engine.send(Command::Leave);
        }
        ui.separator();
        let warn = egui::Color32::from_rgb(230, 160, 60);
        match call.encryption {
            engine::Encryption::EndToEnd => {
                ui.colored_label(egui::Color32::LIGHT_GREEN, "encrypted end to end (SRTP)")
            }
            engine::Encryption::HopByHop => ui
                .colored_label(
                    warn,
                    "encrypted hop by hop: the Janus server can hear the call",
                )
                .on_hover_text(
                    "WebRTC encrypts each link (DTLS-SRTP). Janus decrypts every stream it \
                     forwards; only lipcall's own rooms with a passphrase are end to end.",
                ),
            engine::Encryption::None => ui.colored_label(warn, "NOT encrypted"),
        };
        ui.label(&call.state);
        if call.unknown_payload > 0 {
            ui.colored_label(
                egui::Color32::from_rgb(230, 160, 60),
                format!(
                    "{} packets of unknown payload types dropped",
                    call.unknown_payload
                ),
            );
        }
        if let Some(e) = &call.error {
            ui.colored_label(egui::Color32::LIGHT_RED, e);
        }
    });
}

/// The codec we send in the next call (a call in progress keeps its own).
fn codec_picker_ui(ui: &mut egui::Ui, codec: &mut Codec) {
    // One widget (its label inside), so that the row never wraps between label and box.
    egui::ComboBox::from_id_salt("codec")
        .selected_text(format!("Send {}", codec_label(*codec)))
        .width(90.0)
        .show_ui(ui, |ui| {
            for c in Codec::ALL {
                ui.selectable_value(codec, c, codec_label(c));
            }
        })
        .response
        .on_hover_text(
            "The codec we send in new calls. Opus is what most VoIP speaks; every peer may \
             send any of Opus, Speex, PCMU and PCMA, and all are received.",
        );
}

fn codec_label(codec: Codec) -> &'static str {
    match codec {
        Codec::Speex => "Speex",
        Codec::Opus => "Opus",
        Codec::Pcmu => "PCMU",
        Codec::Pcma => "PCMA",
    }
}

/// Device pickers, the mic level meter, mute and push-to-talk.
#[allow(clippy::too_many_arguments)]
fn audio_ui(
    ui: &mut egui::Ui,
    settings: &mut Settings,
    mic: Option<&crate::audio::MicControls>,
    output_status: &str,
    input_status: &str,
    inputs: &[DeviceInfo],
    outputs: &[DeviceInfo],
    engine: &Engine,
) {
    ui.horizontal_wrapped(|ui| {
        if device_picker_ui(ui, "Microphone", &mut settings.input_device, inputs) {
            engine.send(Command::SetInput(DeviceChoice::from_option(
                Some(settings.input_device.as_str()).filter(|s| !s.is_empty()),
            )));
        }
        if device_picker_ui(ui, "Speaker", &mut settings.output_device, outputs) {
            engine.send(Command::SetOutput(DeviceChoice::from_option(
                Some(settings.output_device.as_str()).filter(|s| !s.is_empty()),
            )));
        }
        match mic {
            Some(mic) => {
                let level = mic.level();
                let fill = ((level.peak_dbfs + 60.0) / 60.0).clamp(0.0, 1.0);
                ui.add(
                    egui::ProgressBar::new(fill)
                        .desired_width(120.0)
                        .text(format!("{:.0} dBFS", level.peak_dbfs.max(-99.0))),
                );
                let mut muted = mic.muted();
                if ui.checkbox(&mut muted, "Mute (M)").changed() {
                    mic.set_muted(muted);
                }
                if ui
                    .checkbox(&mut settings.push_to_talk, "Push-to-talk (hold Space)")
                    .changed()
                {
                    mic.set_push_to_talk(settings.push_to_talk);
                }
                ui.label(if mic.transmitting() { "sending" } else { "" });
            }
            None => {
                ui.label(input_status);
            }
        }
        ui.separator();
        ui.label(output_status);
    });
}

/// A device combo box; true when the choice changed.
fn device_picker_ui(
    ui: &mut egui::Ui,
    label: &str,
    chosen: &mut String,
    devices: &[DeviceInfo],
) -> bool {
    let shown = if chosen.is_empty() {
        "default".to_owned()
    } else {
        devices
            .iter()
            .find(|d| &d.id == chosen)
            .map_or_else(|| chosen.clone(), |d| d.name.clone())
    };
    let mut changed = false;
    ui.label(label);
    egui::ComboBox::from_id_salt(label)
        .selected_text(shown)
        .width(160.0)
        .show_ui(ui, |ui| {
            changed |= ui
                .selectable_value(chosen, String::new(), "default")
                .changed();
            for d in devices {
                changed |= ui.selectable_value(chosen, d.id.clone(), &d.name).changed();
            }
        });
    changed
}

/// Names, talking indicators and link statistics.
pub fn peer_list_ui(ui: &mut egui::Ui, peers: &[PeerView]) {
    ui.heading("Peers");
    if peers.is_empty() {
        ui.label("Nobody here yet.");
    }
    for p in peers {
        ui.horizontal(|ui| {
            let colour = if p.talking {
                egui::Color32::LIGHT_GREEN
            } else {
                egui::Color32::DARK_GRAY
            };
            let (dot, _) = ui.allocate_exact_size(egui::vec2(12.0, 12.0), egui::Sense::hover());
            ui.painter().circle_filled(dot.center(), 5.0, colour);
            ui.strong(&p.name);
            if let Some(codec) = p.codec {
                ui.label(codec_label(codec));
            }
            if p.is_demo {
                ui.weak("(demo)");
            }
        });
        ui.weak(format!(
            "{}  loss {:.1}%  jitter {:.1} ms  delay {:.0} ms",
            p.addr, p.loss_percent, p.jitter_ms, p.delay_ms
        ));
        if p.frames_recovered > 0 {
            ui.weak(format!(
                "{} lost frames rebuilt from FEC",
                p.frames_recovered
            ));
        }
        if p.unknown_payload > 0 {
            ui.colored_label(
                egui::Color32::from_rgb(230, 160, 60),
                format!(
                    "{} packets of an unknown payload type dropped",
                    p.unknown_payload
                ),
            );
        }
        ui.separator();
    }
}

/// The viseme sets offered: the network's own, the paper's reduced sets and the full one.
pub const VISEME_CHOICES: [&str; 7] = ["", "2", "3", "4", "5", "6", "15"];

fn visemes_label(choice: &str) -> String {
    if choice.is_empty() {
        "network's visemes".into()
    } else {
        format!("{choice} visemes")
    }
}

/// One peer's controls: animation, the living face, mute, volume, lipreading view, jaw mode,
/// viseme set, lip closures.
pub fn peer_controls_ui(ui: &mut egui::Ui, id: u32, prefs: &mut PeerPrefs) {
    ui.horizontal_wrapped(|ui| {
        ui.checkbox(&mut prefs.animate, "Animate");
        ui.add_enabled(
            prefs.animate,
            egui::Checkbox::new(&mut prefs.life, "Living face"),
        )
        .on_hover_text("Blinks, glances, and head nods and tilts with the voice");
        ui.checkbox(&mut prefs.muted, "Mute");
        ui.add(
            egui::Slider::new(&mut prefs.volume, 0.0..=2.0)
                .text("Vol")
                .max_decimals(1),
        );
        ui.checkbox(&mut prefs.lipreading, "Lipreading");
        ui.checkbox(&mut prefs.jaw, "Jaw only");
        egui::ComboBox::new(("visemes", id), "Visemes")
            .selected_text(visemes_label(&prefs.visemes))
            .width(140.0)
            .show_ui(ui, |ui| {
                for c in VISEME_CHOICES {
                    ui.selectable_value(&mut prefs.visemes, c.to_owned(), visemes_label(c));
                }
            });
        ui.scope(|ui| {
            // Narrower than the volume slider, so the row fits a third-of-the-window tile.
            ui.spacing_mut().slider_width = 64.0;
            ui.add_enabled(
                !prefs.jaw,
                egui::Slider::new(&mut prefs.closures, -1.0..=1.0)
                    .text("Closures")
                    .step_by(0.25)
                    .show_value(false),
            )
            .on_hover_text(
                "Lip closures for /p b m/: left, only the surest; right, nearly all of them, \
                 at the cost of closing where there is none",
            );
        });
    });
}

/// A grid of head tiles, each with its controls beneath.
pub fn tiles_ui(
    ui: &mut egui::Ui,
    peers: &[PeerView],
    faces: &[Option<FaceRow>],
    prefs: &mut [PeerPrefs],
    mut heads: Option<&mut HeadTiles>,
) {
    if peers.is_empty() {
        ui.centered_and_justified(|ui| {
            ui.label("Waiting for someone to talk… (call a peer or join a room above)");
        });
        return;
    }
    let n = peers.len();
    let avail = ui.available_size();
    let cols = (1..=n)
        .min_by_key(|&c| {
            let rows = n.div_ceil(c);
            let w = avail.x / c as f32;
            let h = avail.y / rows as f32 - 100.0;
            // The largest square head that fits.
            -(w.min(h).max(1.0) as i64)
        })
        .unwrap_or(1);
    let rows = n.div_ceil(cols);
    let tile_w = (avail.x / cols as f32 - 8.0).max(50.0);
    let tile_h = (avail.y / rows as f32 - 8.0).max(80.0);
    egui::Grid::new("tiles").spacing([8.0, 8.0]).show(ui, |ui| {
        for (i, p) in peers.iter().enumerate() {
            ui.allocate_ui(egui::vec2(tile_w, tile_h), |ui| {
                ui.set_min_size(egui::vec2(tile_w, tile_h));
                ui.vertical(|ui| {
                    ui.horizontal(|ui| {
                        ui.strong(&p.name);
                        if p.talking {
                            ui.colored_label(egui::Color32::LIGHT_GREEN, "talking");
                        }
                    });
                    // Room for the name line and up to three rows of controls.
                    let head_h = (tile_h - 100.0).max(40.0);
                    let (rect, _) =
                        ui.allocate_exact_size(egui::vec2(tile_w, head_h), egui::Sense::hover());
                    let (w, mut pose) = match (prefs[i].animate, faces[i]) {
                        (true, Some(face)) if prefs[i].life => {
                            (VisemeWeights(face.weights), face.pose)
                        }
                        (true, Some(face)) => (VisemeWeights(face.weights), FacePose::REST),
                        _ => (VisemeWeights::neutral(), FacePose::REST),
                    };
                    // The lipreading close-up keeps the mouth steady in the frame.
                    if prefs[i].lipreading {
                        pose = pose.without_head_motion();
                    }
                    if let Some(heads) = heads.as_deref_mut() {
                        let tile = HeadTile {
                            id: u64::from(p.ssrc),
                            framing: if prefs[i].lipreading {
                                Framing::Mouth
                            } else {
                                Framing::Face
                            },
                            weights: w,
                            pose,
                        };
                        heads.show(ui, rect, tile);
                    } else {
                        ui.painter()
                            .rect_filled(rect, 6.0, egui::Color32::from_gray(38));
                    }
                    peer_controls_ui(ui, p.ssrc, &mut prefs[i]);
                });
            });
            if (i + 1) % cols == 0 {
                ui.end_row();
            }
        }
    });
}
