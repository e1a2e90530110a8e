//! The delay estimator: how much delay the buffer needs. Each packet's relative delay
//! (arrival less its RTP time) is noted; the fastest over a window is the `base`, the spread
//! above it the network's jitter, and the pull clock's own jitter adds to it. A sender's clock
//! drifting against ours shows as a steady trend (`Trend`), which is no jitter.
//!
//! Spikes. A packet far above the spread the others show (a stall upstream: the sender or a
//! relay starved, its packets then coming in a burst) is a spike, left out of the spread: one
//! lone stall does not hold the delay up for the rest of the call. Spikes that repeat (two
//! starting within `PEAK_PERIOD`) are the path's jitter: while they do, the target covers the
//! highest of them (as WebRTC NetEq's delay-peak detector).

use std::collections::VecDeque;

use super::JitterConfig;
use super::packets::FRAME_SECONDS;
use super::trend::Trend;

/// Pulls whose timing gives the pull clock's jitter.
const PULL_WINDOW: usize = 50;
/// A packet more than this (seconds), and more than the spread, above the spread the others
/// show is a spike: three frames, beyond what a busy sender's pacing adds.
const SPIKE_ABOVE: f64 = 0.06;
/// Spikes that start within this many seconds of each other repeat; one is forgotten after it.
const PEAK_PERIOD: f64 = 10.0;
/// Spikes remembered at most (a stall every 2 s fills them within `PEAK_PERIOD`).
const PEAKS: usize = 8;

/// The delay the buffer aims at, from the packets' delays and the pulls' timing (seconds).
#[derive(Debug)]
pub(super) struct DelayEstimator {
    config: JitterConfig,
    /// Recent packets' arrival and relative delay (arrival less RTP time), seconds, and
    /// whether each was a spike.
    delays: VecDeque<(f64, f64, bool)>,
    /// Recent spikes: when each started and how far above the fastest it rose (seconds).
    peaks: VecDeque<(f64, f64)>,
    /// The last packet was a spike: one that follows it is of the same peak.
    in_peak: bool,
    /// The relative delays' trend: a sender's clock drifting against ours.
    transit_trend: Trend,
    sorted: Vec<f64>,
    /// The 97th percentile of the packets' delays above the fastest, spikes left out
    /// (seconds), once known.
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
            peaks: VecDeque::with_capacity(PEAKS),
            in_peak: false,
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
        self.peaks.clear();
        self.in_peak = false;
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
        self.transit_trend.note(now, r);
        let drift = self.transit_trend.drift();
        let at_now = |&(t, r, _): &(f64, f64, bool)| r + drift * (now - t);
        self.base = self.delays.iter().map(at_now).fold(r, f64::min);
        let spike = self.spike(now, r - self.base);
        self.delays.push_back((now, r, spike));
        let base = self.base;
        self.sorted.clear();
        self.sorted.extend(
            self.delays
                .iter()
                .filter(|d| !d.2)
                .map(|d| at_now(d) - base),
        );
        if self.sorted.len() < 10 {
            return;
        }
        self.sorted.sort_by(f64::total_cmp);
        self.spread = Some(self.sorted[(self.sorted.len() - 1) * 97 / 100]);
        self.update_target();
    }

    /// Whether a packet arriving at `now`, `excess` seconds above the fastest, is a spike; a
    /// spike's first packet starts a peak, the ones that follow it are of that peak.
    fn spike(&mut self, now: f64, excess: f64) -> bool {
        while self
            .peaks
            .front()
            .is_some_and(|&(t, _)| now - t > PEAK_PERIOD)
        {
            self.peaks.pop_front();
        }
        let spike = self
            .spread
            .is_some_and(|spread| excess > spread + spread.max(SPIKE_ABOVE));
        if spike {
            match self.peaks.back_mut() {
                Some((_, height)) if self.in_peak => *height = height.max(excess),
                _ => {
                    if self.peaks.len() == PEAKS {
                        self.peaks.pop_front();
                    }
                    self.peaks.push_back((now, excess));
                }
            }
        }
        self.in_peak = spike;
        spike
    }

    /// The target delay: the packets' spread and the pull clock's own jitter, plus the margin;
    /// while spikes repeat, the highest of them.
    fn update_target(&mut self) {
        let Some(spread) = self.spread else { return };
        let peak = if self.peaks.len() >= 2 {
            self.peaks.iter().map(|&(_, h)| h).fold(spread, f64::max)
        } else {
            spread
        };
        let target = peak + self.pull_jitter + self.config.margin.as_secs_f64();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A sender that stalls its stream every 200 ms for 6 s makes a spike each time: those kept
    /// stay within their cap while they repeat, and 12 s without one forgets them all.
    #[test]
    fn spikes_kept_are_capped_and_forgotten() {
        let mut estimator = DelayEstimator::new(JitterConfig::default());
        let mut now = 0.0;
        let mut packet = |estimator: &mut DelayEstimator, r: f64| {
            now += 0.02;
            estimator.observe(now, r);
        };
        for _ in 0..50 {
            packet(&mut estimator, 0.0);
        }
        for k in 0..300 {
            packet(&mut estimator, if k % 10 == 0 { 0.3 } else { 0.0 });
            assert!(estimator.peaks.len() <= PEAKS);
        }
        assert_eq!(estimator.peaks.len(), PEAKS, "30 spikes made");
        assert!(
            estimator.target() >= 0.3,
            "repeating spikes raise the target"
        );
        for _ in 0..600 {
            packet(&mut estimator, 0.0);
        }
        assert!(estimator.peaks.is_empty(), "{:?}", estimator.peaks);
        assert!(estimator.target() < 0.1, "{}", estimator.target());
    }
}
