"""Re-measure `shapeforest eval --pairs/--protocol ... --point-errors` with exact geodesics.

The eval measures a point's error with heat-method distances (or first-order fast marching),
both approximations. This script reads the eval's `points.csv` (each corresponded point's image
and true vertex on the target shape `B`) and measures the same points with exact polyhedral
geodesics (Mitchell-Mount-Papadimitriou, Kirsanov's implementation via the `pygeodesic`
package), divided by sqrt(area(B)) as the eval does, and prints, per method, the mean error x100
and the fraction within 0.05 and 0.1 by both measures. Strict errors only (no mirror).

Usage: exact_errors.py CLASS_DIR POINTS_CSV [--method NAME] [--pairs N]
Meshes are read from CLASS_DIR/NAME.off or NAME.off.gz (the eval's shape names).
"""

import argparse
import collections
import os
import sys

import numpy as np
import pygeodesic.geodesic as geodesic

import off_io


def read_off(path):
    v, f = off_io.read_off(path)
    return np.array(v, dtype=float).reshape(-1, 3), np.array(off_io.triangles(f), dtype=np.int32)


def mesh_path(class_dir, name):
    for ext in (".off", ".off.gz"):
        p = os.path.join(class_dir, name + ext)
        if os.path.exists(p):
            return p
    sys.exit(f"{class_dir}: no {name}.off or {name}.off.gz")


def area(verts, faces):
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("class_dir")
    ap.add_argument("points_csv")
    ap.add_argument("--method", action="append", help="methods to measure (default: all)")
    ap.add_argument("--pairs", type=int, default=0, help="only the first N pairs (0: all)")
    args = ap.parse_args()

    rows = collections.defaultdict(list)  # (a, b) -> [(method, heat, image, truth)]
    order = []
    with open(args.points_csv) as f:
        header = f.readline().strip().split(",")
        col = {h: i for i, h in enumerate(header)}
        if "image" not in col:
            sys.exit(f"{args.points_csv}: no image/truth columns (written by shapeforest eval since 2026-12-03)")
        for line in f:
            r = line.rstrip("\n").split(",")
            if args.method and r[col["method"]] not in args.method:
                continue
            key = (r[col["a"]], r[col["b"]])
            if key not in rows:
                order.append(key)
            rows[key].append((r[col["method"]], float(r[col["strict"]]), int(r[col["image"]]), int(r[col["truth"]])))
    if args.pairs:
        order = order[: args.pairs]

    heat = collections.defaultdict(list)
    exact = collections.defaultdict(list)
    meshes = {}
    for a, b in order:
        if b not in meshes:
            verts, faces = read_off(mesh_path(args.class_dir, b))
            meshes[b] = (geodesic.PyGeodesicAlgorithmExact(verts, faces), np.sqrt(area(verts, faces)))
        alg, norm = meshes[b]
        by_truth = collections.defaultdict(list)
        for method, h, image, truth in rows[(a, b)]:
            by_truth[truth].append((method, h, image))
        for truth, items in by_truth.items():
            targets = np.array(sorted({image for _, _, image in items}), dtype=np.int32)
            # The propagation stops at twice the largest heat-method error (plus a margin);
            # a target it did not reach is measured again without the bound.
            bound = (2.0 * max(h for _, h, _ in items) + 0.02) * norm
            dist, _ = alg.geodesicDistances(np.array([truth], dtype=np.int32), targets, bound)
            if not np.all(np.isfinite(dist) & (dist < 1e30)):
                dist, _ = alg.geodesicDistances(np.array([truth], dtype=np.int32), targets)
            d = dict(zip(targets.tolist(), dist.tolist()))
            for method, h, image in items:
                heat[method].append(h)
                exact[method].append(d[image] / norm)
        print(f"{a} -> {b}: {len(rows[(a, b)])} points", file=sys.stderr)

    print(f"{len(order)} pairs; strict errors / sqrt(area), heat method (the eval's) vs exact geodesics")
    print(f"{'method':14} {'n':>8} | {'heat mean x100':>14} {'<=0.05':>7} {'<=0.1':>7} | {'exact mean x100':>15} {'<=0.05':>7} {'<=0.1':>7}")
    for method in sorted(heat):
        h, e = np.array(heat[method]), np.array(exact[method])
        print(
            f"{method:14} {len(h):>8} | {100 * h.mean():>14.2f} {100 * (h <= 0.05).mean():>6.1f}% {100 * (h <= 0.1).mean():>6.1f}%"
            f" | {100 * e.mean():>15.2f} {100 * (e <= 0.05).mean():>6.1f}% {100 * (e <= 0.1).mean():>6.1f}%"
        )


if __name__ == "__main__":
    main()
