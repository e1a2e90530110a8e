#!/usr/bin/env python3
"""Track rendered faces with MediaPipe face mesh and compare the lips with phone-derived truth.

    python3 -m venv .venv-track && .venv-track/bin/pip install mediapipe==0.10.21
    .venv-track/bin/python tools/face_track.py FRAMES_DIR [--truth cues.csv] [--fps 25]

FRAMES_DIR holds frame_000000.png, ... from `lipcall animate X.wav --frames FRAMES_DIR`; cues.csv
comes from `cargo run --release --example phone_cues -- X.wav X.phn`. Lengths are in eye widths
(the distance between the outer corners of the two eyes), so they compare across heads and with
video of real speakers. Prints the share of frames with a face, the lip gap's range, and, given the
truth, Pearson r of the lip gap with openness and of the mouth width with the width cue.
"""
import argparse
import csv
import math
import pathlib
import sys

import mediapipe as mp
import numpy as np
from PIL import Image

# Face mesh landmark indices: inner lip centre (upper, lower), mouth corners, outer eye corners.
UPPER_INNER, LOWER_INNER = 13, 14
MOUTH_LEFT, MOUTH_RIGHT = 61, 291
EYE_OUTER = (33, 263)


def pearson(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3 or a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def track_points(frames, indices, static=True):
    """Per frame, the face mesh landmarks `indices` as (x, y, z) in pixels (z scaled like x, as
    MediaPipe gives it), or None where no face was found. `static` tracks every frame alone (as
    `track` does); off, frames are a video (tracking mode, as the GRID tracks were made)."""
    rows = []
    with mp.solutions.face_mesh.FaceMesh(static_image_mode=static, refine_landmarks=True,
                                         max_num_faces=1) as mesh:
        for path in frames:
            image = np.asarray(Image.open(path).convert("RGB"))
            h, w = image.shape[:2]
            found = mesh.process(image).multi_face_landmarks
            if not found:
                rows.append(None)
                continue
            pts = found[0].landmark
            rows.append({i: (pts[i].x * w, pts[i].y * h, pts[i].z * w) for i in indices})
    return rows


def track(frames):
    rows = []
    used = (UPPER_INNER, LOWER_INNER, MOUTH_LEFT, MOUTH_RIGHT) + EYE_OUTER
    for pts in track_points(frames, used):
        if pts is None:
            rows.append(None)
            continue
        p = lambda i: np.array(pts[i][:2])
        eye = np.linalg.norm(p(EYE_OUTER[0]) - p(EYE_OUTER[1]))
        gap = np.linalg.norm(p(UPPER_INNER) - p(LOWER_INNER)) / eye
        width = np.linalg.norm(p(MOUTH_LEFT) - p(MOUTH_RIGHT)) / eye
        rows.append((gap, width))
    return rows


def read_truth(path):
    with open(path) as f:
        return [(float(r["time_s"]), float(r["openness"]), float(r["width"]))
                for r in csv.DictReader(f)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames", type=pathlib.Path)
    ap.add_argument("--truth", type=pathlib.Path)
    ap.add_argument("--fps", type=float, default=25.0)
    ap.add_argument("--csv", type=pathlib.Path, help="write frame,time_s,lip_gap,mouth_width")
    args = ap.parse_args()
    frames = sorted(args.frames.glob("frame_*.png"))
    if not frames:
        sys.exit(f"no frame_*.png in {args.frames}")
    rows = track(frames)
    found = [r for r in rows if r is not None]
    print(f"frames={len(rows)} face_found={len(found)} ({100.0 * len(found) / len(rows):.1f} %)")
    if not found:
        sys.exit(1)
    gaps = np.array([r[0] for r in found])
    print(f"lip_gap_eye_widths min={gaps.min():.3f} p95={np.percentile(gaps, 95):.3f} "
          f"max={gaps.max():.3f} span={gaps.max() - gaps.min():.3f}")
    if args.csv:
        with open(args.csv, "w") as f:
            f.write("frame,time_s,lip_gap,mouth_width\n")
            for k, r in enumerate(rows):
                if r is not None:
                    f.write(f"{k},{k / args.fps:.3f},{r[0]:.4f},{r[1]:.4f}\n")
    if args.truth:
        truth = read_truth(args.truth)
        pairs = []
        for k, r in enumerate(rows):
            n = int(math.floor((k / args.fps) / 0.02 + 1e-9))
            if r is not None and n < len(truth):
                pairs.append((r[0], r[1], truth[n][1], truth[n][2]))
        if pairs:
            gap, width, open_t, width_t = zip(*pairs)
            print(f"r(lip_gap, openness)={pearson(gap, open_t):.3f} "
                  f"r(mouth_width, width)={pearson(width, width_t):.3f} frames={len(pairs)}")


if __name__ == "__main__":
    main()
