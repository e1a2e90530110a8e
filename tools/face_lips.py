#!/usr/bin/env python3
"""Through the face (issue 47): what a rendered head's lips show, against the GRID speakers' own.

For each clip: its audio (`sox NAME.flac -b 16 NAME.wav`, as `lipcall grid` makes it) goes
through `lipcall animate NAME.wav --frames DIR --no-life [--head HEAD] [--model MODEL]` (the
receiver's pipeline: Speex quality 8, the network, the head; 25 fps, a still head so that only
the mouth moves), the frames are tracked by MediaPipe face mesh (tools/face_track.py's
`track_points`, tracking mode, refine_landmarks: as the GRID tracks were made), and both the
render and the video (`../shared/data/grid/*/tracks/NAME.csv`) are measured as `lipcall grid`
measures lips (src/lipsync/lips.rs): nose tip as origin, the outer-eye line (33, 263) level,
the outer-eye distance the unit; aperture = the inner lips' midpoints (13, 14) apart across the
eye line, width = corner to corner (61, 291).

Frames: render frame k is drawn at k / 25 s, where `animate` shows audio frame 2k (rows at their
frame's start, 20 ms apart); video frame k is GRID's k-th (centre (k + 0.5) / 25 s). Frame k is
matched with frame k, no lag searched: the face shows the sound centred 10 ms before the video
frame's centre, as the app shows it. A frame counts where both faces were tracked. A pooled lag
profile (render frame k + L against video frame k, every clip alike, L = -2..2) is printed as a
diagnostic, never as the figure.

Clips: the 9 other-speaker clips (`other`), and s1's held-out clips (`s1`: every tenth s1 clip in
name order, `train::grid::s1_held_out`), of which `--s1-every N` takes every N-th in order
(held-out clips 0, N, 2N, ...; N = 1: all 100). Beside each through-the-face r, the weights-level
r on the same frames (the design table's aperture and width of `animate`'s weights,
src/lipsync/mouth.rs, as `evaluate --grid` and tools/lip_readout.py read them).

Per clip: aperture r and width r, face and weights; per set: the mean of the clips' r and r
pooled over all their frames, and how closely the face follows its own weights (pooled r of
the tracked render against the weights' design-table values). Renders are cached per head in
WORK (`--work`, default target/face_lips): a rerun tracks nothing twice; the PNGs are deleted
once tracked.

    python3 -m venv /tmp/face-venv && /tmp/face-venv/bin/pip install mediapipe==0.10.21
    /tmp/face-venv/bin/python tools/face_lips.py [--head HEAD.glb] [--s1-every 10]

Needs sox and a built lipcall (`--lipcall`, default target/release/lipcall, else
target/debug/lipcall). About 20 s a clip with a debug build on a busy 2-core machine (software
rendering); never part of `cargo test`.
"""

import argparse
import csv
import math
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np

os.environ.setdefault("GLOG_minloglevel", "2")  # MediaPipe's log, before it is imported
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from face_track import track_points  # noqa: E402
from lip_readout import DESIGN  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent
NOSE, EYE_R, EYE_L, CORNER_R, CORNER_L, UPPER_INNER, LOWER_INNER = 1, 33, 263, 61, 291, 13, 14
USED = (NOSE, EYE_R, EYE_L, CORNER_R, CORNER_L, UPPER_INNER, LOWER_INNER)
VIDEO_FPS = 25
AUDIO_FRAMES_PER_VIDEO_FRAME = 2  # 20 ms audio frames per 40 ms video frame


def lips(pts):
    """(aperture, width) in outer-eye distances, as src/lipsync/lips.rs; None without a face."""
    if pts is None:
        return None
    nose = np.array(pts[NOSE][:2])
    d = np.array(pts[EYE_L][:2]) - np.array(pts[EYE_R][:2])
    unit = float(np.hypot(*d))
    if unit < 1e-3:
        return None
    c, s = d / unit

    def face(i):
        x, y = np.array(pts[i][:2]) - nose
        return np.array([c * x + s * y, -s * x + c * y]) / unit

    aperture = face(LOWER_INNER)[1] - face(UPPER_INNER)[1]
    width = float(np.hypot(*(face(CORNER_L) - face(CORNER_R))))
    return (float(aperture), width)


def read_video(path):
    """Per video frame of a GRID tracks CSV, its (aperture, width) or None where untracked."""
    out = []
    with open(path) as f:
        for row in csv.DictReader(f):
            if row["tracked"] != "1":
                out.append(None)
                continue
            pts = {i: (float(row[f"x_{i}"]), float(row[f"y_{i}"]), float(row[f"z_{i}"]))
                   for i in USED}
            out.append(lips(pts))
    return out


def read_weights(path):
    """Per 20 ms row of animate's weights.csv, the design table's (aperture, width)."""
    out = []
    with open(path) as f:
        reader = csv.reader(f)
        names = next(reader)[2:]
        table = [DESIGN[n] for n in names]
        for row in reader:
            w = [float(x) for x in row[2:]]
            out.append((sum(a * x for (a, _), x in zip(table, w)),
                        sum(b * x for (_, b), x in zip(table, w))))
    return out


def pearson(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3 or a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def clip_names(tracks_dir):
    return sorted(p.name[:-len(".csv")] for p in tracks_dir.glob("*.csv"))


def clips(data, sets, s1_every):
    """(set, name, flac, tracks csv) of every clip measured, in a fixed order."""
    out = []
    if "other" in sets:
        d = data / "other-speakers"
        out += [("other", n, d / "audio" / f"{n}.flac", d / "tracks" / f"{n}.csv")
                for n in clip_names(d / "tracks")]
    if "s1" in sets:
        d = data / "s1"
        held = [n for i, n in enumerate(clip_names(d / "tracks")) if i % 10 == 0]
        out += [("s1", n, d / "audio" / f"{n}.flac", d / "tracks" / f"{n}.csv")
                for n in held[::s1_every]]
    return out


def render_and_track(lipcall, wav, head, model, work_dir, extra=()):
    """Per rendered frame (aperture, width) or None, and the weights' design-table values
    (cached as CSVs in work_dir)."""
    face_csv, weights_csv = work_dir / "face.csv", work_dir / "weights.csv"
    if not face_csv.exists():
        frames_dir = work_dir / "frames"
        cmd = [str(lipcall), "animate", str(wav), "--frames", str(frames_dir), "--no-life",
               "--weights", str(weights_csv)]
        if head:
            cmd += ["--head", str(head)]
        if model:
            cmd += ["--model", str(model)]
        cmd += list(extra)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        frames = sorted(frames_dir.glob("frame_*.png"))
        rows = [lips(p) for p in track_points(frames, USED, static=False)]
        tmp = face_csv.with_suffix(".tmp")
        with open(tmp, "w") as f:
            f.write("frame,tracked,aperture,width\n")
            for k, r in enumerate(rows):
                f.write(f"{k},1,{r[0]:.5f},{r[1]:.5f}\n" if r else f"{k},0,,\n")
        tmp.rename(face_csv)
        shutil.rmtree(frames_dir)
    face = []
    with open(face_csv) as f:
        for row in csv.DictReader(f):
            face.append((float(row["aperture"]), float(row["width"]))
                        if row["tracked"] == "1" else None)
    return face, read_weights(weights_csv)


def pairs(face, video, weights, lag=0):
    """(face, video, weights) triples of the frames where both faces were tracked."""
    out = []
    for k, v in enumerate(video):
        j = k + lag
        n = j * AUDIO_FRAMES_PER_VIDEO_FRAME
        if v is None or not 0 <= j < len(face) or face[j] is None or n >= len(weights):
            continue
        out.append((face[j], v, weights[n]))
    return out


def scores(ps):
    f, v, w = (np.array([p[i] for p in ps]) for i in range(3))
    return {"face_ap": pearson(f[:, 0], v[:, 0]), "face_w": pearson(f[:, 1], v[:, 1]),
            "wt_ap": pearson(w[:, 0], v[:, 0]), "wt_w": pearson(w[:, 1], v[:, 1])}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--head", type=pathlib.Path, help="a glTF/GLB head (default: the bundled one)")
    ap.add_argument("--model", type=pathlib.Path, help="a model file (default: the built-in one)")
    ap.add_argument("--drive", choices=("visemes", "controls"), default="visemes",
                    help="how animate drives the head (default: %(default)s)")
    ap.add_argument("--articulation", type=pathlib.Path,
                    help="an articulation network beside the model (animate --articulation)")
    ap.add_argument("--sets", default="other,s1", help="other, s1 or both (default: %(default)s)")
    ap.add_argument("--s1-every", type=int, default=10, metavar="N",
                    help="every N-th of s1's 100 held-out clips (default: %(default)s)")
    ap.add_argument("--data", type=pathlib.Path,
                    default=next((d for d in (ROOT.parent / "shared/data/grid",
                                              ROOT.parent.parent / "shared/data/grid")
                                  if d.exists()), ROOT.parent / "shared/data/grid"),
                    help="the GRID data (default: ../shared/data/grid)")
    ap.add_argument("--lipcall", type=pathlib.Path)
    ap.add_argument("--work", type=pathlib.Path, default=ROOT / "target/face_lips")
    ap.add_argument("--csv", type=pathlib.Path, help="write the per-clip scores here")
    args = ap.parse_args()
    lipcall = args.lipcall or next((p for p in (ROOT / "target/release/lipcall",
                                                ROOT / "target/debug/lipcall") if p.exists()),
                                   None)
    if lipcall is None:
        sys.exit("no lipcall binary: cargo build --release, or give --lipcall")
    sets = args.sets.split(",")
    tag = (args.head.stem if args.head else "default") + (
        f"+{args.model.stem}" if args.model else "") + (
        "+controls" if args.drive == "controls" else "") + (
        f"+{args.articulation.stem}" if args.articulation else "")
    extra = ["--drive", args.drive] + (
        ["--articulation", str(args.articulation)] if args.articulation else [])
    todo = clips(args.data, sets, args.s1_every)
    print(f"head {args.head or 'bundled'}, model {args.model or 'built-in'}, drive {args.drive}, "
          f"articulation {args.articulation or 'none'}, {lipcall}; "
          f"{len(todo)} clips; frame k of the render against frame k of the video, no lag")
    per_set = {}
    table = []
    for set_name, name, flac, track in todo:
        wav = args.work / "wav" / f"{name}.wav"
        wav.parent.mkdir(parents=True, exist_ok=True)
        if not wav.exists():
            subprocess.run(["sox", str(flac), "-b", "16", str(wav)], check=True)
        work_dir = args.work / tag / name
        work_dir.mkdir(parents=True, exist_ok=True)
        face, weights = render_and_track(lipcall, wav, args.head, args.model, work_dir, extra)
        video = read_video(track)
        ps = pairs(face, video, weights)
        s = scores(ps)
        found = sum(r is not None for r in face)
        per_set.setdefault(set_name, []).append((name, face, video, weights, s))
        table.append((set_name, name, len(ps), s))
        print(f"{set_name:5} {name}  frames {len(ps):3} (face found {found}/{len(face)})  "
              f"face: ap r {s['face_ap']:6.3f}  width r {s['face_w']:6.3f}   "
              f"weights: ap r {s['wt_ap']:6.3f}  width r {s['wt_w']:6.3f}", flush=True)
    for set_name, rows in per_set.items():
        mean = {k: float(np.nanmean([r[4][k] for r in rows])) for k in rows[0][4]}
        pooled = scores([p for r in rows for p in pairs(r[1], r[2], r[3])])
        n = sum(len(pairs(r[1], r[2], r[3])) for r in rows)
        print(f"{set_name}: {len(rows)} clips, {n} frames.  face: aperture r {mean['face_ap']:.3f} "
              f"/ width r {mean['face_w']:.3f} (clip mean), {pooled['face_ap']:.3f} / "
              f"{pooled['face_w']:.3f} (pooled).  weights: {mean['wt_ap']:.3f} / "
              f"{mean['wt_w']:.3f} (clip mean), {pooled['wt_ap']:.3f} / {pooled['wt_w']:.3f} "
              f"(pooled)")
        own = [p for r in rows for p in pairs(r[1], r[2], r[3])]
        f, w = np.array([p[0] for p in own]), np.array([p[2] for p in own])
        print(f"  the face against its own weights (pooled): aperture r "
              f"{pearson(f[:, 0], w[:, 0]):.3f}, width r {pearson(f[:, 1], w[:, 1]):.3f}")
        lags = []
        for lag in range(-2, 3):
            s = scores([p for r in rows for p in pairs(r[1], r[2], r[3], lag)])
            lags.append(f"{lag:+d}: {s['face_ap']:.3f}/{s['face_w']:.3f}")
        print("  diagnostic only, pooled face ap/width r with the render L frames later: "
              + "  ".join(lags))
    if args.csv:
        with open(args.csv, "w") as f:
            f.write("set,clip,frames,face_aperture_r,face_width_r,weights_aperture_r,"
                    "weights_width_r\n")
            for set_name, name, n, s in table:
                f.write(f"{set_name},{name},{n},{s['face_ap']:.4f},{s['face_w']:.4f},"
                        f"{s['wt_ap']:.4f},{s['wt_w']:.4f}\n")


if __name__ == "__main__":
    main()
