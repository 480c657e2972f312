//! Heat-method distance columns of a prepared shape, kept for reuse.
//!
//! The regulariser solves a few hundred heat-method sources per scan on each shape: the sparse
//! step's samples and candidates, then anchor growth's samples (the sparse step's 50 samples are
//! the first 50 of growth's 200: the same farthest-point sequence) and the targets of every
//! round (many of them candidates of the sparse step). A [`PreparedShape`](super::PreparedShape)
//! keeps the columns it solved, least recently used dropped first beyond a capacity, so a column
//! is solved once per shape: within a scan, and across scans for a reference that serves many
//! (the daemon's model reference, an evaluation's). A column depends only on the shape and the
//! source, up to round-off: solved in another block of sources it can differ in the last bits
//! (faer's block solves), never more.
//!
//! Kept columns are packed to 16 bits a value ([`Packed`]: each column's distances as multiples
//! of its own step, its largest distance over 65,534): half the memory of `f32`, so a store of
//! the same bytes keeps twice the columns. Every column handed out, solved now or kept, is
//! the unpacked one, so a result does not depend on what the store held.
//!
//! Hand-written rather than a cache crate: a map, a use counter and a byte bound are all it
//! needs.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

/// One column: distances (mesh units) from a source to every vertex, `f32::INFINITY` in another
/// connected component.
pub(crate) type Column = Arc<[f32]>;

/// A column at 16 bits a value: distance `d` as the multiple of `step` nearest to it,
/// `step = max / 65,534` for the column's largest finite distance `max` (so each value is off by
/// at most `max / 131,068`: 1.5·10⁻⁵ of the largest distance, a few thousandths of an edge on a
/// 12.5K-vertex body, where the heat method's own error is a percent or more); [`INFINITE`]
/// for a vertex at no finite distance (in another component), unpacked as `f32::INFINITY`.
pub(crate) struct Packed {
    codes: Box<[u16]>,
    step: f32,
}

/// The code of an unreachable vertex.
const INFINITE: u16 = u16::MAX;

impl Packed {
    pub(crate) fn new(column: &[f32]) -> Self {
        let max = column.iter().copied().filter(|d| d.is_finite()).fold(0.0f32, f32::max);
        let step = max / f32::from(INFINITE - 1);
        let inv = if step > 0.0 { 1.0 / step } else { 0.0 };
        let codes = column
            .iter()
            .map(|&d| {
                if d.is_finite() {
                    (d.max(0.0) * inv).round().min(f32::from(INFINITE - 1)) as u16
                } else {
                    INFINITE
                }
            })
            .collect();
        Self { codes, step }
    }

    pub(crate) fn unpacked(&self) -> Column {
        let step = self.step;
        self.codes.iter().map(|&c| if c == INFINITE { f32::INFINITY } else { f32::from(c) * step }).collect()
    }
}

/// A bounded, least-recently-used store of distance columns by source vertex.
pub(crate) struct ColumnCache {
    capacity_columns: usize,
    inner: Mutex<Inner>,
}

#[derive(Default)]
struct Inner {
    columns: HashMap<usize, (Arc<Packed>, u64)>,
    clock: u64,
    solved: u64,
    reused: u64,
}

impl ColumnCache {
    /// A store of at most `capacity_columns` columns (0: keeps nothing).
    pub(crate) fn new(capacity_columns: usize) -> Self {
        Self { capacity_columns, inner: Mutex::new(Inner::default()) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding the lock leaves the map consistent (every update is one insert
        // or remove), so a poisoned lock is still usable.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The columns of `sources` (in order, each as [`Packed`] keeps it), solving the missing ones
    /// with `solve` (called once, with each missing source once, in first-seen order; it returns
    /// their columns in order).
    pub(crate) fn get_or_solve<E>(
        &self,
        sources: &[usize],
        solve: impl FnOnce(&[usize]) -> Result<Vec<Column>, E>,
    ) -> Result<Vec<Column>, E> {
        let mut out: Vec<Option<Arc<Packed>>> = Vec::with_capacity(sources.len());
        let mut missing = Vec::new();
        {
            let mut g = self.lock();
            g.clock += 1;
            let now = g.clock;
            for &s in sources {
                match g.columns.get_mut(&s) {
                    Some((c, used)) => {
                        *used = now;
                        out.push(Some(c.clone()));
                    }
                    None => {
                        out.push(None);
                        missing.push(s);
                    }
                }
            }
        }
        missing.sort_unstable();
        missing.dedup();
        // keep the first-seen order of the sources for the solve
        let mut order: Vec<usize> = Vec::with_capacity(missing.len());
        let mut placed = vec![false; missing.len()];
        for &s in sources {
            if let Ok(i) = missing.binary_search(&s) {
                if !std::mem::replace(&mut placed[i], true) {
                    order.push(s);
                }
            }
        }
        let mut solved: HashMap<usize, Arc<Packed>> = HashMap::new();
        if !order.is_empty() {
            let cols = solve(&order)?;
            debug_assert_eq!(cols.len(), order.len());
            let packed: Vec<Arc<Packed>> = cols.par_iter().map(|c| Arc::new(Packed::new(c))).collect();
            solved = order.iter().copied().zip(packed).collect();
            let mut g = self.lock();
            g.solved += solved.len() as u64;
            if self.capacity_columns > 0 {
                g.clock += 1;
                let now = g.clock;
                for (&s, c) in &solved {
                    g.columns.insert(s, (c.clone(), now));
                }
                if g.columns.len() > self.capacity_columns {
                    let mut by_use: Vec<(u64, usize)> =
                        g.columns.iter().map(|(&s, (_, u))| (*u, s)).collect();
                    by_use.sort_unstable();
                    let excess = g.columns.len() - self.capacity_columns;
                    for &(_, s) in &by_use[..excess] {
                        g.columns.remove(&s);
                    }
                }
            }
        }
        let mut g = self.lock();
        g.reused += out.iter().filter(|c| c.is_some()).count() as u64;
        drop(g);
        Ok(out
            .into_par_iter()
            .zip(sources)
            .map(|(c, s)| c.as_ref().unwrap_or_else(|| &solved[s]).unpacked())
            .collect())
    }

    /// Columns solved and columns served from the store so far.
    pub(crate) fn counts(&self) -> (u64, u64) {
        let g = self.lock();
        (g.solved, g.reused)
    }

    /// Columns held.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.lock().columns.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn col(s: usize) -> Column {
        vec![s as f32; 3].into()
    }

    #[test]
    fn packed_columns_keep_distances_to_a_step_and_unreachable_vertices_unreachable() {
        let column: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.0137).sin().abs() * 3.0).collect();
        let mut with_gap = column.clone();
        with_gap[7] = f32::INFINITY;
        for c in [&column, &with_gap] {
            let max = c.iter().copied().filter(|d| d.is_finite()).fold(0.0f32, f32::max);
            let back = Packed::new(c).unpacked();
            assert_eq!(back.len(), c.len());
            for (a, b) in c.iter().zip(back.iter()) {
                if a.is_finite() {
                    // Half a step (max / 131,068), and f32's own rounding.
                    assert!((a - b).abs() <= max / 131_068.0 * 1.001, "{a} → {b}");
                } else {
                    assert_eq!(*b, f32::INFINITY);
                }
            }
        }
        // A column of zeros (a one-vertex component) stays zeros.
        assert_eq!(&*Packed::new(&[0.0, 0.0]).unpacked(), &[0.0, 0.0]);
    }

    #[test]
    fn solves_each_missing_source_once_and_evicts_the_least_recently_used() {
        let cache = ColumnCache::new(3);
        let calls = std::cell::RefCell::new(Vec::new());
        let solve = |s: &[usize]| -> Result<Vec<Column>, ()> {
            calls.borrow_mut().push(s.to_vec());
            Ok(s.iter().map(|&v| col(v)).collect())
        };
        let got = cache.get_or_solve(&[5, 2, 5], solve).unwrap();
        assert_eq!(got.iter().map(|c| c[0].round() as usize).collect::<Vec<_>>(), [5, 2, 5]);
        assert_eq!(calls.borrow().as_slice(), [vec![5, 2]]);
        cache.get_or_solve(&[7, 2], solve).unwrap(); // 2 reused, 7 solved; 5 is now the oldest
        cache.get_or_solve(&[9], solve).unwrap(); // over capacity: 5 goes
        assert_eq!(cache.len(), 3);
        cache.get_or_solve(&[2, 5], solve).unwrap();
        assert_eq!(calls.borrow().last().unwrap(), &vec![5]);
        assert_eq!(cache.counts(), (5, 2));
        let off = ColumnCache::new(0);
        off.get_or_solve(&[1, 1], solve).unwrap();
        assert_eq!(off.len(), 0);
        // A failed solve stores nothing and reports the error.
        let e = cache.get_or_solve(&[11], |_| Err::<Vec<Column>, _>("no")).unwrap_err();
        assert_eq!(e, "no");
        assert!(cache.get_or_solve(&[11], solve).is_ok());
    }
}
