#!/usr/bin/env python3
"""SSRC churn soak: does `lipcall receive` stay flat under minutes of short-lived callers?

Starts `lipcall receive --weights` on 127.0.0.1, then for the given minutes sends it, from one
socket, 2,000 one-packet SSRCs a second (a flood of newcomers) and 40 SSRCs a second of six
packets each (callers that are confirmed, play a little and go), while a real `lipcall send` of the demo speech
calls it every 20 s. Every 10 s it samples the receiver's open files and resident memory and
prints them; at the end it compares the last minute with the first.

    python3 tools/ssrc_churn_soak.py --minutes 10 [--lipcall target/debug/lipcall]

Exit status 0 when open files and memory stayed flat (the last minute's peak within 30 files
and 8 MB of the first minute's), 1 otherwise.
"""

import argparse
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

PCMU_FRAME = bytes([0x55]) * 160


def rtp(ssrc, seq, ts):
    # Version 2, payload type 0 (PCMU): any payload decodes.
    return struct.pack("!BBHII", 0x80, 0, seq & 0xFFFF, ts & 0xFFFFFFFF, ssrc) + PCMU_FRAME


def churn(to, stop, counts):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    start = time.monotonic()
    sent = 0
    ssrc = 0x40000000
    while not stop.is_set():
        # Each 25 ms: 50 newcomers of one packet, and one caller of six.
        due = start + sent * 0.025
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        for _ in range(50):
            ssrc += 1
            sock.sendto(rtp(ssrc, 0, 0), to)
        ssrc += 1
        for k in range(6):
            sock.sendto(rtp(ssrc, k, 160 * k), to)
        sent += 1
        counts["ssrcs"] = ssrc - 0x40000000


def sample(pid):
    files = len(os.listdir(f"/proc/{pid}/fd"))
    with open(f"/proc/{pid}/status") as f:
        rss_kb = int(re.search(r"VmRSS:\s+(\d+)", f.read()).group(1))
    return files, rss_kb / 1024.0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--lipcall", default="target/debug/lipcall")
    ap.add_argument("--speech", default="assets/speech/demo.wav")
    args = ap.parse_args()
    seconds = int(args.minutes * 60)
    out = tempfile.mkdtemp(prefix="churn-soak-")
    receiver = subprocess.Popen(
        [args.lipcall, "receive", "--listen", "127.0.0.1:0", "--seconds", str(seconds + 5),
         "--weights", os.path.join(out, "w.csv")],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    port = None
    for line in receiver.stderr:
        m = re.search(r"127\.0\.0\.1:(\d+)", line)
        if m:
            port = int(m.group(1))
            break
    if port is None:
        sys.exit("lipcall receive never said its port")
    # Drain the receiver's stderr so that it never blocks on a full pipe.
    threading.Thread(target=lambda: [None for _ in receiver.stderr], daemon=True).start()
    to = ("127.0.0.1", port)
    stop = threading.Event()
    counts = {"ssrcs": 0}
    threading.Thread(target=churn, args=(to, stop, counts), daemon=True).start()
    rows = []
    start = time.monotonic()
    next_call = start
    callers = []
    print(" time  ssrcs   files  rss MB")
    while time.monotonic() - start < seconds:
        now = time.monotonic()
        if now >= next_call:
            callers.append(subprocess.Popen(
                [args.lipcall, "send", args.speech, "--to", f"127.0.0.1:{port}"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            next_call += 20
        files, rss = sample(receiver.pid)
        t = now - start
        rows.append((t, files, rss))
        print(f"{t:5.0f}  {counts['ssrcs']:6d}  {files:5d}  {rss:6.1f}", flush=True)
        time.sleep(10)
    stop.set()
    for c in callers:
        c.wait()
    receiver.wait()
    written = len(os.listdir(out))
    shutil.rmtree(out, ignore_errors=True)
    first = [r for r in rows if r[0] < 60]
    last = [r for r in rows if r[0] >= rows[-1][0] - 60]
    f0, f1 = max(r[1] for r in first), max(r[1] for r in last)
    m0, m1 = max(r[2] for r in first), max(r[2] for r in last)
    flat = f1 <= f0 + 30 and m1 <= m0 + 8
    print(f"{counts['ssrcs']} SSRCs in {seconds} s, {written} weight files written; open files {f0} -> {f1}, "
          f"RSS {m0:.1f} -> {m1:.1f} MB: {'flat' if flat else 'GROWING'}")
    sys.exit(0 if flat else 1)


if __name__ == "__main__":
    main()
