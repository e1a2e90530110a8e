#!/usr/bin/env python3
"""PESQ (ITU-T P.862) of a received WAV against the WAV it was sent from.

    tools/pesq_score.py SOURCE.wav RECEIVED.wav [--mode wb|nb] [--json]

Both files are brought to 16 kHz (8 kHz for --mode nb) by FFT resampling, the received one is
placed on the source by the lag of the largest cross-correlation (a receiver's file starts when it
joined, not when the sender spoke), cut or padded to the source's length, and scored with PyPI's
`pesq`. Waveform SNR says little about Opus, whose CELT layer keeps the spectrum and not the
waveform; PESQ scores what a listener hears. Prints the score (MOS-LQO) and the lag, or with
--json one object: {"pesq": .., "lag_s": .., "received_s": .., "source_s": ..}.
Exit status 2 for input it cannot score (unreadable, silent, no overlap).
"""

import argparse
import json
import sys
import wave

import numpy as np


def read_wav(path):
    with wave.open(path, "rb") as w:
        if w.getsampwidth() != 2:
            raise ValueError(f"{path}: 16-bit PCM expected, not {8 * w.getsampwidth()}-bit")
        rate, channels = w.getframerate(), w.getnchannels()
        data = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").astype(np.float64)
    if channels > 1:
        data = data.reshape(-1, channels).mean(axis=1)
    return rate, data


def resample(x, rate, to):
    """Band-limited resampling by zero-padding or cutting the spectrum."""
    if rate == to or len(x) == 0:
        return x
    n = int(round(len(x) * to / rate))
    spectrum = np.fft.rfft(x)
    bins = n // 2 + 1
    out = np.zeros(bins, dtype=complex)
    keep = min(bins, len(spectrum))
    out[:keep] = spectrum[:keep]
    return np.fft.irfft(out, n) * (n / len(x))


def best_lag(source, received):
    """Samples the source starts at within `received` (negative: before its start)."""
    n = 1 << int(np.ceil(np.log2(len(source) + len(received))))
    corr = np.fft.irfft(np.fft.rfft(received, n) * np.conj(np.fft.rfft(source, n)), n)
    lag = int(np.argmax(corr))
    return lag - n if lag > n // 2 else lag


def aligned(source, received, lag):
    """The received samples that play with the source's, zeros where it has none."""
    out = np.zeros(len(source))
    lo, hi = max(lag, 0), min(lag + len(source), len(received))
    if hi > lo:
        out[lo - lag : hi - lag] = received[lo:hi]
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("received")
    parser.add_argument("--mode", choices=["wb", "nb"], default="wb")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    try:
        from pesq import pesq
    except ImportError:
        print("pesq_score: PyPI's pesq is not installed (pip install pesq numpy)", file=sys.stderr)
        return 3
    rate = 16000 if args.mode == "wb" else 8000
    try:
        src_rate, source = read_wav(args.source)
        rcv_rate, received = read_wav(args.received)
    except (OSError, EOFError, ValueError, wave.Error) as e:
        print(f"pesq_score: {e}", file=sys.stderr)
        return 2
    source = resample(source, src_rate, rate)
    received = resample(received, rcv_rate, rate)
    if len(source) < rate // 4 or len(received) < rate // 4:
        print("pesq_score: a file is shorter than 0.25 s", file=sys.stderr)
        return 2
    if not np.any(np.abs(received) > 1.0):
        print("pesq_score: the received file is silent", file=sys.stderr)
        return 2
    lag = best_lag(source, received)
    degraded = aligned(source, received, lag)
    clip = lambda x: np.clip(x, -32768, 32767).astype(np.int16)
    try:
        score = float(pesq(rate, clip(source), clip(degraded), args.mode))
    except Exception as e:  # the pesq package raises its own types for unscorable input
        print(f"pesq_score: {e}", file=sys.stderr)
        return 2
    result = {
        "pesq": round(score, 3),
        "lag_s": round(lag / rate, 4),
        "received_s": round(len(received) / rate, 3),
        "source_s": round(len(source) / rate, 3),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"PESQ {result['pesq']:.3f} ({args.mode}), received {result['lag_s']:+.3f} s after its source")
    return 0


if __name__ == "__main__":
    sys.exit(main())
