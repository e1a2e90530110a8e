#!/usr/bin/env python3
"""Scale of one room on one machine: P publishers (`lipcall send`) and S receivers (`lipcall
receive`) in a room on one Janus (the repository's config, assets/janus) and, in the same run,
on lipcall's own relay (`lipcall relay`), for each size asked. Reports per server the loss each
receiver saw, the server's CPU per forwarded stream and the machine's CPU. Not a test: numbers
for docs/janus-scale.md.

    cargo build --release
    python3 tools/janus_scale.py [--sizes 2x2,4x4,8x8] [--repeat 2] [--servers janus,relay]

Everything runs on this machine: signalling on 127.0.0.1, Janus's media on this machine's
interface address (libnice gathers no loopback candidates), the relay on loopback. The relay
admits 4 members per source address and 16 per room: receivers bind their own 127.0.1.N,
publishers send from 127.0.0.1 and, past 4, from ::1 (the relay listens on both), and sizes
past 16 members are Janus only. Standard library only.
"""

import argparse
import os
import re
import resource
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TICKS = os.sysconf("SC_CLK_TCK")
RELAY_MAX_MEMBERS = 16
RELAY_PER_SOURCE = 4


class Child:
    """A process whose stderr is collected line by line; killed (with its group) on close."""

    def __init__(self, args, name):
        self.name = name
        self.proc = subprocess.Popen(
            [str(a) for a in args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        self.lines = []
        self.cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stderr:
            with self.cond:
                self.lines.append(line.rstrip("\n"))
                self.cond.notify_all()
        with self.cond:
            self.cond.notify_all()

    def wait_line(self, pattern, timeout=30):
        """The first stderr line matching `pattern` (a regex), as a match."""
        deadline = time.monotonic() + timeout
        seen = 0
        with self.cond:
            while True:
                for line in self.lines[seen:]:
                    m = re.search(pattern, line)
                    if m:
                        return m
                seen = len(self.lines)
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and seen == len(self.lines)):
                    raise RuntimeError(
                        f"{self.name}: no line like {pattern!r}:\n" + "\n".join(self.lines[-20:])
                    )
                self.cond.wait(min(left, 0.2))

    def wait(self, timeout):
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.close()
            raise RuntimeError(f"{self.name} did not finish in {timeout} s")
        time.sleep(0.05)  # the reader's last lines
        return "\n".join(self.lines)

    def cpu_seconds(self):
        with open(f"/proc/{self.proc.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICKS

    def close(self):
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait()


def machine_busy_seconds():
    """CPU seconds all CPUs have been busy so far."""
    with open("/proc/stat") as f:
        values = [int(v) for v in f.readline().split()[1:]]
    return (sum(values) - values[3] - values[4]) / TICKS


def reaped_children_seconds():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_janus(workdir, event_loops):
    config = workdir / "janus-config"
    config.mkdir()
    port = free_port()
    for path in (ROOT / "assets" / "janus").iterdir():
        text = path.read_text().replace("port = 8088", f"port = {port}")
        if event_loops and path.name == "janus.jcfg":
            text = text.replace("general: {", f"general: {{\n\tevent_loops = {event_loops}", 1)
        (config / path.name).write_text(text)
    janus = Child(["janus", "-F", config, "-L", workdir / "janus.log", "-N"], "janus")
    deadline = time.monotonic() + 15
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            if time.monotonic() > deadline:
                raise RuntimeError("Janus did not open its HTTP port")
            time.sleep(0.05)
    return janus, f"http://127.0.0.1:{port}/janus"


def peer_totals(stderr):
    """Sums over a receiver's `peer ...` lines: received, lost, late packets, and peers."""
    totals = {"received": 0, "lost": 0, "late": 0, "peers": 0}
    for line in stderr.splitlines():
        if line.startswith("peer "):
            totals["peers"] += 1
            for key in ("received", "lost", "late"):
                m = re.search(rf"\b{key}=(\d+)", line)
                totals[key] += int(m.group(1)) if m else 0
    return totals


def run_room(server, publishers, subscribers, lipcall, speech, workdir, event_loops):
    """One room of `publishers` x `subscribers` on `server` ('janus' or 'relay')."""
    # The room's passphrase goes to every lipcall through its environment, never its arguments.
    os.environ["LIPCALL_KEY"] = "scale-test"
    room = f"scale-{publishers}x{subscribers}"
    children = []
    try:
        if server == "janus":
            srv, url = start_janus(workdir, event_loops)
            children.append(srv)
            join = ["--janus", url, "--room", room]
            receive_args = lambda i: ["receive", *join, "--name", f"r{i}"]  # noqa: E731
            ready = r"lipcall: in room "
            send_args = lambda i: ["send", speech, *join, "--name", f"p{i}"]  # noqa: E731
            streams = publishers * subscribers
        else:
            srv = Child([lipcall, "relay", "--listen", "[::]:0"], "relay")
            children.append(srv)
            port = int(srv.wait_line(r"relay listening on .*:(\d+)$").group(1))
            receive_args = lambda i: [  # noqa: E731
                "receive", "--listen", f"127.0.1.{i + 1}:0",
                "--relay", f"127.0.0.1:{port}", "--room", room, "--name", f"r{i}",
            ]
            ready = r"lipcall: listening on "
            send_args = lambda i: [  # noqa: E731
                "send", speech, "--codec", "opus", "--room", room,
                "--to", f"127.0.0.1:{port}" if i < RELAY_PER_SOURCE else f"[::1]:{port}",
                "--name", f"p{i}",
            ]
            # Every member gets every other member's packets: publishers too.
            streams = publishers * (subscribers + publishers - 1)
        receivers = []
        for i in range(subscribers):
            r = Child([lipcall, *receive_args(i)], f"receiver {i}")
            children.append(r)
            receivers.append(r)
        for r in receivers:
            r.wait_line(ready)
        t0, busy0, reaped0 = time.monotonic(), machine_busy_seconds(), reaped_children_seconds()
        server0 = srv.cpu_seconds()
        receivers0 = sum(r.cpu_seconds() for r in receivers)
        senders = []
        for i in range(publishers):
            s = Child([lipcall, *send_args(i)], f"publisher {i}")
            children.append(s)
            senders.append(s)
        sent = 0
        for s in senders:
            out = s.wait(120)
            m = re.search(r"lipcall: sent (\d+) packets", out)
            if not m:
                raise RuntimeError(f"{s.name} failed:\n{out}")
            sent += int(m.group(1))
        # The receivers are still playing out: their CPU so far, the senders' as they were reaped.
        server1 = srv.cpu_seconds()
        receivers1 = sum(r.cpu_seconds() for r in receivers)
        t1, busy1, reaped1 = time.monotonic(), machine_busy_seconds(), reaped_children_seconds()
        losses, late, heard = [], [], []
        for r in receivers:
            # A relay receive ends when its peers have said BYE, a Janus one when they left.
            totals = peer_totals(r.wait(60))
            arrived = totals["received"] + totals["lost"]
            losses.append(100.0 * (totals["lost"] + totals["late"]) / max(arrived, 1))
            late.append(100.0 * totals["late"] / max(arrived, 1))
            heard.append(100.0 * totals["received"] / max(sent, 1))
        seconds = t1 - t0
        server_cpu = 100.0 * (server1 - server0) / seconds
        lipcall_cpu = 100.0 * ((receivers1 - receivers0) + (reaped1 - reaped0)) / seconds
        machine = 100.0 * (busy1 - busy0) / seconds
        return {
            "server": server,
            "size": f"{publishers}x{subscribers}",
            "streams": streams,
            "loss_max": max(losses),
            "loss_mean": sum(losses) / len(losses),
            "late_max": max(late),
            "heard_min": min(heard),
            "server_cpu": server_cpu,
            "cpu_per_stream": server_cpu / streams,
            "lipcall_cpu": lipcall_cpu,
            "other_cpu": max(machine - server_cpu - lipcall_cpu, 0.0),
            "seconds": seconds,
        }
    finally:
        for c in reversed(children):
            c.close()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="2x2,4x4,8x8", help="PxS,PxS,... (publishers x subscribers)")
    parser.add_argument("--servers", default="janus,relay")
    parser.add_argument("--lipcall", type=Path, default=ROOT / "target" / "release" / "lipcall")
    parser.add_argument("--input", type=Path, default=ROOT / "assets" / "speech" / "demo.wav")
    parser.add_argument("--repeat", type=int, default=2, help="the input this many times over")
    parser.add_argument(
        "--event-loops",
        type=int,
        default=0,
        help="Janus's event_loops (media threads shared by all handles; 0: one per handle)",
    )
    args = parser.parse_args()
    if not args.lipcall.is_file():
        sys.exit(f"janus_scale: no {args.lipcall} (cargo build --release)")
    if shutil.which("janus") is None and "janus" in args.servers:
        sys.exit("janus_scale: no janus (apt-get install janus)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        speech = tmp / "speech.wav"
        subprocess.run(["sox", *[args.input] * args.repeat, speech], check=True)
        cores = os.cpu_count()
        print(f"CPU in % of one core ({cores} cores: {100 * cores} % in all)")
        print(
            "server  PxS     streams  loss % max  mean  (late max)  heard % min  server  "
            "per stream  lipcall  others"
        )
        for run, size in enumerate(args.sizes.split(",")):
            p, s = (int(n) for n in size.lower().split("x"))
            for server in args.servers.split(","):
                if server == "relay" and (p + s > RELAY_MAX_MEMBERS or p > 2 * RELAY_PER_SOURCE):
                    print(f"relay   {size:7} -- more members than one relay room takes here")
                    continue
                workdir = tmp / f"{server}-{size}-{run}"
                workdir.mkdir()
                r = run_room(server, p, s, args.lipcall, speech, workdir, args.event_loops)
                print(
                    f"{r['server']:7} {r['size']:7} {r['streams']:7}  {r['loss_max']:10.2f}"
                    f"  {r['loss_mean']:4.2f}  {r['late_max']:10.2f}  {r['heard_min']:11.1f}"
                    f"  {r['server_cpu']:6.1f}"
                    f"  {r['cpu_per_stream']:10.3f}  {r['lipcall_cpu']:7.1f}  {r['other_cpu']:6.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
