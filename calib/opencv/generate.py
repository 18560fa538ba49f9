#!/usr/bin/env python3
"""Reference projections from OpenCV: cv2.projectPoints with the 4-, 5-, 8- and 12-coefficient
distortion vectors, and cv2.Rodrigues. Writes `project_points.json`; scantex's tests read it.

    pip install opencv-python-headless==5.0.0.93 numpy
    python3 calib/opencv/generate.py

Do not regenerate to make a failing test pass.
"""
import json
import os

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
rng = np.random.default_rng(7)

K = np.array([[1450.0, 0.0, 803.2], [0.0, 1462.0, 597.9], [0.0, 0.0, 1.0]])
DIST = {
    4: [-0.11, 0.025, 0.0012, -0.0009],
    5: [-0.11, 0.025, 0.0012, -0.0009, 0.004],
    8: [-0.11, 0.025, 0.0012, -0.0009, 0.004, 0.01, -0.003, 0.002],
    12: [-0.11, 0.025, 0.0012, -0.0009, 0.004, 0.01, -0.003, 0.002, 0.0011, -0.0004, 0.0007, 0.0002],
}

cases = []
for n, dist in DIST.items():
    rvec = rng.normal(size=3) * 0.8
    tvec = rng.normal(size=3) + np.array([0.0, 0.0, 8.0])
    R, _ = cv2.Rodrigues(rvec)
    # Points in front of the camera covering the image and beyond its border (about 45 deg).
    cam = np.column_stack([rng.uniform(-0.7, 0.7, 300), rng.uniform(-0.55, 0.55, 300), np.ones(300)])
    cam *= rng.uniform(1.0, 15.0, 300)[:, None]
    world = (R.T @ (cam - tvec).T).T
    px, _ = cv2.projectPoints(world.reshape(-1, 1, 3), rvec, tvec, K, np.array(dist))
    cases.append({
        "coefficients": n,
        "dist": dist,
        "K": K.tolist(),
        "rvec": rvec.tolist(),
        "tvec": tvec.tolist(),
        "R": R.tolist(),
        "points_world": world.tolist(),
        "pixels": px.reshape(-1, 2).tolist(),
    })

rodrigues = []
for _ in range(50):
    r = rng.normal(size=3) * rng.uniform(0.0, 3.0)
    rodrigues.append({"rvec": r.tolist(), "R": cv2.Rodrigues(r)[0].tolist()})
rodrigues.append({"rvec": [0.0, 0.0, 0.0], "R": cv2.Rodrigues(np.zeros(3))[0].tolist()})
rodrigues.append({"rvec": [1e-9, -2e-9, 0.5e-9], "R": cv2.Rodrigues(np.array([1e-9, -2e-9, 0.5e-9]))[0].tolist()})

with open(os.path.join(HERE, "project_points.json"), "w") as f:
    json.dump({"opencv_version": cv2.__version__, "cases": cases, "rodrigues": rodrigues}, f)
print("opencv", cv2.__version__, len(cases), "cases")
