//! The compact tree code of model format version 3.
//!
//! A grown tree's layout is canonical: nodes are numbered as [`super::tree::grow_tree`] creates
//! them (the root 0; a split node's children get the next two numbers, left then right) and
//! visited depth first, left before right; leaves are numbered in that visiting order. So the
//! pre-order sequence of nodes alone determines every child and leaf index, and a tree is
//! written as that sequence of variable-length records, nothing else:
//!
//! | record | bytes |
//! |---|---|
//! | internal node (`k̄ ≥ 1`) | LEB128 `k̄ + 1`, LEB128 energy index, `f32` threshold (little-endian) |
//! | leaf with one label of probability 1 | LEB128 `1`, LEB128 label |
//! | any other leaf | LEB128 `0`, LEB128 count `c`, `c` × LEB128 label, `c` × `f32` probability |
//!
//! Versions 1–2 stored every node as a full record (energy, `k̄`, threshold, both child indices)
//! and every leaf as an offset, a label and a probability, although leaves are half the nodes
//! and nearly all hold one label of probability 1 (mean leaf support 1.00 on TOSCA). Decoding
//! rebuilds the in-memory [`Tree`] exactly (same node and leaf numbers, so `==` and prediction
//! bit for bit); a tree whose layout is not canonical (not from `grow_tree`) is renumbered
//! canonically, with the same routing and leaves. Every malformed code is an error naming the
//! tree and the problem, with allocation bounded by the code's length.

use serde::{Deserialize, Serialize};

use super::tree::{Node, Tree};

/// One tree in format version 3.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct CompactTree {
    /// Position of the tree in the growth history ([`Tree::index`]).
    pub(crate) index: u64,
    /// Nodes and leaves, to check the code against.
    pub(crate) n_nodes: u32,
    pub(crate) n_leaves: u32,
    /// The pre-order records (see the module docs).
    #[serde(with = "serde_bytes")]
    pub(crate) code: Vec<u8>,
}

fn put_varint(out: &mut Vec<u8>, mut x: u64) {
    while x >= 0x80 {
        out.push((x as u8 & 0x7f) | 0x80);
        x >>= 7;
    }
    out.push(x as u8);
}

/// A reader over a tree's code.
struct Reader<'a> {
    code: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn varint(&mut self) -> Result<u64, String> {
        let mut x = 0u64;
        for shift in (0..64).step_by(7) {
            let b = *self.code.get(self.at).ok_or("the code ends inside a number")?;
            self.at += 1;
            x |= ((b & 0x7f) as u64) << shift;
            if b & 0x80 == 0 {
                return Ok(x);
            }
        }
        Err("a number longer than 64 bits".into())
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        let x = self.varint()?;
        u32::try_from(x).map_err(|_| format!("{what} {x} does not fit in 32 bits"))
    }

    fn f32(&mut self) -> Result<f32, String> {
        let b = self.code.get(self.at..self.at + 4).ok_or("the code ends inside a number")?;
        self.at += 4;
        Ok(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
}

impl CompactTree {
    /// Encodes `tree` (pre-order from the root; unreachable nodes are dropped).
    pub(crate) fn encode(tree: &Tree) -> Result<Self, String> {
        let mut code = Vec::with_capacity(tree.nodes.len() * 5);
        let (mut n_nodes, mut n_leaves) = (0u32, 0u32);
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let node = tree.nodes.get(i).ok_or_else(|| format!("node {i} is missing"))?;
            n_nodes += 1;
            if node.k_bar == 0 {
                n_leaves += 1;
                if node.left as usize >= tree.n_leaves() {
                    return Err(format!("node {i} points to a missing leaf"));
                }
                let (labels, probs) = tree.leaf_distribution(node.left as usize);
                if labels.len() == 1 && probs[0].to_bits() == 1f32.to_bits() {
                    put_varint(&mut code, 1);
                    put_varint(&mut code, labels[0] as u64);
                } else {
                    put_varint(&mut code, 0);
                    put_varint(&mut code, labels.len() as u64);
                    for &l in labels {
                        put_varint(&mut code, l as u64);
                    }
                    for &p in probs {
                        code.extend_from_slice(&p.to_le_bytes());
                    }
                }
            } else {
                put_varint(&mut code, node.k_bar as u64 + 1);
                put_varint(&mut code, node.energy as u64);
                code.extend_from_slice(&node.threshold.to_le_bytes());
                stack.push(node.right as usize);
                stack.push(node.left as usize);
            }
            if n_nodes as usize > tree.nodes.len() {
                return Err("the node graph has a cycle".into());
            }
        }
        Ok(CompactTree { index: tree.index, n_nodes, n_leaves, code })
    }

    /// Rebuilds the tree (see the module docs); the forest's [`validate`] checks the ranges
    /// of labels, energies and `k̄` afterwards.
    ///
    /// [`validate`]: super::RandomForest
    pub(crate) fn decode(&self) -> Result<Tree, String> {
        // Every record takes at least two bytes: the declared counts cannot exceed that.
        let max_records = self.code.len() / 2;
        if self.n_nodes as usize > max_records || self.n_leaves > self.n_nodes || self.n_nodes == 0 {
            return Err(format!(
                "{} nodes and {} leaves declared for {} bytes of code",
                self.n_nodes,
                self.n_leaves,
                self.code.len()
            ));
        }
        let blank = Node { energy: 0, k_bar: 0, threshold: 0.0, left: 0, right: 0 };
        let mut tree = Tree {
            nodes: Vec::with_capacity(self.n_nodes as usize),
            leaf_offsets: Vec::with_capacity(self.n_leaves as usize + 1),
            leaf_labels: Vec::with_capacity(self.n_leaves as usize),
            leaf_probs: Vec::with_capacity(self.n_leaves as usize),
            index: self.index,
        };
        tree.nodes.push(blank);
        tree.leaf_offsets.push(0);
        let mut r = Reader { code: &self.code, at: 0 };
        let mut stack = vec![0usize];
        while let Some(id) = stack.pop() {
            match r.varint()? {
                tag @ (0 | 1) => {
                    let leaf = tree.leaf_offsets.len() - 1;
                    if tag == 1 {
                        tree.leaf_labels.push(r.u32("a label")?);
                        tree.leaf_probs.push(1.0);
                    } else {
                        let c = r.varint()?;
                        // each label takes at least one byte and each probability four
                        if c > (self.code.len() - r.at) as u64 / 5 {
                            return Err(format!(
                                "a leaf of {c} labels in a code of {} bytes",
                                self.code.len()
                            ));
                        }
                        for _ in 0..c {
                            tree.leaf_labels.push(r.u32("a label")?);
                        }
                        for _ in 0..c {
                            tree.leaf_probs.push(r.f32()?);
                        }
                    }
                    tree.leaf_offsets.push(tree.leaf_labels.len() as u32);
                    tree.nodes[id] = Node { left: leaf as u32, ..blank };
                }
                tag => {
                    let k_bar =
                        u16::try_from(tag - 1).map_err(|_| format!("k̄ = {} is out of range", tag - 1))?;
                    let energy = r.u32("an energy index")?;
                    let threshold = r.f32()?;
                    let left = tree.nodes.len();
                    if left + 2 > self.n_nodes as usize {
                        return Err(format!("more nodes than the {} declared", self.n_nodes));
                    }
                    tree.nodes.push(blank);
                    tree.nodes.push(blank);
                    tree.nodes[id] =
                        Node { energy, k_bar, threshold, left: left as u32, right: left as u32 + 1 };
                    stack.push(left + 1);
                    stack.push(left);
                }
            }
        }
        if r.at != self.code.len() {
            return Err(format!("{} bytes of code after the last node", self.code.len() - r.at));
        }
        if tree.nodes.len() != self.n_nodes as usize || tree.n_leaves() != self.n_leaves as usize {
            return Err(format!(
                "{} nodes and {} leaves decoded, {} and {} declared",
                tree.nodes.len(),
                tree.n_leaves(),
                self.n_nodes,
                self.n_leaves
            ));
        }
        Ok(tree)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leaf(i: u32) -> Node {
        Node { energy: 0, k_bar: 0, threshold: 0.0, left: i, right: 0 }
    }

    /// Root split, left leaf (label 7, p = 1), right split into a two-label leaf and a
    /// one-label leaf: every record kind, numbered as `grow_tree` numbers them.
    fn sample() -> Tree {
        Tree {
            nodes: vec![
                Node { energy: 3, k_bar: 12, threshold: 0.25, left: 1, right: 2 },
                leaf(0),
                Node { energy: 255, k_bar: 300, threshold: -1.5e-7, left: 3, right: 4 },
                leaf(1),
                leaf(2),
            ],
            leaf_offsets: vec![0, 1, 3, 4],
            leaf_labels: vec![7, 2, 70_000, 9],
            leaf_probs: vec![1.0, 0.25, 0.75, 1.0],
            index: 42,
        }
    }

    #[test]
    fn a_canonical_tree_round_trips_exactly() {
        let t = sample();
        let c = CompactTree::encode(&t).unwrap();
        assert_eq!((c.n_nodes, c.n_leaves), (5, 3));
        // 2 internal × 6..7 bytes, leaves 2 + (1+1+1+3+8) + 2 bytes
        assert!(c.code.len() <= 32, "{} bytes", c.code.len());
        assert_eq!(c.decode().unwrap(), t);
    }

    #[test]
    fn a_renumbered_tree_decodes_to_the_same_routing() {
        // The same tree with the root's children swapped in storage order.
        let mut t = sample();
        t.nodes.swap(1, 2);
        t.nodes[0].left = 2;
        t.nodes[0].right = 1;
        let d = CompactTree::encode(&t).unwrap().decode().unwrap();
        assert_eq!(d, sample());
    }

    #[test]
    fn malformed_codes_are_errors() {
        let c = CompactTree::encode(&sample()).unwrap();
        for cut in 0..c.code.len() {
            let short = CompactTree { code: c.code[..cut].to_vec(), ..c.clone() };
            assert!(short.decode().is_err(), "cut at {cut}");
        }
        let mut long = c.clone();
        long.code.push(1);
        long.code.push(1);
        assert!(long.decode().is_err());
        let huge = CompactTree { n_nodes: u32::MAX, ..c.clone() };
        assert!(huge.decode().unwrap_err().contains("declared"));
        // A leaf claiming 2^40 labels.
        let mut code = vec![0u8];
        put_varint(&mut code, 1 << 40);
        let e = CompactTree { index: 0, n_nodes: 1, n_leaves: 1, code }.decode().unwrap_err();
        assert!(e.contains("labels"), "{e}");
    }
}
