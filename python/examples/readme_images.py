#!/usr/bin/env python3
"""The README's pictures: a good map and a bad one of the same scan, as PNG snapshots.

Trains a forest on 6 synthetic creatures, matches a held-out pose, and writes
docs/img/map-regularised.png (the regularised map, `forest.match`) and docs/img/map-raw.png (the
forest's raw most-probable label per vertex, before the regulariser), printing the accuracy of
each. Usage: python readme_images.py [OUT_DIR]   (default: docs/img of the repository)
"""
import pathlib
import sys

import numpy as np

import shapeforest as sf

out = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else pathlib.Path(__file__).resolve().parents[2] / "docs" / "img"
out.mkdir(parents=True, exist_ok=True)
shapes = sf.synthetic_creatures(n_shapes=8, vertices=5000, seed=1)
forest = sf.Forest.train(shapes[:6], n_trees=15, seed=0)
scan, reference = shapes[7], shapes[0]
truth = np.arange(scan.n_vertices)
points = np.arange(0, scan.n_vertices, 5)
regularised = forest.match(scan, reference)
raw = forest.predict(scan, top_k=1)[0][:, 0]
raw = np.where(raw < 0, 0, raw)
for name, m in (("map-regularised", regularised), ("map-raw", raw)):
    e = sf.geodesic_errors(reference, m, truth, points=points)
    sf.snapshot(scan, reference, m, out / f"{name}.png", width=640, height=320)
    print(f"{name}: {100 * (e <= 0.05).mean():.1f} % within 0.05, mean {e.mean():.4f} → {out / name}.png")
