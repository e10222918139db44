#!/usr/bin/python3
"""colmap_compare.py MODEL_TXT_DIR GPS_REF [--strip-prefix] -> one JSON line of figures of a COLMAP text model.

Used by bench/ground_vs_colmap.sh on both COLMAP's model and ours, so that every figure of the table comes from the
same code: images registered, sparse points, mean track length, reprojection error recomputed from the model (RMS and
mean over all observations, OPENCV / FULL_OPENCV / SIMPLE_RADIAL / PINHOLE cameras), the intrinsics, and, when GPS_REF
exists (lines `name x y z`, metres), the RMS of the camera centres against it. The model should already be aligned to
GPS_REF (COLMAP's model_aligner); the RMS is taken after a least-squares similarity as well, so an unaligned model
still gives the right figure. --strip-prefix maps uavmosaic's stored names (000012_DJI_0018.JPG) to the originals.
"""
import json
import math
import re
import sys

import numpy as np


def read_cameras(path):
    cams = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        f = line.split()
        cams[int(f[0])] = (f[1], int(f[2]), int(f[3]), [float(v) for v in f[4:]])
    return cams


def read_images(path, strip):
    images = {}
    lines = [l for l in open(path) if not l.startswith("#")]
    for i in range(0, len(lines) - 1, 2):
        f = lines[i].split()
        if not f:
            continue
        q = np.array([float(v) for v in f[1:5]])
        t = np.array([float(v) for v in f[5:8]])
        name = f[9]
        if strip:
            name = re.sub(r"^\d{6}_", "", name)
        pts = lines[i + 1].split()
        obs = [(float(pts[k]), float(pts[k + 1]), int(pts[k + 2])) for k in range(0, len(pts), 3)]
        images[int(f[0])] = {"name": name, "q": q, "t": t, "cam": int(f[8]), "obs": obs}
    return images


def read_points(path):
    pts = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        f = line.split()
        track = f[8:]
        pts[int(f[0])] = (np.array([float(v) for v in f[1:4]]), len(track) // 2)
    return pts


def rotation(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def intrinsics(model, p):
    """fx fy cx cy k1 k2 p1 p2 k3 of the camera models COLMAP's mapper and our export use."""
    if model == "PINHOLE":
        return p[0], p[1], p[2], p[3], 0, 0, 0, 0, 0
    if model == "SIMPLE_RADIAL":
        return p[0], p[0], p[1], p[2], p[3], 0, 0, 0, 0
    if model == "RADIAL":
        return p[0], p[0], p[1], p[2], p[3], p[4], 0, 0, 0
    if model == "OPENCV":
        return p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], 0
    if model == "FULL_OPENCV":  # k1 k2 p1 p2 k3 k4 k5 k6 (k4.. not used by either side)
        return p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]
    raise SystemExit("unsupported camera model " + model)


def project(intr, X):
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = intr
    x, y = X[0] / X[2], X[1] / X[2]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return fx * xd + cx, fy * yd + cy


def similarity_rms(src, dst):
    """RMS of dst - (s R src + t) for the least-squares similarity (Umeyama): 3-D, horizontal, vertical."""
    src, dst = np.asarray(src), np.asarray(dst)
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, d, vt = np.linalg.svd(b.T @ a / len(src))
    s_fix = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s_fix[2, 2] = -1
    r = u @ s_fix @ vt
    scale = np.trace(np.diag(d) @ s_fix) / (a ** 2).sum(1).mean()
    res = b - scale * (r @ a.T).T
    return (math.sqrt((res ** 2).sum(1).mean()), math.sqrt((res[:, :2] ** 2).sum(1).mean()),
            math.sqrt((res[:, 2] ** 2).mean()))


def main():
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    d, ref_path, strip = sys.argv[1], sys.argv[2], "--strip-prefix" in sys.argv
    cams = read_cameras(d + "/cameras.txt")
    images = read_images(d + "/images.txt", strip)
    points = read_points(d + "/points3D.txt")
    sq, ab, n = 0.0, 0.0, 0
    centres = {}
    for im in images.values():
        model, _, _, p = cams[im["cam"]]
        intr = intrinsics(model, p)
        R = rotation(im["q"])
        centres[im["name"]] = -R.T @ im["t"]
        for x, y, pid in im["obs"]:
            if pid < 0 or pid not in points:
                continue
            Xc = R @ points[pid][0] + im["t"]
            if Xc[2] <= 0:
                continue
            u, v = project(intr, Xc)
            e2 = (u - x) ** 2 + (v - y) ** 2
            sq += e2
            ab += math.sqrt(e2)
            n += 1
    model, w, h, p = next(iter(cams.values()))
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = intrinsics(model, p)
    out = {
        "images": len(images),
        "names": sorted(im["name"] for im in images.values()),
        "points": len(points),
        "observations": n,
        "mean_track_length": (sum(t for _, t in points.values()) / len(points)) if points else 0,
        "reprojection_rms_px": math.sqrt(sq / n) if n else None,
        "reprojection_mean_px": ab / n if n else None,
        "camera": {"model": model, "cameras": len(cams), "f": fx, "cx": cx, "cy": cy, "k1": k1, "k2": k2,
                   "p1": p1, "p2": p2, "k3": k3, "width": w, "height": h},
    }
    try:
        ref = {}
        for line in open(ref_path):
            f = line.split()
            if len(f) == 4:
                ref[f[0]] = np.array([float(v) for v in f[1:4]])
        common = [k for k in centres if k in ref]
        if len(common) >= 3:
            src = [centres[k] for k in common]
            dst = [ref[k] for k in common]
            out["gps_common"] = len(common)
            out["gps_rms_m"], out["gps_rms_xy_m"], out["gps_rms_z_m"] = similarity_rms(src, dst)
            out["gps_rms_as_aligned_m"] = math.sqrt(np.mean([((a - b) ** 2).sum() for a, b in zip(src, dst)]))
    except FileNotFoundError:
        pass
    print(json.dumps(out))


if __name__ == "__main__":
    main()
