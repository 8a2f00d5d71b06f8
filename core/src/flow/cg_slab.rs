//! [`super::cg::solve`] on a slab of whole rows of a grid cut along its last axis, with the
//! serial bits: the conjugate gradients of the flow's implicit stages as the ranks of an MPI
//! run would solve them, each owning a slab (docs/parallel.md, "The CG on slabs").
//!
//! Every vector is the slab's own cells with a halo row on each cut side (the layout of
//! [`super::cycle_slab`]). The iteration is the serial one, step for step:
//! - a product `A p` fills `p`'s halo rows from the neighbours, then runs the serial fused
//!   product on the slab's view ([`super::cycle_slab`]);
//! - an element-wise update (`x += alpha p`, `p = z + beta p`) is the serial arithmetic cell
//!   by cell;
//! - a dot product writes its terms (the serial products, `r_i r_i`, `p_i (A p)_i`, `r_i z_i`)
//!   and hands them to [`Links::sum`], whose result is the serial blocked sum on every slab;
//! - the preconditioner is [`super::cycle_slab`]'s, and the switch from the lines to the
//!   V-cycle ([`Preconditioner::Auto`]) is decided from those sums, so on every slab alike.
//!
//! So every slab takes the same number of iterations as the serial solve and its own cells
//! end with the serial bits.

use super::cg::{Preconditioner, Solve, Stop, LONG, PROBE};
use super::cycle_slab::{self, fine_product, swap_fine, Fine, Links, Plan};
use crate::real::Real;

/// Scratch vectors of one slab solve: `r`, `p`, `ap` padded ([`Plan::padded_len`]); `pre`,
/// `line`, `tmp` and `terms` one value per own cell; `work` [`Plan::workspace_len`].
pub struct Scratch<'a, R> {
    /// residual
    pub r: &'a mut [R],
    /// search direction
    pub p: &'a mut [R],
    /// A p, and the preconditioned residual
    pub ap: &'a mut [R],
    /// inverse pivots of the line preconditioner
    pub pre: &'a mut [R],
    /// its multipliers
    pub line: &'a mut [R],
    /// the fine residual of the V-cycle
    pub tmp: &'a mut [R],
    /// the terms of a dot product
    pub terms: &'a mut [R],
    /// the preconditioner's workspace
    pub work: &'a mut [R],
}

/// `sum_i term(i)` over the own cells, the serial bits on every slab.
fn dot<R: Real, L: Links<R>>(links: &mut L, terms: &mut [R], term: impl Fn(usize) -> R) -> R {
    for (i, t) in terms.iter_mut().enumerate() {
        *t = term(i);
    }
    links.sum(terms)
}

/// Solves `A x = b` on the slab (`b`, `x` padded; `x` holds the initial guess of the own
/// cells) with the serial solve's iterations and bits: see [`super::cg::solve`]. Collective:
/// every slab calls it with its part of the same system.
pub fn solve<R: Real, L: Links<R>, const D: usize>(
    plan: &Plan<D>,
    links: &mut L,
    fine: &Fine<'_, R, D>,
    b: &[R],
    x: &mut [R],
    sc: Scratch<'_, R>,
    stop: Stop<R>,
) -> Solve<R> {
    let own = plan.own_range();
    let (o, n) = (own.start, own.len());
    let (tol, floor, max_iter) = (stop.relative, stop.floor, stop.max_iterations);
    let Scratch {
        r,
        p,
        ap,
        pre,
        line,
        tmp,
        terms,
        work,
    } = sc;
    let (terms, pre, line) = (&mut terms[..n], &mut pre[..n], &mut line[..n]);
    let bnorm = dot(links, terms, |i| b[o + i] * b[o + i]).sqrt();
    if bnorm == R::ZERO {
        x[own].fill(R::ZERO);
        return Solve {
            iterations: 0,
            relative_residual: R::ZERO,
        };
    }
    swap_fine(plan, links, x);
    fine_product::<false, R, D>(plan, fine, x, x, &mut ap[own.clone()]);
    let mut rr = {
        for i in own.clone() {
            r[i] = b[i] - ap[i];
        }
        dot(links, terms, |i| r[o + i] * r[o + i])
    };
    let target = tol * bnorm.max(floor);
    if rr.sqrt() <= target {
        return Solve {
            iterations: 0,
            relative_residual: rr.sqrt() / bnorm,
        };
    }
    cycle_slab::factor(plan, links, fine, pre, line, work);
    let mut probe = match stop.preconditioner {
        _ if !plan.can_coarsen() => u32::MAX,
        Preconditioner::Lines => u32::MAX,
        Preconditioner::Multigrid => 0,
        Preconditioner::Auto => PROBE,
    };
    let (mut r0, long) = (rr.sqrt(), R::from_f64(LONG));
    let mut coarsened = false;
    if probe == 0 {
        cycle_slab::coarsen(plan, links, fine, pre, work);
        coarsened = true;
    }
    // z = B r into `z`, returns r . z
    let precondition = |links: &mut L,
                        (pre, tmp, work, terms): (&[R], &mut [R], &mut [R], &mut [R]),
                        r: &[R],
                        z: &mut [R],
                        coarsened: bool| {
        cycle_slab::apply(plan, links, fine, (pre, line), r, z, tmp, work, coarsened);
        dot(links, terms, |i| r[o + i] * z[o + i])
    };
    let mut rz = precondition(links, (pre, tmp, work, terms), r, p, coarsened);
    let mut it = 0;
    while it < max_iter {
        it += 1;
        swap_fine(plan, links, p);
        fine_product::<false, R, D>(plan, fine, p, p, &mut ap[own.clone()]);
        let pap = dot(links, terms, |i| p[o + i] * ap[o + i]);
        if !(pap > R::ZERO) {
            break; // breakdown (only with an exact solution or a broken operator)
        }
        let alpha = rz / pap;
        rr = {
            for i in own.clone() {
                x[i] += alpha * p[i];
                r[i] -= alpha * ap[i];
            }
            dot(links, terms, |i| r[o + i] * r[o + i])
        };
        let rn = rr.sqrt();
        if rn <= target {
            break;
        }
        if it == probe {
            let rate = (rn / r0).ln() / R::from_usize(PROBE as usize);
            (probe, r0) = (probe + PROBE, rn);
            if rate >= R::ZERO || (target / rn).ln() / rate > long {
                probe = u32::MAX;
                cycle_slab::coarsen(plan, links, fine, pre, work);
                coarsened = true;
                rz = precondition(links, (pre, tmp, work, terms), r, p, coarsened);
                continue;
            }
        }
        let rz_new = precondition(links, (pre, tmp, work, terms), r, ap, coarsened);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in own.clone() {
            p[i] = ap[i] + beta * p[i];
        }
    }
    Solve {
        iterations: it,
        relative_residual: rr.sqrt() / bnorm,
    }
}
