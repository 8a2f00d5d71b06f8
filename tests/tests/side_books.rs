//! The books of a box's inflow and outflow sides (docs/model.md 5.6, "Mass through open
//! sides"): every boundary face's small-phase flux of every step, booked exactly
//! ([`sieve_core::sum::FixedSum`]), so that the cells, the flushed amount and what crossed the
//! sides close the small phase's mass to round-off in a scene whose flow crosses its box.

use crate::common::{boxed, config, gray_thornton, Inflow, Profile, GT_C, N2};
use sieve_core::sum::FixedSum;
use sieve_core::{
    diagnose, Boundaries, Boundary, DirectionMode, Grid, Phase, Real, Scheme, Segregation,
};

/// `m(t) + flushed + out - m(0)`, relative to the mass and the amounts that crossed.
fn unbooked<R: Real, const D: usize, const N: usize>(s: &Segregation<R, D, N>, m0: f64) -> f64 {
    let out = s.small_mass_out_through_sides();
    let net: f64 = out.iter().flatten().map(|x| x.to_f64()).sum();
    let crossed: f64 = out.iter().flatten().map(|x| x.to_f64().abs()).sum();
    let m = diagnose(s).mass_small.to_f64();
    (m + s.flushed_small_mass().to_f64() + net - m0).abs() / (m0 + crossed)
}

/// Gray-Thornton's plug (u = 1, c = 0.6) on [0, 2] x [0, 1]: the inflow face carries
/// `u c phihat = 0.36` of fines per unit time and height, the walls nothing; the books close
/// the mass while the layer segregates, and the large phase tracked books the same.
#[test]
fn a_plug_books_its_inflow_exactly_and_closes_the_mass() {
    let mut s = gray_thornton::<N2>(
        Profile::Plug,
        Inflow::Mixed(0.6),
        2.0,
        40,
        20,
        Scheme::Modified,
    );
    let m0 = diagnose(&*s).mass_small;
    let t = 0.75;
    s.advance_to(t, u64::MAX);
    let out = s.small_mass_out_through_sides();
    println!("plug: out {out:?}, unbooked {:e}", unbooked(&*s, m0));
    assert!((out[0][0] + GT_C * 0.6 * t).abs() < 1e-14, "{out:?}");
    // the layer starts in the inflow state and the percolation only moves fines within a
    // column, so the outflow side lets out what came in (the fines that sank to the floor
    // included)
    assert!((out[0][1] - GT_C * 0.6 * t).abs() < 1e-13, "{out:?}");
    assert_eq!(out[1], [0.0, 0.0], "walls book nothing");
    assert!(unbooked(&*s, m0) < 1e-13, "{}", unbooked(&*s, m0));

    // the large phase tracked: the same flux (the modified scheme is phase independent), so
    // the same books of the small phase, from c's transport minus the large phase's flux
    let mut l = large_plug();
    l.advance_to(t, u64::MAX);
    let out_l = l.small_mass_out_through_sides();
    println!(
        "plug, large phase tracked: out {out_l:?}, unbooked {:e}",
        unbooked(&*l, m0)
    );
    for a in 0..2 {
        for side in 0..2 {
            assert!(
                (out_l[a][side] - out[a][side]).abs() < 1e-13,
                "{out_l:?} vs {out:?}"
            );
        }
    }
    assert!(unbooked(&*l, m0) < 1e-13, "{}", unbooked(&*l, m0));
}

/// [`gray_thornton`]'s plug with the large phase tracked.
fn large_plug() -> Box<Segregation<f64, 2, N2>> {
    let mut s = boxed::<f64, 2, N2>();
    let grid = Grid::new([40, 20], [0.0, 0.0], [2.0, 1.0], N2).expect("grid");
    let bc: Boundaries<2> = [
        [Boundary::Inflow, Boundary::Outflow],
        [Boundary::Wall, Boundary::Wall],
    ];
    let cfg = config(
        Scheme::Modified,
        Phase::Large,
        [0.0, -1.0],
        DirectionMode::Gravity,
    );
    s.setup(grid, bc, cfg).expect("setup");
    for i in 0..grid.len() {
        s.set_cell(i, GT_C, 1.0, [1.0, 0.0], GT_C * 0.6);
    }
    grid.for_each_boundary_cell(0, false, |i, _| s.set_inflow(i, GT_C * 0.6));
    s.prepare().expect("prepare");
    s
}

/// f32 (the soft sensor's precision), open sides on both axes, a flow that is not uniform:
/// the books close the mass to f32 round-off, and a closed box books nothing.
#[test]
fn f32_open_sides_close_the_mass_and_walls_book_nothing() {
    for open in [true, false] {
        let mut s = boxed::<f32, 2, N2>();
        let grid = Grid::new([24, 16], [0.0, 0.0], [0.24f32, 0.16], N2).expect("grid");
        let bc: Boundaries<2> = if open {
            [
                [Boundary::Inflow, Boundary::Outflow],
                [Boundary::Outflow, Boundary::Inflow],
            ]
        } else {
            [[Boundary::Periodic; 2], [Boundary::Wall; 2]]
        };
        let mut cfg = config(
            Scheme::Modified,
            Phase::Small,
            [0.0, -9.81],
            DirectionMode::Gravity,
        );
        cfg.s0 = 0.2;
        cfg.diffusion = 1e-6;
        cfg.compensated = true;
        s.setup(grid, bc, cfg).expect("setup");
        for i in 0..grid.len() {
            let [x, z] = grid.center(i);
            let c = 0.5 + 0.1 * z / 0.16;
            s.set_cell(
                i,
                c,
                1e-3,
                [0.05 + 0.2 * z, -0.03 - 0.1 * x],
                c * (0.3 + 2.0 * x),
            );
            s.set_inflow(i, 0.8 * c);
        }
        s.prepare().expect("prepare");
        let m0 = diagnose(&*s).mass_small.to_f64();
        s.advance_to(2.0, u64::MAX);
        let out = s.small_mass_out_through_sides();
        let gap = unbooked(&*s, m0);
        println!(
            "f32 open {open}: {} steps, out {out:?}, unbooked {gap:e}",
            s.steps()
        );
        assert!(s.steps() > 50);
        if open {
            assert!(gap < 1e-6, "{gap:e}");
            assert!(out[0][0] < 0.0 && out[1][1] < 0.0, "{out:?}");
        } else {
            assert_eq!(s.side_books(), [[FixedSum::ZERO; 2]; 2]);
            assert!(gap < 1e-6, "{gap:e}");
        }
    }
}

/// The fixed-point book: the same bits whatever the order and grouping of its terms, a cut
/// of less than `2^-80` per term, NaN adding nothing and saturation instead of wrap-around.
#[test]
fn fixed_sum_is_independent_of_order_and_grouping() {
    let mut x = 0x2545_f491_4f6c_dd1d_u64;
    let terms: Vec<f64> = (0..5000)
        .map(|i| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let u = (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            u * 10f64.powi(i % 40 - 30)
        })
        .collect();
    let mut forward = FixedSum::ZERO;
    terms.iter().for_each(|&t| forward.add(t));
    let mut backward = FixedSum::ZERO;
    terms.iter().rev().for_each(|&t| backward.add(t));
    let mut parts = [FixedSum::ZERO; 3];
    for (i, &t) in terms.iter().enumerate() {
        parts[(i * 7) % 3].add(t);
    }
    let mut merged = FixedSum::ZERO;
    for p in parts.iter().rev() {
        merged.merge(*p);
    }
    assert_eq!(forward, backward);
    assert_eq!(forward, merged);
    // against a plain sum: within the cuts (2^-80 each) and the plain sum's own rounding
    let plain: f64 = terms.iter().sum();
    let abs: f64 = terms.iter().map(|t| t.abs()).sum();
    let bound = terms.len() as f64 * 2f64.powi(-80) + abs * terms.len() as f64 * f64::EPSILON;
    assert!(
        (forward.to_f64() - plain).abs() < bound,
        "{} vs {plain}",
        forward.to_f64()
    );
    // the cut: below 2^-80 a term vanishes, above it does not
    let (mut tiny, mut small) = (FixedSum::ZERO, FixedSum::ZERO);
    tiny.add(0.9 * 2f64.powi(-80));
    small.add(3.0 * 2f64.powi(-80));
    assert_eq!((tiny.to_f64(), small.to_f64()), (0.0, 3.0 * 2f64.powi(-80)));
    // NaN adds nothing; huge terms saturate at about 2^47 and never wrap to negative
    let mut odd = FixedSum::ZERO;
    odd.add(f64::NAN);
    assert_eq!(odd, FixedSum::ZERO);
    odd.add(1e300);
    odd.add(1e300);
    assert!(
        odd.to_f64() > 1e14 && odd.to_f64() < 2e14,
        "{}",
        odd.to_f64()
    );
    // words round-trip (messages between ranks, checkpoints)
    assert_eq!(FixedSum::from_words(forward.to_words()), forward);
    let mut neg = FixedSum::ZERO;
    neg.add(-1.25f32);
    assert_eq!(FixedSum::from_words(neg.to_words()).to_f64(), -1.25);
}
