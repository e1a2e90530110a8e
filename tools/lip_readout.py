#!/usr/bin/env python3
"""How much of real lips a network's viseme weights carry, whatever shape values a head gives them.

A face shows aperture = sum_k w_k a_k and width = sum_k w_k b_k: the network's convex weights w
times each viseme shape's aperture a_k and width b_k. `evaluate --grid` scores the design table's
values (src/lipsync/mouth.rs). This reads the same weights (from `lipcall animate --weights`)
through other values, to tell whether the values or the weights hold the score back:

- design:   the design table's values (what the bundled head shows; as `evaluate --grid`);
- s1 keys:  s1's measured key shapes (clearest quarter, docs/table_i.md), in eye widths;
- s1 fit:   values fitted by least squares on s1's 100 held-out clips (never trained on);
- oracle:   values fitted on the 9 other-speaker clips themselves: the best any head's shape
            values could do with these weights (an upper bound, not a result).

Fits are on each clip's lips and weights less their own means, as the per-clip r sees them.
Scores: the mean of the clips' own Pearson r, and r pooled over all their tracked frames.

    python3 tools/lip_readout.py --model my.lipmodel        # about a minute
    python3 tools/lip_readout.py --self-test
"""

import argparse
import csv
import math
import os
import subprocess
import sys
import tempfile

VISEMES = "sil PP FF TH DD kk CH SS nn RR aa E I O U".split()
# src/lipsync/mouth.rs ARTICULATION: (lip aperture, width) per viseme.
DESIGN = {
    "sil": (0.0, 0.0), "PP": (0.0, 0.0), "FF": (0.1, 0.1), "TH": (0.3, 0.1),
    "DD": (0.3, 0.15), "kk": (0.35, 0.1), "CH": (0.3, -0.3), "SS": (0.2, 0.3),
    "nn": (0.3, 0.1), "RR": (0.25, -0.3), "aa": (1.0, 0.1), "E": (0.55, 0.4),
    "I": (0.3, 0.7), "O": (0.6, -0.5), "U": (0.2, -0.8),
}
# docs/table_i.md: s1's key shapes, clearest quarter (lip gap, width in eye widths).
S1_KEYS = {
    "sil": (0.000, 0.592), "PP": (0.002, 0.576), "FF": (0.009, 0.584), "TH": (0.006, 0.571),
    "DD": (0.131, 0.602), "kk": (0.135, 0.606), "CH": (0.140, 0.598), "SS": (0.122, 0.605),
    "nn": (0.010, 0.584), "RR": (0.005, 0.566), "aa": (0.141, 0.584), "E": (0.150, 0.609),
    "I": (0.147, 0.606), "O": (0.049, 0.530), "U": (0.010, 0.553),
}


def pearson(x, y):
    n = len(x)
    if n < 2:
        return 0.0
    mx, my = sum(x) / n, sum(y) / n
    sxy = sum((a - mx) * (b - my) for a, b in zip(x, y))
    sxx = sum((a - mx) ** 2 for a in x)
    syy = sum((b - my) ** 2 for b in y)
    return sxy / math.sqrt(sxx * syy) if sxx > 0 and syy > 0 else 0.0


def solve(a, b):
    """Solves a x = b (a square, list of rows) by Gaussian elimination with partial pivoting."""
    n = len(b)
    m = [row[:] + [b[i]] for i, row in enumerate(a)]
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(m[r][col]))
        m[col], m[pivot] = m[pivot], m[col]
        if abs(m[col][col]) < 1e-12:
            raise ValueError("singular system")
        for r in range(n):
            if r != col:
                f = m[r][col] / m[col][col]
                m[r] = [x - f * y for x, y in zip(m[r], m[col])]
    return [m[i][n] / m[i][i] for i in range(n)]


def centred(rows):
    n = len(rows)
    means = [sum(col) / n for col in zip(*rows)]
    return [[x - mu for x, mu in zip(row, means)] for row in rows]


def fit_values(clips, cue, ridge=1e-6):
    """Shape values v minimising the squared error of (w - mean w) . v against lips - mean lips
    over every clip's tracked frames. Weights sum to 1, so one direction is free: a small ridge
    picks the least-norm values."""
    k = len(clips[0][0][0])
    ata = [[0.0] * k for _ in range(k)]
    atb = [0.0] * k
    for weights, lips in clips:
        w = centred(weights)
        y = centred([[l[cue]] for l in lips])
        for row, (t,) in zip(w, y):
            for i in range(k):
                atb[i] += row[i] * t
                for j in range(k):
                    ata[i][j] += row[i] * row[j]
    for i in range(k):
        ata[i][i] += ridge * (1.0 + ata[i][i])
    return solve(ata, atb)


def score(clips, values):
    """(per-clip mean r, pooled r) of aperture and width shown through `values` (k x 2)."""
    out = []
    for cue in range(2):
        own, shown_all, real_all = [], [], []
        for weights, lips in clips:
            shown = [sum(w * v[cue] for w, v in zip(row, values)) for row in weights]
            real = [l[cue] for l in lips]
            own.append(pearson(shown, real))
            shown_all += shown
            real_all += real
        out.append((sum(own) / len(own), pearson(shown_all, real_all)))
    return out


def read_clip(lips_csv, weights_csv):
    with open(weights_csv) as f:
        rows = list(csv.DictReader(f))
    names = [n for n in rows[0].keys() if n not in ("frame", "time_s")]
    weights = {int(r["frame"]): [float(r[n]) for n in names] for r in rows}
    w, l = [], []
    with open(lips_csv) as f:
        for r in csv.DictReader(f):
            n = int(r["frame"])
            if r["tracked"] == "1" and n in weights:
                w.append(weights[n])
                l.append((float(r["aperture"]), float(r["width"])))
    return names, (w, l)


def clips_of(binary, model, lips_dir, names, tmp):
    out, set_names = [], None
    for name in names:
        weights_csv = os.path.join(tmp, name + ".weights.csv")
        cmd = [binary, "animate", os.path.join(lips_dir, name + ".wav"), "--weights", weights_csv]
        if model:
            cmd += ["--model", model]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        set_names, clip = read_clip(os.path.join(lips_dir, name + ".lips.csv"), weights_csv)
        if len(clip[0]) > 2:
            out.append(clip)
    return set_names, out


def names_in(directory):
    return sorted(f[: -len(".lips.csv")] for f in os.listdir(directory) if f.endswith(".lips.csv"))


def self_test():
    # Three shapes, lips made from weights through known values: every fit finds them again
    # (up to the free direction) and scores r = 1; the wrong values score less.
    clips = []
    for c in range(3):
        weights, lips = [], []
        for n in range(40):
            a, b = (math.sin(0.3 * n + c) + 1) / 3, (math.cos(0.7 * n) + 1) / 3
            row = [a, b, 1 - a - b]
            weights.append(row)
            lips.append((0.1 * c + 0.2 * row[0] + 0.9 * row[1], 0.5 + 0.3 * row[0] - 0.4 * row[1]))
        clips.append((weights, lips))
    values = list(zip(fit_values(clips, 0), fit_values(clips, 1)))
    (ap_clip, _), (wd_clip, wd_pooled) = score(clips, values)
    assert ap_clip > 0.999 and wd_clip > 0.999 and wd_pooled > 0.999, (ap_clip, wd_clip)
    (wrong, _), _ = score(clips, [(0.0, 0.0), (0.0, 0.0), (1.0, 0.0)])
    assert wrong < 0.9, wrong
    assert abs(pearson([1, 2, 3], [2, 4, 6.5]) - 0.9986) < 1e-3
    print("self-test passed")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", help="a model file (default: the built-in network)")
    p.add_argument("--grid", default="target/grid", help="the data step's output")
    p.add_argument("--binary", default="target/release/lipcall")
    p.add_argument("--self-test", action="store_true")
    args = p.parse_args()
    if args.self_test:
        self_test()
        return
    s1_dir, other_dir = os.path.join(args.grid, "s1"), os.path.join(args.grid, "other")
    held_out = [n for i, n in enumerate(names_in(s1_dir)) if i % 10 == 0]
    with tempfile.TemporaryDirectory() as tmp:
        set_names, s1 = clips_of(args.binary, args.model, s1_dir, held_out, tmp)
        _, others = clips_of(args.binary, args.model, other_dir, names_in(other_dir), tmp)
    fitted_s1 = list(zip(fit_values(s1, 0), fit_values(s1, 1)))
    oracle = list(zip(fit_values(others, 0), fit_values(others, 1)))
    readouts = [
        ("design", [DESIGN[n] for n in set_names]),
        ("s1 keys", [S1_KEYS[n] for n in set_names]),
        ("s1 fit", fitted_s1),
        ("oracle", oracle),
    ]
    print(f"model {args.model or 'built-in'} ({','.join(set_names)}); "
          f"{len(s1)} s1 held-out clips, {len(others)} other-speaker clips")
    print("readout   values (aperture, width) per viseme" + " " * 30
          + "s1 held out: ap / width (clip mean)   9 others: ap / width (clip mean)")
    for label, values in readouts:
        shown = " ".join(f"{n}({a:+.3f},{b:+.3f})" for n, (a, b) in zip(set_names, values))
        (s1a, s1ap), (s1w, s1wp) = score(s1, values)
        (oa, oap), (ow, owp) = score(others, values)
        print(f"{label:8}  {shown}\n          s1 {s1ap:.3f} / {s1wp:.3f} ({s1a:.3f} / {s1w:.3f})"
              f"   others {oap:.3f} / {owp:.3f} ({oa:.3f} / {ow:.3f})")


if __name__ == "__main__":
    sys.exit(main())
