#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets into tools/fuzz/corpus/<target>/.

Seeds are small real inputs: packets and files cut from the repository's speech sample
(assets/speech/demo.wav) through speexenc, opusenc and sox, the golden Speex stream, the built-in
model, and hand-built packets, heads and CSVs. Run from anywhere; needs sox, speexenc, opusenc.
The packet-stream targets read records: speex_walker a 1-byte length then the packet,
silk_walker and srtp a 2-byte big-endian length then the bytes (see each target's comment).
"""

import base64
import json
import os
import struct
import subprocess
import sys
import tempfile
import zlib

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
CORPUS = os.path.join(ROOT, "tools", "fuzz", "corpus")
SPEECH = os.path.join(ROOT, "assets", "speech", "demo.wav")
WORK = tempfile.mkdtemp(prefix="lipcall-seeds-")


def write(target, name, data):
    folder = os.path.join(CORPUS, target)
    os.makedirs(folder, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(folder, name), "wb") as f:
        f.write(data)


def run(*args):
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def speech(name, rate, seconds, channels=1, start=1.0, extra=()):
    """A piece of the speech sample as a WAV at `rate`."""
    path = os.path.join(WORK, name)
    run("sox", SPEECH, "-r", str(rate), "-c", str(channels), "-b", "16", *extra, path,
        "trim", str(start), str(seconds))
    return path


def ogg_packets(path):
    """The packets of every logical stream of an Ogg file, in order (headers included)."""
    data = open(path, "rb").read()
    packets, partial, at = [], b"", 0
    while at + 27 <= len(data) and data[at:at + 4] == b"OggS":
        segments = data[at + 26]
        table = data[at + 27:at + 27 + segments]
        body = at + 27 + segments
        for lacing in table:
            partial += data[body:body + lacing]
            body += lacing
            if lacing < 255:
                packets.append(partial)
                partial = b""
        at = body
    return packets


def short_records(packets):
    return b"".join(bytes([len(p)]) + p for p in packets if len(p) < 256)


def records(packets):
    return b"".join(struct.pack(">H", len(p)) + p for p in packets)


# RTP and RTCP ---------------------------------------------------------------------------------

def rtp(pt, seq, ts, ssrc, payload, marker=False, csrcs=(), extension=None, padding=0):
    first = 0x80 | (0x20 if padding else 0) | (0x10 if extension is not None else 0) | len(csrcs)
    head = struct.pack(">BBHII", first, pt | (0x80 if marker else 0), seq, ts, ssrc)
    head += b"".join(struct.pack(">I", c) for c in csrcs)
    if extension is not None:
        head += struct.pack(">HH", 0xBEDE, len(extension) // 4) + extension
    tail = b"\0" * (padding - 1) + bytes([padding]) if padding else b""
    return head + payload + tail


def rtcp_sr(ssrc, blocks):
    body = struct.pack(">IQIII", ssrc, 0xE1234567_89ABCDEF, 160000, 50, 2000)
    body += b"".join(blocks)
    return struct.pack(">BBH", 0x80 | len(blocks), 200, len(body) // 4) + body


def rtcp_rr(ssrc, blocks):
    body = struct.pack(">I", ssrc) + b"".join(blocks)
    return struct.pack(">BBH", 0x80 | len(blocks), 201, len(body) // 4) + body


def report_block(ssrc, lost=3):
    return struct.pack(">IIIIII", ssrc, (12 << 24) | lost, 70000, 33, 0x1234_5678, 6553)


def rtcp_sdes(ssrc, cname, name=None):
    items = bytes([1, len(cname)]) + cname
    if name is not None:
        items += bytes([2, len(name)]) + name
    items += b"\0"
    chunk = struct.pack(">I", ssrc) + items
    chunk += b"\0" * (-len(chunk) % 4)
    return struct.pack(">BBH", 0x81, 202, len(chunk) // 4) + chunk


def rtcp_bye(ssrcs):
    body = b"".join(struct.pack(">I", s) for s in ssrcs)
    return struct.pack(">BBH", 0x80 | len(ssrcs), 203, len(body) // 4) + body


def rtp_and_rtcp_seeds():
    speex_frame = bytes.fromhex("1a5b4c3d2e1f00112233445566778899aabbccddeeff00112233445566778899aabbccdd")
    packets = {
        "speex": rtp(110, 1000, 160000, 0x11223344, speex_frame, marker=True),
        "opus": rtp(111, 7, 960, 0xCAFE, bytes([0x08]) + bytes(range(40))),
        "pcmu": rtp(0, 65535, 4294967000, 1, bytes([0xFF] * 160)),
        "csrc-ext-pad": rtp(96, 2, 3, 4, b"payload!", csrcs=(9, 10),
                            extension=b"\x10\xAA\0\0", padding=4),
    }
    for name, p in packets.items():
        write("rtp", name, p)
    a, b = 0x11223344, 0x55667788
    compounds = {
        "sr-sdes": rtcp_sr(a, [report_block(b)]) + rtcp_sdes(a, b"alice@host", "Alice".encode()),
        "rr-sdes-bye": rtcp_rr(b, [report_block(a), report_block(7, 0)]) +
        rtcp_sdes(b, b"bob@host") + rtcp_bye([b]),
        "sdes-utf8": rtcp_rr(a, []) + rtcp_sdes(a, b"c", "Zoë \u00e9\u4e16".encode()),
    }
    for name, p in compounds.items():
        write("rtcp", name, p)
    # srtp: scheme byte (even: RFC 3711, odd: per session), then operations.
    def protect(op, packet, at=0, by=0):
        return bytes([op]) + struct.pack(">H", len(packet)) + packet + struct.pack(">HB", at, by)
    stream = [rtp(110, 100 + i, 160 * i, a, speex_frame) for i in range(3)]
    write("srtp", "rtp-rfc3711", b"\0" + b"".join(protect(2, p) for p in stream))
    write("srtp", "rtp-per-session", b"\1" + b"".join(protect(2, p) for p in stream))
    write("srtp", "rtp-tampered", b"\0" + protect(2, stream[0]) + protect(2, stream[1], 20, 1))
    write("srtp", "rtcp-both", b"\0" + protect(3, compounds["sr-sdes"]) +
          protect(3, compounds["rr-sdes-bye"]))
    write("srtp", "raw", b"\1" + bytes([0]) + struct.pack(">H", len(stream[0]) + 18) +
          stream[0] + bytes(18) + bytes([1]) + struct.pack(">H", 40) + bytes(40))
    write("srtp", "rollover", b"\0" + protect(2, rtp(110, 65534, 0, a, b"x")) +
          protect(2, rtp(110, 65535, 160, a, b"y")) + protect(2, rtp(110, 0, 320, a, b"z")))


# Relay control --------------------------------------------------------------------------------

def relay_seeds():
    def control(kind, room=b"\x01" * 16, cookie=b"\0" * 16, detail=0):
        return b"LPCR" + bytes([2, kind, detail]) + room + cookie

    write("relay_control", "join", control(1))
    write("relay_control", "refused", control(4, detail=2))
    write("relay_control", "legacy-join", b"LPCR" + bytes([1, 1]) + b"\x05" * 16)
    # Operations: op, address, then the op's argument (see the target).
    media = rtp(110, 1, 160, 5, b"voice")
    join_a, join_b = b"\x01\x00\x00", b"\x01\x05\x00"
    confirm_a, confirm_b = b"\x02\x00\x00", b"\x02\x05\x00"
    send_a = b"\x00\x00" + struct.pack(">H", len(media)) + media
    write("relay_control", "two-members-talk",
          join_a + confirm_a + join_b + confirm_b + send_a + send_a + b"\x03\x00\x00")
    write("relay_control", "keepalive-expiry",
          join_a + confirm_a + b"\x04\x00\x07\x00" + confirm_a + b"\x04\x00\x0f\x00" +
          b"\x05\x00" + send_a)
    write("relay_control", "forged-and-full",
          join_a + b"\x02\x00\x01" + b"".join(bytes([1, k, 0, 2, k, 0]) for k in range(8)) +
          b"\x00\x01\x00\x27" + control(6))


# Speex and Opus packets and files ---------------------------------------------------------------

def codec_seeds():
    nb = speech("nb.wav", 8000, 0.4)
    wb = speech("wb.wav", 16000, 0.4)
    stereo = speech("stereo.wav", 8000, 0.3, channels=2)
    spx = {
        "q8": ("-n", "--quality", "8"),
        "q2-vbr": ("-n", "--quality", "2", "--vbr"),
        "q0-dtx": ("-n", "--quality", "0", "--vbr", "--dtx"),
        "q10-3frames": ("-n", "--quality", "10", "--nframes", "3"),
        "q4-abr": ("-n", "--abr", "11000"),
    }
    for name, options in spx.items():
        out = os.path.join(WORK, name + ".spx")
        run("speexenc", *options, nb, out)
        write("speex_walker", name, short_records(ogg_packets(out)[2:14]))
        if name in ("q2-vbr", "q10-3frames"):
            write("ogg", name + ".spx", open(out, "rb").read())
    out = os.path.join(WORK, "wb.spx")
    run("speexenc", "-w", "--quality", "6", wb, out)
    write("speex_walker", "wideband", short_records(ogg_packets(out)[2:10]))
    write("ogg", "wideband.spx", open(out, "rb").read())
    out = os.path.join(WORK, "stereo.spx")
    run("speexenc", "-n", "--quality", "4", stereo, out)
    write("ogg", "stereo.spx", open(out, "rb").read())
    write("ogg", "golden-q8.spx", open(os.path.join(ROOT, "tests", "data", "golden-q8.spx"), "rb").read())
    write("speex_walker", "in-band",
          short_records([bytes([0b01110_000, 0x10, 0x5A]), bytes([0b01101_001, 0x80, 0x55, 0xAA]),
                         bytes([0b00000_111, 0xFF])]))

    fb = speech("fb.wav", 48000, 0.3)
    mb = speech("mb.wav", 12000, 0.4)
    opus = {
        "nb-20ms": (nb, ("--bitrate", "8", "--framesize", "20")),
        "mb-10ms": (mb, ("--bitrate", "12", "--framesize", "10")),
        "wb-60ms": (wb, ("--bitrate", "16", "--framesize", "60")),
        "wb-fec": (wb, ("--bitrate", "20", "--expect-loss", "20")),
        "hybrid": (fb, ("--bitrate", "32", "--framesize", "20")),
        "celt": (fb, ("--bitrate", "96", "--framesize", "10", "--music")),
        "stereo": (stereo, ("--bitrate", "24",)),
        "vbr-40ms": (nb, ("--bitrate", "10", "--framesize", "40", "--cvbr")),
    }
    for name, (source, options) in opus.items():
        out = os.path.join(WORK, name + ".opus")
        run("opusenc", "--quiet", *options, source, out)
        packets = ogg_packets(out)[2:12]
        write("silk_walker", name, records(packets[:5] + [b""] + packets[5:]))
        if name in ("nb-20ms", "wb-fec", "celt", "stereo"):
            write("ogg", name + ".opus", open(out, "rb").read())
    # Opus framing codes 1 to 3 around SILK NB frames.
    frame = ogg_packets(os.path.join(WORK, "nb-20ms.opus"))[4][1:]
    toc = 0x08
    write("silk_walker", "codes", records([
        bytes([toc | 1]) + frame[:10] + frame[:10],
        bytes([toc | 2, 12]) + frame[:12] + frame[:20],
        bytes([toc | 3, 0x80 | 0x40 | 3, 2, 10, 8]) + frame[:10] + frame[:8] + frame[:9] + b"\0\0",
    ]))


# WAV ------------------------------------------------------------------------------------------

def wav_seeds():
    tone = ("synth", "0.02", "sine", "300")
    for name, options in {
        "8k-s16": ("-r", "8000", "-c", "1", "-b", "16"),
        "44k-stereo": ("-r", "44100", "-c", "2", "-b", "16"),
        "16k-u8": ("-r", "16000", "-c", "1", "-b", "8", "-e", "unsigned"),
        "48k-s24": ("-r", "48000", "-c", "1", "-b", "24"),
        "22k-f32": ("-r", "22050", "-c", "1", "-b", "32", "-e", "floating-point"),
        "32k-s32-3ch": ("-r", "32000", "-c", "3", "-b", "32"),
        "4k-s16": ("-r", "4000", "-c", "1", "-b", "16"),
    }.items():
        path = os.path.join(WORK, name + ".wav")
        run("sox", "-n", *options, path, *tone)
        write("wav", name + ".wav", open(path, "rb").read())
    write("wav", "speech-8k.wav", open(speech("short.wav", 8000, 0.1), "rb").read())


# glTF heads -----------------------------------------------------------------------------------

FLOAT, USHORT, UINT = 5126, 5123, 5125


def tiny_png():
    raw = b"".join(b"\0" + bytes([200, 120, 100, 255] * 2) for _ in range(2))
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 2, 8, 6, 0, 0, 0)) +
            chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


class Gltf:
    def __init__(self):
        self.bin = b""
        self.views, self.accessors = [], []

    def view(self, data):
        self.bin += b"\0" * (-len(self.bin) % 4)
        self.views.append({"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)})
        self.bin += data
        return len(self.views) - 1

    def vec3(self, items, bounds=False):
        view = self.view(b"".join(struct.pack("<3f", *v) for v in items))
        a = {"bufferView": view, "componentType": FLOAT, "count": len(items), "type": "VEC3"}
        if bounds:
            a["min"] = [min(v[k] for v in items) for k in range(3)]
            a["max"] = [max(v[k] for v in items) for k in range(3)]
        self.accessors.append(a)
        return len(self.accessors) - 1

    def vec2(self, items):
        view = self.view(b"".join(struct.pack("<2f", *v) for v in items))
        self.accessors.append({"bufferView": view, "componentType": FLOAT, "count": len(items),
                               "type": "VEC2"})
        return len(self.accessors) - 1

    def indices(self, items, kind=USHORT):
        fmt = "<H" if kind == USHORT else "<I"
        view = self.view(b"".join(struct.pack(fmt, i) for i in items))
        self.accessors.append({"bufferView": view, "componentType": kind, "count": len(items),
                               "type": "SCALAR"})
        return len(self.accessors) - 1

    def sparse_vec3(self, count, changes):
        index_view = self.view(b"".join(struct.pack("<H", i) for i, _ in changes))
        value_view = self.view(b"".join(struct.pack("<3f", *v) for _, v in changes))
        self.accessors.append({"componentType": FLOAT, "count": count, "type": "VEC3", "sparse": {
            "count": len(changes), "indices": {"bufferView": index_view, "componentType": USHORT},
            "values": {"bufferView": value_view}}})
        return len(self.accessors) - 1


def face():
    """A small face: a grid of vertices whose lower middle rows are the mouth."""
    side = 5
    positions = [(x / 4 - 0.5, y / 4 - 0.5, 0.1 * ((x - 2) ** 2 + (y - 2) ** 2) ** 0.5)
                 for y in range(side) for x in range(side)]
    triangles = []
    for y in range(side - 1):
        for x in range(side - 1):
            i = y * side + x
            triangles += [i, i + 1, i + side, i + 1, i + side + 1, i + side]
    return positions, triangles


def head_json(g, targets, names, extra_nodes=None, material=None, index_kind=USHORT, uv=True):
    positions, triangles = face()
    attributes = {"POSITION": g.vec3(positions, bounds=True),
                  "NORMAL": g.vec3([(0.0, 0.0, 1.0)] * len(positions))}
    if uv:
        attributes["TEXCOORD_0"] = g.vec2([(p[0] + 0.5, p[1] + 0.5) for p in positions])
    primitive = {"attributes": attributes, "indices": g.indices(triangles, index_kind),
                 "targets": targets(g, len(positions))}
    if material is not None:
        primitive["material"] = 0
    doc = {"asset": {"version": "2.0"}, "scene": 0,
           "meshes": [{"name": "face", "primitives": [primitive], "extras": {"targetNames": names}}],
           "nodes": [{"mesh": 0, "name": "head", "translation": [0, 1.6, 0]}],
           "scenes": [{"nodes": [0]}]}
    if extra_nodes:
        doc["nodes"] += extra_nodes
        doc["nodes"][0]["children"] = list(range(1, 1 + len(extra_nodes)))
    if material is not None:
        doc.update(material)
    return doc


def mouth_targets(g, n, sparse=False):
    out = []
    for k, dy in enumerate((0.0, -0.05, -0.12)):
        moved = [(i, (0.0, dy * (1 + k), 0.01)) for i in range(n) if 5 <= i < 15]
        if sparse:
            out.append({"POSITION": g.sparse_vec3(n, moved or [(0, (0, 0, 0))])})
        else:
            full = [(0.0, 0.0, 0.0)] * n
            for i, v in moved:
                full[i] = v
            out.append({"POSITION": g.vec3(full, bounds=True)})
    return out


def glb(doc, g):
    doc["bufferViews"] = g.views
    doc["accessors"] = g.accessors
    doc["buffers"] = [{"byteLength": len(g.bin)}]
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = g.bin + b"\0" * (-len(g.bin) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def gltf_seeds():
    names = ["viseme_sil", "viseme_PP", "viseme_aa"]
    g = Gltf()
    write("gltf", "visemes.glb", glb(head_json(g, mouth_targets, names), g))
    g = Gltf()
    write("gltf", "sparse-uint.glb",
          glb(head_json(g, lambda g, n: mouth_targets(g, n, sparse=True), ["PP", "aa", "jawOpen"],
                        index_kind=UINT), g))
    g = Gltf()
    png = g.view(tiny_png())
    material = {"materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                        "baseColorFactor": [1, 0.9, 0.8, 1]}}],
                "textures": [{"source": 0}], "images": [{"bufferView": png, "mimeType": "image/png"}]}
    write("gltf", "textured-arkit.glb",
          glb(head_json(g, mouth_targets, ["jawOpen", "mouthClose", "eyeBlinkLeft"],
                        material=material), g))
    g = Gltf()
    nodes = [{"name": "jaw", "rotation": [0.1, 0, 0, 0.995]}, {"name": "eyes", "scale": [1, 1, 1],
             "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0.1, 0, 1]}]
    doc = head_json(g, mouth_targets, ["viseme_sil", "viseme_O", "eyeBlink"], extra_nodes=nodes, uv=False)
    doc["bufferViews"] = g.views
    doc["accessors"] = g.accessors
    doc["buffers"] = [{"byteLength": len(g.bin),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(g.bin).decode()}]
    write("gltf", "embedded.gltf", json.dumps(doc, indent=1))


# Model files and marker CSVs -------------------------------------------------------------------

def model_seeds():
    default = open(os.path.join(ROOT, "assets", "models", "default.lipmodel")).read()
    write("model", "default.lipmodel", default)
    hidden = 2
    inputs = 11
    version_one = "\n".join([
        "lipcall-viseme-mlp 1", "visemes PP aa", "context 0", f"hidden {hidden}",
        "input_offset " + " ".join(["0.5"] * 10 + ["-50"]),
        "input_scale " + " ".join(["2"] * 10 + ["0.03"]),
        "w1 " + " ".join(f"{(-1) ** i * 0.1 * (i % 7)}" for i in range(hidden * inputs)),
        "b1 0.1 -0.2", "w2 1 -1 -1 1", "b2 0 0.5", "end", ""])
    write("model", "version-1.lipmodel", version_one)
    lines = default.splitlines()
    version_two = []
    for line in lines:
        if line.startswith("lipcall-viseme-mlp"):
            version_two.append("lipcall-viseme-mlp 2")
        elif line.startswith(("lookahead", "normalise")):
            continue
        elif line.startswith("dynamics"):
            version_two.append("dynamics off")
        elif line.startswith("w1"):
            version_two.append("w1 " + " ".join(["0.01"] * (8 * 33)))
        else:
            version_two.append(line)
    write("model", "version-2-no-dynamics.lipmodel", "\n".join(version_two) + "\n")


def marker_seeds():
    write("markers", "nose-lip-chin",
          "frame,nose_x,nose_y,lip_x,lip_y,chin_x,chin_y\n10,100,50,100,80,100,120\n"
          "11,101,50,101,90,101,140\n12,100,50,100,85,100,130\n\0viseme,frame\nPP,10\naa,11\n")
    write("markers", "three-d",
          "frame,a_x,a_y,a_z,b_x,b_y,b_z\n1,0,0,0,1,1,1\n2,0.5,0,0,1,2,1.5\n3,0,0.25,0,1,1.5,1\n"
          "\0viseme, frame\nsil,1\nO,2\nE,3\n")
    write("markers", "no-keys", "frame,p_x,p_y\n0,1e3,-2.5e-2\n1,3,4\n")
    # A finding: points this far apart overflowed once the origin (the first marker) was subtracted.
    write("markers", "origin-far", "frame,nose_x,nose_y,lip_x,lip_y\n1,-3e38,0,3e38,0\n2,0,0,1,1\n")


def sdp_seeds():
    write("sdp", "softphone-offer",
          "v=0\r\no=- 123 456 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\nt=0 0\r\n"
          "m=audio 10000 RTP/AVP 96 0 8 101\r\na=rtpmap:96 opus/48000/2\r\n"
          "a=fmtp:96 stereo=1\r\na=rtpmap:101 telephone-event/8000\r\na=fmtp:101 0-15\r\n"
          "a=sendrecv\r\n")
    write("sdp", "sipp-answer",
          "v=0\r\no=sipp 1 1 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\nt=0 0\r\n"
          "m=audio 6000 RTP/AVP 0\r\na=rtpmap:0 PCMU/8000\r\n")
    write("sdp", "ipv6-hold-video",
          "v=0\r\no=x 1 2 IN IP6 ::1\r\ns=-\r\nt=0 0\r\nm=audio 7000 RTP/AVP 8 9 18 111 102\r\n"
          "c=IN IP6 ::1\r\na=rtpmap:111 OPUS/48000/2\r\na=rtpmap:102 telephone-event/48000\r\n"
          "a=sendonly\r\nm=video 0 RTP/AVP 96\r\n")


def mumble_seeds():
    """A flag byte (odd: TLS tunnel only), then operations: op, time step (ms), a 2-byte length
    and the bytes (see fuzz_targets/mumble.rs)."""
    def frame(kind, body):
        return struct.pack(">HI", kind, len(body)) + body

    def op(code, data, step=20):
        return bytes([code, step]) + struct.pack(">H", len(data)) + data

    def voice(session, sequence, payload, last=False):
        length = len(payload) | (0x2000 if last else 0)
        return bytes([0x80, session, sequence, 0x80 | (length >> 8), length & 0xFF]) + payload

    channel = frame(7, b"\x08\x01\x10\x00\x1a\x05Lobby")
    users = frame(9, b"\x08\x05\x1a\x03Bob\x28\x01") + frame(9, b"\x08\x03\x1a\x04fuzz\x28\x00")
    sync = frame(5, b"\x08\x03\x1a\x02hi")
    moved = frame(9, b"\x08\x03\x28\x01")
    opus = bytes([0x08]) + bytes(range(40))
    talk = b"".join(op(2, voice(5, 2 * i, opus)) + op(4, b"") for i in range(6))
    write("mumble", "join-and-talk", b"\0" + op(0, channel + users + sync + moved) + talk)
    tunnelled = b"".join(op(0, frame(1, voice(5, 2 * i, opus, i == 5))) for i in range(6))
    write("mumble", "tunnel-only", b"\1" + op(0, channel + users + sync) + tunnelled + op(3, opus))
    reject = frame(4, b"\x08\x04\x12\x05wrong")
    write("mumble", "reject-and-raw", b"\0" + op(0, reject) + op(1, b"\x00\x01\x02\x03\x04"))


def main():
    for make in (rtp_and_rtcp_seeds, relay_seeds, codec_seeds, wav_seeds, gltf_seeds, model_seeds,
                 marker_seeds, sdp_seeds, mumble_seeds):
        make()
    total = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(CORPUS) for f in fs)
    print(f"seeds written to {CORPUS}: {total} bytes", file=sys.stderr)


if __name__ == "__main__":
    main()
