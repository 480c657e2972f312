//! Connectivity: a union–find over element indices and a mesh's vertices joined through its
//! faces (behind the mesh summary, [`super::vertex_components`], the geodesic solvers and the
//! spectral solver).

use super::Mesh;

/// Disjoint sets over `0..n` with path halving; the smaller index becomes the root, so roots
/// are the smallest members and [`UnionFind::labels`] numbers components by smallest member.
///
/// ```
/// use shapeforest::mesh::UnionFind;
/// let mut uf = UnionFind::new(5);
/// uf.union(4, 1);
/// uf.union(3, 2);
/// assert_eq!(uf.labels(), (vec![0, 1, 2, 2, 1], 3));
/// ```
#[derive(Clone, Debug)]
pub struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    /// `n` singletons.
    pub fn new(n: usize) -> Self {
        Self { parent: (0..n).collect() }
    }

    /// The root (smallest member) of `x`'s set.
    pub fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    /// Merges the sets of `a` and `b`; whether they were apart.
    pub fn union(&mut self, a: usize, b: usize) -> bool {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        self.parent[hi] = lo;
        true
    }

    /// Component label per element, labels `0..count` in order of smallest member, and `count`.
    pub fn labels(&mut self) -> (Vec<usize>, usize) {
        let n = self.parent.len();
        let mut label = vec![usize::MAX; n];
        let mut out = Vec::with_capacity(n);
        let mut count = 0;
        for i in 0..n {
            let r = self.find(i);
            if label[r] == usize::MAX {
                label[r] = count;
                count += 1;
            }
            out.push(label[r]);
        }
        (out, count)
    }
}

/// The union–find of a mesh's vertices joined through its faces.
pub fn face_connectivity(mesh: &Mesh) -> UnionFind {
    let mut uf = UnionFind::new(mesh.n_vertices());
    for f in &mesh.faces {
        uf.union(f[0], f[1]);
        uf.union(f[0], f[2]);
    }
    uf
}
