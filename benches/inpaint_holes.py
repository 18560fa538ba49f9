#!/usr/bin/env python3
"""Scores of `scantex inpaint` results inside the holes against the image before the holes
(the inputs of benches/inpaint_speed.py: the truth is the image itself, since scantex never
reads the pixels under the mask): PSNR, low-frequency PSNR (both images blurred with a
Gaussian of sigma 4 first) and the detail ratio (standard deviation of the image minus its
Gaussian blur of sigma 2, result over truth), all over the mask's white pixels.

    python3 benches/inpaint_holes.py TRUTH.png MASK.png RESULT.png [RESULT.png ...]
"""
import sys

import cv2
import numpy as np


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    truth = cv2.imread(sys.argv[1]).astype(np.float32)
    mask = cv2.imread(sys.argv[2], cv2.IMREAD_GRAYSCALE) > 127
    truth_low = cv2.GaussianBlur(truth, (0, 0), 4)
    truth_high = truth - cv2.GaussianBlur(truth, (0, 0), 2)
    for path in sys.argv[3:]:
        out = cv2.imread(path).astype(np.float32)
        mse = ((out - truth)[mask] ** 2).mean()
        mse_low = ((cv2.GaussianBlur(out, (0, 0), 4) - truth_low)[mask] ** 2).mean()
        detail = (out - cv2.GaussianBlur(out, (0, 0), 2))[mask].std() / truth_high[mask].std()
        print(f"{path}: PSNR {10 * np.log10(255**2 / mse):.2f} dB, low-frequency PSNR "
              f"{10 * np.log10(255**2 / mse_low):.2f} dB, detail ratio {detail:.3f}")


if __name__ == "__main__":
    main()
