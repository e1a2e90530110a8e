//! The trend of a per-packet time over the last seconds: a sender's clock drifting against
//! ours. Per block of arrivals the value of its fastest packet (jitter only delays: the
//! smallest transit, the largest slack); a line through the
//! blocks once the stream has settled (`SETTLED` seconds of blocks), fitted so that a burst
//! does not tilt it: the median of the pairwise slopes (Theil-Sen) finds the line most blocks
//! lie on, blocks far off it (a stall that held up every packet of a block: a busy machine, a
//! start-up burst) are left out, and least squares through the rest gives the slope and its
//! error. A slope beyond what clocks do (`MAX_DRIFT`) is no drift either. The fit is made once
//! per block, not per packet.

use std::collections::VecDeque;

/// Seconds of arrivals one block of the trend spans.
const BLOCK: f64 = 0.25;
/// Blocks the trend is fitted over (12 s).
const BLOCKS: usize = 48;
/// Seconds of blocks before a trend is fitted (a 1 % drift must be known before a pause or
/// two has passed); a start's burst that the blocks still hold is an outlier of the fit.
const SETTLED: f64 = 1.0;
/// A block further off the robust line than this many robust standard deviations (and than
/// `NOISE_FLOOR`) is an outlier.
const OUTLIER_SIGMAS: f64 = 3.0;
/// Seconds within which blocks agree with the line whatever the spread of the others.
const NOISE_FLOOR: f64 = 0.002;
/// The fastest drift taken for clocks (8 %): crystals differ by parts per million, a
/// mis-set rate by parts per hundred; faster trends are the timing of a busy machine.
const MAX_DRIFT: f64 = 0.08;

#[derive(Debug)]
pub(super) struct Trend {
    /// The fastest packet's value is the largest (slack), not the smallest (transit).
    largest: bool,
    block_start: f64,
    block_min: f64,
    blocks: VecDeque<(f64, f64)>,
    /// The last fit (slope, standard error), made as the last block closed.
    fit: Option<(f64, f64)>,
    slopes: Vec<f64>,
    kept: Vec<(f64, f64)>,
}

impl Trend {
    /// The trend of a transit time (the smallest value of a block counts).
    pub fn new() -> Self {
        Self::of(false)
    }

    /// The trend of a slack (the largest value of a block counts).
    pub fn of_slack() -> Self {
        Self::of(true)
    }

    fn of(largest: bool) -> Self {
        Self {
            largest,
            block_start: f64::NAN,
            block_min: f64::INFINITY,
            blocks: VecDeque::with_capacity(BLOCKS),
            fit: None,
            slopes: Vec::new(),
            kept: Vec::with_capacity(BLOCKS),
        }
    }

    pub fn clear(&mut self) {
        self.block_start = f64::NAN;
        self.block_min = f64::INFINITY;
        self.blocks.clear();
        self.fit = None;
    }

    /// A packet arriving at `now` (seconds) with `value`.
    pub fn note(&mut self, now: f64, value: f64) {
        if self.block_start.is_nan() {
            self.block_start = now;
        }
        if now - self.block_start >= BLOCK {
            if self.blocks.len() == BLOCKS {
                self.blocks.pop_front();
            }
            let fastest = if self.largest {
                -self.block_min
            } else {
                self.block_min
            };
            self.blocks.push_back((self.block_start, fastest));
            self.block_start = now;
            self.block_min = f64::INFINITY;
            self.fit = self.refit();
        }
        let value = if self.largest { -value } else { value };
        self.block_min = self.block_min.min(value);
    }

    /// Seconds gained per second, and its standard error; none before the stream has settled.
    /// Of the slack: negative when the sender's clock is slower than the playout clock
    /// (packets come later and later), positive when it is faster.
    pub fn fit(&self) -> Option<(f64, f64)> {
        self.fit
    }

    /// The drift as far as it is certain: the slope less twice its standard error (0 when
    /// that leaves nothing), so that jitter is not taken for drift.
    pub fn drift(&self) -> f64 {
        self.fit.map_or(0.0, |(slope, error)| {
            slope.signum() * (slope.abs() - 2.0 * error).max(0.0)
        })
    }

    fn refit(&mut self) -> Option<(f64, f64)> {
        let (first, last) = (self.blocks.front()?.0, self.blocks.back()?.0);
        if last - first < SETTLED - BLOCK || self.blocks.len() < 4 {
            return None;
        }
        let blocks = self.blocks.make_contiguous();
        self.slopes.clear();
        for (i, &(ti, mi)) in blocks.iter().enumerate() {
            for &(tj, mj) in &blocks[i + 1..] {
                if tj > ti {
                    self.slopes.push((mj - mi) / (tj - ti));
                }
            }
        }
        let robust = median(&mut self.slopes)?;
        let mut residuals: Vec<f64> = blocks.iter().map(|&(t, m)| m - robust * t).collect();
        let intercept = median(&mut residuals)?;
        residuals
            .iter_mut()
            .zip(blocks.iter())
            .for_each(|(r, &(t, m))| *r = (m - intercept - robust * t).abs());
        let spread = 1.4826 * median(&mut residuals.clone())?;
        let limit = (OUTLIER_SIGMAS * spread).max(NOISE_FLOOR);
        self.kept.clear();
        self.kept.extend(
            blocks
                .iter()
                .zip(&residuals)
                .filter(|&(_, &r)| r <= limit)
                .map(|(&b, _)| b),
        );
        let fit = least_squares(&self.kept)?;
        (fit.0.abs() <= MAX_DRIFT).then_some(fit)
    }
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// Slope and its standard error of a least-squares line through `points` (at least 3).
fn least_squares(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len();
    if n < 3 {
        return None;
    }
    let (st, sm) = points
        .iter()
        .fold((0.0, 0.0), |(st, sm), &(t, m)| (st + t, sm + m));
    let (t_mean, m_mean) = (st / n as f64, sm / n as f64);
    let (mut num, mut den) = (0.0, 0.0);
    for &(t, m) in points {
        num += (t - t_mean) * (m - m_mean);
        den += (t - t_mean) * (t - t_mean);
    }
    if den <= 0.0 {
        return None;
    }
    let slope = num / den;
    let residual: f64 = points
        .iter()
        .map(|&(t, m)| (m - m_mean - slope * (t - t_mean)).powi(2))
        .sum();
    Some((slope, (residual / (n - 2) as f64 / den).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A trend fed one value every 20 ms for `seconds`: `value(t)`.
    fn fed(seconds: f64, value: impl Fn(f64) -> f64) -> Trend {
        let mut trend = Trend::new();
        for k in 0..(seconds * 50.0) as usize {
            let t = k as f64 * 0.02;
            trend.note(t, value(t));
        }
        trend
    }

    #[test]
    fn a_steady_drift_is_measured_once_the_stream_has_settled() {
        let early = fed(0.8, |t| 0.03 - 0.0003 * t);
        assert_eq!(early.fit(), None);
        let settled = fed(6.0, |t| 0.03 - 0.0003 * t);
        let (slope, error) = settled.fit().unwrap();
        assert!((slope + 0.0003).abs() < 1e-6, "{slope} {error}");
        assert!(settled.drift() < -0.00029);
    }

    #[test]
    fn stalls_that_hold_up_whole_blocks_do_not_tilt_the_trend() {
        // No drift; stalls of 300 ms every 2 s (every packet in them held up by up to 300 ms),
        // the first one at the start: one block in eight far above the line.
        let stalled = fed(12.0, |t| {
            let phase = t % 2.0;
            if phase < 0.3 {
                0.3 - phase + 0.02
            } else {
                0.02
            }
        });
        let (slope, _) = stalled.fit().unwrap();
        assert!(slope.abs() < 50e-6, "{slope}");
        // A trend of 20 % is a busy machine's timing, not a clock.
        let wild = fed(6.0, |t| 0.2 * t);
        assert_eq!(wild.fit(), None);
    }
}
