//! The receive loop every transport's `receive` shares: pulls the call's frames every 20 ms,
//! mixes them, runs each peer's lip-sync pipeline and writes what it plays (OUT.wav, each
//! peer's FEATURES.csv and WEIGHTS.csv); says what the link reports.

use std::collections::{HashSet, VecDeque};
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Result;

use super::recording::{Recorder, TICK, stopped};
use crate::audio::FrameResampler;
use crate::call::link::{Link, LinkEvent};
use crate::call::pipeline::{Animated, PeerPipeline};
use crate::lipsync::network::Model;
use crate::lipsync::{self, LipSync, LipSyncOptions};
use crate::net::transport::{PeerFrame, PeerId};
use crate::vocab::FrameFeatures;

/// What the receiver keeps per remote speaker: with `--weights`, its pipeline and the output
/// ticks of the frames whose weights have not come out yet.
struct PeerTrack<'m> {
    peer: PeerId,
    pipeline: Option<PeerPipeline<'m>>,
    /// The next frame's tag (frames fed to the lip sync, counted).
    next_tag: u64,
    /// (tag, output tick) of frames waiting for their weights, oldest first.
    waiting: VecDeque<(u64, usize)>,
    /// The peer's audio to the mix's rate.
    resampler: Option<FrameResampler>,
}

impl PeerTrack<'_> {
    /// Weights the lip sync gave out (for the frame tagged `tag`) go to WEIGHTS.csv.
    fn store(
        waiting: &mut VecDeque<(u64, usize)>,
        peer: PeerId,
        out: Option<Animated<'_>>,
        recorder: &mut Recorder,
    ) -> Result<()> {
        let Some(Animated {
            tag, weights: w, ..
        }) = out
        else {
            return Ok(());
        };
        while let Some(&(t, frame)) = waiting.front() {
            if t > tag {
                break;
            }
            waiting.pop_front();
            recorder.weights(peer.number(), frame, if t == tag { w } else { &[] })?;
        }
        Ok(())
    }

    /// The frames still waiting for their look-ahead, given out now (the peer's next frame
    /// did not come in time, or the call ended).
    fn flush(&mut self, all: bool, recorder: &mut Recorder) -> Result<()> {
        if let Some(pipeline) = &mut self.pipeline {
            while let Some(out) = pipeline.flush() {
                Self::store(&mut self.waiting, self.peer, Some(out), recorder)?;
                if !all {
                    break;
                }
            }
        }
        if all {
            for (_, frame) in self.waiting.drain(..) {
                recorder.weights(self.peer.number(), frame, &[])?;
            }
        }
        Ok(())
    }
}

/// WEIGHTS.csv's viseme columns for a model (what its lip sync gives out).
fn viseme_names(model: Option<&Model>) -> Result<Vec<String>> {
    let Some(model) = model else {
        return Ok(Vec::new());
    };
    let lipsync = LipSync::new(model, &LipSyncOptions::default())?;
    Ok(lipsync
        .visemes()
        .members()
        .iter()
        .map(|v| v.name().to_string())
        .collect())
}

/// What a receive writes and how long it lasts, whatever carries the call (a Janus room, a
/// Mumble channel).
#[derive(Debug, Clone, Default)]
pub struct ReceiveOutputs {
    pub wav: Option<std::path::PathBuf>,
    /// OUT.wav's rate (else the rate of the stream first heard).
    pub rate: Option<u32>,
    pub weights: Option<std::path::PathBuf>,
    pub features: Option<std::path::PathBuf>,
    pub seconds: Option<f64>,
}

impl ReceiveOutputs {
    /// [`open_outputs`] for these paths.
    pub(crate) fn open(&self) -> Result<(Option<Model>, Recorder)> {
        open_outputs(
            self.wav.as_deref(),
            self.rate,
            self.features.as_deref(),
            self.weights.as_deref(),
        )
    }
}

/// What a receive writes (each path checked before the call: one that cannot be written fails
/// now) and the lip-sync model that `--weights` needs.
pub(crate) fn open_outputs(
    wav: Option<&Path>,
    rate: Option<u32>,
    features: Option<&Path>,
    weights: Option<&Path>,
) -> Result<(Option<Model>, Recorder)> {
    let model = weights.map(|_| lipsync::default_model());
    let names = viseme_names(model.as_ref())?;
    let recorder = Recorder::create(wav, rate, features, weights, names)?;
    Ok((model, recorder))
}

/// How a transport's messages name the call and its peers, so that each says its own.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Wording {
    /// The call as a place: "the Janus room".
    pub(crate) place: &'static str,
    /// Back in it: "back in the Janus room as".
    pub(crate) back: &'static str,
    /// What getting it back is: "rejoin" ("rejoining", "cannot rejoin yet").
    pub(crate) retry: &'static str,
    /// Before a peer's id: "session " (Mumble), nothing (a Janus feed).
    pub(crate) peer: &'static str,
    /// A peer arriving: "is publishing; subscribed".
    pub(crate) arrives: &'static str,
}

pub(crate) const JANUS: Wording = Wording {
    place: "the Janus room",
    back: "back in the Janus room as",
    retry: "rejoin",
    peer: "",
    arrives: "is publishing; subscribed",
};

pub(crate) const MUMBLE: Wording = Wording {
    place: "the Mumble server",
    back: "back on the Mumble server as session",
    retry: "reconnect",
    peer: "session ",
    arrives: "is in the channel",
};

/// lipcall's own session (a direct call or a relay room) and a SIP call.
pub(crate) const DIRECT: Wording = Wording {
    place: "the call",
    back: "back in the call as",
    retry: "rejoin",
    peer: "SSRC ",
    arrives: "is sending",
};

/// What a link said (peers coming and going, losses), on stderr in its transport's words.
pub(crate) fn print_event(event: &LinkEvent, words: Wording) {
    let Wording {
        place,
        back,
        retry,
        peer,
        arrives,
    } = words;
    match event {
        LinkEvent::Joined { place, id } => eprintln!("lipcall: in {place} as {id}"),
        LinkEvent::Failed(reason) => eprintln!("lipcall: the call failed: {reason}"),
        LinkEvent::PeerJoined { id, name } => eprintln!("lipcall: {name:?} ({peer}{id}) {arrives}"),
        LinkEvent::PeerLeft { id, name } => eprintln!("lipcall: {name:?} ({peer}{id}) left"),
        LinkEvent::PeerSkipped { id, name, reason } => {
            eprintln!("lipcall: {name:?} ({peer}{id}) cannot be heard, skipped: {reason}")
        }
        LinkEvent::Lost { reason } => eprintln!("lipcall: lost {place} ({reason}); {retry}ing"),
        LinkEvent::RejoinFailed { reason } => {
            eprintln!("lipcall: cannot {retry} yet ({reason}); trying again")
        }
        LinkEvent::Rejoined { id } => eprintln!("lipcall: {back} {id}"),
        LinkEvent::Note(said)
        | LinkEvent::Refusal(said)
        | LinkEvent::Progress(said)
        | LinkEvent::Over { reason: said }
        | LinkEvent::Ended { reason: said } => eprintln!("lipcall: {said}"),
        // A progress line names the media agreed, and the ringing.
        LinkEvent::Media { .. } | LinkEvent::Ringing => {}
    }
}

/// The receive loop: pulls every 20 ms, mixes, runs each peer's pipeline when a model is
/// given, and streams what it plays to `recorder`. Ends at `until` (the command's `--seconds`,
/// counted from its start), when every peer has left (without it), when the link says the call failed or is over, or when `stop` is
/// set (SIGINT, SIGTERM).
pub(crate) fn play<'m>(
    link: &mut dyn Link,
    words: Wording,
    until: Option<Instant>,
    model: Option<&'m Model>,
    on_frame: &mut dyn FnMut(u32, f64, &FrameFeatures),
    recorder: &mut Recorder,
    stop: &AtomicBool,
) -> Result<()> {
    let start = Instant::now();
    let mut tracks: Vec<PeerTrack> = Vec::new();
    let mut frames: Vec<PeerFrame> = Vec::new();
    // Output ticks since the first audible one.
    let mut timeline: Option<usize> = None;
    let mut tick = 0u32;
    let result = loop {
        let due = start + TICK * tick;
        tick += 1;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        if stopped(stop) {
            eprintln!("lipcall: stopped by a signal; finishing the outputs");
            break Ok(());
        }
        if until.is_some_and(|until| due >= until) {
            break Ok(());
        }
        frames.clear();
        let mut ended = false;
        for event in link.poll() {
            print_event(&event, words);
            ended |= event.ends_call();
        }
        if ended {
            break Ok(());
        }
        link.pull(due, &mut frames);
        if frames.is_empty() && timeline.is_some() && until.is_none() && link.all_left() {
            break Ok(());
        }
        if frames.is_empty() && link.over() {
            break Ok(());
        }
        if frames.is_empty() && timeline.is_none() {
            continue;
        }
        let row = timeline.get_or_insert(0);
        let index = *row;
        *row += 1;
        if let Err(e) = play_tick(&frames, index, model, &mut tracks, on_frame, recorder) {
            break Err(e);
        }
        if tick.is_multiple_of(RELEASE_EVERY)
            && let Err(e) = release_departed(&*link, &frames, &mut tracks, recorder)
        {
            break Err(e);
        }
    };
    for track in &mut tracks {
        track.flush(true, recorder)?;
    }
    result
}

/// How often (in ticks) the tracks and files of peers gone from the call are let go.
const RELEASE_EVERY: u32 = 50;

/// Finishes and lets go the track and files of every peer the link no longer has.
fn release_departed(
    link: &dyn Link,
    frames: &[PeerFrame],
    tracks: &mut Vec<PeerTrack<'_>>,
    recorder: &mut Recorder,
) -> Result<()> {
    let present: HashSet<PeerId> = link.peers().iter().map(|p| p.id).collect();
    let mut kept = Vec::with_capacity(tracks.len());
    for mut track in tracks.drain(..) {
        if present.contains(&track.peer) || frames.iter().any(|f| f.peer == track.peer) {
            kept.push(track);
        } else {
            track.flush(true, recorder)?;
            recorder.release(track.peer.number())?;
        }
    }
    *tracks = kept;
    Ok(())
}

/// One output tick: every peer's frame mixed, its features and weights recorded.
fn play_tick<'m>(
    frames: &[PeerFrame],
    index: usize,
    model: Option<&'m Model>,
    tracks: &mut Vec<PeerTrack<'m>>,
    on_frame: &mut dyn FnMut(u32, f64, &FrameFeatures),
    recorder: &mut Recorder,
) -> Result<()> {
    let heard = frames.iter().map(|f| f.frame.audio.rate()).max();
    let mix_rate = match heard {
        Some(rate) if recorder.wants_audio() => Some(recorder.mix_rate(rate)?),
        _ => None,
    };
    let mut mix = vec![0i32; mix_rate.map_or(0, |r| r as usize / 50)];
    for f in frames {
        let time = index as f64 * TICK.as_secs_f64();
        on_frame(f.peer.number(), time, &f.frame.features);
        let slot = match tracks.iter().position(|t| t.peer == f.peer) {
            Some(i) => i,
            None => {
                let pipeline = match model {
                    Some(model) => Some(PeerPipeline::new(
                        model,
                        &LipSyncOptions::default(),
                        u64::from(f.peer.number()),
                        false,
                    )?),
                    None => None,
                };
                tracks.push(PeerTrack {
                    peer: f.peer,
                    pipeline,
                    next_tag: 0,
                    waiting: VecDeque::new(),
                    resampler: None,
                });
                tracks.len() - 1
            }
        };
        let track = &mut tracks[slot];
        if let Some(to) = mix_rate {
            let from = f.frame.audio.rate();
            let resampler = match &mut track.resampler {
                Some(r) if r.from_rate() == from && r.to_rate() == to => r,
                slot => slot.insert(FrameResampler::new(from, to)?),
            };
            resampler.add_into(f.frame.audio.samples(), &mut mix)?;
        }
        recorder.features(f.peer.number(), index, &f.frame.features)?;
        if let Some(pipeline) = &mut track.pipeline {
            let tag = track.next_tag;
            track.next_tag += 1;
            track.waiting.push_back((tag, index));
            let out = pipeline.push(tag, &f.frame.features, &f.frame.pcm);
            PeerTrack::store(&mut track.waiting, f.peer, out, recorder)?;
        }
    }
    for track in tracks.iter_mut() {
        if !frames.iter().any(|f| f.peer == track.peer) {
            track.flush(false, recorder)?;
        }
    }
    let pcm: Vec<i16> = mix.iter().map(|&m| m.clamp(-32768, 32767) as i16).collect();
    recorder.audio(&pcm, !frames.is_empty())
}
