//! A bounded number of places: requests waiting for a render slot ([`super::admission`])
//! or for memory ([`super::memory`]), newcomers on probation at the connection cap
//! ([`super::connection`]). A place is taken only while fewer than the limit are taken,
//! and given back when dropped, also when the future holding it is dropped (a client
//! that leaves while it waits).

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Up to `limit` places, counted.
#[derive(Debug)]
pub struct Places {
    taken: AtomicUsize,
    limit: usize,
}

/// A place, given back when dropped.
#[derive(Debug)]
pub struct Place<'a>(&'a Places);

/// A place that can move into a task of its own, given back when dropped.
#[derive(Debug)]
pub struct OwnedPlace(Arc<Places>);

impl Places {
    /// `limit` places, none taken.
    pub fn new(limit: usize) -> Places {
        Places {
            taken: AtomicUsize::new(0),
            limit,
        }
    }

    /// How many there are.
    pub fn limit(&self) -> usize {
        self.limit
    }

    /// How many are taken now.
    pub fn taken(&self) -> usize {
        self.taken.load(Ordering::SeqCst)
    }

    fn take(&self) -> bool {
        self.taken
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| {
                (n < self.limit).then_some(n + 1)
            })
            .is_ok()
    }

    /// A place, if one is free.
    pub fn enter(&self) -> Option<Place<'_>> {
        // Made only once taken (not `then_some`): a place dropped unused would give
        // back one that was never taken.
        self.take().then(|| Place(self))
    }

    /// A place that outlives the borrow, if one is free.
    pub fn enter_owned(self: &Arc<Self>) -> Option<OwnedPlace> {
        self.take().then(|| OwnedPlace(self.clone()))
    }
}

impl Drop for Place<'_> {
    fn drop(&mut self) {
        self.0.taken.fetch_sub(1, Ordering::SeqCst);
    }
}

impl Drop for OwnedPlace {
    fn drop(&mut self) {
        self.0.taken.fetch_sub(1, Ordering::SeqCst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn places_past_the_limit_are_refused_until_one_is_given_back() {
        let p = Arc::new(Places::new(2));
        let a = p.enter().unwrap();
        let b = p.enter_owned().unwrap();
        assert!(p.enter().is_none() && p.enter_owned().is_none());
        assert_eq!(p.taken(), 2);
        drop(a);
        let c = p.enter_owned().unwrap();
        drop((b, c));
        assert_eq!(p.taken(), 0);
        assert!(Places::new(0).enter().is_none());
    }
}
