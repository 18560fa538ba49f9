#!/usr/bin/env python3
"""Reference pyramids from OpenCV: cv2.pyrDown and cv2.pyrUp (default and odd destination
sizes) on random float images, and a two-image blend by cv2.detail.MultiBandBlender.
Writes `pyramid.json`; scantex's tests (src/merge tests and tests/it/pyramid_reference.rs) read it.

    pip install opencv-python-headless==5.0.0.93 numpy
    python3 calib/opencv/pyramid.py

Do not regenerate to make a failing test pass.
"""
import json
import os

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
rng = np.random.default_rng(11)


def flat(a):
    # Nine significant digits: far below the 1e-5 the tests ask, a third of the file size.
    return [float(f"{v:.9g}") for v in np.asarray(a, dtype=np.float64).ravel()]


cases = []
for (w, h, c) in [(13, 9, 1), (16, 12, 3), (7, 5, 3), (8, 3, 1), (21, 17, 3)]:
    img = rng.random((h, w, c) if c > 1 else (h, w)).astype(np.float32)
    down = cv2.pyrDown(img)
    up = cv2.pyrUp(img)
    up_odd = cv2.pyrUp(img, dstsize=(2 * w - 1, 2 * h - 1))
    cases.append({
        "w": w, "h": h, "c": c, "image": flat(img),
        "down": {"w": down.shape[1], "h": down.shape[0], "data": flat(down)},
        "up": {"w": up.shape[1], "h": up.shape[0], "data": flat(up)},
        "up_odd": {"w": up_odd.shape[1], "h": up_odd.shape[0], "data": flat(up_odd)},
    })

# Two images of one scene under different exposure, a vertical seam between their masks.
W, H, BANDS = 96, 64, 4
yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
scene = 0.5 + 0.25 * np.sin(xx / 5.0)[..., None] * np.cos(yy / 7.0)[..., None] * np.array([1.0, 0.8, 0.6])
scene += 0.05 * rng.standard_normal((H, W, 3))
a = np.clip(scene * 0.8, 0, 1)
b = np.clip(scene * 1.2 + 0.05, 0, 1)
mask_a = (xx < W / 2).astype(np.uint8) * 255
mask_b = 255 - mask_a
blender = cv2.detail.MultiBandBlender(try_gpu=0, num_bands=BANDS, weight_type=cv2.CV_32F)
blender.prepare((0, 0, W, H))
# The blender takes 16-bit images: the fixture stores exactly what it was fed.
a16 = (a * 255.0).astype(np.int16)
b16 = (b * 255.0).astype(np.int16)
for img, m in [(a16, mask_a), (b16, mask_b)]:
    blender.feed(img, m, (0, 0))
out, out_mask = blender.blend(None, None)


def spline(imgs, masks, bands, exact_int16):
    """The multiresolution spline with cv2.pyrDown/pyrUp: in float32 (what scantex computes)
    or with MultiBandBlender's 16-bit arithmetic (each band, each weighted product and each
    normalised band truncated to int16), which reproduces the blender bit for bit."""
    num = den = None
    for im, m in zip(imgs, masks):
        g = [im.astype(np.int16 if exact_int16 else np.float32)]
        for _ in range(bands):
            g.append(cv2.pyrDown(g[-1]))
        lap = [cv2.subtract(g[i], cv2.pyrUp(g[i + 1], dstsize=(g[i].shape[1], g[i].shape[0])))
               for i in range(bands)] + [g[bands]]
        mg = [(m > 0).astype(np.float32)]
        for _ in range(bands):
            mg.append(cv2.pyrDown(mg[-1]))
        if num is None:
            num = [np.zeros(x.shape, x.dtype) for x in lap]
            den = [np.zeros_like(x) for x in mg]
        for i in range(bands + 1):
            prod = lap[i].astype(np.float32) * mg[i][..., None]
            num[i] = (num[i] + prod.astype(np.int16)).astype(np.int16) if exact_int16 else num[i] + prod
            den[i] += mg[i]
    for i in range(bands + 1):
        q = num[i].astype(np.float32) / (den[i][..., None] + 1e-5)
        num[i] = q.astype(np.int16) if exact_int16 else q
    r = num[bands]
    for i in range(bands - 1, -1, -1):
        r = cv2.add(cv2.pyrUp(r, dstsize=(num[i].shape[1], num[i].shape[0])), num[i])
    return r


emulated = spline([a16, b16], [mask_a, mask_b], BANDS, True)
assert np.array_equal(emulated, out), "the 16-bit emulation must reproduce the blender"
reference = spline([a16, b16], [mask_a, mask_b], BANDS, False)
print("float spline vs MultiBandBlender: mean |diff| %.3f, max %.3f"
      % (np.abs(reference - out).mean(), np.abs(reference - out).max()))
blend = {
    "w": W, "h": H, "bands": BANDS,
    "a": flat(a16), "b": flat(b16),
    "mask_a": [int(v > 0) for v in mask_a.ravel()],
    "result": flat(out),
    "float_reference": flat(reference),
}

with open(os.path.join(HERE, "pyramid.json"), "w") as f:
    json.dump({"opencv": cv2.__version__, "cases": cases, "blend": blend}, f)
print("wrote pyramid.json:", len(cases), "pyramid cases and one blend")
