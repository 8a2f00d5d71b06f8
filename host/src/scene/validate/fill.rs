//! `initial.fill`: a bed as `initial.c` gives it, or settled at rest under its own weight
//! (model.md 5.8). The settled fill keeps each cell's mixture (`phihat = phi / c` as the
//! initial expressions give it) and replaces the packing of each run of bed cells along
//! gravity by the flow step's discrete rest state ([`sieve_core::flow::rest::settle_run`]).
//! A uniform fill at `c = 0.6` holds `p_y(0.6)` at every depth, more than the weight above
//! anywhere in a 0.4 m silo, so it expands upwards when released; the settled bed does not.

use super::{Fields, Problems, Scene, FLOW_MARGIN};
use crate::error::Error;
use crate::scene::{Fill, FrameKind, SceneFile};
use sieve_core::flow::rest::settle_run;
use sieve_core::flow::FlowConfig;
use sieve_core::Boundary;

/// Checks what `initial.fill = "settled"` needs: a solved flow, no rotating frame, gravity along
/// exactly one axis, and that axis not periodic (a periodic column has no top). `gravity`
/// and `bounds` are the validated ones (solver axis order), None if invalid (then nothing is
/// reported twice).
pub(super) fn check(
    p: &mut Problems,
    l: &str,
    f: &SceneFile,
    has_flow: bool,
    gravity: Option<&[f64]>,
    bounds: Option<&[[Boundary; 2]]>,
) -> Fill {
    let fill = f.initial.fill.unwrap_or_default();
    if fill == Fill::Given {
        return fill;
    }
    let bad = |why: &str| Error::range(l, "initial.fill", "\"settled\"", why);
    if !has_flow {
        p.push(bad(
            "\"given\" unless the flow is solved (model.equations = \"frozen\" or \"coupled\")",
        ));
    } else if f
        .frame
        .as_ref()
        .is_some_and(|fs| fs.kind.unwrap_or_default() == FrameKind::Rotating)
    {
        p.push(bad(
            "\"given\" in a rotating frame (its gravity turns: no bed is at rest in it)",
        ));
    } else if let (Some(g), Some(b)) = (gravity, bounds) {
        let along: Vec<usize> = (0..g.len()).filter(|&a| g[a] != 0.0).collect();
        if along.len() != 1 {
            p.push(bad(
                "\"given\" unless physics.gravity points along one axis (one non-zero component)",
            ));
        } else if b[along[0]].contains(&Boundary::Periodic) {
            p.push(bad(
                "\"given\" when the boundaries along gravity are periodic (a column without a top)",
            ));
        }
    }
    fill
}

impl Scene {
    /// Settles the bed of `f` in place (`initial.fill = "settled"`, checked by [`check`]):
    /// along gravity's axis, every run of cells with `c >= surface` (the flow's free-surface
    /// threshold) from its top down gets the cold rest packing of its cells' limits, and phi
    /// keeps its phihat. The bed must be cold (`T = 0`); a run so deep that it would pack
    /// past the flow's `c_max` is reported (exit 2) rather than run.
    pub(super) fn settle(&self, f: &mut Fields, p: &mut Problems) {
        let Some(fm) = self.flow.as_ref() else {
            return;
        };
        let Some(a) = (0..self.dim).find(|&a| self.gravity[a] != 0.0) else {
            return;
        };
        let l = &self.label;
        let mat = self.flow_material::<f64>(fm);
        let surface = FlowConfig::<f64, 1>::new(mat).surface;
        let pk = fm.back_coupling.packing();
        let h = self.spacing()[a];
        let b_h = self.gravity[a].abs() * h;
        let stride: usize = self.cells[..a].iter().product();
        let n = self.cells[a];
        // Cell `k` from the top of the line through `base`.
        let cell = |base: usize, k: usize| {
            let j = if self.gravity[a] < 0.0 { n - 1 - k } else { k };
            base + j * stride
        };
        let (mut rcp, mut rlp, mut c, mut hat) = (vec![], vec![], vec![], vec![]);
        for base in (0..self.len()).filter(|i| (i / stride).is_multiple_of(n)) {
            let mut k = 0;
            while k < n {
                if f.c[cell(base, k)] < surface {
                    k += 1;
                    continue;
                }
                let top = k;
                while k < n && f.c[cell(base, k)] >= surface {
                    k += 1;
                }
                let run: Vec<usize> = (top..k).map(|k| cell(base, k)).collect();
                rcp.clear();
                rlp.clear();
                c.clear();
                hat.clear();
                for &i in &run {
                    if f.t[i] != 0.0 {
                        p.push_once(
                            "initial.T",
                            Error::range(
                                l,
                                "initial.T",
                                format!("{} {}", f.t[i], self.at(i)),
                                "0 in the bed with initial.fill = \"settled\" (a cold bed at rest)",
                            ),
                        );
                    }
                    let phihat = f.phi[i] / f.c[i];
                    let (r, s) = pk.limits(&mat, phihat);
                    rcp.push(r);
                    rlp.push(s);
                    c.push(f.c[i]);
                    hat.push(phihat);
                }
                settle_run(b_h, mat.t0, &rcp, &rlp, &mut c);
                for (j, &i) in run.iter().enumerate() {
                    let c_max = (1.0 - FLOW_MARGIN) * rcp[j];
                    if !(c[j] < c_max) {
                        p.push_once(
                            "initial.fill",
                            Error::range(
                                l,
                                "initial.fill",
                                format!("\"settled\" (the bed packs to c = {} {})", c[j], self.at(i)),
                                &format!("a bed shallow enough to stay below the flow's c_max = (1 - {FLOW_MARGIN}) c_rcp = {c_max}"),
                            ),
                        );
                    }
                    f.c[i] = c[j];
                    f.phi[i] = hat[j] * c[j];
                }
            }
        }
    }
}
