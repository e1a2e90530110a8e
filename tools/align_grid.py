#!/usr/bin/env python3
"""Offline forced alignment of GRID speaker s1 into TIMIT-style phone files.

GRID (Cooke, Barker, Cunningham, Shao 2006; CC BY 4.0) gives each clip's word alignment
(`s1/align/NAME.align`, `START END WORD` in 1/25000 s) but no phones. This script aligns every
s1 clip's words (the align file's words without `sil`) with the same pocketsphinx step as
`tools/align_an4.py` (bundled US English model and CMU dictionary; its functions are reused)
and writes

    tools/alignments/grid-s1/NAME.phn      lines `start_sample end_sample phone`

in 16 kHz samples, contiguous from 0 to the end of the clip, TIMIT's lowercase symbols. The
audio is the clip's FLAC converted to a 16 kHz WAV by sox in a temporary folder. A clip whose
alignment fails is skipped and counted; the summary goes to stdout and, for a full run, to
`tools/alignments/grid-s1/SUMMARY.txt`. `lipcall decompose --grid` reads the phone files (phone
centres pick the key frames of the viseme shapes).

An offline data step, never part of `cargo test`. Usage (from the repository root):

    python3 -m venv /tmp/align-venv && /tmp/align-venv/bin/pip install pocketsphinx
    /tmp/align-venv/bin/python tools/align_grid.py                 # all s1 clips, 2 processes
    /tmp/align-venv/bin/python tools/align_grid.py --limit 10 --out /tmp/grid-try
"""

import argparse
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from align_an4 import (  # noqa: E402
    format_phn,
    merged_dictionary,
    run_jobs,
    summarise,
    write_dictionary,
)

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_DATA = REPO_ROOT / ".." / "shared" / "data" / "grid"
DEFAULT_OUT = REPO_ROOT / "tools" / "alignments" / "grid-s1"


def clip_words(align_path):
    """The words of a GRID `.align` file, silences left out."""
    words = []
    for line in align_path.read_text().splitlines():
        fields = line.split()
        if len(fields) == 3 and fields[2] not in ("sil", "sp"):
            words.append(fields[2].lower())
    return words


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="GRID folder (default: %(default)s)")
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="phone files (default: %(default)s)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--limit", type=int, help="align only the first N clips")
    args = ap.parse_args()
    data, out = Path(args.data), Path(args.out)
    aligns = sorted((data / "s1" / "align").glob("*.align"))
    if args.limit is not None:
        aligns = aligns[: args.limit]
    entries = merged_dictionary(None)
    start = time.monotonic()
    early_skips, jobs = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for align in aligns:
            flac = data / "s1" / "audio" / f"{align.stem}.flac"
            words = clip_words(align)
            unknown = sorted({w for w in words if w not in entries})
            if not flac.exists():
                early_skips.append((align.stem, "no audio"))
            elif not words or unknown:
                early_skips.append((align.stem, "unknown words: " + " ".join(unknown)))
            else:
                wav = Path(tmp) / f"{align.stem}.wav"
                subprocess.run(["sox", str(flac), "-r", "16000", "-c", "1", "-b", "16", str(wav)],
                               check=True)
                jobs.append((align.stem, str(wav), words))
        dict_path = Path(tmp) / "grid.dict"
        write_dictionary(entries, [w for job in jobs for w in job[2]], dict_path)
        results = run_jobs(jobs, dict_path, args.jobs)
    elapsed = time.monotonic() - start
    full_run = args.limit is None
    out.mkdir(parents=True, exist_ok=True)
    if full_run:
        for old in sorted(out.glob("*.phn")):
            old.unlink()
    audio_seconds = 0.0
    for key, segments, _, seconds, _ in results:
        if segments is not None:
            audio_seconds += seconds
            (out / f"{key}.phn").write_text(format_phn(segments))
    title = (f"GRID s1 forced alignment: pocketsphinx {metadata.version('pocketsphinx')}, "
             f"bundled en-us model and CMU dictionary, words from s1/align")
    if not full_run:
        title += f" (partial run: --limit {args.limit})"
    summary = summarise(title, len(aligns), results, early_skips, audio_seconds, elapsed)
    sys.stdout.write(summary)
    if full_run:
        (out / "SUMMARY.txt").write_text(summary.replace(f"time: {elapsed:.1f} s\n", ""))
    print(f"phone files under {out}")


if __name__ == "__main__":
    main()
