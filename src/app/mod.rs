//! The desktop app: an eframe/egui window with one head tile per remote peer.
//!
//! Threads: the UI thread (egui, wgpu) reads the engine's snapshot once per frame and looks up
//! each peer's weights at the audio position heard now; the engine thread ([`engine`]) runs
//! the sessions, the microphone and the per-peer animation at 20 ms.

mod audio_panel;
pub mod call_panel;
pub mod call_status;
mod channel_panel;
pub mod counters;
mod demo;
mod device_opener;
pub mod engine;
pub mod listen;
mod lookup;
pub mod mumble_call;
mod off_worker;
pub mod peer;
pub mod peer_panel;
mod retire;
mod revival;
pub mod ring_notice;
mod ringing;
pub mod roster;
pub mod settings;
mod settings_window;
pub mod sip_call;
mod sip_panel;
pub mod tiles;
mod timing;

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
pub use audio_panel::{MicKeys, audio_ui};
pub use call_panel::CallForm;
pub use call_panel::call_ui;
pub use channel_panel::channels_ui;
use engine::{Command, Engine, EngineConfig};
pub use peer_panel::{ShownPeer, left_notice_ui, peer_controls_ui, peer_list_ui, tiles_ui};
pub use ringing::RingingBanner;
use settings::Settings;
pub use settings_window::{SettingsParts, settings_ui, settings_window};
pub use sip_panel::{SipForm, sip_ui};
use tiles::{HeadTiles, RenderCounters};

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
    /// Call this address (HOST:PORT, or a relay or Janus address) at start, with the settings'
    /// codec and band: two apps then talk unattended.
    pub call: Option<String>,
    /// The output ring's margin above a device period, in ms, instead of the settings'.
    pub output_margin_ms: Option<u32>,
    /// Open the settings window at start (screenshots, a first run's set-up).
    pub open_settings: bool,
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
    let (mut settings, settings_note) = match &settings_path {
        Some(p) => Settings::load(p),
        None => (Settings::default(), None),
    };
    // The settings may hold passwords, and the call form takes passphrases at any time.
    crate::secrets::forbid_core_dumps();
    let chosen = listen.is_none();
    let mut listen = match listen {
        Some(a) => a,
        None => keep_listen_port(&mut settings, settings_path.as_deref())?,
    };
    let choice = |id: &str| DeviceChoice::from_option((!id.is_empty()).then_some(id));
    let start = |listen: SocketAddr| {
        Engine::start(EngineConfig {
            listen: Some(listen),
            demo: !options.no_demo,
            name: settings.name.clone(),
            input: choice(&settings.input_device),
            output: choice(&settings.output_device),
            no_audio: options.no_audio,
            output_margin: settings::output_margin(
                options
                    .output_margin_ms
                    .unwrap_or(settings.output_margin_ms),
            ),
        })
    };
    // A port found free can be taken before the engine binds it (another app starting):
    // then the next free one, a few times.
    let mut tries = 0;
    let engine = loop {
        match start(listen) {
            Ok(engine) => break engine,
            Err(e) if chosen && tries < 3 => {
                tries += 1;
                let next = listen.port().saturating_add(1);
                tracing::warn!("cannot listen on {listen} ({e:#}); trying from port {next}");
                listen.set_port(listen::free_port_from(next)?);
            }
            Err(e) => return Err(e),
        }
    };
    if let Some(addr) = engine::lock(&engine.shared).call.local_addr {
        let dial: Vec<String> = listen::dialable(addr)
            .iter()
            .map(|a| a.to_string())
            .collect();
        eprintln!("lipcall: listening on {addr} (dial {})", dial.join(" or "));
    }
    if let Some(address) = &options.call {
        engine.send(engine::Command::Call(Box::new(engine::CallSpec {
            address: address.clone(),
            name: settings.name.clone(),
            codec: settings.codec,
            bandwidth: settings.bandwidth,
            frame_ms: settings.frame_ms,
            ..engine::CallSpec::default()
        })));
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

/// All interfaces at the settings' port, or the next free one while it is taken; a fresh
/// settings file keeps the port first chosen, so that it stays across restarts.
fn keep_listen_port(
    settings: &mut Settings,
    path: Option<&std::path::Path>,
) -> anyhow::Result<SocketAddr> {
    // Port 0 would be a new port at every start: not one to keep.
    let kept = settings.listen_port.filter(|&p| p != 0);
    let preferred = kept.unwrap_or(listen::DEFAULT_PORT);
    let port = listen::free_port_from(preferred)
        .with_context(|| format!("no free UDP port from {preferred} to listen on"))?;
    if kept.is_none() {
        settings.listen_port = Some(port);
        if let Some(p) = path
            && let Err(e) = settings.save(p)
        {
            eprintln!("lipcall: cannot save settings to {}: {e}", p.display());
        }
    }
    Ok(SocketAddr::from(([0, 0, 0, 0], port)))
}

pub struct LipcallApp {
    engine: Engine,
    settings: Settings,
    settings_path: Option<PathBuf>,
    options: AppOptions,
    form: CallForm,
    sip_form: SipForm,
    ringing: ringing::RingingBanner,
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
    mic_keys: MicKeys,
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
            settings_open: options.open_settings,
            ..CallForm::default()
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
        let sip_form = SipForm {
            error: sip_panel::use_account(&settings, &engine).err(),
            ..SipForm::default()
        };
        Self {
            engine,
            settings,
            settings_path,
            options,
            form,
            sip_form,
            ringing: ringing::RingingBanner::default(),
            notes,
            started: Instant::now(),
            last_status: Instant::now(),
            last_save: Instant::now(),
            counters,
            heads,
            frames: 0,
            inputs,
            outputs,
            mic_keys: MicKeys::default(),
        }
    }

    fn save_settings(&self) {
        if let Some(p) = &self.settings_path
            && let Err(e) = self.settings.save(p)
        {
            eprintln!("lipcall: cannot save settings to {}: {e}", p.display());
        }
    }

    /// `listening`: the call's local address (so a script can call an app started on port 0).
    fn write_status(&self, peers: &[ShownPeer], listening: Option<SocketAddr>, call_word: &str) {
        let Some(path) = &self.options.status else {
            return;
        };
        let c = &self.engine.counters;
        let (output_ms, underruns, starved_ms) = {
            let s = engine::lock(&self.engine.shared);
            let delay = s.playback.output_delay(Instant::now());
            let ms = delay.map_or(f64::NAN, |d| d.as_secs_f64() * 1000.0);
            let rate = f64::from(s.playback.mix_rate());
            // Silence the mixer played for each peer, its queue empty mid-stream.
            let starved: Vec<f64> = peers
                .iter()
                .map(|p| {
                    let c = s.playback.peer_controls(p.view.feed);
                    c.map_or(0.0, |c| c.starved() as f64 * 1000.0 / rate)
                })
                .collect();
            (ms, s.playback.stats().underruns, starved)
        };
        let mut text = format!(
            "time_s={:.2} ui_frames={} network_ms={:.1} frames_animated={} record_ms={:.1} \
             tiles_drawn={} tiles_shown={} triangles_drawn={} weights_sent={} weights_fallback={} weights_late={} late_ms={:.1} \
             output_ms={output_ms:.1} underruns={underruns} listening={} call={}\n",
            self.started.elapsed().as_secs_f64(),
            self.frames,
            c.network_ns.load(Ordering::Relaxed) as f64 / 1e6,
            c.frames_animated.load(Ordering::Relaxed),
            self.counters.record_ns.load(Ordering::Relaxed) as f64 / 1e6,
            self.counters.tiles_drawn.load(Ordering::Relaxed),
            self.counters.tiles_shown.load(Ordering::Relaxed),
            self.counters.triangles_drawn.load(Ordering::Relaxed),
            c.weights_sent.load(Ordering::Relaxed),
            c.weights_fallback.load(Ordering::Relaxed),
            c.weights_late.load(Ordering::Relaxed),
            c.late_us.load(Ordering::Relaxed) as f64 / 1000.0,
            listening.map_or("-".to_owned(), |a| a.to_string()),
            call_word,
        );
        for (
            i,
            ShownPeer {
                view: p,
                frames_shown: shown,
                ..
            },
        ) in peers.iter().enumerate()
        {
            text += &format!(
                "peer {} name={:?} demo={} talking={} animated={} shown={} received={} \
                 codec={} recovered={} unknown_pt={} jitter_buffer_ms={:.1} queue_ms={:.1} \
                 starved_ms={:.0} jitter_ms={:.1} target_ms={:.1} stretched={} dropped={} \
                 late={}\n",
                p.peer,
                p.name,
                p.is_demo,
                p.talking,
                p.frames_animated,
                shown,
                p.frames_received,
                p.codec.map_or("-", Codec::name),
                p.frames_recovered,
                p.unknown_payload,
                p.delay_ms,
                p.queued_ms,
                starved_ms.get(i).copied().unwrap_or(0.0),
                p.jitter_ms,
                p.buffer.target_delay_ms,
                p.buffer.stretched,
                p.buffer.dropped,
                p.buffer.late,
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
}

impl eframe::App for LipcallApp {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        self.frames += 1;
        let mic_now = engine::lock(&self.engine.shared).mic.clone();
        self.mic_keys.handle(&ctx, mic_now.as_ref());
        let now = Instant::now();

        // One lock: the snapshot, each peer's choices, and its weights for the audio heard now.
        let (mut peers, left, call, output_status, input_status, mic, mumble, phone) = {
            let mut guard = engine::lock(&self.engine.shared);
            let s = &mut *guard;
            if let Some(status) = s.playback.poll() {
                s.output_status = engine::describe_output(status);
            }
            let mut peers = Vec::new();
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
                let face = s
                    .playback
                    .weights_now(&mut peer.schedule, view.feed, now)
                    .copied();
                if face.is_some() {
                    peer.frames_shown += 1;
                }
                peers.push(ShownPeer {
                    view,
                    face,
                    prefs: peer.prefs.clone(),
                    frames_shown: peer.frames_shown,
                });
            }
            peer_panel::join_order(&mut peers);
            (
                peers,
                s.peers.left(now),
                s.call.clone(),
                s.output_status.clone(),
                s.input_status.clone(),
                s.mic.clone(),
                s.mumble.clone(),
                s.phone.clone(),
            )
        };
        let before: Vec<_> = peers.iter().map(|p| p.prefs.clone()).collect();

        // Panels are the window's clear colour (see `clear_color`) rather than filled rectangles:
        // on a software adapter every pixel egui fills costs.
        let side = egui::Frame::side_top_panel(ui.style()).fill(egui::Color32::TRANSPARENT);
        self.ringing.show(ui, &call, &self.engine);
        egui::Panel::top("call").frame(side).show(ui, |ui| {
            call_ui(ui, &mut self.form, &mut self.settings, &call, &self.engine);
            sip_ui(ui, &mut self.sip_form, &phone, &self.engine);
        });
        if std::mem::take(&mut self.sip_form.editing) {
            self.form.settings_open = true;
        }
        let mut open = self.form.settings_open;
        settings_window(
            &ctx,
            &mut open,
            &mut self.settings,
            SettingsParts {
                form: &mut self.form,
                sip_form: &mut self.sip_form,
                inputs: &self.inputs,
                outputs: &self.outputs,
                engine: &self.engine,
            },
        );
        self.form.settings_open &= open;
        egui::Panel::bottom("audio").frame(side).show(ui, |ui| {
            audio_ui(
                ui,
                &self.mic_keys,
                &mut self.settings,
                mic.as_ref(),
                &output_status,
                &input_status,
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
            .show(ui, |ui| {
                if let Some(id) = mumble.as_ref().and_then(|view| channels_ui(ui, view)) {
                    self.engine.send(Command::Channel(id));
                }
                // Sixteen peers' rows are taller than the window.
                egui::ScrollArea::vertical().show(ui, |ui| peer_list_ui(ui, &peers));
            });
        let central = egui::Frame::central_panel(ui.style()).fill(egui::Color32::TRANSPARENT);
        egui::CentralPanel::default().frame(central).show(ui, |ui| {
            left_notice_ui(ui, &left);
            tiles_ui(ui, &mut peers, self.heads.as_mut());
        });
        if let Some(heads) = &mut self.heads {
            heads.end_frame();
        }

        if peers.iter().zip(&before).any(|(p, was)| p.prefs != *was) {
            let mut s = engine::lock(&self.engine.shared);
            for ShownPeer {
                view: p, prefs: pr, ..
            } in &peers
            {
                if let Some(peer) = s.peers.get_mut(p.peer) {
                    peer.prefs = pr.clone();
                }
                if !p.is_demo && p.named {
                    self.settings.peers.insert(p.name.clone(), pr.clone());
                }
            }
        }

        if self.last_status.elapsed() >= Duration::from_millis(500) {
            self.last_status = Instant::now();
            self.write_status(&peers, call.local_addr, call.phase.word());
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
            self.write_status(&peers, call.local_addr, call.phase.word());
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
