#!/usr/bin/env python3
"""Does a head's mouth gauge agree with a face tracker? Tracks the renders of
`cargo run --example viseme_gauge -- DIR [--head FILE.glb]` with MediaPipe (tools/face_track.py)
and prints, per viseme and amount, the gauge's and the tracker's lip gap and mouth width above the
rest shape, then Pearson r and the least-squares slope (tracker over gauge) of each.

    .venv-track/bin/python tools/gauge_check.py DIR
"""
import csv
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from face_track import pearson, track  # noqa: E402


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = pathlib.Path(sys.argv[1])
    with open(out / "gauge.csv") as f:
        rows = list(csv.DictReader(f))
    tracked = track([out / f"{r['viseme']}_{r['amount']}.png" for r in rows])
    if any(t is None for t in tracked):
        sys.exit("the tracker found no face on some renders")
    rest = next(t for r, t in zip(rows, tracked) if r["viseme"] == "sil")
    rest_gauge = next((float(r["lip_gap"]), float(r["mouth_width"]))
                      for r in rows if r["viseme"] == "sil")
    print(f"{'viseme':>6} {'amount':>6} {'gap: gauge':>10} {'tracker':>8} "
          f"{'width: gauge':>12} {'tracker':>8}")
    pairs = []
    for r, t in zip(rows, tracked):
        g = (float(r["lip_gap"]) - rest_gauge[0], float(r["mouth_width"]) - rest_gauge[1])
        k = (t[0] - rest[0], t[1] - rest[1])
        pairs.append((g, k))
        print(f"{r['viseme']:>6} {r['amount']:>6} {g[0]:10.3f} {k[0]:8.3f} "
              f"{g[1]:12.3f} {k[1]:8.3f}")
    for i, what in enumerate(("lip gap", "mouth width")):
        g = np.array([p[0][i] for p in pairs])
        k = np.array([p[1][i] for p in pairs])
        slope = float(g @ k / (g @ g)) if g @ g > 0 else float("nan")
        print(f"{what}: r={pearson(g, k):.3f} slope={slope:.2f} "
              f"(tracker per gauge eye width, through the rest)")


if __name__ == "__main__":
    main()
