//! Where a library call's work runs.

/// Runs `work` on a thread of the current rayon pool and returns its result: in place when
/// called from one, otherwise handed to the pool while the calling thread waits.
///
/// A heavy call from outside the pool (the command line's main thread, a pipeline actor,
/// Python) would otherwise run its sequential steps on the calling thread and hand each
/// parallel step to the pool: every step wakes the pool's threads, and then the caller, which
/// sleeps meanwhile; a regularisation takes many such steps. On a pool thread a parallel
/// step starts at once on that thread while the others steal its halves, and the steps in
/// between run there too. What is computed does not change, only which thread computes it.
pub(crate) fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
}

#[cfg(test)]
mod tests {
    use super::on_pool;

    #[test]
    fn work_runs_on_a_pool_thread_and_in_place_when_already_on_one() {
        // A test's own thread is not one of the pool's.
        assert_eq!(rayon::current_thread_index(), None);
        let (outer, inner) =
            on_pool(|| (rayon::current_thread_index(), on_pool(rayon::current_thread_index)));
        assert!(outer.is_some(), "the work was not handed to the pool");
        assert_eq!(inner, outer, "a call from a pool thread moved to another");
        // Results and errors come back to the caller.
        assert_eq!(on_pool(|| Err::<(), _>("failed")), Err("failed"));
    }
}
