#!/usr/bin/env python3
"""How far free regression of the lips carries to other speakers (docs/model.md, "Fourth check").

Issue 30's stand-in, rebuilt as an analysis: a small tanh MLP reads the Speex decoder's own
features (quality 8: 10 LSPs less the speaker's causal running mean, the energy against its
running peak, the energy change; 2 past frames, the frame, 1 future frame) and regresses
aperture and width as two free numbers, not as convex viseme weights. It trains on s1's training
clips (every tenth clip in name order held out, as `lipcall grid` holds them out), optionally
with the TIMIT training regions' phone targets (dr1-dr3) beside them, each source's targets
scaled to zero mean and unit spread; dr4 is reported, the test regions are never read. Scores are
Pearson r per clip, averaged, as `lipcall evaluate --grid` reports them.

Needs numpy, the data step's output (`lipcall grid`, target/grid) and a release build. Not part
of `cargo test`; about a minute a run on two cores.

    python3 tools/free_lips.py [--timit-weight 10] [--past 2] [--hidden 16] [--seed 1] [--smoothing 0.3]
"""

import argparse
import csv
import pathlib
import subprocess
import tempfile
from collections import defaultdict

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
LIPCALL = ROOT / "target/release/lipcall"
TIMIT_TRAIN = ("dr1", "dr2", "dr3")


def speex_features(wav, cache):
    """Per-20-ms rows of 10 LSPs and the energy in dB, from a quality-8 Speex round trip."""
    out = cache / (wav.parent.name + "_" + wav.stem + ".csv")
    if not out.exists():
        with tempfile.TemporaryDirectory() as tmp:
            spx, back = pathlib.Path(tmp, "a.spx"), pathlib.Path(tmp, "a.wav")
            run = dict(check=True, capture_output=True)
            subprocess.run([LIPCALL, "encode", "--quality", "8", wav, spx], **run)
            subprocess.run([LIPCALL, "decode", "--features", out, spx, back], **run)
    return np.genfromtxt(out, delimiter=",", skip_header=1)[:, 3:14]


def inputs(rows, prior, past, future):
    """What the receiver sees per frame: causal speaker normalisation, peak-relative energy."""
    lsp, energy = rows[:, :10], rows[:, 10]
    peak = np.maximum.accumulate(energy)
    speech = energy > peak - 30
    mean = np.empty_like(lsp)
    total, count = prior * 25, 25.0
    for i in range(len(energy)):
        if speech[i]:
            total, count = total + lsp[i], count + 1
        mean[i] = total / count
    frame = np.column_stack([
        (lsp - mean) * 4,
        np.clip(energy - peak, -60, 0) / 30 + 1,
        np.diff(energy, prepend=energy[0]) / 10,
    ])
    n = len(frame)
    return np.hstack([frame[np.clip(np.arange(n) + k, 0, n - 1)] for k in range(-past, future + 1)])


def grid_clips(grid, speaker, cache):
    clips = {}
    for lips in sorted((grid / speaker).glob("*.lips.csv")):
        track = np.genfromtxt(lips, delimiter=",", skip_header=1)
        rows = speex_features(lips.with_name(lips.name.replace(".lips.csv", ".wav")), cache)
        n = min(len(rows), len(track))
        tracked = track[:n, 2] == 1
        clips[lips.name[: -len(".lips.csv")]] = (rows[:n], track[:n, 3:5], tracked)
    return clips


def timit_utterances(corpus, cache):
    """TIMIT regions dr1-dr4 with their phone targets (lip aperture, width) per frame."""
    frames = cache / "timit_frames.csv"
    if not frames.exists():
        subprocess.run([LIPCALL, "evaluate", "--corpus", corpus, "--speakers", "dr1,dr2,dr3,dr4",
                        "--per-frame", frames], check=True, capture_output=True)
    targets = defaultdict(list)
    with open(frames) as f:
        for r in csv.DictReader(f):
            targets[(r["speaker"], r["utterance"])].append(
                (float(r["target_aperture"]), float(r["target_width"])))
    utterances = {}
    for (speaker, utt), rows in targets.items():
        feats = speex_features(corpus / speaker / (utt + ".wav"), cache)
        n = min(len(feats), len(rows))
        utterances[(speaker, utt)] = (feats[:n], np.array(rows[:n]))
    return utterances


class Mlp:
    def __init__(self, n_in, hidden, rng):
        self.p = [rng.normal(0, n_in ** -0.5, (n_in, hidden)), np.zeros(hidden),
                  rng.normal(0, hidden ** -0.5, (hidden, 2)), np.zeros(2)]

    def __call__(self, x):
        w1, b1, w2, b2 = self.p
        return np.tanh(x @ w1 + b1) @ w2 + b2

    def fit(self, x, y, weight, epochs, rng, lr=0.003, batch=256):
        m = [np.zeros_like(p) for p in self.p]
        v = [np.zeros_like(p) for p in self.p]
        step = 0
        for _ in range(epochs):
            order = rng.permutation(len(x))
            for s in range(0, len(x), batch):
                i = order[s: s + batch]
                w1, b1, w2, b2 = self.p
                h = np.tanh(x[i] @ w1 + b1)
                g = 2 * (h @ w2 + b2 - y[i]) * weight[i, None] / len(i)
                gh = g @ w2.T * (1 - h * h)
                grads = [x[i].T @ gh, gh.sum(0), h.T @ g, g.sum(0)]
                step += 1
                for p, gr, mk, vk in zip(self.p, grads, m, v):
                    mk += 0.1 * (gr - mk)
                    vk += 0.001 * (gr * gr - vk)
                    p -= lr * (mk / (1 - 0.9 ** step)) / (np.sqrt(vk / (1 - 0.999 ** step)) + 1e-8)


def standard(y):
    return (y - y.mean(0)) / y.std(0)


def smooth(out, s):
    for j in range(1, len(out)):
        out[j] = s * out[j - 1] + (1 - s) * out[j]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=pathlib.Path, default=ROOT / "target/grid")
    ap.add_argument("--corpus", type=pathlib.Path, default=ROOT / "../shared/data/timit-sample")
    ap.add_argument("--cache", type=pathlib.Path, default=ROOT / "target/free_lips")
    ap.add_argument("--timit-weight", type=float, default=0.0)
    ap.add_argument("--past", type=int, default=2)
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--smoothing", type=float, default=0.0)
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)

    s1 = grid_clips(a.grid, "s1", a.cache)
    others = grid_clips(a.grid, "other", a.cache)
    names = sorted(s1)
    held = set(names[::10])
    train = [n for n in names if n not in held]
    prior = np.mean([r[:, :10][r[:, 10] > r[:, 10].max() - 30].mean(0)
                     for n, (r, _, _) in s1.items() if n in train], axis=0)
    feat = lambda rows: inputs(rows, prior, a.past, 1)

    xs = [feat(s1[n][0])[s1[n][2]] for n in train]
    ys = [standard(np.concatenate([s1[n][1][s1[n][2]] for n in train]))]
    weights = [np.ones(sum(len(x) for x in xs))]
    timit = timit_utterances(a.corpus, a.cache) if a.timit_weight > 0 else {}
    taught = [k for k in timit if k[0].startswith(TIMIT_TRAIN)]
    if taught:
        xs += [feat(timit[k][0]) for k in taught]
        ys.append(standard(np.concatenate([timit[k][1] for k in taught])))
        weights.append(np.full(len(ys[-1]), a.timit_weight))
    x, y, weight = np.concatenate(xs), np.concatenate(ys), np.concatenate(weights)
    mu, sd = x.mean(0), x.std(0) + 1e-6
    rng = np.random.default_rng(a.seed)
    net = Mlp(x.shape[1], a.hidden, rng)
    net.fit((x - mu) / sd, y, weight, a.epochs, rng)
    predict = lambda rows: smooth(net((feat(rows) - mu) / sd), a.smoothing)

    def per_clip(clips):
        r = []
        for rows, lips, tracked in clips:
            out = predict(rows)[tracked]
            r.append([np.corrcoef(out[:, c], lips[tracked, c])[0, 1] for c in range(2)])
        return np.array(r)

    print(f"free (aperture, width) MLP: {x.shape[1]} inputs, {a.hidden} hidden "
          f"({x.shape[1] * a.hidden + a.hidden * 2} multiply-adds), TIMIT weight {a.timit_weight}, "
          f"seed {a.seed}, smoothing {a.smoothing}")
    for label, clips in [("9 other speakers", [others[n] for n in sorted(others)]),
                         ("s1 held out", [s1[n] for n in sorted(held)])]:
        r = per_clip(clips)
        print(f"{label}: per-clip mean aperture r {r[:, 0].mean():.3f}, width r {r[:, 1].mean():.3f}"
              + (f" (clips: {' '.join(f'{v:.2f}' for v in r[:, 0])})" if len(r) < 20 else ""))
    valid = [k for k in timit if k[0].startswith("dr4")]
    if valid:
        out = np.concatenate([predict(timit[k][0]) for k in valid])
        target = np.concatenate([timit[k][1] for k in valid])
        print(f"TIMIT dr4 phone targets: aperture r {np.corrcoef(out[:, 0], target[:, 0])[0, 1]:.3f}, "
              f"width r {np.corrcoef(out[:, 1], target[:, 1])[0, 1]:.3f}")


if __name__ == "__main__":
    main()
