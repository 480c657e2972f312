#!/usr/bin/env python3
"""Peer timings for `shapeforest bench`: scipy's eigsh and potpourri3d's heat method on the
same meshes, with the same cotangent Laplacian, lumped mass, unit-area scaling and shift.

Usage: peer_bench.py MANIFEST.json OUT.json
MANIFEST lists meshes written by `shapeforest bench` (OFF files) with the parameters used:
{"k": 100, "shift": -0.01, "n_sources": 50, "meshes": [{"name": ..., "path": ..., "sources": [...]}, ...]}
Writes per mesh (best of the manifest's "repeat" runs): eigsh seconds and eigenvalues, heat-method setup and solve seconds.
"""
import json
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import off_io


def read_off(path):
    v, f = off_io.read_off(path)
    return np.array(v, dtype=np.float64).reshape(-1, 3), np.array(off_io.triangles(f), dtype=np.int64)


def cotan_laplacian_and_mass(v, f):
    """Cotangent stiffness L (PSD, rows sum to zero) and lumped barycentric mass, as shapeforest."""
    n = len(v)
    rows, cols, vals = [], [], []
    p = [v[f[:, c]] for c in range(3)]
    for c in range(3):
        a, b = (c + 1) % 3, (c + 2) % 3
        u, w = p[a] - p[c], p[b] - p[c]
        cr = np.linalg.norm(np.cross(u, w), axis=1)
        scale = np.maximum((u * u).sum(1), (w * w).sum(1))
        ok = cr > 1e-14 * scale
        cot = np.zeros(len(f))
        cot[ok] = (u * w).sum(1)[ok] / cr[ok]
        wgt = 0.5 * cot
        i, j = f[:, a], f[:, b]
        rows += [i, j, i, j]
        cols += [j, i, i, j]
        vals += [-wgt, -wgt, wgt, wgt]
    L = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    area = 0.5 * np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]), axis=1)
    mass = np.zeros(n)
    for c in range(3):
        np.add.at(mass, f[:, c], area / 3.0)
    return L, mass


def _version(package):
    try:
        from importlib.metadata import version
        return version(package)
    except Exception:  # noqa: BLE001 - any metadata failure just means "unknown"
        return "installed"


def main():
    manifest = json.load(open(sys.argv[1]))
    out = {"peer": {}, "meshes": []}
    try:
        import potpourri3d as pp3d
        out["peer"]["potpourri3d"] = _version("potpourri3d")
    except ImportError:
        pp3d = None
        print("potpourri3d not installed: heat-method peer timings skipped", file=sys.stderr)
    import scipy
    out["peer"]["scipy"] = scipy.__version__
    out["peer"]["numpy"] = np.__version__
    k, shift = manifest["k"], manifest["shift"]
    repeat = max(1, int(manifest.get("repeat", 1)))  # best of `repeat`, as shapeforest
    for m in manifest["meshes"]:
        v, f = read_off(m["path"])
        L, mass = cotan_laplacian_and_mass(v, f)
        total = mass.sum()
        M = sp.diags(mass / total).tocsc()  # unit-area mass; L is scale invariant
        t_eig = float("inf")
        for _ in range(repeat):
            t0 = time.perf_counter()
            vals, _ = sla.eigsh(L, k=k, M=M, sigma=shift, which="LM")
            t_eig = min(t_eig, time.perf_counter() - t0)
        rec = {"name": m["name"], "vertices": len(v), "eigsh_s": t_eig, "eigenvalues": sorted(vals.tolist())}
        if pp3d is not None:
            t_setup, t_solve = float("inf"), float("inf")
            for _ in range(repeat):
                t0 = time.perf_counter()
                solver = pp3d.MeshHeatMethodDistanceSolver(v, f)
                t_setup = min(t_setup, time.perf_counter() - t0)
                t0 = time.perf_counter()
                for s in m["sources"]:
                    solver.compute_distance(int(s))
                t_solve = min(t_solve, time.perf_counter() - t0)
            rec["heat_setup_s"] = t_setup
            rec["heat_solve_s"] = t_solve
        print(f"peer {m['name']:>14} {len(v):>6} v  eigsh {t_eig:7.3f} s"
              + (f"  heat {rec['heat_setup_s']:.3f} + {rec['heat_solve_s']:.3f} s" if pp3d else ""), flush=True)
        out["meshes"].append(rec)
    json.dump(out, open(sys.argv[2], "w"), indent=1)


if __name__ == "__main__":
    main()
