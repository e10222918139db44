#!/usr/bin/python3
"""independent_score.py COLMAP_DB SESSION [SESSION ...] -> one JSON line per session: its maps scored on matches no
session chose.

A session's held-out RMS is taken on its own held-out points, which its detector and matcher picked: two runs that
found different pairs and points are scored on different sets (caliterra: 0.755 px with one detector, 1.17 px for the
same code with the frames not resampled by a lens first). This scores every session on one fixed set instead: the
verified inlier matches of COLMAP's own SIFT and matcher (`colmap feature_extractor` + `exhaustive_matcher` on the
original images, bench/independent_score.sh), independent of the product.

For each verified match (p in frame i, q in frame j), both recorded pixels are undistorted with the session's lens
(camera.yaml), p is carried through the session's maps (transforms.csv: mosaic_from_frame, ideal pixels) into frame j
and compared with q, in frame j's pixels at the session's working resolution (config.yaml work_long_side), the unit of
report.json's held-out RMS. Pairs whose frames the session did not register are skipped (counted). A few of COLMAP's
matches are wrong whatever the maps: the figures are the median, the RMS of the errors within --trim-px (the same
set for every session: a match is trimmed only when it is beyond the threshold in every session scored together),
and the share beyond it.
"""
import argparse
import json
import math
import os
import sqlite3
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scripts"))
from compare_sessions import read as read_maps  # noqa: E402  (the sessions' transforms.csv, one reader)

PAIR_ID_BASE = 2147483647  # COLMAP: pair_id = image_id1 * 2147483647 + image_id2, image_id1 < image_id2


def read_matches(db_path):
    """{(name_i, name_j): (pts_i Nx2, pts_j Nx2)} in pixel-centre coordinates ((0,0) = centre of the top-left pixel)."""
    db = sqlite3.connect(db_path)
    names = dict(db.execute("SELECT image_id, name FROM images"))
    keypoints = {}
    for image_id, rows, cols, data in db.execute("SELECT image_id, rows, cols, data FROM keypoints"):
        if rows == 0:
            continue
        # COLMAP's origin is the top-left pixel's corner: its centre is at (0.5, 0.5).
        keypoints[image_id] = np.frombuffer(data, dtype=np.float32).reshape(rows, cols)[:, :2].astype(float) - 0.5
    pairs = {}
    for pair_id, rows, cols, data in db.execute("SELECT pair_id, rows, cols, data FROM two_view_geometries"):
        if rows == 0 or data is None:
            continue
        id_j = pair_id % PAIR_ID_BASE
        id_i = (pair_id - id_j) // PAIR_ID_BASE
        idx = np.frombuffer(data, dtype=np.uint32).reshape(rows, cols)
        pairs[(names[id_i], names[id_j])] = (keypoints[id_i][idx[:, 0]], keypoints[id_j][idx[:, 1]])
    return pairs


def read_yaml_numbers(path, keys):
    out = {}
    for line in open(path):
        key, _, value = line.strip().partition(":")
        if key in keys:
            out[key] = float(value)
    return out


def read_session(session):
    cam = read_yaml_numbers(f"{session}/camera.yaml", {"width", "height", "focal_px", "cx", "cy", "k1", "k2", "p1", "p2"})
    work = read_yaml_numbers(f"{session}/config.yaml", {"work_long_side"}).get("work_long_side", 1000.0)
    _, rows = read_maps(session)  # a00 a01 a02 a10 a11 a12 h20 h21 of each registered frame
    maps = {name: np.array([a[0:3], a[3:6], [a[6], a[7], 1.0]]) for name, a in rows.items()}
    scale = work / max(cam["width"], cam["height"])
    return cam, maps, scale


def undistort(cam, pts):
    """Brown-Conrady (OpenCV's convention) inverted by fixed-point iteration, as the product's LensDistortion."""
    if not (cam.get("k1") or cam.get("k2") or cam.get("p1") or cam.get("p2")):
        return pts
    f, c = cam["focal_px"], np.array([cam["cx"], cam["cy"]])
    d = (pts - c) / f
    x = d.copy()
    for _ in range(50):
        r2 = (x * x).sum(axis=1, keepdims=True)
        radial = 1 + cam["k1"] * r2 + cam["k2"] * r2 * r2
        xy = x[:, :1] * x[:, 1:]
        tx = 2 * cam["p1"] * xy + cam["p2"] * (r2 + 2 * x[:, :1] ** 2)
        ty = cam["p1"] * (r2 + 2 * x[:, 1:] ** 2) + 2 * cam["p2"] * xy
        step = d - (x * radial + np.hstack([tx, ty]))
        x += step
        if (step * step).sum(axis=1).max() < 1e-24:
            break
    return x * f + c


def transfer_errors(session, pairs):
    cam, maps, scale = read_session(session)
    errors, skipped = {}, 0
    for (name_i, name_j), (p, q) in pairs.items():
        if name_i not in maps or name_j not in maps:
            skipped += 1
            continue
        tgt_from_src = np.linalg.inv(maps[name_j]) @ maps[name_i]
        ph = np.hstack([undistort(cam, p), np.ones((len(p), 1))]) @ tgt_from_src.T
        moved = ph[:, :2] / ph[:, 2:]
        errors[(name_i, name_j)] = np.linalg.norm(moved - undistort(cam, q), axis=1) * scale
    return errors, skipped, len(maps)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("db")
    ap.add_argument("sessions", nargs="+")
    ap.add_argument("--trim-px", type=float, default=3.0, help="working pixels (the product's RANSAC threshold)")
    args = ap.parse_args()
    pairs = read_matches(args.db)
    scored = [(s, *transfer_errors(s, pairs)) for s in args.sessions]
    # The pairs every session registered: the same set for all.
    common = set.intersection(*(set(e) for _, e, _, _ in scored))
    if not common:
        sys.exit("independent_score: no pair of COLMAP's matches is registered by every session")
    keep = {k: np.zeros(len(pairs[k][0]), dtype=bool) for k in common}
    for _, errors, _, _ in scored:
        for k in common:
            keep[k] |= errors[k] <= args.trim_px
    for session, errors, skipped, registered in scored:
        all_e = np.concatenate([errors[k] for k in sorted(common)])
        kept = np.concatenate([errors[k][keep[k]] for k in sorted(common)])
        print(json.dumps({
            "session": session,
            "registered": registered,
            "pairs": len(common),
            "matches": int(all_e.size),
            "median_px": round(float(np.median(all_e)), 4),
            "rms_within_trim_px": round(float(math.sqrt(float((kept * kept).mean()))), 4),
            "trim_px": args.trim_px,
            "share_beyond_trim": round(float((all_e > args.trim_px).mean()), 4),
            "pairs_not_registered": skipped,
        }))


if __name__ == "__main__":
    main()
