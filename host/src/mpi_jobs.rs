//! The solver jobs of MPI ranks (the `mpi` feature; docs/parallel.md, "MPI: sieve run under
//! mpirun"): a follower's `sieve run` ([`follow`]) and the check without files
//! ([`check_scene`], `host/examples/mpi_check.rs`). Kept apart from [`crate::parallel_mpi`]
//! because they build solvers through [`crate::run`], which calls `parallel_mpi` for rank 0's
//! stepper and snapshots: modules import no circle (host/tests/house.rs).

use crate::checkpoint::{self as cp, Stored};
use crate::error::{Error, Result};
use crate::parallel_mpi::{driver_for, serve, world};
use crate::run::{FlowJob, SolverJob};
use crate::scene::{Fields, Scene};
use sieve_core::flow::Flow;
use sieve_core::{state_hash, Real, Segregation};

/// A follower's `sieve run`: builds the scene's solver as rank 0 does (a frozen flow spun up
/// here too, or taken from the checkpoint), restores the checkpoint it resumes (`resume`:
/// the one rank 0 resumes, read by this rank), then [`serve`]s rank 0's commands until stop.
/// Returns the stop's exit code as a silent error (rank 0 reports).
pub fn follow(scene: &Scene, fields: &Fields, resume: Option<&Stored>) -> Result<()> {
    if let Some(st) = resume {
        // rank 0 refuses the same checkpoint for the same reason (its line is the one shown)
        st.check_identity(scene, fields)?;
    }
    let job = Follower {
        scene,
        fields,
        resume,
    };
    crate::run::with_scene_solvers(scene, job)
}

struct Follower<'a> {
    scene: &'a Scene,
    fields: &'a Fields,
    resume: Option<&'a Stored>,
}

impl Follower<'_> {
    /// Restores the segregation state of the resumed checkpoint, as rank 0's run does.
    fn restore<R: Real, const D: usize, const N: usize>(
        &self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<()> {
        match self.resume {
            Some(st) => cp::restore_segregation(&st.entries, s).map_err(|w| st.incompatible(w)),
            None => Ok(()),
        }
    }
}

impl SolverJob for Follower<'_> {
    type Output = ();
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<()> {
        crate::run::load(s, self.scene, self.fields)?;
        // cut cells as rank 0 builds and prepares them (crate::run's RunJob)
        let geo = crate::embedded::build(s, self.scene)?;
        let geo = geo.as_deref();
        if let Some(g) = geo {
            crate::embedded::prepare(s, self.scene, g)?;
        }
        self.restore(s)?;
        serve(s, geo, self.scene, None)
    }
}

impl FlowJob for Follower<'_> {
    type Output = ();
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
        f: &mut Flow<R, D, N>,
    ) -> Result<()> {
        crate::run::load(s, self.scene, self.fields)?;
        if crate::parallel::is_coupled(self.scene) {
            // as rank 0's coupled run (run.rs, flow.rs): the same container and whole run,
            // then this rank's slab
            let resumed = self.resume.map(|st| &st.entries);
            let geo = crate::embedded::build(s, self.scene)?;
            let geo = geo.as_deref();
            let mut cpl = crate::flow::coupled_start(f, s, self.scene, self.fields, geo, resumed)
                .map_err(|w| match self.resume {
                Some(st) => st.incompatible(w),
                None => w,
            })?;
            return crate::rank_coupled::serve(&mut cpl, self.scene);
        }
        // as rank 0's frozen-flow run (run.rs): the same spin-up (or the checkpoint's frozen
        // flow, no spin-up), the same bits
        let frozen = match self.resume {
            Some(st) => cp::frozen(&st.entries, self.scene.len(), self.scene.dim)
                .map_err(|w| st.incompatible(w))?,
            None => crate::flow::spin_up(f, self.scene, self.fields)?,
        };
        crate::flow::hand_over_frozen(s, self.scene, self.fields, &frozen)?;
        self.restore(s)?;
        serve(s, None, self.scene, Some(frozen.p))
    }
}

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
/// along the last axis; the run's [`crate::parallel_mpi::Driver`] and followers in one call) and, on rank 0,
/// serially; returns both state hashes on rank 0. Needs `parallel_mpi::launch` first (and
/// `parallel_mpi::finish`).
pub fn check_scene(scene: &Scene, fields: &Fields) -> Result<Check> {
    crate::run::with_solver(scene.precision, scene.dim, Job { scene, fields })
}

impl SolverJob for Job<'_> {
    type Output = Check;
    fn run<R: Real, const D: usize, const N: usize>(
        self,
        s: &mut Segregation<R, D, N>,
    ) -> Result<Check> {
        let (rank, ranks) = world().ok_or_else(|| Error::failure("not an MPI run"))?;
        let prepared = |s: &mut Segregation<R, D, N>| -> Result<_> {
            crate::run::load(s, self.scene, self.fields)?;
            let geo = crate::embedded::build(s, self.scene)?;
            if let Some(g) = geo.as_deref() {
                crate::embedded::prepare(s, self.scene, g)?;
            }
            Ok(geo)
        };
        let geo = prepared(s)?;
        let geo = geo.as_deref();
        if rank > 0 {
            serve(s, geo, self.scene, None)?;
            return Ok(Check {
                ranks,
                steps: 0,
                hash: 0,
                serial: 0,
            });
        }
        let t_end = R::from_f64(self.scene.t_end);
        let driver = driver_for(s, geo)?.ok_or_else(|| Error::failure("not rank 0"))?;
        let steps = driver.advance(s, t_end, u64::MAX);
        let hash = state_hash(s);
        prepared(s)?;
        match geo {
            Some(g) => s.advance_to_embedded(t_end, u64::MAX, g),
            None => s.advance_to(t_end, u64::MAX),
        };
        Ok(Check {
            ranks,
            steps,
            hash,
            serial: state_hash(s),
        })
    }
}
