#!/usr/bin/env python3
"""Accuracy peer: pyFM (PyPI `pyfmaps`) on the pairs of a `shapeforest eval` run.

Reads OUT/peer/pairs.json written by `shapeforest eval --out OUT`: for each pair, the test and
reference mesh files and the evaluated vertices (test vertex -> ground-truth reference vertex).
Runs pyFM with its documented defaults (README example: area-normalised meshes, WKS descriptors,
`preprocess()` defaults, `fit(K=(35, 35))` with default weights, point-to-point map from the
functional map, then ZoomOut refinement with `nit=15, step=1`) and reports the same figures as
shapeforest: geodesic error on the reference between the mapped vertex and the ground truth,
divided by sqrt(area of the reference), at the same evaluation points. Distances come from the
heat method too (potpourri3d's MeshHeatMethodDistanceSolver, t = mean edge length squared).
Symmetric figures (a match counts as correct near the ground truth or near its mirror image,
as in `shapeforest eval`) when pairs.json carries the mirror images of the evaluated reference
vertices. Meshes may be gzipped (`.off.gz`).

Usage: pyfm_peer.py OUT [--csv OUT/peer/pyfm_results.csv]
"""
import argparse
import json
import os
import sys
import time

import numpy as np

import off_io


def read_off(path):
    v, f = off_io.read_off(path)
    return np.array(v, dtype=float).reshape(-1, 3), np.array(off_io.triangles(f), dtype=np.int64)


def area(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()


def summary(e):
    e = np.asarray(e)
    return {"within_005": float((e <= 0.05).mean()), "within_010": float((e <= 0.1).mean()), "mean": float(e.mean())}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", help="output folder of `shapeforest eval`")
    ap.add_argument("--csv", default=None)
    args = ap.parse_args()
    pairs_path = os.path.join(args.out, "peer", "pairs.json")
    try:
        with open(pairs_path) as fh:
            spec = json.load(fh)
    except OSError as e:
        raise SystemExit(f"cannot read {pairs_path}: {e}")
    import potpourri3d as pp3d
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    sym = any(p.get("eval_reference_mirror_vertices") is not None for p in spec["pairs"])
    methods = ["pyfm", "pyfm+zoomout"]
    pooled = {m: ([], []) for m in methods}
    rows = []
    for p in spec["pairs"]:
        v_ref, f_ref = read_off(p["reference_mesh"])
        v_test, f_test = read_off(p["test_mesh"])
        t0 = time.perf_counter()
        mesh1 = TriMesh(v_ref, f_ref, area_normalize=True)
        mesh2 = TriMesh(v_test, f_test, area_normalize=True)
        model = FunctionalMapping(mesh1, mesh2)
        model.preprocess()  # documented defaults: n_descr=100, WKS, k_process=200
        t_pre = time.perf_counter() - t0
        t0 = time.perf_counter()
        model.fit(K=(35, 35))
        p2p = model.get_p2p()  # test (mesh2) vertex -> reference (mesh1) vertex
        t_fit = time.perf_counter() - t0
        t0 = time.perf_counter()
        fm_zo = model.zoomout_refine(nit=15, step=1)
        p2p_zo = model.get_p2p(FM=fm_zo)
        t_zo = time.perf_counter() - t0
        # Evaluation: heat-method distances on the reference from each ground-truth point.
        t0 = time.perf_counter()
        solver = pp3d.MeshHeatMethodDistanceSolver(v_ref, f_ref)
        norm = 1.0 / np.sqrt(area(v_ref, f_ref))
        ev_t = np.asarray(p["eval_test_vertices"])
        ev_r = np.asarray(p["eval_reference_vertices"])
        ev_m = p.get("eval_reference_mirror_vertices")
        errs = {m: ([], []) for m in methods}
        for j, (mt, gr) in enumerate(zip(ev_t, ev_r)):
            d = solver.compute_distance(int(gr))
            d_mirror = solver.compute_distance(int(ev_m[j])) if sym and ev_m is not None else None
            for m, mp in (("pyfm", p2p), ("pyfm+zoomout", p2p_zo)):
                r = mp[mt]
                e = d[r] * norm
                errs[m][0].append(e)
                if d_mirror is not None:
                    errs[m][1].append(min(e, d_mirror[r] * norm))
        t_eval = time.perf_counter() - t0
        for m in methods:
            s = summary(errs[m][0])
            y = summary(errs[m][1]) if errs[m][1] else None
            pooled[m][0].extend(errs[m][0])
            pooled[m][1].extend(errs[m][1])
            rows.append((p["test"], p["reference"], m, s, y))
        print(
            f"{p['test']} -> {p['reference']}: preprocess {t_pre:.2f} s, fit+p2p {t_fit:.2f} s, "
            f"zoomout+p2p {t_zo:.2f} s, eval {t_eval:.2f} s",
            flush=True,
        )
    print(f"\npyFM {getattr(sys.modules.get('pyFM'), '__version__', '?')} over {len(spec['pairs'])} pair(s)")
    hdr = f"{'method':<14} | {'<=0.05':>7} {'<=0.1':>7} {'mean':>7}"
    if sym:
        hdr += f" | {'sym<=0.05':>9} {'sym<=0.1':>9} {'sym mean':>8}"
    print(hdr)
    for m in methods:
        s = summary(pooled[m][0])
        line = f"{m:<14} | {100*s['within_005']:6.1f}% {100*s['within_010']:6.1f}% {s['mean']:7.4f}"
        if sym and pooled[m][1]:
            y = summary(pooled[m][1])
            line += f" | {100*y['within_005']:8.1f}% {100*y['within_010']:8.1f}% {y['mean']:8.4f}"
        print(line)
    csv = args.csv or os.path.join(args.out, "peer", "pyfm_results.csv")
    with open(csv, "w") as fh:
        fh.write("test,reference,method,within_005,within_010,mean,sym_within_005,sym_within_010,sym_mean\n")
        for t, r, m, s, y in rows:
            ys = f"{y['within_005']:.6f},{y['within_010']:.6f},{y['mean']:.6f}" if y else ",,"
            fh.write(f"{t},{r},{m},{s['within_005']:.6f},{s['within_010']:.6f},{s['mean']:.6f},{ys}\n")
    print(f"wrote {csv}")


if __name__ == "__main__":
    main()
