//! The delay estimator: how much delay the buffer needs. Each packet's relative delay
//! (arrival less its RTP time) is noted; the fastest over a window is the `base`, the spread
//! above it the network's jitter, and the pull clock's own jitter adds to it. A sender's clock
//! drifting against ours shows as a steady trend (`Trend`), which is no jitter.

use std::collections::VecDeque;

use super::JitterConfig;
use super::packets::FRAME_SECONDS;
use super::trend::Trend;

/// Pulls whose timing gives the pull clock's jitter.
const PULL_WINDOW: usize = 50;

/// The delay the buffer aims at, from the packets' delays and the pulls' timing (seconds).
#[derive(Debug)]
pub(super) struct DelayEstimator {
    config: JitterConfig,
    /// Recent packets' arrival and relative delay (arrival less RTP time), seconds.
    delays: VecDeque<(f64, f64)>,
    /// The relative delays' trend: a sender's clock drifting against ours.
    transit_trend: Trend,
    sorted: Vec<f64>,
    /// The 97th percentile of the packets' delays above the fastest (seconds), once known.
    spread: Option<f64>,
    /// The fastest relative delay, projected to now along the drift.
    base: f64,
    target: f64,
    /// How early recent pulls came (see `note_pull`), and the 90th percentile of it.
    pulls_early: VecDeque<f64>,
    pulls_sorted: Vec<f64>,
    pull_jitter: f64,
    last_pull: Option<f64>,
    /// The next pull replaces a dropped frame (it comes at the same time, and is no jitter).
    replacing: bool,
}

impl DelayEstimator {
    pub fn new(config: JitterConfig) -> Self {
        Self {
            config,
            delays: VecDeque::with_capacity(config.window),
            transit_trend: Trend::new(),
            sorted: Vec::with_capacity(config.window),
            spread: None,
            base: 0.0,
            target: config.initial_delay.as_secs_f64(),
            pulls_early: VecDeque::with_capacity(PULL_WINDOW),
            pulls_sorted: Vec::with_capacity(PULL_WINDOW),
            pull_jitter: 0.0,
            last_pull: None,
            replacing: false,
        }
    }

    /// Forgets the packets' delays (a new timeline); the pulls' timing stays.
    pub fn reset(&mut self) {
        self.delays.clear();
        self.transit_trend.clear();
        self.spread = None;
        self.base = 0.0;
        self.target = self.config.initial_delay.as_secs_f64();
    }

    /// The timeline was re-anchored: the delays' trend so far says nothing of it.
    pub fn clear_trend(&mut self) {
        self.transit_trend.clear();
    }

    /// The fastest relative delay seen lately (seconds).
    pub fn base(&self) -> f64 {
        self.base
    }

    /// How early the pulls come (the 90th percentile, seconds).
    pub fn pull_jitter(&self) -> f64 {
        self.pull_jitter
    }

    /// The delay to play at (seconds).
    pub fn target(&self) -> f64 {
        self.target
    }

    /// The next pull comes at the time of the last (it replaces a dropped frame).
    pub fn replace_next_pull(&mut self) {
        self.replacing = true;
    }

    /// A packet arriving at `now` with relative delay `r`. A sender's clock drifting against
    /// ours moves every packet's delay steadily, which is no jitter: the delays are compared
    /// as projected to now along their trend.
    pub fn observe(&mut self, now: f64, r: f64) {
        if self.delays.len() == self.config.window {
            self.delays.pop_front();
        }
        self.delays.push_back((now, r));
        self.transit_trend.note(now, r);
        let drift = self.transit_trend.drift();
        let at_now = |&(t, r): &(f64, f64)| r + drift * (now - t);
        self.base = self.delays.iter().map(at_now).fold(f64::INFINITY, f64::min);
        if self.delays.len() < 10 {
            return;
        }
        let base = self.base;
        self.sorted.clear();
        self.sorted
            .extend(self.delays.iter().map(|d| at_now(d) - base));
        self.sorted.sort_by(f64::total_cmp);
        self.spread = Some(self.sorted[(self.sorted.len() - 1) * 97 / 100]);
        self.update_target();
    }

    /// The target delay: the packets' spread and the pull clock's own jitter, plus the margin.
    fn update_target(&mut self) {
        let Some(spread) = self.spread else { return };
        let target = spread + self.pull_jitter + self.config.margin.as_secs_f64();
        self.target = target.clamp(
            self.config.min_delay.as_secs_f64(),
            self.config.max_delay.as_secs_f64(),
        );
    }

    /// A pull at `now`: how much earlier than 20 ms after the last one it came. An output that
    /// takes 40 ms at a time has its frames pulled in pairs, the second 20 ms early: its packet
    /// needs that much more delay.
    pub fn note_pull(&mut self, now: f64) {
        if let Some(last) = self.last_pull
            && !std::mem::take(&mut self.replacing)
        {
            if self.pulls_early.len() == PULL_WINDOW {
                self.pulls_early.pop_front();
            }
            self.pulls_early
                .push_back((last + FRAME_SECONDS - now).max(0.0));
            self.pulls_sorted.clear();
            self.pulls_sorted.extend(self.pulls_early.iter().copied());
            self.pulls_sorted.sort_by(f64::total_cmp);
            self.pull_jitter = self.pulls_sorted[(self.pulls_sorted.len() - 1) * 9 / 10];
            self.update_target();
        }
        self.last_pull = Some(now);
    }
}
