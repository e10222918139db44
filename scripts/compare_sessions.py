#!/usr/bin/env python3
"""compare_sessions.py A B [--max-px 0.5]: do two sessions of the same flight agree (e.g. native vs aarch64)?

Both must register the same frames. For each frame, the four corners and the centre of the frame (its original size,
from frames.csv) are mapped into the mosaic by each session's transform (transforms.csv: affine a00..a12 plus the
projective row h20 h21). A mosaic's own frame is arbitrary (its origin is the corner of its bounding box, which moves
with any frame), so one global affine map from A's mosaic to B's is fitted to all those points first (least squares);
what remains is the disagreement, expressed in the frame's own pixels (divided by the scale of session A's map).
Prints the median and maximum and exits 1 above --max-px.
"""
import argparse
import csv
import math
import statistics
import sys


def read(session):
    sizes = {}
    with open(f"{session}/frames.csv", newline="") as f:
        for row in csv.DictReader(f):
            sizes[row["filename"]] = (float(row["width"]), float(row["height"]))
    maps = {}
    with open(f"{session}/transforms.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["registered"] != "1":
                continue
            m = [float(row[k]) for k in ("a00", "a01", "a02", "a10", "a11", "a12", "h20", "h21")]
            maps[row["filename"]] = m
    return sizes, maps


def apply(m, x, y):
    w = m[6] * x + m[7] * y + 1.0
    return ((m[0] * x + m[1] * y + m[2]) / w, (m[3] * x + m[4] * y + m[5]) / w)


def solve3(m, v):
    """Solves the 3x3 system m x = v (Cramer's rule; m is a normal matrix, well conditioned here)."""
    def det(a):
        return (a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
                + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]))
    d = det(m)
    out = []
    for c in range(3):
        mc = [row[:] for row in m]
        for r in range(3):
            mc[r][c] = v[r]
        out.append(det(mc) / d)
    return out


def fit_affine(src, dst):
    """Least-squares 2-D affine dst ~ A src + t, as two rows (a, b, c): x' = a x + b y + c."""
    n = [[0.0] * 3 for _ in range(3)]
    vx = [0.0] * 3
    vy = [0.0] * 3
    for (x, y), (u, v) in zip(src, dst):
        f = (x, y, 1.0)
        for i in range(3):
            for j in range(3):
                n[i][j] += f[i] * f[j]
            vx[i] += f[i] * u
            vy[i] += f[i] * v
    return solve3(n, vx), solve3(n, vy)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--max-px", type=float, default=0.5)
    args = ap.parse_args()
    sizes, ma = read(args.a)
    _, mb = read(args.b)
    if set(ma) != set(mb):
        print(f"registered sets differ: only in A {sorted(set(ma) - set(mb))}, only in B {sorted(set(mb) - set(ma))}")
        return 1
    points = []  # (frame scale, point in A's mosaic, point in B's mosaic)
    for name, a in ma.items():
        w, h = sizes[name]
        scale = math.sqrt(abs(a[0] * a[4] - a[1] * a[3]))
        for x, y in ((0, 0), (w, 0), (0, h), (w, h), (w / 2, h / 2)):
            points.append((scale, apply(a, x, y), apply(mb[name], x, y)))
    rx, ry = fit_affine([p[1] for p in points], [p[2] for p in points])
    errors = []
    for scale, (x, y), (u, v) in points:
        du = rx[0] * x + rx[1] * y + rx[2] - u
        dv = ry[0] * x + ry[1] * y + ry[2] - v
        errors.append(math.hypot(du, dv) / scale)
    med, worst = statistics.median(errors), max(errors)
    print(f"{len(ma)} frames registered in both; transform difference in frame pixels after one global affine: median {med:.4f}, max {worst:.4f}"
          f" (limit {args.max_px})")
    return 0 if worst <= args.max_px else 1


if __name__ == "__main__":
    sys.exit(main())
