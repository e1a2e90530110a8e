//! The corrector: when the buffer inserts or drops a frame to move its delay. It tracks how
//! early each packet comes before its playout slot (its slack) and the slack's trend (clock
//! drift); from the worst slack it asks for a correction inside the next pause, or makes one at
//! once at the limits. A pause is three quiet frames in a row, as the decoder's caller heard
//! them.

use std::collections::VecDeque;

use super::packets::FRAME_SECONDS;
use super::trend::Trend;
use super::{Correction, JitterConfig, Loudness};

/// Packets whose slack steers the delay while playing.
pub(super) const SLACK_WINDOW: usize = 100;
/// Quiet frames in a row before the buffer corrects inside them: a pause, not a stop's
/// closure within a word.
const QUIET_RUN: u32 = 3;
/// Frames between two corrections inside a pause.
const QUIET_INTERVAL: u32 = 3;
/// The longest the buffer expects speech to go on without a pause, in seconds: against a slow
/// sender it keeps the delay the drift would eat meanwhile.
const ANTICIPATION: f64 = 3.0;
/// Spare delay, in seconds, beyond what the buffer sheds in pauses, at which it drops a frame
/// whatever its loudness (a sound that never pauses, from a fast sender).
const FORCED_SPARE: f64 = 0.2;
/// Delay a start held up by this much (seconds) or more than it asked for is shed in a pause,
/// when the worst slack allows a frame less: half a frame, so that a start one frame late less
/// a few milliseconds of jitter is not kept for the whole call.
const HELD_UP: f64 = 0.5 * FRAME_SECONDS;
/// A drift of the slack faster than this (seconds per second, 0.05 %) is a fast sender: the
/// buffer sheds spare delay in pauses from a lower level than a jitter-free start can show.
const FAST_DRIFT: f64 = 0.0005;

/// What the last adaptation asked for, to be done inside a pause.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Want {
    Nothing,
    Grow,
    Shrink,
}

/// What the buffer is to do with the frame it is popping ([`Corrector::adapt`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Adjust {
    None,
    /// Insert a frame, as asked after a quiet one.
    Stretch,
    /// Insert a frame now, whatever the audio: a packet is about to be late.
    ForcedStretch,
    /// Skip the next slot now, whatever the audio: far more delay than needed.
    ForcedSkip,
}

/// See [`Corrector::limits`].
struct Limits {
    grow_forced: f64,
    grow_quiet: f64,
    shrink_quiet: f64,
    shrink_forced: f64,
}

#[derive(Debug)]
pub(super) struct Corrector {
    margin: f64,
    adapt_interval: u32,
    /// How early each recent packet arrived before its playout slot, and when, in seconds; and
    /// whether it came after its slot's tick yet before the slot was pulled (a puller held up).
    slack: VecDeque<(f64, f64, bool)>,
    slack_sorted: Vec<f64>,
    /// The delay the corrections added since playout started (seconds): the slack trend
    /// measures without it.
    shifted: f64,
    trend: Trend,
    since_adjust: u32,
    /// A correction to make inside a pause, asked for by the last pop.
    want: Want,
    /// Quiet frames played in a row.
    quiet_run: u32,
    /// Frames played since the last pause (a run of `QUIET_RUN` quiet frames).
    since_pause: u32,
    /// The next pop inserts a frame (a pause is on and the delay is short).
    insert_next: bool,
    /// The last pop handed out received audio (which may be dropped).
    handed_audio: bool,
    /// The fastest relative delay when playout started, less the delay playout started above
    /// its target and the frames shed since (seconds): see [`Corrector::adapt`].
    start_base: f64,
}

impl Corrector {
    pub fn new(config: &JitterConfig) -> Self {
        Self {
            margin: config.margin.as_secs_f64(),
            adapt_interval: config.adapt_interval,
            slack: VecDeque::with_capacity(SLACK_WINDOW),
            slack_sorted: Vec::with_capacity(SLACK_WINDOW),
            shifted: 0.0,
            trend: Trend::of_slack(),
            since_adjust: 0,
            want: Want::Nothing,
            quiet_run: 0,
            since_pause: 0,
            insert_next: false,
            handed_audio: false,
            start_base: f64::NAN,
        }
    }

    /// Playout starts (a talk spurt), with `base` the fastest relative delay seen so far and
    /// `above` the delay it starts with above its target (its oldest packet was older than the
    /// target asked: a burst): slack and trend are measured afresh.
    pub fn start(&mut self, base: f64, above: f64) {
        self.start_base = base + above.max(0.0);
        self.slack.clear();
        self.trend.clear();
        self.shifted = 0.0;
        self.quiet_run = 0;
        self.insert_next = false;
        self.since_adjust = 0;
    }

    /// Playout resumed `frames` frames behind after a stall upstream: the delay the stall
    /// added is surplus, as a held-up start's is, shed in the next pauses down to where the
    /// delay was before it.
    pub fn resumed(&mut self, frames: i64) {
        self.start_base += frames as f64 * FRAME_SECONDS;
    }

    /// The timeline lost its slack (a new one): the slack kept says nothing of it.
    pub fn forget_slack(&mut self) {
        self.slack.clear();
        self.trend.clear();
    }

    /// The timeline was re-anchored: the trend so far says nothing of it.
    pub fn clear_trend(&mut self) {
        self.trend.clear();
    }

    /// The delay played at is a frame or more below the target the packets' spread asks for
    /// (it rose since playout started: a path that got busier): grow in the next pause,
    /// before its late packets are concealed.
    pub fn below_target(&mut self) {
        if self.want == Want::Nothing && self.since_adjust >= QUIET_INTERVAL {
            self.want = Want::Grow;
        }
    }

    /// A pop begins: nothing asked for, nothing handed out yet.
    pub fn begin_pop(&mut self) {
        self.want = Want::Nothing;
        self.handed_audio = false;
    }

    /// The pop handed out received audio.
    pub fn handed_audio(&mut self) {
        self.handed_audio = true;
    }

    /// A packet arrived at `now` while playing, `slack` seconds before its slot's playout.
    pub fn note_slack(&mut self, now: f64, slack: f64, in_time: bool) {
        if self.slack.len() == SLACK_WINDOW {
            self.slack.pop_front();
        }
        self.slack.push_back((now, slack, in_time && slack < 0.0));
        self.trend.note(now, slack - self.shifted);
    }

    /// The slack's drift in parts per million, 0 until known.
    pub fn drift_ppm(&self) -> f64 {
        self.trend.fit().map_or(0.0, |(slope, _)| slope * 1e6)
    }

    /// What a pop at `now` is to do to the delay; `room` says whether it may grow,
    /// `can_skip` whether the slot after the next is here to play instead. `base` is the
    /// fastest relative delay now, `pull_jitter` how early the pulls come (delay the slack does
    /// not show). When playout started on packets that were held up (a sender's capture or
    /// start-up burst: playout started with more delay than its target, or the fastest packets
    /// since came faster than those it started on) by [`HELD_UP`] or more, that delay is more
    /// than the start asked for, and a frame of it is shed in a pause as soon as the worst slack
    /// allows a frame less.
    pub fn adapt(
        &mut self,
        now: f64,
        room: bool,
        (base, pull_jitter): (f64, f64),
        can_skip: impl FnOnce() -> bool,
    ) -> Adjust {
        self.since_adjust = self.since_adjust.saturating_add(1);
        if std::mem::take(&mut self.insert_next) && room {
            // Asked for after a quiet frame (`played`).
            return Adjust::Stretch;
        }
        // With frames of surplus to shed (a stall's, a held-up start's) every quiet frame of a
        // pause may go: the stall's delay is gone within a pause or two.
        let surplus = self.start_base - base;
        let interval = if surplus >= 2.0 * FRAME_SECONDS {
            1
        } else {
            QUIET_INTERVAL
        };
        if self.since_adjust >= interval && self.slack.len() >= 10 {
            // The worst slack, each packet's projected to now along the drift: against a
            // drifting sender the oldest packets' slack is no longer what the buffer keeps.
            let drift = self.trend.drift();
            self.slack_sorted.clear();
            // A packet that came after its slot's tick but before the slot was pulled (the
            // puller held up by a busy machine, the packet's stamp held up alike) counts as
            // one just in time: it asks for more delay in the next pause, never a frame
            // inserted in speech.
            let just_in_time = 0.5 * self.grow_forced();
            self.slack_sorted
                .extend(self.slack.iter().map(|&(t, s, held)| {
                    if held {
                        just_in_time
                    } else {
                        s + drift * (now - t)
                    }
                }));
            self.slack_sorted.sort_by(f64::total_cmp);
            let worst = self.slack_sorted.len() / 50;
            let low = self.slack_sorted[worst];
            let mut limits = self.limits();
            let forcing = self
                .slack
                .iter()
                .filter(|&&(t, s, held)| !held && s + drift * (now - t) < limits.grow_forced)
                .count();
            if surplus >= HELD_UP {
                let spare = limits.grow_quiet + self.margin + pull_jitter + FRAME_SECONDS;
                limits.shrink_quiet = limits.shrink_quiet.min(spare);
            }
            let due = self.since_adjust >= self.adapt_interval;
            if forcing > worst && due && room {
                return Adjust::ForcedStretch;
            }
            if self.since_adjust < QUIET_INTERVAL && low >= limits.grow_quiet {
                // Between two quick sheds: nothing but shrinking is due yet.
                if low > limits.shrink_quiet {
                    self.want = Want::Shrink;
                }
                return Adjust::None;
            }
            if low < limits.grow_quiet && room {
                self.want = Want::Grow;
            } else if self.slack.len() >= SLACK_WINDOW / 2 && low > limits.shrink_quiet {
                // Shrinking waits for a fuller picture: start-up bursts look like spare delay.
                self.want = Want::Shrink;
                // Surplus is shed in pauses; a loud frame goes only when none came for as long
                // as speech usually goes on without one (a sound that never pauses).
                let no_pause = f64::from(self.since_pause) * FRAME_SECONDS >= ANTICIPATION;
                if due && no_pause && low > limits.shrink_forced && can_skip() {
                    return Adjust::ForcedSkip;
                }
            }
        }
        Adjust::None
    }

    /// The worst slack below which the buffer inserts a frame whatever the audio.
    fn grow_forced(&self) -> f64 {
        0.25 * self.margin
    }

    /// Where the buffer corrects its delay, by the worst slack (seconds): below `grow_forced`
    /// it inserts a frame at once, below `grow_quiet` in the next pause; above `shrink_quiet`
    /// it drops a quiet frame, above `shrink_forced` any frame.
    fn limits(&self) -> Limits {
        let margin = self.margin;
        // A drift three standard errors from none, at the slope measured.
        let drift = self
            .trend
            .fit()
            .filter(|&(slope, error)| slope.abs() > 3.0 * error)
            .map_or(0.0, |(slope, _)| slope);
        let grow_forced = self.grow_forced();
        // Against a slow sender: the delay the drift eats before the next pause is likely (and
        // some, however slow it is, so that there is a pause to grow in before the limit).
        let grow_quiet = if drift < 0.0 {
            grow_forced + (-drift * ANTICIPATION).clamp(0.5 * margin, 4.0 * FRAME_SECONDS)
        } else {
            grow_forced
        };
        // Without drift, only more spare delay than a jitter-free link can show: playout starts
        // on a 20 ms output tick (up to a frame above the target) and whole frames are rounded
        // onto the grid (up to half a frame early). A fast sender's surplus is shed from lower
        // down, a frame above where the buffer would grow.
        let shrink_quiet = if drift > FAST_DRIFT {
            grow_quiet + margin + FRAME_SECONDS
        } else {
            (margin + 3.0 * FRAME_SECONDS).max(grow_quiet + margin + FRAME_SECONDS)
        };
        Limits {
            grow_forced,
            grow_quiet,
            shrink_quiet,
            shrink_forced: shrink_quiet + FORCED_SPARE,
        }
    }

    /// A frame was inserted: 20 ms more delay.
    pub fn grew(&mut self) {
        self.since_adjust = 0;
        self.slack
            .iter_mut()
            .for_each(|(_, s, _)| *s += FRAME_SECONDS);
        self.shifted += FRAME_SECONDS;
    }

    /// A frame was skipped: 20 ms less delay.
    pub fn shrank(&mut self) {
        self.since_adjust = 0;
        self.start_base -= FRAME_SECONDS;
        self.slack
            .iter_mut()
            .for_each(|(_, s, _)| *s -= FRAME_SECONDS);
        self.shifted -= FRAME_SECONDS;
    }

    /// How loud the frame just handed out played, while `playing`: inside a pause, the
    /// correction asked for. Received audio only is dropped, and only when `next_here` says
    /// what follows is here.
    pub fn played(&mut self, loudness: Loudness, playing: bool, next_here: bool) -> Correction {
        if loudness == Loudness::Audible || !playing {
            self.quiet_run = 0;
            self.since_pause = self.since_pause.saturating_add(1);
            return Correction::Keep;
        }
        self.quiet_run = self.quiet_run.saturating_add(1);
        if self.quiet_run < QUIET_RUN {
            self.since_pause = self.since_pause.saturating_add(1);
            return Correction::Keep;
        }
        self.since_pause = 0;
        match std::mem::replace(&mut self.want, Want::Nothing) {
            Want::Grow => {
                self.insert_next = true;
                Correction::Insert
            }
            Want::Shrink if self.handed_audio && next_here => {
                self.shrank();
                self.handed_audio = false;
                Correction::Drop
            }
            _ => Correction::Keep,
        }
    }
}
