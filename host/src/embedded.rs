//! Scenes with a `[geometry]` (issue 8; docs/geometry.md): the cut cells of the scene's
//! container, built once on the solver thread, and the segregation solver set up on them
//! (solid cells hold no grains; merged groups start uniform), plus what the outputs need
//! (open volume fractions, the geometry block of summary.json).
//!
//! Which commands run cut cells: `sieve run` (prescribed scenes on the segregation solver,
//! coupled scenes with the flow on the same cut cells, `crate::flow`) and `sieve converge`
//! (readouts only: the open volumes differ between grids, `crate::converge`). `sieve record`
//! refuses them ([`refuse`]): never a silent fallback to the box. A frozen flow with a
//! geometry is refused by validation.

use crate::data::GeometrySummary;
use crate::error::{Error, Result};
use crate::scene::{solver_errors, Scene};
use sieve_core::geometry::CutCells;
use sieve_core::{Boundary, Real, Segregation};

/// The cut cells of `scene`'s geometry on the solver's grid (None without a geometry). The
/// value is large (`(4 + 5 D) N` reals), so it is boxed; call it on the solver thread, whose
/// stack has room for the temporary.
pub fn build<R: Real, const D: usize, const N: usize>(
    s: &Segregation<R, D, N>,
    scene: &Scene,
) -> Result<Option<Box<CutCells<R, D, N>>>> {
    let Some(g) = &scene.geometry else {
        return Ok(None);
    };
    let mut geo = Box::new(CutCells::<R, D, N>::zeroed());
    let periodic: [bool; D] =
        core::array::from_fn(|a| scene.boundaries[a][0] == Boundary::Periodic);
    geo.build(
        s.grid(),
        &g.region::<R, D>(),
        periodic,
        R::from_f64(g.small),
    )
    .map_err(|e| {
        Error::at(
            &scene.label,
            "geometry",
            format!("cannot build the cut cells: {e}"),
        )
    })?;
    Ok(Some(geo))
}

/// Empties the solid cells of `s` (c = phi = T = 0, u = 0: solid cells never hold grains),
/// then prepares it on the cut cells (merged groups take their volume-weighted means).
pub fn prepare<R: Real, const D: usize, const N: usize>(
    s: &mut Segregation<R, D, N>,
    scene: &Scene,
    geo: &CutCells<R, D, N>,
) -> Result<()> {
    for i in 0..s.len() {
        if geo.is_solid(i) {
            s.set_cell(i, R::ZERO, R::ZERO, [R::ZERO; D], R::ZERO);
        }
    }
    s.prepare_embedded(geo)
        .map_err(|e| solver_errors::setup_error(scene, &e))
}

/// Open volume fraction of every cell (solver cell order).
pub fn volumes<R: Real, const D: usize, const N: usize>(geo: &CutCells<R, D, N>) -> Vec<f64> {
    (0..geo.len()).map(|i| geo.volume(i).to_f64()).collect()
}

/// The `geometry` block of summary.json.
pub fn summary<R: Real, const D: usize, const N: usize>(
    scene: &Scene,
    geo: &CutCells<R, D, N>,
) -> Option<GeometrySummary> {
    let g = scene.geometry.as_ref()?;
    let st = geo.stats();
    let box_volume: f64 = (0..scene.dim)
        .map(|a| scene.upper[a] - scene.lower[a])
        .product();
    let open = st.open_volume.to_f64();
    Some(GeometrySummary {
        shape: g.shape.name().into(),
        open_volume: open,
        open_fraction: open / box_volume,
        cut_cells: st.cut,
        merged_cells: st.merged,
        removed_cells: st.removed,
        removed_volume: st.removed_volume.to_f64(),
        min_volume_fraction: st.min_volume.to_f64(),
        min_group_volume: st.min_group_volume.to_f64(),
        small: g.small,
    })
}

/// Refuses a scene with a geometry in a command that does not run cut cells.
pub fn refuse(scene: &Scene, command: &str) -> Result<()> {
    if scene.geometry.is_some() {
        return Err(Error::at(
            &scene.label,
            "geometry",
            format!("not supported by `{command}` yet (it runs the box solver): allowed with `sieve run`"),
        ));
    }
    Ok(())
}
