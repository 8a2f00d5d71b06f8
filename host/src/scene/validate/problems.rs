//! Every problem of a scene file in one go: the validators record each bad key here and go
//! on, so a user fixes a scene in one edit instead of one run per mistake (issue 11).

use crate::error::{Error, Result};
use std::collections::BTreeSet;

/// The problems found so far, in the order the validators met them (the file's sections).
#[derive(Debug, Default)]
pub struct Problems {
    errors: Vec<Error>,
    /// Keys already reported by a per-cell check (one line per key, not per cell).
    keys: BTreeSet<String>,
}

impl Problems {
    /// Records a problem.
    pub fn push(&mut self, e: Error) {
        self.errors.push(e);
    }

    /// The value of `r`, or `None` with its error recorded.
    pub fn ok<T>(&mut self, r: Result<T>) -> Option<T> {
        match r {
            Ok(v) => Some(v),
            Err(e) => {
                self.push(e);
                None
            }
        }
    }

    /// Records `e` for `key` unless a problem was already recorded for that key (per-cell
    /// checks report the first bad cell of each key only).
    pub fn push_once(&mut self, key: &str, e: Error) {
        if self.keys.insert(key.to_string()) {
            self.push(e);
        }
    }

    /// True if a problem was recorded for `key` through [`Problems::push_once`].
    pub fn has_key(&self, key: &str) -> bool {
        self.keys.contains(key)
    }

    /// True if nothing was recorded.
    pub fn is_empty(&self) -> bool {
        self.errors.is_empty()
    }

    /// `Ok` if nothing was recorded, else every problem as one error (one line each).
    pub fn finish(self) -> Result<()> {
        if self.errors.is_empty() {
            Ok(())
        } else {
            Err(Error::many(self.errors))
        }
    }
}
