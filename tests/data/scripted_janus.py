#!/usr/bin/env python3
"""A scripted, misbehaving Janus for lipcall's hardening tests: it speaks enough of Janus's HTTP
API (sessions, handles, VideoRoom join, long polls) to let lipcall join a room, then does what
one mode says. It prints "listening on PORT" once it accepts connections.

Modes:
  churn   a publisher joins and leaves every 50 ms; each subscription is answered 8 s late
  flood   the join is never answered; every long poll returns 2,000 unsolicited events
  noopus  one publisher whose stream has no Opus (PCMU only)
  mute    answers the join, then never answers anything again (requests hang)
  garbage answers every request with HTML
"""

import json
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

MODE = sys.argv[1]
ROOM_HANDLE = 11
lock = threading.Lock()
events = []  # what the next long poll returns
next_id = [100]
muted = threading.Event()


def push(event):
    with lock:
        events.append(event)


def room_event(sender, transaction, data, jsep=None):
    e = {
        "janus": "event",
        "sender": sender,
        "plugindata": {"plugin": "janus.plugin.videoroom", "data": data},
    }
    if transaction:
        e["transaction"] = transaction
    if jsep:
        e["jsep"] = jsep
    return e


def audio_publisher(pid, name):
    return {"id": pid, "display": name, "streams": [{"type": "audio", "mid": "0", "codec": "opus"}]}


PCMU_OFFER = (
    "v=0\r\no=- 1 1 IN IP4 127.0.0.1\r\ns=-\r\nt=0 0\r\n"
    "m=audio 9 UDP/TLS/RTP/SAVPF 0\r\nc=IN IP4 127.0.0.1\r\na=rtpmap:0 PCMU/8000\r\n"
    "a=mid:0\r\na=sendonly\r\n"
)


def churn():
    """A publisher comes and goes every 50 ms, for ever."""
    while True:
        with lock:
            pid = next_id[0]
            next_id[0] += 1
        push(room_event(ROOM_HANDLE, None, {"videoroom": "event", "publishers": [audio_publisher(pid, "churn")]}))
        time.sleep(0.025)
        push(room_event(ROOM_HANDLE, None, {"videoroom": "event", "leaving": pid}))
        time.sleep(0.025)


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"

    def log_message(self, *args):
        pass

    def reply(self, body, content_type="application/json"):
        data = body.encode() if isinstance(body, str) else json.dumps(body).encode()
        self.send_response(200)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def do_GET(self):
        if MODE == "garbage":
            return self.reply("<html><body>It works!</body></html>", "text/html")
        if muted.is_set():
            time.sleep(3600)
        if MODE == "flood":
            flood = [room_event(999, "not-ours-%d" % i, {"videoroom": "event", "n": i}) for i in range(2000)]
            time.sleep(0.01)
            return self.reply(flood)
        deadline = time.time() + 1.0
        while time.time() < deadline:
            with lock:
                if events:
                    batch = events[:10]
                    del events[:10]
                    return self.reply(batch)
            time.sleep(0.005)
        self.reply({"janus": "keepalive"})

    def do_POST(self):
        length = int(self.headers.get("Content-Length", "0"))
        msg = json.loads(self.rfile.read(length) or b"{}")
        if MODE == "garbage":
            return self.reply("<html><body>It works!</body></html>", "text/html")
        if muted.is_set():
            time.sleep(3600)
        t = msg.get("transaction")
        kind = msg.get("janus")
        if kind == "create":
            return self.reply({"janus": "success", "transaction": t, "data": {"id": 7}})
        if kind == "attach":
            with lock:
                handle = ROOM_HANDLE if not getattr(Handler, "attached", False) else next_id[0] + 5000
                Handler.attached = True
                next_id[0] += 1
            return self.reply({"janus": "success", "transaction": t, "data": {"id": handle}})
        if kind in ("keepalive", "trickle"):
            return self.reply({"janus": "ack", "transaction": t})
        if kind in ("detach", "destroy"):
            return self.reply({"janus": "success", "transaction": t})
        if kind != "message":
            return self.reply({"janus": "error", "transaction": t, "error": {"code": 456, "reason": "?"}})
        body = msg.get("body", {})
        handle = int(self.path.rstrip("/").split("/")[-1])
        self.reply({"janus": "ack", "transaction": t})
        if body.get("ptype") == "publisher":
            if MODE == "flood":
                return  # never answered
            publishers = [audio_publisher(55, "PCMU phone")] if MODE == "noopus" else []
            push(room_event(handle, t, {"videoroom": "joined", "room": body.get("room"), "id": 1,
                                        "private_id": 2, "publishers": publishers}))
            if MODE == "churn":
                threading.Thread(target=churn, daemon=True).start()
            if MODE == "mute":
                threading.Timer(0.5, muted.set).start()
        elif body.get("ptype") == "subscriber":
            if MODE == "churn":
                def late():
                    time.sleep(8)
                    push(room_event(handle, t, {"videoroom": "event", "error_code": 428,
                                                "error": "No such feed"}))
                threading.Thread(target=late, daemon=True).start()
            else:
                push(room_event(handle, t, {"videoroom": "attached", "room": body.get("room")},
                                {"type": "offer", "sdp": PCMU_OFFER}))


server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
server.daemon_threads = True
print("listening on %d" % server.server_address[1], flush=True)
server.serve_forever()
