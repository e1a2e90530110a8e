//! The loss and its gradient: Kullback-Leibler divergence from the target weights plus the
//! articulatory terms, through the one hidden layer by backpropagation; Adam's parameter shapes.

use super::dataset::Dataset;
use crate::lipsync::controls::CONTROL_COUNT;
use crate::lipsync::mouth::CUE_COUNT;
use crate::lipsync::network::{LINEAR_CONTROLS, Model};
use crate::train::video::LIP_CUES;

/// Gradients (or Adam moments) shaped like the model's parameters.
#[derive(Debug, Clone)]
pub(crate) struct Params {
    pub(super) w1: Vec<f32>,
    pub(super) b1: Vec<f32>,
    pub(super) w2: Vec<f32>,
    pub(super) b2: Vec<f32>,
}

impl Params {
    pub(super) fn zeros_like(model: &Model) -> Self {
        Self {
            w1: vec![0.0; model.w1.len()],
            b1: vec![0.0; model.b1.len()],
            w2: vec![0.0; model.w2.len()],
            b2: vec![0.0; model.b2.len()],
        }
    }

    pub(super) fn slices_mut(&mut self) -> [&mut Vec<f32>; 4] {
        [&mut self.w1, &mut self.b1, &mut self.w2, &mut self.b2]
    }

    pub(super) fn clear(&mut self) {
        for s in self.slices_mut() {
            s.fill(0.0);
        }
    }
}

pub(super) fn model_params_mut(model: &mut Model) -> [&mut Vec<f32>; 4] {
    [&mut model.w1, &mut model.b1, &mut model.w2, &mut model.b2]
}

/// Weighted mean KL loss over `frames`; adds its gradient into `grad` when given.
pub(crate) fn loss_and_gradient(
    model: &Model,
    data: &Dataset,
    frames: &[usize],
    mut grad: Option<&mut Params>,
) -> f64 {
    if model.has_control_outputs() {
        return control_loss_and_gradient(model, data, frames, grad);
    }
    let (hidden_len, outputs) = (model.hidden, model.outputs());
    let mut hidden = vec![0.0; hidden_len];
    let mut probs = vec![0.0; outputs];
    let mut delta_out = vec![0.0; outputs];
    let mut delta_hidden = vec![0.0; hidden_len];
    let total_weight: f64 = frames.iter().map(|&n| data.weights[n] as f64).sum();
    if total_weight <= 0.0 {
        return 0.0;
    }
    let mut loss = 0.0f64;
    for &n in frames {
        let (x, t) = (data.input(n), data.target(n));
        model.forward(x, &mut hidden, &mut probs);
        let weight = data.weights[n] as f64 / total_weight;
        if let Some(lips) = data.video.get(n).copied().flatten() {
            loss += weight * video_loss(data, &probs, &lips, &mut delta_out);
            if let Some(grad) = grad.as_deref_mut() {
                for d in delta_out.iter_mut() {
                    *d *= weight as f32;
                }
                backprop(model, x, &hidden, &delta_out, &mut delta_hidden, grad);
            }
            continue;
        }
        let kl: f64 = t
            .iter()
            .zip(&probs)
            .filter(|(t, _)| **t > 0.0)
            .map(|(&t, &p)| t as f64 * ((t as f64) / (p as f64).max(1e-30)).ln())
            .sum();
        let mut predicted = [0.0f32; CUE_COUNT];
        for (p, c) in probs.iter().zip(&data.cues) {
            for (out, c) in predicted.iter_mut().zip(c) {
                *out += p * c;
            }
        }
        let mut errors = [0.0f32; CUE_COUNT];
        let mut cue_loss = 0.0f32;
        for (i, e) in errors.iter_mut().enumerate() {
            *e = predicted[i] - data.target_cues[n][i];
            cue_loss += data.cue_weights[i] * *e * *e;
        }
        loss += weight * (kl + cue_loss as f64);
        let Some(grad) = grad.as_deref_mut() else {
            continue;
        };
        // d(cue)/d(logit k) = p_k (cue_k - cue) through the softmax.
        for (((d, p), t), c) in delta_out.iter_mut().zip(&probs).zip(t).zip(&data.cues) {
            let mut cue_term = 0.0;
            for i in 0..CUE_COUNT {
                cue_term += 2.0 * data.cue_weights[i] * errors[i] * p * (c[i] - predicted[i]);
            }
            *d = weight as f32 * (p - t + cue_term);
        }
        backprop(model, x, &hidden, &delta_out, &mut delta_hidden, grad);
    }
    loss
}

/// A control network's loss: per frame, the squared error of each known control in units of
/// its spread (`data.control_scale`), weighted mean over `frames`; adds its gradient into
/// `grad` when given.
fn control_loss_and_gradient(
    model: &Model,
    data: &Dataset,
    frames: &[usize],
    mut grad: Option<&mut Params>,
) -> f64 {
    let mut hidden = vec![0.0; model.hidden];
    let mut out = [0.0f32; CONTROL_COUNT];
    let mut delta_out = [0.0f32; CONTROL_COUNT];
    let mut delta_hidden = vec![0.0; model.hidden];
    let total_weight: f64 = frames.iter().map(|&n| data.weights[n] as f64).sum();
    if total_weight <= 0.0 {
        return 0.0;
    }
    let mut loss = 0.0f64;
    for &n in frames {
        let weight = data.weights[n] as f64 / total_weight;
        if weight == 0.0 {
            continue;
        }
        let (x, t) = (data.input(n), data.target(n));
        model.forward(x, &mut hidden, &mut out);
        let mut frame_loss = 0.0f32;
        for c in 0..CONTROL_COUNT {
            let scale = data.known[n][c] * data.control_scale[c];
            let error = out[c] - t[c];
            frame_loss += scale * error * error;
            // Through the logistic of the bounded controls: d out / d z = out (1 - out).
            let slope = if c < LINEAR_CONTROLS {
                1.0
            } else {
                out[c] * (1.0 - out[c])
            };
            delta_out[c] = weight as f32 * 2.0 * scale * error * slope;
        }
        loss += weight * frame_loss as f64;
        if let Some(grad) = grad.as_deref_mut() {
            backprop(model, x, &hidden, &delta_out, &mut delta_hidden, grad);
        }
    }
    loss
}

/// A video frame's loss, the weighted squared errors of the aperture and width the weights
/// show through the keys; its gradient at the logits goes into `delta_out`.
fn video_loss(data: &Dataset, probs: &[f32], lips: &[f32; LIP_CUES], delta_out: &mut [f32]) -> f64 {
    let mut shown = [0.0f32; LIP_CUES];
    for (p, key) in probs.iter().zip(&data.video_keys) {
        for (s, k) in shown.iter_mut().zip(key) {
            *s += p * k;
        }
    }
    let mut errors = [0.0f32; LIP_CUES];
    let mut loss = 0.0f32;
    for i in 0..LIP_CUES {
        errors[i] = shown[i] - lips[i];
        loss += data.video_cue_weights[i] * errors[i] * errors[i];
    }
    // d(shown)/d(logit k) = p_k (key_k - shown) through the softmax.
    for ((d, p), key) in delta_out.iter_mut().zip(probs).zip(&data.video_keys) {
        *d = (0..LIP_CUES)
            .map(|i| 2.0 * data.video_cue_weights[i] * errors[i] * p * (key[i] - shown[i]))
            .sum();
    }
    loss as f64
}

/// Adds the gradient of one frame into `grad`, given the loss gradient at the output logits.
pub(super) fn backprop(
    model: &Model,
    x: &[f32],
    hidden: &[f32],
    delta_out: &[f32],
    delta_hidden: &mut [f32],
    grad: &mut Params,
) {
    let hidden_len = model.hidden;
    delta_hidden.fill(0.0);
    for (k, &d) in delta_out.iter().enumerate() {
        grad.b2[k] += d;
        let row = k * hidden_len..(k + 1) * hidden_len;
        for ((g, w), (h, dh)) in grad.w2[row.clone()]
            .iter_mut()
            .zip(&model.w2[row])
            .zip(hidden.iter().zip(delta_hidden.iter_mut()))
        {
            *g += d * h;
            *dh += d * w;
        }
    }
    for (j, (dh, h)) in delta_hidden.iter().zip(hidden).enumerate() {
        let da = dh * (1.0 - h * h);
        grad.b1[j] += da;
        for (g, xi) in grad.w1[j * x.len()..(j + 1) * x.len()].iter_mut().zip(x) {
            *g += da * xi;
        }
    }
}

/// Mean over `segments` (indices into the dataset's segments) of `-ln P(closed somewhere)`,
/// `P = 1 - prod(1 - p_closed)` over the segment's frames, times `scale`; adds its gradient
/// into `grad` when given.
pub(crate) fn segment_loss_and_gradient(
    model: &Model,
    data: &Dataset,
    segments: &[usize],
    scale: f32,
    mut grad: Option<&mut Params>,
) -> f64 {
    let Some(closed) = model.closed_index() else {
        return 0.0;
    };
    if segments.is_empty() || scale <= 0.0 {
        return 0.0;
    }
    let (hidden_len, outputs) = (model.hidden, model.outputs());
    let mut delta_out = vec![0.0; outputs];
    let mut delta_hidden = vec![0.0; hidden_len];
    let per_segment = scale as f64 / segments.len() as f64;
    let mut loss = 0.0;
    for &s in segments {
        let frames = data.segments[s].clone();
        let forward: Vec<(Vec<f32>, Vec<f32>)> = frames
            .clone()
            .map(|n| {
                let (mut h, mut p) = (vec![0.0; hidden_len], vec![0.0; outputs]);
                model.forward(data.input(n), &mut h, &mut p);
                (h, p)
            })
            .collect();
        let open: Vec<f64> = forward
            .iter()
            .map(|(_, p)| (1.0 - p[closed] as f64).max(1e-12))
            .collect();
        let all_open: f64 = open.iter().product();
        let closes = (1.0 - all_open).max(1e-12);
        loss += per_segment * -closes.ln();
        let Some(grad) = grad.as_deref_mut() else {
            continue;
        };
        for ((n, (hidden, p)), open_here) in frames.zip(&forward).zip(&open) {
            // d(-ln P)/d p_t = -prod_{s != t}(1 - p_s) / P; through the softmax:
            // d p_t / d z_k = p_t (1[k = closed] - p_k).
            let d_closed = -(all_open / open_here) / closes * per_segment;
            let p_closed = p[closed] as f64;
            for (k, d) in delta_out.iter_mut().enumerate() {
                let indicator = if k == closed { 1.0 } else { 0.0 };
                *d = (d_closed * p_closed * (indicator - p[k] as f64)) as f32;
            }
            backprop(
                model,
                data.input(n),
                hidden,
                &delta_out,
                &mut delta_hidden,
                grad,
            );
        }
    }
    loss
}
