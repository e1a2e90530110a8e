#!/usr/bin/env python3
"""Serves the browser page of a lipcall room on Janus (assets/web) with Debian's janus.js and
adapter.js (libjs-janus-gateway, libjs-webrtc-adapter) under /javascript/, where Debian's
javascript-common puts them for a web server. Janus's HTTP API serves no files.

    python3 tools/room_page.py [--bind 127.0.0.1] [--port 8080]

then open http://127.0.0.1:8080/room.html?room=ROOM&pin=PIN&name=NAME (see docs/janus.md).
With --port 0 it takes a free port. It says where on stderr, first
`lipcall: listening on IP:PORT`, then the page's address. Standard library only.
"""

import argparse
import http.server
import sys
from pathlib import Path

WEB = Path(__file__).resolve().parent.parent / "assets" / "web"


class Handler(http.server.SimpleHTTPRequestHandler):
    javascript = Path("/usr/share/javascript")

    def translate_path(self, path):
        if path.startswith("/javascript/"):
            return self.under(self.javascript, path[len("/javascript") :])
        return self.under(WEB, path)

    def under(self, root, path):
        saved = self.directory
        self.directory = str(root)
        try:
            return super().translate_path(path)
        finally:
            self.directory = saved

    def do_GET(self):
        # The room page is the only page: / goes there, query string and all.
        if self.path == "/" or self.path.startswith("/?"):
            self.send_response(302)
            self.send_header("Location", "/room.html" + self.path[1:])
            self.end_headers()
            return
        super().do_GET()

    def end_headers(self):
        # The page is small and changes with the repository: no stale copies.
        self.send_header("Cache-Control", "no-cache")
        super().end_headers()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bind", default="127.0.0.1", help="address to listen on")
    parser.add_argument("--port", type=int, default=8080, help="port (0: any free port)")
    parser.add_argument(
        "--javascript",
        type=Path,
        default=Handler.javascript,
        help="folder served as /javascript/ (holding janus-gateway/ and webrtc-adapter/)",
    )
    args = parser.parse_args()
    for lib in ("janus-gateway/janus.js", "webrtc-adapter/adapter.js"):
        if not (args.javascript / lib).is_file():
            sys.exit(
                f"room_page: no {args.javascript / lib} "
                "(apt-get install libjs-janus-gateway libjs-webrtc-adapter)"
            )
    Handler.javascript = args.javascript
    server = http.server.ThreadingHTTPServer((args.bind, args.port), Handler)
    host, port = server.server_address[:2]
    print(f"lipcall: listening on {host}:{port}", file=sys.stderr, flush=True)
    print(
        f"room page: http://{host}:{port}/room.html?room=ROOM&pin=PIN&name=NAME",
        file=sys.stderr,
        flush=True,
    )
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
