#!/usr/bin/env python3
"""Offline forced alignment of CMU AN4 into TIMIT-style phone files.

AN4 (https://github.com/cmusphinx/an4, CMU's licence: free for any use, keep its copyright
notice) has transcripts but no time-aligned phones. This script aligns every utterance with the
PyPI `pocketsphinx` wheel (its bundled US English acoustic model; the words' pronunciations come
from the bundled CMU dictionary merged with AN4's own `etc/an4.dic`) and writes one phone file
per utterance:

    tools/alignments/an4/<speaker>/<utt>.phn      lines `start_sample end_sample phone`

in 16 kHz samples, contiguous from 0 to the end of the WAV, phones in TIMIT's lowercase symbols
(ARPAbet lowercased; silence at the start and end `h#`, inner silence and noise `pau`).
An utterance that cannot be aligned is skipped and counted; the summary goes to stdout and, for
a full run, to `tools/alignments/an4/SUMMARY.txt`.

This is an offline data step, never part of `cargo test`. Usage (from the repository root):

    python3 -m venv /tmp/align-venv && /tmp/align-venv/bin/pip install pocketsphinx
    /tmp/align-venv/bin/python tools/align_an4.py                  # all of AN4, 2 processes
    /tmp/align-venv/bin/python tools/align_an4.py --limit 20 --out /tmp/an4-try
    /tmp/align-venv/bin/python tools/align_an4.py --check-timit   # accuracy on the TIMIT sample

`--check-timit` aligns the hand-labelled TIMIT sample from its transcripts and prints how well
the aligner agrees with the hand labels. It writes nothing: the TIMIT sample is CC BY-NC-SA and
nothing derived from it belongs in the repository.

The output is deterministic: the same corpus and pocketsphinx version give the same files,
whatever `--jobs` is.
"""

import argparse
import multiprocessing
import re
import sys
import tempfile
import time
import wave
from collections import Counter
from importlib import metadata
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CORPUS = REPO_ROOT / ".." / "shared" / "data" / "an4"
DEFAULT_TIMIT = REPO_ROOT / ".." / "shared" / "data" / "timit-sample"
DEFAULT_OUT = REPO_ROOT / "tools" / "alignments" / "an4"

RATE = 16000
# pocketsphinx's frame shift: 100 frames per second.
SAMPLES_PER_FRAME = RATE // 100
# Frame k's analysis window (pocketsphinx's default 25.625 ms = 410 samples) starts at sample
# k * 160, so its centre is at k * 160 + 205, and the boundary between frames k - 1 and k lies
# halfway between their centres: k * 160 + 125. Fixed by the window geometry, not fitted.
BOUNDARY_OFFSET = (410 - SAMPLES_PER_FRAME) // 2
# AN4's two halves: folder under wav/ -> transcript under etc/.
AN4_PARTS = [
    ("an4_clstk", "an4_train.transcription"),
    ("an4test_clstk", "an4_test.transcription"),
]
# Sentence markers some transcripts carry; not words.
MARKERS = {"<s>", "</s>", "<sil>"}
# A speech phone this long means the aligner has pushed a word over noise or a gap.
MAX_PHONE_SECONDS = 1.0
SILENCES = {"h#", "pau", "epi"}

# The phones src/lipsync/phones.rs accepts, and their viseme targets (transcribed from
# `phone_target`): a viseme name, a (first half, second half) pair for diphthongs, or None
# for phones that take their shape from the neighbours.
VISEME = {}
for _names, _target in [
    ("h# pau epi", "sil"),
    ("p b m em pcl bcl", "PP"),
    ("f v", "FF"),
    ("th dh", "TH"),
    ("t d dx tcl dcl", "DD"),
    ("k g ng eng kcl gcl", "kk"),
    ("ch jh sh zh", "CH"),
    ("s z", "SS"),
    ("n en nx l el", "nn"),
    ("r er axr", "RR"),
    ("aa ae ah", "aa"),
    ("eh ax ax-h", "E"),
    ("ih ix iy y", "I"),
    ("ao", "O"),
    ("uh uw ux w", "U"),
    ("ey", ("E", "I")),
    ("ay", ("aa", "I")),
    ("aw", ("aa", "U")),
    ("ow", ("O", "U")),
    ("oy", ("O", "I")),
    ("hh hv q", None),
]:
    for _phone in _names.split():
        VISEME[_phone] = _target


# ---------------------------------------------------------------------------------------------
# Pronunciations


def read_dictionary(path, entries):
    """Adds the pronunciations of a Sphinx dictionary (`WORD(n) PH PH ..`) to `entries`
    (lowercase word -> list of phone strings, first seen first), skipping duplicates."""
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            fields = line.split()
            if len(fields) < 2:
                continue
            word = re.sub(r"\(\d+\)$", "", fields[0]).lower()
            phones = " ".join(p.upper() for p in fields[1:])
            prons = entries.setdefault(word, [])
            if phones not in prons:
                prons.append(phones)


def bundled_model():
    import pocketsphinx

    return Path(pocketsphinx.get_model_path()) / "en-us"


def merged_dictionary(extra_dic):
    """The bundled CMU dictionary, with the pronunciations of `extra_dic` (if any) added."""
    entries = {}
    read_dictionary(bundled_model() / "cmudict-en-us.dict", entries)
    if extra_dic is not None:
        read_dictionary(extra_dic, entries)
    return entries


def write_dictionary(entries, words, path):
    """Writes the pronunciations of `words` as a Sphinx dictionary."""
    with open(path, "w", encoding="utf-8") as f:
        for word in sorted(set(words)):
            for i, phones in enumerate(entries[word]):
                name = word if i == 0 else f"{word}({i + 1})"
                f.write(f"{name} {phones}\n")


# ---------------------------------------------------------------------------------------------
# Alignment (runs in the worker processes)

_dict_path = None
# Silence added at both ends on a second try, when the audio stops too abruptly for the
# aligner's final silence (pocketsphinx then fails with "Failed to stop utterance processing").
PAD_FRAMES = 30


def init_worker(dict_path):
    global _dict_path
    _dict_path = str(dict_path)


class Skip(Exception):
    """An utterance that cannot be aligned; the message is the reason, for the summary."""


def read_wav(path):
    try:
        with wave.open(str(path), "rb") as w:
            if (w.getframerate(), w.getnchannels(), w.getsampwidth()) != (RATE, 1, 2):
                raise Skip("not 16 kHz mono 16-bit")
            return w.readframes(w.getnframes()), w.getnframes()
    except (wave.Error, EOFError, OSError) as e:
        raise Skip(f"unreadable WAV ({e})") from None


def decode(data, words):
    """Force-aligns `words`; returns pocketsphinx phones as (NAME, start_frame, frames).

    A fresh decoder per utterance: a reused one carries state (cepstral mean, search) from
    one utterance to the next, which would make the labels depend on the order of the work."""
    from pocketsphinx import Decoder

    d = Decoder(samprate=RATE, lm=None, dict=_dict_path, loglevel="FATAL", bestpath=False)
    try:
        d.set_align_text(" ".join(words))
        d.start_utt()
        d.process_raw(data, full_utt=True)
        d.end_utt()
        if d.hyp() is None:
            raise Skip("no alignment (first pass)")
        d.set_alignment()
        d.start_utt()
        d.process_raw(data, full_utt=True)
        d.end_utt()
        alignment = d.get_alignment()
    except RuntimeError as e:
        raise Skip(f"decoder error ({e})") from None
    if alignment is None:
        raise Skip("no alignment (second pass)")
    aligned_words = [
        re.sub(r"\(\d+\)$", "", w.name)
        for w in alignment.words()
        if not (w.name in MARKERS or w.name.startswith("[") or w.name.startswith("+"))
    ]
    if aligned_words != list(words):
        raise Skip("aligned words differ from the transcript")
    return [(p.name, p.start, p.duration) for p in alignment.phones()]


def decode_padded(data, n_samples, words):
    """`decode` on the audio with PAD_FRAMES of digital silence at each end, the phones
    clipped back to the original audio."""
    pad = b"\0\0" * (PAD_FRAMES * SAMPLES_PER_FRAME)
    n_frames = -(-n_samples // SAMPLES_PER_FRAME)
    phones = []
    for name, start, frames in decode(pad + data + pad, words):
        start, end = start - PAD_FRAMES, start + frames - PAD_FRAMES
        start, end = max(start, 0), min(end, n_frames)
        if end > start:
            phones.append((name, start, end - start))
        elif name != "SIL":
            raise Skip("degenerate: speech aligned to the padding")
    return phones


def timit_phone(name):
    """A pocketsphinx phone as a TIMIT phone; None for silence (placed later)."""
    if name == "SIL":
        return None
    if name.startswith("+") or name.startswith("["):
        return "pau"
    phone = name.lower()
    if phone not in VISEME:
        raise Skip(f"phone {name} has no TIMIT symbol")
    return phone


def to_segments(phones, n_samples):
    """Pocketsphinx phones -> contiguous TIMIT segments (start, end, phone) in samples, from 0
    to `n_samples`. Raises Skip on a degenerate alignment."""
    if not phones:
        raise Skip("degenerate: no phones")
    for (_, start, frames), (_, next_start, _) in zip(phones, phones[1:]):
        if frames <= 0 or start + frames != next_start:
            raise Skip("degenerate: phones not contiguous")
    labels = [timit_phone(name) for name, _, _ in phones]
    speech = [i for i, label in enumerate(labels) if label is not None and label != "pau"]
    if not speech:
        raise Skip("degenerate: no speech phones")
    for i, label in enumerate(labels):
        if label is None:
            labels[i] = "h#" if i < speech[0] or i > speech[-1] else "pau"
    starts = [start * SAMPLES_PER_FRAME + BOUNDARY_OFFSET for _, start, _ in phones]
    starts[0] = 0
    ends = starts[1:] + [n_samples]
    segments = []
    for start, end, label in zip(starts, ends, labels):
        if end <= start:
            raise Skip("degenerate: alignment runs past the end of the audio")
        if segments and label in SILENCES and segments[-1][2] == label:
            segments[-1] = (segments[-1][0], end, label)
        else:
            segments.append((start, end, label))
    for start, end, label in segments:
        if label not in SILENCES and (end - start) > MAX_PHONE_SECONDS * RATE:
            raise Skip(f"degenerate: a phone longer than {MAX_PHONE_SECONDS:g} s")
    return segments


def align_job(job):
    """(key, wav path, words) -> (key, segments or None, skip reason or None, seconds of
    audio, whether it took the padded second try)."""
    key, wav_path, words = job
    try:
        data, n_samples = read_wav(wav_path)
        try:
            phones, padded = decode(data, words), False
        except Skip as first:
            try:
                phones, padded = decode_padded(data, n_samples, words), True
            except Skip as second:
                raise Skip(f"{first}; padded: {second}") from None
        return key, to_segments(phones, n_samples), None, n_samples / RATE, padded
    except Skip as e:
        return key, None, str(e), 0.0, False


def run_jobs(jobs, dict_path, n_procs):
    """Results in the order of `jobs`, whatever the number of processes."""
    init_worker(dict_path)
    if n_procs <= 1:
        return [align_job(j) for j in jobs]
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(n_procs, initializer=init_worker, initargs=(dict_path,)) as pool:
        return list(pool.imap(align_job, jobs, chunksize=4))


def format_phn(segments):
    return "".join(f"{start} {end} {phone}\n" for start, end, phone in segments)


# ---------------------------------------------------------------------------------------------
# AN4


def read_transcripts(path):
    """`[<s>] WORDS [</s>] (utt-id)` lines -> {utt-id: [lowercase words]}."""
    out = {}
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            m = re.match(r"^(.*)\((\S+)\)\s*$", line)
            if not m:
                if line.strip():
                    print(f"{path}:{n}: unparsed line {line.strip()!r}", file=sys.stderr)
                continue
            words = [w.lower() for w in m.group(1).split() if w.lower() not in MARKERS]
            out[m.group(2)] = words
    return out


def an4_jobs(corpus):
    """Every AN4 WAV with its transcript, sorted; and the skips found before aligning."""
    jobs, skipped = [], []
    for folder, transcript in AN4_PARTS:
        texts = read_transcripts(corpus / "etc" / transcript)
        wavs = sorted((corpus / "wav" / folder).glob("*/*.wav"))
        for wav in wavs:
            key = f"{wav.parent.name}/{wav.stem}"
            words = texts.pop(wav.stem, None)
            if not words:
                skipped.append((key, "no transcript"))
            else:
                jobs.append((key, str(wav), words))
        for utt in sorted(texts):
            skipped.append((f"?/{utt}", "transcript without a WAV"))
    return jobs, skipped


def summarise(title, n_total, results, early_skips, audio_seconds, elapsed, extra=()):
    aligned = [r for r in results if r[2] is None]
    skipped = [(r[0], r[2]) for r in results if r[2] is not None] + list(early_skips)
    reasons = Counter(reason for _, reason in skipped)
    padded = sorted(r[0] for r in aligned if r[4])
    lines = [
        title,
        f"utterances: {n_total}",
        f"aligned: {len(aligned)} ({audio_seconds / 60:.1f} min of audio), of which "
        f"{len(padded)} on a second try with {PAD_FRAMES * 10} ms of silence added at each end"
        + (f" ({', '.join(padded)})" if padded else ""),
        f"skipped: {len(skipped)}",
    ]
    for reason, count in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0])):
        lines.append(f"  {count:4d}  {reason}")
    for key, reason in sorted(skipped):
        lines.append(f"  skipped {key}: {reason}")
    lines.extend(extra)
    lines.append(f"time: {elapsed:.1f} s")
    return "\n".join(lines) + "\n"


def align_an4(args):
    corpus = Path(args.corpus)
    out = Path(args.out)
    jobs, early_skips = an4_jobs(corpus)
    n_total = len(jobs) + len(early_skips)
    if args.limit is not None:
        jobs, early_skips = jobs[: args.limit], []
        n_total = len(jobs)
    entries = merged_dictionary(corpus / "etc" / "an4.dic")
    known = []
    for job in jobs:
        unknown = sorted({w for w in job[2] if w not in entries})
        if unknown:
            early_skips.append((job[0], "unknown words: " + " ".join(unknown)))
        else:
            known.append(job)
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        dict_path = Path(tmp) / "an4-merged.dict"
        write_dictionary(entries, [w for job in known for w in job[2]], dict_path)
        results = run_jobs(known, dict_path, args.jobs)
    elapsed = time.monotonic() - start

    full_run = args.limit is None
    if full_run:
        # Remove the labels of an earlier run, so that a skipped utterance leaves no stale file.
        for old in sorted(out.glob("*/*.phn")):
            old.unlink()
        for folder in sorted(p for p in out.glob("*") if p.is_dir()):
            if not any(folder.iterdir()):
                folder.rmdir()
    audio_seconds = 0.0
    for key, segments, reason, seconds, _ in results:
        if segments is None:
            continue
        audio_seconds += seconds
        path = out / f"{key}.phn"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(format_phn(segments))

    title = (
        f"AN4 forced alignment: pocketsphinx {metadata.version('pocketsphinx')}, "
        f"bundled en-us model, CMU dictionary + etc/an4.dic"
    )
    if not full_run:
        title += f" (partial run: --limit {args.limit})"
    summary = summarise(title, n_total, results, early_skips, audio_seconds, elapsed)
    sys.stdout.write(summary)
    if full_run:
        (out / "SUMMARY.txt").write_text(summary.replace(f"time: {elapsed:.1f} s\n", ""))
    print(f"phone files under {out}")


# ---------------------------------------------------------------------------------------------
# Accuracy against TIMIT's hand labels


def read_phn(path):
    segments = []
    with open(path) as f:
        for line in f:
            fields = line.split()
            if len(fields) == 3:
                segments.append((int(fields[0]), int(fields[1]), fields[2]))
    return segments


def timit_words(text):
    """Words of a TIMIT `.txt` line (`start end Words ...`): lowercase, punctuation dropped."""
    words = []
    for token in text.split()[2:]:
        word = re.sub(r"[^a-z'\-]", "", token.lower()).strip("'-")
        if word:
            words.append(word)
    return words


def in_dictionary(words, entries):
    """Words with unknown hyphenated compounds split into their parts; None if still unknown."""
    out = []
    for word in words:
        if word in entries:
            out.append(word)
        elif "-" in word and all(part in entries for part in word.split("-") if part):
            out.extend(part for part in word.split("-") if part)
        else:
            return None
    return out


CLOSURES = {"bcl": "b", "dcl": "d", "gcl": "g", "pcl": "p", "tcl": "t", "kcl": "k"}
RELEASES_AFTER = {"dcl": {"d", "jh"}, "tcl": {"t", "ch"}}


def boundary_segments(segments):
    """Segments whose inner boundaries are compared: a stop's closure joins its release (the
    CMU phone set has no closures), and adjacent silences merge."""
    out = []
    for start, end, phone in segments:
        if phone in SILENCES:
            phone = "sil"
        if out:
            prev_start, _, prev = out[-1]
            releases = RELEASES_AFTER.get(prev, {CLOSURES.get(prev)})
            if (prev == "sil" and phone == "sil") or phone in releases:
                out[-1] = (prev_start, end, phone)
                continue
        out.append((start, end, phone))
    return out


def viseme_at(segments, sample):
    """The viseme class of the phone sounding at `sample` (diphthongs by half); '-' for the
    transparent phones, None outside the labels."""
    for start, end, phone in segments:
        if start <= sample < end:
            target = VISEME[phone]
            if target is None:
                return "-"
            if isinstance(target, tuple):
                return target[0] if sample < (start + end) / 2 else target[1]
            return target
    return None


def compare(hand, aligned, tolerances):
    """Boundary hits per tolerance (each hand boundary against the nearest aligned one),
    hand boundary count, 10 ms frames agreeing on the viseme class, frames compared, and the
    disagreeing (hand, aligned) class pairs."""
    hand_b = [s[0] for s in boundary_segments(hand)[1:]]
    ali_b = [s[0] for s in boundary_segments(aligned)[1:]]
    hits = [0] * len(tolerances)
    for b in hand_b:
        nearest = min((abs(b - a) for a in ali_b), default=None)
        for i, tol in enumerate(tolerances):
            if nearest is not None and nearest <= tol * RATE:
                hits[i] += 1
    same, frames, confusions = 0, 0, Counter()
    end = min(hand[-1][1], aligned[-1][1])
    for k in range(end // SAMPLES_PER_FRAME):
        centre = k * SAMPLES_PER_FRAME + SAMPLES_PER_FRAME // 2
        h, a = viseme_at(hand, centre), viseme_at(aligned, centre)
        if h is None or a is None:
            continue
        frames += 1
        if h == a:
            same += 1
        else:
            confusions[(h, a)] += 1
    return hits, len(hand_b), same, frames, confusions


def check_timit(args):
    root = Path(args.timit)
    entries = merged_dictionary(None)
    jobs, early_skips, hand = [], [], {}
    for txt in sorted(root.glob("*/*.txt")):
        key = f"{txt.parent.name}/{txt.stem}"
        wav, phn = txt.with_suffix(".wav"), txt.with_suffix(".phn")
        if not (wav.is_file() and phn.is_file()):
            early_skips.append((key, "no wav or phn"))
            continue
        words = in_dictionary(timit_words(txt.read_text()), entries)
        if words is None:
            early_skips.append((key, "unknown words"))
            continue
        jobs.append((key, str(wav), words))
        hand[key] = read_phn(phn)
    if args.limit is not None:
        jobs, early_skips = jobs[: args.limit], []
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        dict_path = Path(tmp) / "timit.dict"
        write_dictionary(entries, [w for job in jobs for w in job[2]], dict_path)
        results = run_jobs(jobs, dict_path, args.jobs)
    elapsed = time.monotonic() - start

    tolerances = [0.010, 0.020, 0.040]
    hits, n_bound, same, frames, confusions = [0] * len(tolerances), 0, 0, 0, Counter()
    audio_seconds = 0.0
    for key, segments, reason, seconds, _ in results:
        if segments is None:
            continue
        audio_seconds += seconds
        h, nb, s, f, c = compare(hand[key], segments, tolerances)
        hits = [x + y for x, y in zip(hits, h)]
        n_bound, same, frames = n_bound + nb, same + s, frames + f
        confusions.update(c)
    extra = [
        f"hand-labelled boundaries: {n_bound} (stop closures joined to their release, "
        "silences merged)",
    ]
    for tol, hit in zip(tolerances, hits):
        extra.append(
            f"  within {tol * 1000:.0f} ms of an aligned boundary: {100 * hit / max(n_bound, 1):.1f} %"
        )
    extra.append(
        f"10 ms frames in the same viseme class: {100 * same / max(frames, 1):.1f} % "
        f"of {frames}"
    )
    extra.append("most frequent disagreements (hand -> aligned): " + ", ".join(
        f"{h}->{a} {100 * n / max(frames, 1):.1f} %" for (h, a), n in confusions.most_common(6)
    ))
    title = (
        f"TIMIT-sample check: pocketsphinx {metadata.version('pocketsphinx')}, bundled en-us "
        "model and CMU dictionary (nothing written)"
    )
    n_total = len(jobs) + len(early_skips)
    sys.stdout.write(summarise(title, n_total, results, early_skips, audio_seconds, elapsed, extra))


def main():
    parser = argparse.ArgumentParser(
        description="Force-align CMU AN4 with pocketsphinx into TIMIT-style .phn files.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 1)[1],
    )
    parser.add_argument("--corpus", default=str(DEFAULT_CORPUS), help="AN4 root (default: %(default)s)")
    parser.add_argument("--out", default=str(DEFAULT_OUT), help="where the .phn files go (default: %(default)s)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--limit", type=int, help="align only the first N utterances (a quick try; keeps SUMMARY.txt)")
    parser.add_argument("--check-timit", action="store_true", help="measure the aligner on the hand-labelled TIMIT sample instead")
    parser.add_argument("--timit", default=str(DEFAULT_TIMIT), help="TIMIT sample root (default: %(default)s)")
    args = parser.parse_args()
    if args.jobs < 1 or (args.limit is not None and args.limit < 1):
        parser.error("--jobs and --limit must be at least 1")
    try:
        import pocketsphinx  # noqa: F401
    except ImportError:
        sys.exit("pocketsphinx is missing: pip install pocketsphinx (see the top of this file)")
    if args.check_timit:
        check_timit(args)
    else:
        align_an4(args)


if __name__ == "__main__":
    main()
