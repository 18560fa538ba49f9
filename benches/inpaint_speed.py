#!/usr/bin/env python3
"""Inputs of the restoration speed figures in docs/benchmarks.md: a 600x450 RGB photograph
(criminisi image1 resized) with 5% scattered blobs, and a 4096x4096 RGB texture (gravel tiled
under a ramp) with 5% blobs, written to /tmp/s600*.png and /tmp/s4096*.png. Then:

    scantex inpaint /tmp/s600.png --mask /tmp/s600_mask.png -o /tmp/o600.png --json
    scantex inpaint /tmp/s4096.png --mask /tmp/s4096_mask.png -o /tmp/o4096.png --json
"""
import os
import sys

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "calib", "opencv"))
import inpaint as ref  # noqa: E402

data = os.path.join(ROOT, "..", "shared", "data")
im = cv2.imread(os.path.join(data, "inpaint", "criminisi", "image1.jpg"))
cv2.imwrite("/tmp/s600.png", cv2.resize(im, (600, 450), interpolation=cv2.INTER_CUBIC))
cv2.imwrite("/tmp/s600_mask.png", ref.blobs(450, 600, 0.05, 1) * 255)
g = cv2.imread(os.path.join(data, "textures", "gravel.png"))
big = np.tile(g, (8, 8, 1)).astype(np.float32) * np.linspace(0.4, 1.0, 4096)[None, :, None]
cv2.imwrite("/tmp/s4096.png", big.astype(np.uint8))
cv2.imwrite("/tmp/s4096_mask.png", ref.blobs(4096, 4096, 0.05, 2) * 255)
print("wrote /tmp/s600.png, /tmp/s4096.png and their masks")
