#!/usr/bin/python3
"""daisy_reference.py IMAGE.png OUT.txt STEP: scikit-image's DAISY descriptors of IMAGE (8-bit gray) with the seed's
parameters (radius 15, 3 rings, 8 histograms, 8 orientations, per-histogram "daisy" normalisation), one line per
sampled pixel: `x y v0 ... v199`, pixels every STEP from the first one with the whole pattern inside (15, 15).
The independent implementation tests/daisy_test.cpp checks core/stereo/daisy.cpp against (Debian's python3-skimage)."""
import sys

import numpy as np
from skimage import io
from skimage.feature import daisy

img = io.imread(sys.argv[1]).astype(np.float64) / 255.0
step = int(sys.argv[3])
d = daisy(img, step=step, radius=15, rings=3, histograms=8, orientations=8, normalization="daisy")
with open(sys.argv[2], "w") as out:
    for r in range(d.shape[0]):
        for c in range(d.shape[1]):
            out.write(f"{15 + c * step} {15 + r * step} " + " ".join(f"{v:.7g}" for v in d[r, c]) + "\n")
