#!/usr/bin/env python3
"""Serves the browser page of a lipcall room on Janus (assets/web) with Debian's janus.js and
adapter.js (libjs-janus-gateway, libjs-webrtc-adapter) under /javascript/, where Debian's
javascript-common puts them for a web server. Janus's HTTP API serves no files.

    python3 tools/room_page.py [--bind 127.0.0.1] [--port 8080]
                               [--cert CERT.pem --key KEY.pem | --self-signed]

then open http://127.0.0.1:8080/room.html?room=ROOM&pin=PIN&name=NAME (see docs/janus.md).
With --port 0 it takes a free port. It says where on stderr, first
`lipcall: listening on IP:PORT`, then the page's address. Standard library only (and the
openssl command for --self-signed).

Browsers open the microphone only for pages on localhost or served over HTTPS: to send a link
to someone on another machine, serve it with the site's certificate (--cert, --key), or with
--self-signed, a certificate made here that every browser warns about until it is accepted.
"""

import argparse
import http.server
import ssl
import subprocess
import sys
import tempfile
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


def self_signed(host):
    """A certificate and key for `host`, made with openssl in a folder of their own."""
    folder = Path(tempfile.mkdtemp(prefix="lipcall-room-page-"))
    cert, key = folder / "cert.pem", folder / "key.pem"
    alt = f"IP:{host}" if host.replace(".", "").isdigit() or ":" in host else f"DNS:{host}"
    try:
        subprocess.run(
            ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "30",
             "-subj", f"/CN={host}", "-addext", f"subjectAltName={alt}",
             "-keyout", str(key), "-out", str(cert)],
            check=True, capture_output=True,
        )
    except (OSError, subprocess.CalledProcessError) as e:
        sys.exit(f"room_page: cannot make a self-signed certificate with openssl: {e}")
    return cert, key


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
    parser.add_argument("--cert", type=Path, help="serve HTTPS with this certificate (PEM)")
    parser.add_argument("--key", type=Path, help="the certificate's private key (PEM)")
    parser.add_argument(
        "--self-signed",
        action="store_true",
        help="serve HTTPS with a certificate made here (browsers warn about it)",
    )
    args = parser.parse_args()
    if (args.cert is None) != (args.key is None):
        sys.exit("room_page: --cert and --key go together")
    if args.self_signed and args.cert:
        sys.exit("room_page: --self-signed or --cert/--key, not both")
    for lib in ("janus-gateway/janus.js", "webrtc-adapter/adapter.js"):
        if not (args.javascript / lib).is_file():
            sys.exit(
                f"room_page: no {args.javascript / lib} "
                "(apt-get install libjs-janus-gateway libjs-webrtc-adapter)"
            )
    Handler.javascript = args.javascript
    server = http.server.ThreadingHTTPServer((args.bind, args.port), Handler)
    host, port = server.server_address[:2]
    scheme = "http"
    if args.self_signed:
        args.cert, args.key = self_signed(host)
    if args.cert:
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        try:
            context.load_cert_chain(args.cert, args.key)
        except (OSError, ssl.SSLError) as e:
            sys.exit(f"room_page: cannot use {args.cert} and {args.key}: {e}")
        server.socket = context.wrap_socket(server.socket, server_side=True)
        scheme = "https"
    print(f"lipcall: listening on {host}:{port}", file=sys.stderr, flush=True)
    if args.self_signed:
        print(
            f"room_page: WARNING: a self-signed certificate ({args.cert}): every browser "
            "will warn that the page is not secure until the visitor accepts it; for links "
            "you send to others, use your site's certificate (--cert, --key)",
            file=sys.stderr,
            flush=True,
        )
    print(
        f"room page: {scheme}://{host}:{port}/room.html?room=ROOM&pin=PIN&name=NAME",
        file=sys.stderr,
        flush=True,
    )
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
