//! `[output]`: which arrays the VTK snapshots hold, at which output times, compressed or not
//! (issue 10: a 512 x 512 run with `output_interval = 3e-5` wrote 8 GB in 30 s).
//!
//! phihat and c are always written: the pictures (`plots/`, `sieve plot DIR`) are drawn from
//! the snapshots. The first and the last output time always get a snapshot, so a thinned run
//! still shows where it started and ended; series.csv keeps every output time.

use super::Problems;
use crate::error::Error;
use crate::scene::OutputSpec;

/// The arrays a snapshot may hold, in file order.
pub const ARRAYS: [&str; 7] = ["phihat", "phi", "c", "T", "u", "p", "volume"];

/// Validated `[output]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputModel {
    /// Arrays written (a subset of [`ARRAYS`], in its order; phihat and c always).
    pub fields: Vec<&'static str>,
    /// A snapshot at every `vtk_every`-th output time (1: every one).
    pub vtk_every: usize,
    /// zlib-compressed arrays.
    pub compress: bool,
}

impl Default for OutputModel {
    fn default() -> Self {
        Self {
            fields: ARRAYS.to_vec(),
            vtk_every: 1,
            compress: false,
        }
    }
}

impl OutputModel {
    /// Whether array `name` is written (if the scene has it).
    pub fn has(&self, name: &str) -> bool {
        self.fields.contains(&name)
    }

    /// Whether output `k` of `count` (0-based) gets a snapshot.
    pub fn writes(&self, k: usize, count: usize) -> bool {
        k.is_multiple_of(self.vtk_every) || k + 1 >= count
    }
}

/// Checks `[output]`; every problem is recorded in `p`.
pub(super) fn check(p: &mut Problems, l: &str, spec: Option<&OutputSpec>) -> Option<OutputModel> {
    let Some(spec) = spec else {
        return Some(OutputModel::default());
    };
    let mut ok = true;
    let mut model = OutputModel::default();
    if let Some(list) = &spec.fields {
        let mut fields = vec!["phihat", "c"];
        for (i, name) in list.iter().enumerate() {
            match ARRAYS.iter().find(|a| **a == name.as_str()) {
                Some(a) => fields.push(a),
                // one line per wrong name, however often it is listed
                None if list[..i].contains(name) => {}
                None => {
                    ok = false;
                    p.push(Error::range(
                        l,
                        "output.fields",
                        format!("{name:?}"),
                        "names among \"phihat\", \"phi\", \"c\", \"T\", \"u\", \"p\", \"volume\"",
                    ));
                }
            }
        }
        model.fields = ARRAYS
            .iter()
            .copied()
            .filter(|a| fields.contains(a))
            .collect();
    }
    if let Some(n) = spec.vtk_every {
        if (1..=1_000_000).contains(&n) {
            model.vtk_every = n as usize;
        } else {
            ok = false;
            p.push(Error::range(
                l,
                "output.vtk_every",
                n,
                "integer 1..=1000000 (a snapshot at every N-th output time)",
            ));
        }
    }
    model.compress = spec.compress;
    ok.then_some(model)
}
