#!/usr/bin/env python3
"""radiometry_exif.py RADIOMETRY_CSV IMAGES_DIR FLIGHT CORNER: one markdown row comparing the gains a session found with
the camera's recorded exposure (EXIF ExposureTime x ISO / FNumber^2), read with a minimal TIFF/EXIF parser."""
import csv
import math
import os
import struct
import sys


def recorded_exposure(path):
    data = open(path, 'rb').read(1 << 18)
    start = data.find(b'Exif\x00\x00')
    if start < 0:
        return None
    t = start + 6
    order = '<' if data[t:t + 2] == b'II' else '>'
    u16 = lambda o: struct.unpack(order + 'H', data[t + o:t + o + 2])[0]
    u32 = lambda o: struct.unpack(order + 'I', data[t + o:t + o + 4])[0]
    tags = {}

    def walk(offset):
        for k in range(u16(offset)):
            e = offset + 2 + 12 * k
            tag, kind, value = u16(e), u16(e + 2), u32(e + 8)
            if tag == 0x8769:  # Exif sub-IFD
                walk(value)
            elif tag in (0x829A, 0x829D) and kind == 5:  # ExposureTime, FNumber (rationals)
                tags[tag] = u32(value) / max(1, u32(value + 4))
            elif tag == 0x8827:  # ISO
                tags[tag] = u16(e + 8)

    walk(u32(4))
    if not all(k in tags for k in (0x829A, 0x829D, 0x8827)) or tags[0x829D] <= 0:
        return None
    return tags[0x829A] * tags[0x8827] / tags[0x829D] ** 2


def main():
    rows = list(csv.DictReader(open(sys.argv[1])))
    pairs = []
    for r in rows:
        e = recorded_exposure(os.path.join(sys.argv[2], r['name']))
        if e:
            pairs.append((math.log(e), math.log(float(r['gain_g']))))
    if len(pairs) < 3:
        print(f"| {sys.argv[3]} | {len(rows)} | - | - | - | {sys.argv[4]} |")
        return
    mx = sum(p[0] for p in pairs) / len(pairs)
    my = sum(p[1] for p in pairs) / len(pairs)
    xs = [p[0] - mx for p in pairs]
    ys = [p[1] - my for p in pairs]
    sxx, syy = sum(x * x for x in xs), sum(y * y for y in ys)
    # A camera on fixed exposure has nothing to correlate with: the gains found are then the light's own changes.
    corr = f"{sum(x * y for x, y in zip(xs, ys)) / math.sqrt(sxx * syy):.2f}" if sxx > 1e-12 and syy > 0 else \
        "- (exposure fixed)"
    rms = math.sqrt(sum((x - y) ** 2 for x, y in zip(xs, ys)) / len(xs))
    print(f"| {sys.argv[3]} | {len(pairs)} | {corr} | {rms:.3f} | {math.sqrt(sxx / len(xs)):.3f} | {sys.argv[4]} |")


if __name__ == '__main__':
    main()
