//! 0 <= phi <= c exactly (no round-off allowance) under the limited carried transport
//! (`Transport::Limited`, docs/model.md 5.7), on hostile data: random face mass fluxes cut by
//! a donor limiter (some cells emptied to the last bit), c with empty cells, cells just below
//! and above the vacuum threshold, near-packing c and jumps between them, phihat 0 and 1,
//! walls, periodic, inflow and outflow sides, both phases, in 1D and 2D; and on cut cells, in
//! the coupled half drum of `flow_drum_coupled.rs`. Also: each phase's mass (with what left
//! and came in through the sides) to round-off, the carried c equal to `c - out + in`, and
//! bit-identical reruns.

use crate::drum_common;

use crate::common::boxed;
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;
use sieve_core::segregation::MassFluxes;
use sieve_core::{Boundary, Grid, Phase, Segregation, SegregationConfig, Transport};

const N: usize = 256;

/// Face amounts per axis and cell (the layout of `MassFluxes`).
type Amounts<const D: usize> = Box<[[f64; N]; D]>;

fn c_value() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => Just(0.0),
        1 => Just(5e-7),
        1 => Just(2e-6),
        2 => Just(0.64),
        1 => Just(0.639_999_999_999),
        1 => 1e-12..1e-3f64,
        4 => 0.0..0.64f64,
    ]
}

fn phihat() -> impl Strategy<Value = f64> {
    prop_oneof![2 => Just(0.0), 2 => Just(1.0), 1 => Just(0.5), 5 => 0.0..1.0f64]
}

fn flux_value() -> impl Strategy<Value = f64> {
    prop_oneof![3 => Just(0.0), 6 => -0.8..0.8f64, 1 => -1e-9..1e-9f64, 1 => -5.0..5.0f64]
}

fn sides() -> impl Strategy<Value = [Boundary; 2]> {
    use Boundary::*;
    prop_oneof![
        2 => Just([Wall, Wall]),
        2 => Just([Periodic, Periodic]),
        1 => Just([Inflow, Outflow]),
        1 => Just([Outflow, Inflow]),
        1 => Just([Wall, Outflow]),
    ]
}

/// Random raw face amounts, limited like the flow's donor limiter: every face has one donor
/// (the side the amount leaves), and a donor whose faces would take more than its `c` has all
/// of them scaled by `c / out`. Walls carry nothing; closed (non-periodic) sides carry only
/// what `raw` gives them.
fn limited_fluxes<const D: usize>(
    s: &Segregation<f64, D, N>,
    bc: &[[Boundary; 2]; D],
    raw_faces: &[Vec<f64>; D],
    raw_low: &[Vec<f64>; D],
) -> (Amounts<D>, Amounts<D>) {
    let grid = *s.grid();
    let n = grid.len();
    let cells = grid.cells();
    let mut faces = Box::new([[0.0; N]; D]);
    let mut low = Box::new([[0.0; N]; D]);
    for a in 0..D {
        let st = grid.stride(a);
        for i in 0..n {
            let last = (i / st) % cells[a] == cells[a] - 1;
            let first = (i / st) % cells[a] == 0;
            faces[a][i] = if last && bc[a][1] == Boundary::Wall {
                0.0
            } else {
                raw_faces[a][i]
            };
            low[a][i] = if first && bc[a][0] != Boundary::Wall && bc[a][0] != Boundary::Periodic {
                raw_low[a][i]
            } else {
                0.0
            };
        }
    }
    // outflow of each cell, then the donor limiter
    let mut out = vec![0.0; n];
    for a in 0..D {
        let st = grid.stride(a);
        for i in 0..n {
            let ca = (i / st) % cells[a];
            let f = faces[a][i];
            if f > 0.0 {
                out[i] += f;
            } else if f < 0.0 {
                let j = if ca + 1 < cells[a] {
                    i + st
                } else if bc[a][0] == Boundary::Periodic {
                    i - (cells[a] - 1) * st
                } else {
                    continue; // inflow through the high side
                };
                out[j] -= f;
            }
            if ca == 0 && low[a][i] < 0.0 {
                out[i] -= low[a][i];
            }
        }
    }
    let lim: Vec<f64> = (0..n)
        .map(|i| {
            if out[i] > s.c(i) {
                s.c(i) / out[i]
            } else {
                1.0
            }
        })
        .collect();
    for a in 0..D {
        let st = grid.stride(a);
        for i in 0..n {
            let ca = (i / st) % cells[a];
            let f = faces[a][i];
            if f > 0.0 {
                faces[a][i] = f * lim[i];
            } else if f < 0.0 {
                if ca + 1 < cells[a] {
                    faces[a][i] = f * lim[i + st];
                } else if bc[a][0] == Boundary::Periodic {
                    faces[a][i] = f * lim[i - (cells[a] - 1) * st];
                }
            }
            if ca == 0 && low[a][i] < 0.0 {
                low[a][i] *= lim[i];
            }
        }
    }
    (faces, low)
}

/// Sets up, runs `steps` carried transports with fluxes re-limited to the current c every
/// step, checks the bounds exactly and the mass; returns the final tracked fractions' bits.
#[allow(clippy::too_many_arguments)]
fn run<const D: usize>(
    cells: [usize; D],
    bc: [[Boundary; 2]; D],
    phase: Phase,
    c: &[f64],
    ph: &[f64],
    inflow: &[f64],
    raw_faces: &[Vec<f64>; D],
    raw_low: &[Vec<f64>; D],
    steps: usize,
) -> Result<Vec<u64>, TestCaseError> {
    let mut s = boxed::<f64, D, N>();
    let grid = Grid::new(cells, [0.0; D], [1.0; D], N).unwrap();
    let mut cfg = SegregationConfig::new();
    cfg.s0 = 0.0;
    cfg.phase = phase;
    s.setup(grid, bc, cfg).unwrap();
    s.set_transport(Transport::Limited);
    let n = grid.len();
    for i in 0..n {
        s.set_cell(i, c[i], 0.0, [0.0; D], (c[i] * ph[i]).min(c[i]));
        s.set_inflow(i, (c[i] * inflow[i]).min(c[i]));
    }
    s.prepare().unwrap();
    let vol = grid.cell_volume();
    let mass = |s: &Segregation<f64, D, N>| {
        let (mut m, mut t) = (0.0, 0.0);
        for i in 0..n {
            m += s.phi(i) * vol;
            t += s.c(i) * vol;
        }
        (m, t)
    };
    let (m0, t0) = mass(&s);
    let (mut out_small, mut out_total, mut moved) = (0.0, 0.0, 0.0);
    for k in 0..steps {
        let (faces, low) = limited_fluxes(&s, &bc, raw_faces, raw_low);
        // c - out + in, face by face (the flow's own c)
        let c_before: Vec<f64> = (0..n).map(|i| s.c(i)).collect();
        let d = s.carry_mass_fluxes(MassFluxes {
            faces: &faces,
            low: &low,
            open: bc.map(|b| b.map(|k| matches!(k, Boundary::Inflow | Boundary::Outflow))),
        });
        prop_assert_eq!(d.guarded, 0.0);
        for a in 0..D {
            for side in 0..2 {
                out_small += d.small[a][side];
                out_total += d.total[a][side];
            }
        }
        for a in 0..D {
            for i in 0..n {
                moved += faces[a][i].abs() * vol + low[a][i].abs() * vol;
            }
        }
        for i in 0..n {
            let (phi, ci) = (s.phi(i), s.c(i));
            prop_assert!(phi.is_finite() && ci.is_finite());
            prop_assert!(
                phi >= 0.0 && phi <= ci,
                "step {k}, cell {i}: phi = {phi:e} outside [0, c = {ci:e}] (c before {:e})",
                c_before[i]
            );
        }
        // the inflow state follows the carried c, as the coupled driver's boundary cells do
        for i in 0..n {
            s.set_inflow(i, (s.c(i) * inflow[i]).min(s.c(i)));
        }
    }
    let (m, t) = mass(&s);
    let scale = m0.max(t0) + moved;
    prop_assert!(
        (m + out_small - m0).abs() <= 1e-13 * scale,
        "small-grain mass {m:e} + out {out_small:e} != {m0:e}"
    );
    prop_assert!(
        (t + out_total - t0).abs() <= 1e-13 * scale,
        "grain mass {t:e} + out {out_total:e} != {t0:e}"
    );
    Ok((0..n).map(|i| s.phi(i).to_bits()).collect())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// 1D: random c, phihat, inflow, fluxes, sides, phase.
    #[test]
    fn limited_keeps_bounds_exactly_1d(
        (c, ph, inflow, f, lo) in (2usize..40).prop_flat_map(|n| (
            prop::collection::vec(c_value(), n),
            prop::collection::vec(phihat(), n),
            prop::collection::vec(phihat(), n),
            prop::collection::vec(flux_value(), n),
            prop::collection::vec(flux_value(), n),
        )),
        bc in sides(),
        large in any::<bool>(),
        steps in 1usize..6,
    ) {
        let phase = if large { Phase::Large } else { Phase::Small };
        let n = c.len();
        let (f, lo) = ([f], [lo]);
        let a = run([n], [bc], phase, &c, &ph, &inflow, &f, &lo, steps)?;
        let b = run([n], [bc], phase, &c, &ph, &inflow, &f, &lo, steps)?;
        prop_assert_eq!(a, b);
    }

    /// 2D: the same on random nx x nz grids with independent sides per axis.
    #[test]
    fn limited_keeps_bounds_exactly_2d(
        (nx, c, ph, inflow, fx, fz, lx, lz) in (2usize..14, 2usize..14).prop_flat_map(|(nx, nz)| (
            Just(nx),
            prop::collection::vec(c_value(), nx * nz),
            prop::collection::vec(phihat(), nx * nz),
            prop::collection::vec(phihat(), nx * nz),
            prop::collection::vec(flux_value(), nx * nz),
            prop::collection::vec(flux_value(), nx * nz),
            prop::collection::vec(flux_value(), nx * nz),
            prop::collection::vec(flux_value(), nx * nz),
        )),
        bx in sides(),
        bz in sides(),
        large in any::<bool>(),
        steps in 1usize..5,
    ) {
        let phase = if large { Phase::Large } else { Phase::Small };
        let nz = c.len() / nx;
        let (f, lo) = ([fx, fz], [lx, lz]);
        let a = run([nx, nz], [bx, bz], phase, &c, &ph, &inflow, &f, &lo, steps)?;
        let b = run([nx, nz], [bx, bz], phase, &c, &ph, &inflow, &f, &lo, steps)?;
        prop_assert_eq!(a, b);
    }
}

/// A smooth layer of fines carried through a half-full periodic channel: bounds exactly,
/// and the limited rule keeps the layer sharper than the donor rule (its variance of phihat
/// about the mean stays larger), a sanity check that it is active.
#[test]
fn limited_transport_is_active_and_less_diffusive() {
    let n = 32;
    let mut var = [0.0; 2];
    for (k, t) in [Transport::Donor, Transport::Limited]
        .into_iter()
        .enumerate()
    {
        let mut s = boxed::<f64, 2, N2>();
        let grid = Grid::new([n, n], [0.0; 2], [1.0; 2], N2).unwrap();
        let mut cfg = SegregationConfig::new();
        cfg.s0 = 0.0;
        s.setup(grid, [[Boundary::Periodic; 2], [Boundary::Wall; 2]], cfg)
            .unwrap();
        s.set_transport(t);
        for i in 0..grid.len() {
            let x = grid.center(i);
            let c = if x[1] < 0.5 { 0.6 } else { 0.0 };
            let ph = if (x[0] - 0.5).abs() < 0.2 { 1.0 } else { 0.0 };
            s.set_cell(i, c, 0.0, [0.0; 2], c * ph);
        }
        s.prepare().unwrap();
        let mut faces = Box::new([[0.0; N2]; 2]);
        for i in 0..grid.len() {
            faces[0][i] = 0.3 * s.c(i);
        }
        let low = Box::new([[0.0; N2]; 2]);
        for _ in 0..2 * n {
            s.carry_mass_fluxes(MassFluxes {
                faces: &faces,
                low: &low,
                open: [[false; 2]; 2],
            });
            for i in 0..grid.len() {
                assert!(s.phi(i) >= 0.0 && s.phi(i) <= s.c(i));
            }
        }
        let cells: Vec<usize> = (0..grid.len()).filter(|&i| s.c(i) > 0.0).collect();
        let mean = cells.iter().map(|&i| s.phi(i) / s.c(i)).sum::<f64>() / cells.len() as f64;
        var[k] = cells
            .iter()
            .map(|&i| (s.phi(i) / s.c(i) - mean).powi(2))
            .sum::<f64>()
            / cells.len() as f64;
    }
    println!(
        "square wave, 32 cells, 2 periods at nu 0.3: variance of phihat donor {:.4}, limited {:.4} (initial 0.24)",
        var[0], var[1]
    );
    assert!(var[1] > 1.5 * var[0], "{var:?}");
}

const N2: usize = 1024;

/// The coupled half drum of `flow_drum_coupled.rs` (24 x 24 cut cells, glass beads, 1 rev/s
/// in its own frame, back-coupling) with the limited transport: bounds exactly in every cell
/// after every step (cut and merged cells included), both phases to round-off, the carried c
/// equal to the flow's, a bit-identical rerun, and a state that differs from the donor
/// rule's (the limited face value is used).
mod drum {
    use super::drum_common::{half_drum, HalfDrum};
    use sieve_core::closure::{Material, Packing};
    use sieve_core::diagnostics::diagnose_embedded;
    use sieve_core::flow::coupled::{Coupled, CouplingConfig, Mode};
    use sieve_core::flow::FlowConfig;

    use sieve_core::Transport;
    use sieve_tests::run_big;

    const N: usize = 1024;

    /// (small drift, grain drift, worst over, worst under, c mismatch, hash)
    fn drum(steps: usize, transport: Transport) -> (f64, f64, f64, f64, f64, u64) {
        let mut cfg = FlowConfig::new(Material::glass_beads());
        cfg.free_surface_push = true;
        let HalfDrum {
            grid,
            mut flow,
            mut seg,
            cut,
        } = half_drum::<N>(cfg);
        seg.set_transport(transport);
        for i in 0..grid.len() {
            let [x, z] = grid.center(i);
            let c = if z < 0.05 && !cut.is_solid(i) {
                0.6
            } else {
                0.0
            };
            // a layered start, so that phihat has gradients to carry from the first step
            let ph = if x < 0.05 { 0.9 } else { 0.1 };
            flow.set_cell(i, c, [0.0; 2], 0.0);
            seg.set_cell(i, c, 0.0, [0.0; 2], ph * c);
        }
        let mut cc = CouplingConfig::new(Mode::Coupled);
        cc.packing = Packing::FitHalf;
        let mut cpl = Coupled::new_embedded(&mut flow, &mut seg, cc, &cut).unwrap();
        let d0 = diagnose_embedded(cpl.seg, &cut);
        let total0: f64 = (0..grid.len()).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
        let (mut over, mut under, mut mismatch) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..steps {
            cpl.step().unwrap();
            for i in 0..grid.len() {
                let (phi, c) = (cpl.seg.phi(i), cpl.seg.c(i));
                assert!(phi.is_finite() && c.is_finite());
                over = over.max(phi - c);
                under = under.max(-phi);
                mismatch = mismatch.max((c - cpl.flow.c(i)).abs());
            }
        }
        let d = diagnose_embedded(cpl.seg, &cut);
        let total: f64 = (0..grid.len()).map(|i| cpl.seg.c(i) * cut.volume(i)).sum();
        (
            (d.mass_small - d0.mass_small).abs() / d0.mass_small,
            (total - total0).abs() / total0,
            over,
            under,
            mismatch,
            sieve_core::state_hash(cpl.seg),
        )
    }

    #[test]
    fn limited_transport_on_cut_cells_keeps_bounds_and_mass() {
        run_big(|| {
            let l = drum(300, Transport::Limited);
            println!(
                "coupled half drum, limited: small drift {:.1e}, grains {:.1e}, max(phi - c) {:.1e}, max(-phi) {:.1e}, |c_seg - c_flow| {:.1e}",
                l.0, l.1, l.2, l.3, l.4
            );
            assert!(l.0 < 1e-12 && l.1 < 1e-12, "{l:?}");
            assert!(l.2 <= 0.0 && l.3 <= 0.0, "{l:?}");
            assert!(l.4 < 1e-12, "{l:?}");
            assert_eq!(l.5, drum(300, Transport::Limited).5);
            assert_ne!(l.5, drum(300, Transport::Donor).5);
        });
    }
}
