#!/usr/bin/env python3
"""Reference data for restoration (issue 7): masks cut into the textures of
../shared/data/textures, and what OpenCV's cv2.inpaint (TELEA and NS, radius 5) makes of them.

Writes calib/opencv/inpaint/<mask>.png (the masks, white = fill) and
calib/opencv/inpaint.json (per texture, variant and mask: PSNR, SSIM, low-frequency PSNR and
detail ratio inside the mask for TELEA and NS). tests/it/restore_reference.rs reads both; the
metrics are defined once, in `metrics()` here and `restore_metrics` in that test.

    pip install opencv-python-headless numpy
    python3 calib/opencv/inpaint.py
"""
import json
import os
import sys

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
DATA = os.path.join(ROOT, "..", "shared", "data", "textures")

TEXTURES = ["brick.png", "grass.png", "gravel.png"] + [
    "portilla_simoncelli/" + n
    for n in ["metal.pgm", "nuts.pgm", "reptil_skin.pgm", "text.pgm", "sawtooth.pgm", "checkerboard.pgm"]
]


def texture_name(path):
    return os.path.splitext(os.path.basename(path))[0]


def load(path, ramp):
    """Grey texture in [0, 1]; with `ramp`, multiplied by a left-to-right ramp 0.2 -> 1.0."""
    img = cv2.imread(os.path.join(DATA, path), cv2.IMREAD_GRAYSCALE).astype(np.float64) / 255.0
    if ramp:
        h, w = img.shape
        img = img * (0.2 + 0.8 * np.arange(w)[None, :] / (w - 1))
    return img


def blobs(h, w, fraction, seed):
    """Scattered discs of radius 4 to 12 until `fraction` of the image is covered."""
    rng = np.random.default_rng(seed)
    m = np.zeros((h, w), np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    while m.mean() < fraction:
        r = rng.uniform(4, 12)
        cx, cy = rng.uniform(r, w - r), rng.uniform(r, h - r)
        m[(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r] = 1
    return m


def disc(h, w, fraction):
    r = np.sqrt(fraction * h * w / np.pi)
    yy, xx = np.mgrid[0:h, 0:w]
    return ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2 <= r * r).astype(np.uint8)


def masks_for(h, w):
    return {
        "blobs5": blobs(h, w, 0.05, 5),
        "blobs15": blobs(h, w, 0.15, 15),
        "disc10": disc(h, w, 0.10),
    }


def psnr(a, b):
    mse = np.mean((a - b) ** 2)
    return float(10 * np.log10(1.0 / max(mse, 1e-12)))


def ssim_map(a, b):
    """Wang et al.'s SSIM map, Gaussian window sigma 1.5 (11x11), data range 1."""
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    g = lambda x: cv2.GaussianBlur(x, (11, 11), 1.5, borderType=cv2.BORDER_REFLECT)
    ma, mb = g(a), g(b)
    va, vb, cab = g(a * a) - ma * ma, g(b * b) - mb * mb, g(a * b) - ma * mb
    return ((2 * ma * mb + c1) * (2 * cab + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))


def gauss(x, k):
    # sigma 0 lets OpenCV derive it from the size: 1.1 for 5x5, 1.7 for 9x9.
    return cv2.GaussianBlur(x, (k, k), 0, borderType=cv2.BORDER_REFLECT)


def metrics(truth, result, mask):
    """Inside the mask: PSNR, mean SSIM, PSNR of 9x9-Gaussian-blurred images, and the detail
    ratio std(high-pass in the hole) / std(high-pass outside), high-pass = image - 5x5 blur."""
    m = mask.astype(bool)
    lo_t, lo_r = gauss(truth, 9), gauss(result, 9)
    hp = result - gauss(result, 5)
    return {
        "psnr": psnr(truth[m], result[m]),
        "ssim": float(ssim_map(truth, result)[m].mean()),
        "lowfreq_psnr": psnr(lo_t[m], lo_r[m]),
        "detail_ratio": float(hp[m].std() / hp[~m].std()),
    }


def main():
    out_dir = os.path.join(HERE, "inpaint")
    os.makedirs(out_dir, exist_ok=True)
    results = []
    for t in TEXTURES:
        for ramp in (False, True):
            truth = load(t, ramp)
            h, w = truth.shape
            for mname, m in masks_for(h, w).items():
                mpath = os.path.join(out_dir, f"{mname}_{w}x{h}.png")
                if not os.path.exists(mpath):
                    cv2.imwrite(mpath, m * 255)
                # OpenCV inpaints 8-bit images; both methods see the same quantised input.
                src = np.round(truth * 255).astype(np.uint8)
                row = {
                    "texture": texture_name(t),
                    "path": t,
                    "ramp": ramp,
                    "mask": mname,
                    "mask_file": os.path.basename(mpath),
                    "masked_fraction": float(m.mean()),
                }
                for name, flag in (("telea", cv2.INPAINT_TELEA), ("ns", cv2.INPAINT_NS)):
                    res = cv2.inpaint(src, m, 5, flag).astype(np.float64) / 255.0
                    row[name] = metrics(truth, res, m)
                results.append(row)
    with open(os.path.join(HERE, "inpaint.json"), "w") as f:
        json.dump(
            {"opencv": cv2.__version__, "radius": 5, "results": results},
            f,
            indent=1,
        )
    print(f"wrote {len(results)} cases", file=sys.stderr)


if __name__ == "__main__":
    main()
