#!/usr/bin/env python3
"""A copy of a scene whose mesh has the same triangles in another order (issue 23): how much of
a run's time the input's face and vertex order costs.

    pip install numpy trimesh
    python3 benches/mesh_order.py <scene> <new scene>            # spatial (Morton) order
    python3 benches/mesh_order.py --shuffle <scene> <new scene>  # random order, seed 0

<scene> is a scene directory with `mesh.ply` (as benches/scale_curve.py writes them); the new
scene gets the reordered `mesh.ply` and symbolic links to the scene's `images`, `masks` and
`sparse`. Vertices are sorted by the Morton code of their position (10 bits per axis over the
bounding box), faces by that of their centroid: consecutive faces then share vertices and lie
next to each other in every photograph and in the atlas. Prints, before and after, the median
jump of the lowest vertex index from one face to the next (a scan's mesher writes faces near
each other; the 1.5M-face scene of `scale_curve.py --exact` jumps by about a fifth of its
vertices).
"""
import os
import sys

import numpy as np
import trimesh


def morton(points):
    """Morton codes of `points` (n x 3) over their bounding box, 10 bits per axis."""
    lo, hi = points.min(0), points.max(0)
    q = ((points - lo) / max((hi - lo).max(), 1e-300) * 1023).astype(np.uint64)

    def spread(x):
        x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
        return (x | (x << np.uint64(2))) & np.uint64(0x09249249)

    return spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))


def median_jump(faces):
    return float(np.median(np.abs(np.diff(faces.min(1)))))


def main():
    args = sys.argv[1:]
    shuffle = "--shuffle" in args
    args = [a for a in args if a != "--shuffle"]
    if len(args) != 2:
        sys.exit(__doc__)
    src, dst = args
    mesh = trimesh.load(os.path.join(src, "mesh.ply"), process=False)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if shuffle:
        rng = np.random.default_rng(0)
        vo, fo = rng.permutation(len(v)), rng.permutation(len(f))
    else:
        vo = np.argsort(morton(v), kind="stable")
        fo = np.argsort(morton(v[f].mean(1)), kind="stable")
    new_index = np.empty(len(v), np.int64)
    new_index[vo] = np.arange(len(v))
    f2 = new_index[f][fo]
    os.makedirs(dst, exist_ok=True)
    for name in ("images", "masks", "sparse"):
        target = os.path.abspath(os.path.join(src, name))
        link = os.path.join(dst, name)
        if os.path.exists(target) and not os.path.lexists(link):
            os.symlink(target, link)
    trimesh.Trimesh(v[vo], f2, process=False).export(os.path.join(dst, "mesh.ply"))
    print(
        f"{len(f)} faces, {len(v)} vertices: median jump of the lowest vertex index between "
        f"consecutive faces {median_jump(f):.0f} -> {median_jump(f2):.0f}"
    )


if __name__ == "__main__":
    main()
