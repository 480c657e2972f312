"""The OFF reader of the Python scripts (standard library only, so that the scripts run with or
without numpy): `read_off(path)` gives the vertices as `[x, y, z]` lists and the faces as
vertex-index lists, as written (polygons stay polygons); `triangles(faces)` fans polygons into
triangles. Gzipped files (`.gz`) are read too; `#` starts a comment."""
import gzip
import sys


def read_off(path):
    opener = gzip.open if str(path).endswith(".gz") else open
    with opener(path, "rt") as f:
        tokens = [t for line in f for t in line.split("#", 1)[0].split()]
    if not tokens or not tokens[0].upper().endswith("OFF"):
        sys.exit(f"{path}: not an OFF file")
    nv, nf = int(tokens[1]), int(tokens[2])
    pos = 4
    verts = [[float(t) for t in tokens[pos + 3 * i:pos + 3 * i + 3]] for i in range(nv)]
    pos += 3 * nv
    faces = []
    for _ in range(nf):
        n = int(tokens[pos])
        faces.append([int(t) for t in tokens[pos + 1:pos + 1 + n]])
        pos += 1 + n
    return verts, faces


def triangles(faces):
    """Each polygon as the fan of triangles from its first vertex."""
    return [[f[0], f[j], f[j + 1]] for f in faces for j in range(1, len(f) - 1)]
