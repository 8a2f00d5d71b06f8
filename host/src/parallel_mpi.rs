//! MPI ranks as subdomains (the `mpi` feature; docs/parallel.md): the threads' construction
//! ([`crate::parallel`], [`sieve_core::decomp`]) with one subdomain per rank and the halo
//! rows sent as MPI messages. First step: [`check_scene`] runs a scene's segregation to its
//! end time on the ranks and compares the gathered state hash with a serial run on rank 0
//! (`.ci/mpi-check`). `sieve run` under `mpirun` (outputs from rank 0) is not wired yet.
//!
//! Messages carry f64 (an f32 state widens exactly and narrows back exactly), so the driver
//! is generic over the precision without an MPI datatype per float type.

use crate::error::{Error, Result};
use crate::run::SolverJob;
use crate::scene::{Fields, Scene};
use mpi::traits::*;
use sieve_core::decomp::{self, Side, Subdomain};
use sieve_core::segregation::snap_slack;
use sieve_core::{state_hash, Real, Segregation};

/// What [`check_scene`] found.
#[derive(Debug, Clone)]
pub struct Check {
    /// Number of ranks.
    pub ranks: usize,
    /// Steps taken.
    pub steps: u64,
    /// State hash of the ranks' gathered state (rank 0; 0 elsewhere).
    pub hash: u64,
    /// State hash of the serial run (rank 0; 0 elsewhere).
    pub serial: u64,
}

struct Job<'a> {
    scene: &'a Scene,
    fields: &'a Fields,
}

/// Runs the scene's segregation from 0 to `t_end` on the MPI ranks (one subdomain each, split
/// along the last axis) and, on rank 0, serially; returns both state hashes on rank 0.
/// Initialises and finalises MPI itself (on the solver thread).
pub fn check_scene(scene: &Scene, fields: &Fields) -> Result<Check> {
    crate::run::with_solver(scene.precision, scene.dim, Job { scene, fields })
}

impl SolverJob for Job<'_> {
    type Output = Check;
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<Check> {
        let universe =
            mpi::initialize().ok_or_else(|| Error::failure("MPI is already initialised"))?;
        let world = universe.world();
        let (rank, ranks) = (world.rank() as usize, world.size() as usize);
        let t_end = R::from_f64(self.scene.t_end);
        let mut serial = 0;
        if rank == 0 {
            crate::run::load(s, self.scene, self.fields)?;
            s.advance_to(t_end, u64::MAX);
            serial = state_hash(s);
        }
        crate::run::load(s, self.scene, self.fields)?;
        let halo = decomp::halo_width(s);
        let sub = Subdomain::new(s.grid(), s.boundaries(), ranks, rank, halo)
            .map_err(|e| Error::input(format!("{ranks} ranks cannot split the grid: {e:?}")))?;
        let mut local = Box::new(Segregation::<R, D, N>::zeroed());
        decomp::load_subdomain(s, &sub, &mut local)
            .map_err(|e| Error::failure(format!("rank {rank}: {e:?}")))?;
        // every rank holds the prepared global solver: the global dt is its own; check the
        // subdomains agree to the bit (the minimum over ranks)
        let mine = local.stable_dt().to_f64();
        let mut min = 0.0f64;
        world.all_reduce_into(&mine, &mut min, mpi::collective::SystemOperation::min());
        if min.to_bits() != s.stable_dt().to_f64().to_bits() {
            return Err(Error::failure(format!(
                "rank time step {min:e} differs from the global {:e}",
                s.stable_dt().to_f64()
            )));
        }
        let dt = s.stable_dt();
        let slack = snap_slack(t_end);
        let floor = s.config().flush_below;
        let own = sub.owned_cells();
        let mut excess = s.tracked_excess();
        let mut flushed_steps: Vec<u64> = Vec::new();
        let mut flushed: Vec<f64> = Vec::new();
        let mut send = [
            vec![R::ZERO; sub.message_len(Side::Low, 1)],
            vec![R::ZERO; sub.message_len(Side::High, 1)],
        ];
        let mut send64 = [Vec::new(), Vec::new()];
        let mut recv64 = [
            vec![0.0f64; sub.message_len(Side::Low, 1)],
            vec![0.0f64; sub.message_len(Side::High, 1)],
        ];
        let sides = [Side::Low, Side::High];
        while local.time() < t_end {
            let before = local.steps();
            let remaining = t_end - local.time();
            if remaining <= dt || remaining - dt <= slack {
                local.step(remaining);
                local.set_clock(t_end, local.steps());
            } else {
                local.step(dt);
            }
            local.end_owned_step(own.clone(), floor, before, &mut excess, |_, v| {
                if v != R::ZERO {
                    flushed_steps.push(before);
                    flushed.push(v.to_f64());
                }
            });
            // halo exchange: non-blocking sends of the owned rows next to each cut (tagged
            // with the sending side), blocking receives into the halos
            for side in sides {
                if sub.neighbour(side).is_some() {
                    let k = side as usize;
                    decomp::pack(&local, &sub, side, &["q"], &mut send[k]);
                    send64[k] = send[k].iter().map(|x| x.to_f64()).collect();
                }
            }
            mpi::request::scope(|sc| {
                let mut pending = Vec::new();
                for side in sides {
                    if let Some(nb) = sub.neighbour(side) {
                        let p = world.process_at_rank(nb as i32);
                        pending.push(p.immediate_send_with_tag(
                            sc,
                            &send64[side as usize][..],
                            side as i32,
                        ));
                    }
                }
                for side in sides {
                    if let Some(nb) = sub.neighbour(side) {
                        let p = world.process_at_rank(nb as i32);
                        p.receive_into_with_tag(
                            &mut recv64[side as usize][..],
                            side.opposite() as i32,
                        );
                    }
                }
                for r in pending {
                    r.wait();
                }
            });
            for side in sides {
                if sub.neighbour(side).is_some() {
                    let k = side as usize;
                    send[k] = recv64[k].iter().map(|&x| R::from_f64(x)).collect();
                    decomp::unpack(&mut local, &sub, side, &["q"], &send[k]);
                    send[k].resize(sub.message_len(side, 1), R::ZERO);
                }
            }
        }
        let steps = local.steps();
        // gather to rank 0: owned q and carry, bound maxima, flushed values
        let own_q: Vec<f64> = own
            .clone()
            .map(|i| local.tracked_fraction(i).to_f64())
            .collect();
        let own_e: Vec<f64> = own.clone().map(|i| local.carry(i).to_f64()).collect();
        let ex = [excess[0].to_f64(), excess[1].to_f64()];
        let root = world.process_at_rank(0);
        if rank != 0 {
            root.send_with_tag(&own_q[..], 10);
            root.send_with_tag(&own_e[..], 11);
            root.send_with_tag(&ex[..], 12);
            root.send_with_tag(&flushed_steps[..], 13);
            root.send_with_tag(&flushed[..], 14);
            return Ok(Check {
                ranks,
                steps,
                hash: 0,
                serial: 0,
            });
        }
        let mut all_excess = s.tracked_excess();
        let mut lists: Vec<(Vec<u64>, Vec<f64>)> = Vec::with_capacity(ranks);
        for r in 0..ranks {
            let sub_r = Subdomain::new(s.grid(), s.boundaries(), ranks, r, halo)
                .map_err(|e| Error::failure(format!("{e:?}")))?;
            let (q, e, x, fs, fv) = if r == 0 {
                (
                    own_q.clone(),
                    own_e.clone(),
                    ex.to_vec(),
                    flushed_steps.clone(),
                    flushed.clone(),
                )
            } else {
                let p = world.process_at_rank(r as i32);
                (
                    p.receive_vec_with_tag::<f64>(10).0,
                    p.receive_vec_with_tag::<f64>(11).0,
                    p.receive_vec_with_tag::<f64>(12).0,
                    p.receive_vec_with_tag::<u64>(13).0,
                    p.receive_vec_with_tag::<f64>(14).0,
                )
            };
            let cells = sub_r.global_cells();
            for (k, i) in cells.enumerate() {
                s.set_tracked(i, R::from_f64(q[k]));
                s.set_carry(i, R::from_f64(e[k]));
            }
            all_excess = [
                all_excess[0].max(R::from_f64(x[0])),
                all_excess[1].max(R::from_f64(x[1])),
            ];
            lists.push((fs, fv));
        }
        s.set_clock(local.time(), steps);
        s.set_tracked_excess(all_excess);
        // the flushed counter in (step, rank, cell) order: the serial order
        let mut total = s.flushed_tracked();
        let mut at = vec![0usize; ranks];
        while let Some(step) = lists
            .iter()
            .zip(&at)
            .filter_map(|((st, _), &k)| st.get(k).copied())
            .min()
        {
            for ((st, v), k) in lists.iter().zip(at.iter_mut()) {
                while st.get(*k) == Some(&step) {
                    total += R::from_f64(v[*k]);
                    *k += 1;
                }
            }
        }
        s.set_flushed_tracked(total);
        Ok(Check {
            ranks,
            steps,
            hash: state_hash(s),
            serial,
        })
    }
}
