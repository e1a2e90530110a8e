#!/usr/bin/env python3
"""Mouth-to-ear delay between two lipcall apps, measured on PulseAudio null sinks.

Run by tools/mouth_to_ear.sh, which starts the sound server, the sinks and the two apps. This
part plays a click track into the talker's microphone sink (MOUTH), records MOUTH's monitor
(what the talker's microphone hears) and the listener's output sink's monitor (EAR) with one
parec each, and pairs each click's onset in the two recordings. Each recording's sample clock
is placed on this process's monotonic clock from the arrival times of parec's reads (a read
arrives when the server renders the block it starts in, never before), so the two recordings
share one time base. Prints the median and spread over the clicks, and the listener's own
account of where the delay sits (its --status file: jitter buffer, queue, output).

    mouth_to_ear.py MOUTH_SINK EAR_SINK CLICKS EAR_STATUS_FILE
"""

import array
import math
import os
import statistics
import subprocess
import sys
import threading
import time

RATE = 48_000
PERIOD_S = 0.9
# A click: 8 ms of 1 kHz at half scale, faded in and out over a millisecond, loud enough to open
# the microphone's gate and to stand clear of the codec's noise.
CLICK = [
    int(16000 * min(1.0, i / 48, (384 - i) / 48) * math.sin(2 * math.pi * 1000 * i / RATE))
    for i in range(384)
]


class Recorder:
    """parec of one monitor: the samples, and (first sample index, arrival time) per read."""

    def __init__(self, source):
        self.proc = subprocess.Popen(
            ["parec", "-d", source, "--raw", "--format=s16le", "--channels=1",
             f"--rate={RATE}", "--latency-msec=2"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        self.samples = array.array("h")
        self.reads = []
        self.odd = b""
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        fd = self.proc.stdout.fileno()
        while True:
            data = os.read(fd, 4096)
            at = time.monotonic()
            if not data:
                return
            self.reads.append((len(self.samples), at))
            data = self.odd + data
            cut = len(data) - len(data) % 2
            self.odd = data[cut:]
            self.samples.frombytes(data[:cut])

    def stop(self):
        self.proc.terminate()
        self.proc.wait()
        self.thread.join(timeout=2)

    def origin(self):
        """Monotonic time of sample 0: the median over the reads that open a rendered block."""
        starts, prev = [], None
        for first, at in self.reads:
            if prev is None or at - prev > 0.0005:
                starts.append(at - first / RATE)
            prev = at
        return statistics.median(starts)


def onsets(samples, quiet_s=0.3):
    """Sample index of each click: the first sample above a fifth of the peak after quiet_s."""
    peak = max((abs(s) for s in samples), default=0)
    if peak < 1000:
        return []
    threshold = peak // 5
    quiet = int(quiet_s * RATE)
    out, last = [], None
    for i, s in enumerate(samples):
        if s > threshold or s < -threshold:
            if last is None or i - last > quiet:
                out.append(i)
            last = i
    return out


def status_fields(path):
    """The listener's status file: its global line and its first peer's line, as dicts."""
    try:
        lines = open(path).read().splitlines()
    except OSError:
        return {}, {}
    parse = lambda line: dict(kv.split("=", 1) for kv in line.split() if "=" in kv)
    head = parse(lines[0]) if lines else {}
    peer = next((parse(l) for l in lines[1:] if l.startswith("peer ")), {})
    return head, peer


def main():
    mouth, ear, clicks, ear_status = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    mouth_rec, ear_rec = Recorder(f"{mouth}.monitor"), Recorder(f"{ear}.monitor")
    time.sleep(1.0)
    track = array.array("h", [0] * int(RATE * (PERIOD_S * clicks + 1.0)))
    for k in range(clicks):
        # Irregular spacing (0.9 s plus up to 90 ms), so no click pairs with its neighbour.
        at = int(RATE * (0.5 + k * PERIOD_S + 0.09 * ((k * 7) % 10) / 10))
        track[at:at + len(CLICK)] = array.array("h", CLICK)
    player = subprocess.Popen(
        ["pacat", "-p", "-d", mouth, "--raw", "--format=s16le", "--channels=1", f"--rate={RATE}",
         "--latency-msec=10"], stdin=subprocess.PIPE)
    samples = {"jitter_buffer_ms": [], "queue_ms": [], "output_ms": []}
    underruns_before = None

    def watch():
        nonlocal underruns_before
        while player.poll() is None:
            head, peer = status_fields(ear_status)
            if underruns_before is None and "underruns" in head:
                underruns_before = int(head["underruns"])
            for key, src in (("jitter_buffer_ms", peer), ("queue_ms", peer), ("output_ms", head)):
                try:
                    v = float(src[key])
                    if v == v:
                        samples[key].append(v)
                except (KeyError, ValueError):
                    pass
            time.sleep(0.5)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    player.stdin.write(track.tobytes())
    player.stdin.close()
    player.wait()
    time.sleep(1.5)
    mouth_rec.stop()
    ear_rec.stop()
    head, peer = status_fields(ear_status)
    underruns = int(head.get("underruns", 0)) - (underruns_before or 0)

    t_mouth = [mouth_rec.origin() + i / RATE for i in onsets(mouth_rec.samples)]
    t_ear = [ear_rec.origin() + i / RATE for i in onsets(ear_rec.samples)]
    delays = []
    for t in t_mouth:
        later = [e - t for e in t_ear if 0.0 < e - t < 0.6]
        if later:
            delays.append(1000 * min(later))
    print(f"clicks played {clicks}, heard at the mouth {len(t_mouth)}, at the ear {len(t_ear)}, "
          f"paired {len(delays)}")
    if len(delays) < 2:
        print("too few clicks paired: no measurement")
        return 1
    delays.sort()
    q = statistics.quantiles(delays, n=10)
    print(f"mouth-to-ear ms: median {statistics.median(delays):.1f}, p10 {q[0]:.1f}, "
          f"p90 {q[-1]:.1f}, min {delays[0]:.1f}, max {delays[-1]:.1f}, "
          f"stdev {statistics.stdev(delays):.1f}")
    parts = {k: statistics.median(v) for k, v in samples.items() if v}
    framing = 20.0 + 6.5
    told = framing + sum(parts.values())
    print("breakdown (listener's status, medians over the run; framing is one 20 ms frame plus "
          "Opus's 6.5 ms look-ahead):")
    print(f"  framing {framing:.1f}  " + "  ".join(f"{k[:-3]} {v:.1f}" for k, v in parts.items())
          + f"  capture+network+polling (the rest) {statistics.median(delays) - told:.1f}")
    print(f"listener's output underruns during the clicks: {underruns}; silence played for the "
          f"talker, its queue empty, over the call: {peer.get('starved_ms', '?')} ms")
    print(f"listener's weights rows sent {head.get('weights_sent', '?')}, of them late (their audio "
          f"already heard: the look-ahead not hidden) {head.get('weights_late', '?')}, by "
          f"{head.get('late_ms', '?')} ms in all")
    print(f"listener's jitter buffer at the end: target {peer.get('target_ms', '?')} ms, "
          f"interarrival jitter {peer.get('jitter_ms', '?')} ms, frames inserted "
          f"{peer.get('stretched', '?')}, dropped {peer.get('dropped', '?')}, late "
          f"{peer.get('late', '?')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
