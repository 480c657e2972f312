#!/usr/bin/env python3
"""Match two shapes of the shared data with shapeforest and with pyFM, and print both accuracies.

The pair is TOSCA `wolf0` (scan) → `wolf1` (reference) by default. shapeforest trains a forest on
the other shapes of the class (`wolf1`, `wolf2`: the reference is a training shape, as in the
paper's protocol) and matches; pyFM (PyPI `pyfmaps`) fits a functional map on the same pair
with its documented defaults (WKS descriptors, `fit(K=(35, 35))`, then ZoomOut), as
`scripts/pyfm_peer.py` runs it. Both maps are scored the same way, by
`shapeforest.geodesic_errors`: heat-method distance on the reference between the mapped vertex
and the ground truth (TOSCA shares vertex indexing), divided by √area, at 1,000 seeded points.

Usage: python match_with_pyfm.py [--data DIR] [--class wolf] [--scan 0] [--reference 1]
Data: --data, else $SHAPEFOREST_DATA, else ../shared/data beside the repository.
Needs: pip install ./python pyfmaps
"""
import argparse
import os
import pathlib
import sys
import time

import numpy as np

import shapeforest as sf


def data_dir(arg):
    if arg:
        return pathlib.Path(arg)
    if os.environ.get("SHAPEFOREST_DATA"):
        return pathlib.Path(os.environ["SHAPEFOREST_DATA"])
    return pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data"


def summary(name, errors, seconds):
    return (
        f"{name:<26} {100 * (errors <= 0.05).mean():6.1f} % {100 * (errors <= 0.10).mean():6.1f} % "
        f"{errors.mean():8.4f} {seconds:8.1f} s"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data")
    ap.add_argument("--class", dest="cls", default="wolf")
    ap.add_argument("--scan", type=int, default=0)
    ap.add_argument("--reference", type=int, default=1)
    ap.add_argument("--trees", type=int, default=15)
    args = ap.parse_args()
    tosca = data_dir(args.data) / "tosca"
    files = sorted(tosca.glob(f"{args.cls}[0-9]*.off"), key=lambda p: int(p.stem[len(args.cls):]))
    if len(files) < 2:
        sys.exit(f"need at least two {args.cls}N.off files in {tosca} (set --data or SHAPEFOREST_DATA)")
    meshes = {int(p.stem[len(args.cls):]): sf.read_mesh(p) for p in files}
    scan, reference = meshes[args.scan], meshes[args.reference]
    train = [reference] + [m for i, m in meshes.items() if i not in (args.scan, args.reference)]
    print(f"{scan.name} ({scan.n_vertices} vertices) → {reference.name}; training on "
          f"{', '.join(m.name for m in train)}")

    truth = np.arange(scan.n_vertices)  # TOSCA classes share one vertex indexing
    points = np.random.default_rng(0).choice(scan.n_vertices, size=min(1000, scan.n_vertices), replace=False)

    t0 = time.perf_counter()
    forest = sf.Forest.train(train, n_trees=args.trees, seed=0, progress=True)
    ours = forest.match(scan, reference, progress=True)
    t_ours = time.perf_counter() - t0
    e_ours = sf.geodesic_errors(reference, ours, truth, points=points)

    try:
        from pyFM.functional import FunctionalMapping
        from pyFM.mesh import TriMesh
    except ImportError:
        sys.exit("pyFM is missing: pip install pyfmaps")
    t0 = time.perf_counter()
    mesh1 = TriMesh(reference.vertices, reference.faces, area_normalize=True)
    mesh2 = TriMesh(scan.vertices, scan.faces, area_normalize=True)
    model = FunctionalMapping(mesh1, mesh2)
    model.preprocess(verbose=False)  # documented defaults: 100 WKS descriptors
    model.fit(K=(35, 35), verbose=False)
    pyfm = model.get_p2p()  # scan (mesh2) vertex → reference (mesh1) vertex
    t_pyfm = time.perf_counter() - t0
    pyfm_zo = model.get_p2p(FM=model.zoomout_refine(nit=15, step=1, verbose=False))
    t_zo = time.perf_counter() - t0
    e_pyfm = sf.geodesic_errors(reference, pyfm, truth, points=points)
    e_zo = sf.geodesic_errors(reference, pyfm_zo, truth, points=points)

    print(f"\ngeodesic error / √area at {len(points)} points, {scan.name} → {reference.name}")
    print(f"{'method':<26} {'≤ 0.05':>8} {'≤ 0.10':>8} {'mean':>8} {'time':>10}")
    print(summary(f"shapeforest ({len(train)} train)", e_ours, t_ours))
    print(summary("pyFM", e_pyfm, t_pyfm))
    print(summary("pyFM + ZoomOut", e_zo, t_zo))


if __name__ == "__main__":
    main()
