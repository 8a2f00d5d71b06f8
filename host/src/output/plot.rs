//! PNG plots (plotters, bitmap backend, embedded DejaVu Sans font): the mixing index Psi(t),
//! and phihat at output times: profiles phihat(z) in 1D, colour maps in 2D, the mid-plane
//! (y = middle) x-z slice in 3D.

use crate::data::{Profiles, SeriesRow};
use crate::error::{Error, Result};
use crate::scene::Scene;
use plotters::prelude::*;
use std::path::Path;

/// DejaVu Sans (Bitstream Vera licence, see `host/assets/DejaVuSans-LICENSE.txt`): a fresh
/// machine has no system fonts, so the font travels with the binary.
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
const FONT_NAME: &str = "sans-serif";

/// At most this many profile curves (1D) or colour maps (2D/3D) per run.
pub const MAX_FRAMES_1D: usize = 8;
/// See [`MAX_FRAMES_1D`].
pub const MAX_FRAMES_MAP: usize = 12;

fn ensure_font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FONT_NAME, FontStyle::Normal, FONT).is_ok());
    if ok {
        Ok(())
    } else {
        Err(Error::failure("cannot load the embedded plot font"))
    }
}

fn fail<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> Error + '_ {
    move |e| Error::failure(format!("{}: plotting failed: {e:?}", path.display()))
}

/// Output indices to plot: all if there are at most `max`, else `max` evenly spread ones
/// including the first and the last.
pub fn frame_indices(n_outputs: usize, max: usize) -> Vec<usize> {
    if n_outputs <= max {
        return (0..n_outputs).collect();
    }
    let mut v: Vec<usize> = (0..max)
        .map(|i| (i * (n_outputs - 1) + (max - 1) / 2) / (max - 1))
        .collect();
    v.dedup();
    v
}

/// The colour of masked cells (no material: solid or empty) in the colour maps.
pub const MASKED: RGBColor = RGBColor(225, 225, 225);

/// A perceptually ordered colour map (viridis, 9 anchors, linear in between) for `x` in [0, 1].
pub fn viridis(x: f64) -> RGBColor {
    const A: [(u8, u8, u8); 9] = [
        (68, 1, 84),
        (71, 44, 122),
        (59, 81, 139),
        (44, 113, 142),
        (33, 144, 141),
        (39, 173, 129),
        (92, 200, 99),
        (170, 220, 50),
        (253, 231, 37),
    ];
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = x * (A.len() - 1) as f64;
    let i = (f.floor() as usize).min(A.len() - 2);
    let w = f - i as f64;
    let mix = |a: u8, b: u8| (a as f64 + (b as f64 - a as f64) * w).round() as u8;
    RGBColor(
        mix(A[i].0, A[i + 1].0),
        mix(A[i].1, A[i + 1].1),
        mix(A[i].2, A[i + 1].2),
    )
}

/// Psi(t) with the threshold of the segregation time.
pub fn psi(path: &Path, series: &[SeriesRow], threshold: f64, title: &str) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let t_max = series.last().map_or(1.0, |r| r.t).max(f64::MIN_POSITIVE);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT_NAME, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_max, 0.0..1.05)
        .map_err(fail(path))?;
    chart
        .configure_mesh()
        .x_desc("t [s]")
        .y_desc("mixing index Psi")
        .label_style((FONT_NAME, 15))
        .axis_desc_style((FONT_NAME, 17))
        .draw()
        .map_err(fail(path))?;
    chart
        .draw_series(LineSeries::new(
            series.iter().map(|r| (r.t, r.psi)),
            BLUE.stroke_width(2),
        ))
        .map_err(fail(path))?
        .label("Psi")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            vec![(0.0, threshold), (t_max, threshold)],
            RED.stroke_width(1),
        ))
        .map_err(fail(path))?
        .label(format!("threshold {threshold}"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(1)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .label_font((FONT_NAME, 15))
        .draw()
        .map_err(fail(path))?;
    root.present().map_err(fail(path))
}

/// 1D: phihat(z) profiles, one curve per frame `(t, phihat per cell)`.
pub fn profiles(path: &Path, scene: &Scene, frames: &[(f64, Vec<f64>)]) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, (700, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let (z0, z1) = (scene.lower[0], scene.upper[0]);
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("{}: phihat profiles", scene.name), (FONT_NAME, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.02..1.02, z0..z1)
        .map_err(fail(path))?;
    chart
        .configure_mesh()
        .x_desc("phihat = phi / c (small-grain fraction)")
        .y_desc("z [m]")
        .label_style((FONT_NAME, 15))
        .axis_desc_style((FONT_NAME, 17))
        .draw()
        .map_err(fail(path))?;
    let n = frames.len().max(2) - 1;
    for (j, (t, ph)) in frames.iter().enumerate() {
        let colour = viridis(0.9 * j as f64 / n as f64);
        let pts: Vec<(f64, f64)> = ph
            .iter()
            .enumerate()
            .map(|(i, &v)| (v, scene.center(i)[2]))
            .collect();
        chart
            .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
            .map_err(fail(path))?
            .label(format!("t = {}", crate::output::num(*t)))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .label_font((FONT_NAME, 14))
        .draw()
        .map_err(fail(path))?;
    root.present().map_err(fail(path))
}

/// A colour map of `values` (`nx` x `nz`, x fastest) over the box `[x0, x1] x [z0, z1]`,
/// with a colour bar for [0, 1]. Large grids are averaged down to at most 300 blocks per axis.
/// NaN values are masked (drawn light grey, left out of block averages): the solid and empty
/// cells of a container, which hold no phihat at all. `outline`: polylines drawn on top (the
/// container's walls).
#[allow(clippy::too_many_arguments)]
pub fn colour_map(
    path: &Path,
    title: &str,
    (nx, nz): (usize, usize),
    (x0, x1): (f64, f64),
    (z0, z1): (f64, f64),
    (xlabel, zlabel): (&str, &str),
    values: &[f64],
    outline: &[Vec<(f64, f64)>],
) -> Result<()> {
    ensure_font()?;
    let aspect = ((z1 - z0) / (x1 - x0)).clamp(0.25, 2.0);
    let plot_w = 700.0;
    let height = (plot_w * aspect + 110.0) as u32;
    let root = BitMapBackend::new(path, (820, height)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let (main, bar) = root.split_horizontally(730);
    let mut chart = ChartBuilder::on(&main)
        .caption(title, (FONT_NAME, 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, z0..z1)
        .map_err(fail(path))?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(xlabel)
        .y_desc(zlabel)
        .label_style((FONT_NAME, 14))
        .axis_desc_style((FONT_NAME, 16))
        .draw()
        .map_err(fail(path))?;
    let bx = nx.div_ceil(300).max(1);
    let bz = nz.div_ceil(300).max(1);
    let (hx, hz) = ((x1 - x0) / nx as f64, (z1 - z0) / nz as f64);
    let mut rects = Vec::with_capacity(nx.div_ceil(bx) * nz.div_ceil(bz));
    for jz in (0..nz).step_by(bz) {
        for jx in (0..nx).step_by(bx) {
            let (ex, ez) = ((jx + bx).min(nx), (jz + bz).min(nz));
            let (mut sum, mut count) = (0.0, 0usize);
            for iz in jz..ez {
                for ix in jx..ex {
                    let v = values[ix + nx * iz];
                    if !v.is_nan() {
                        sum += v;
                        count += 1;
                    }
                }
            }
            let colour = if count > 0 {
                viridis(sum / count as f64)
            } else {
                MASKED
            };
            rects.push(Rectangle::new(
                [
                    (x0 + jx as f64 * hx, z0 + jz as f64 * hz),
                    (x0 + ex as f64 * hx, z0 + ez as f64 * hz),
                ],
                colour.filled(),
            ));
        }
    }
    chart.draw_series(rects).map_err(fail(path))?;
    for line in outline {
        let clipped = line
            .iter()
            .map(|&(x, z)| (x.clamp(x0, x1), z.clamp(z0, z1)));
        chart
            .draw_series(std::iter::once(PathElement::new(
                clipped.collect::<Vec<_>>(),
                BLACK.stroke_width(2),
            )))
            .map_err(fail(path))?;
    }
    // Colour bar.
    let mut cb = ChartBuilder::on(&bar)
        .margin_top(40)
        .margin_bottom(50)
        .margin_right(45)
        .y_label_area_size(0)
        .right_y_label_area_size(40)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)
        .map_err(fail(path))?;
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(6)
        .label_style((FONT_NAME, 13))
        .draw()
        .map_err(fail(path))?;
    cb.draw_series((0..100).map(|k| {
        let v = k as f64 / 100.0;
        Rectangle::new([(0.0, v), (1.0, v + 0.01)], viridis(v + 0.005).filled())
    }))
    .map_err(fail(path))?;
    root.present().map_err(fail(path))
}

/// Curves `x(z)` (one per label) against the vertical axis, linear or logarithmic in x.
pub fn vertical_curves(
    path: &Path,
    title: &str,
    xlabel: &str,
    curves: &[(String, Vec<(f64, f64)>)],
    log_x: bool,
) -> Result<()> {
    ensure_font()?;
    let pts = || curves.iter().flat_map(|(_, v)| v.iter().copied());
    let finite = |x: f64| x.is_finite() && (!log_x || x > 0.0);
    let (mut x0, mut x1, mut z0, mut z1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, z) in pts().filter(|&(x, z)| finite(x) && z.is_finite()) {
        x0 = x0.min(x);
        x1 = x1.max(x);
        z0 = z0.min(z);
        z1 = z1.max(z);
    }
    if x0 > x1 {
        (x0, x1, z0, z1) = if log_x {
            (1e-3, 1.0, 0.0, 1.0)
        } else {
            (0.0, 1.0, 0.0, 1.0)
        };
    }
    if x1 <= x0 {
        x1 = if log_x { x0 * 10.0 } else { x0 + 1.0 };
    }
    if z1 <= z0 {
        z1 = z0 + 1.0;
    }
    let root = BitMapBackend::new(path, (700, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(title, (FONT_NAME, 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70);
    let n = curves.len().max(2) - 1;
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_label_formatter(&|x: &f64| tick(*x, log_x))
                .x_desc(xlabel)
                .y_desc("z [m]")
                .label_style((FONT_NAME, 14))
                .axis_desc_style((FONT_NAME, 16))
                .draw()
                .map_err(fail(path))?;
            for (j, (label, v)) in curves.iter().enumerate() {
                let colour = viridis(0.9 * j as f64 / n as f64);
                let line: Vec<(f64, f64)> = v.iter().copied().filter(|&(x, _)| finite(x)).collect();
                chart
                    .draw_series(LineSeries::new(line, colour.stroke_width(2)))
                    .map_err(fail(path))?
                    .label(label.clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                    });
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .border_style(BLACK)
                .background_style(WHITE.mix(0.9))
                .label_font((FONT_NAME, 14))
                .draw()
                .map_err(fail(path))?;
        }};
    }
    if log_x {
        draw!(builder
            .build_cartesian_2d((x0..x1).log_scale(), z0..z1)
            .map_err(fail(path))?);
    } else {
        let pad = 0.02 * (x1 - x0);
        draw!(builder
            .build_cartesian_2d((x0 - pad)..(x1 + pad), z0..z1)
            .map_err(fail(path))?);
    }
    root.present().map_err(fail(path))
}

/// Tick label: one significant digit in exponent form on a log axis; at most 6 decimals on a
/// linear one.
fn tick(x: f64, log: bool) -> String {
    if log {
        format!("{x:.0e}")
    } else {
        format!("{}", (x * 1e6).round() / 1e6)
    }
}

/// The flow profiles of a run: `flow_velocity.png` (mean u_x(z)), `flow_temperature.png`
/// (mean T(z), log scale) and `flow_shear_ratio.png` (sqrt(T)/shear rate over its steady
/// uniform shear value sqrt(a eta0/eps0), rows with T > 1e-12 only).
pub fn flow_profiles(dir: &Path, name: &str, p: &Profiles) -> Result<()> {
    let one = |v: &[f64]| -> Vec<(String, Vec<(f64, f64)>)> {
        vec![(
            name.to_string(),
            v.iter().copied().zip(p.z.iter().copied()).collect(),
        )]
    };
    vertical_curves(
        &dir.join("flow_velocity.png"),
        &format!("{name}: mean velocity u_x(z)"),
        "u_x [m/s]",
        &one(&p.u),
        false,
    )?;
    vertical_curves(
        &dir.join("flow_temperature.png"),
        &format!("{name}: mean granular temperature T(z)"),
        "T [m^2/s^2]",
        &one(&p.t),
        true,
    )?;
    vertical_curves(
        &dir.join("flow_shear_ratio.png"),
        &format!("{name}: sqrt(T)/shear rate / sqrt(a eta0/eps0)"),
        "sqrt(T) / |du_x/dz| / sqrt(a eta0 / eps0)",
        &one(&shear_ratio(p)),
        false,
    )
}

/// `sqrt(T)/shear / sqrt(a eta0/eps0)` per row; NaN where T <= 1e-12 or no shear.
pub fn shear_ratio(p: &Profiles) -> Vec<f64> {
    p.t.iter()
        .zip(&p.shear)
        .map(|(&t, &g)| {
            if t > 1e-12 && g > 0.0 {
                t.sqrt() / g / p.ratio_theory
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// Psi(t) curves (one per label) with the threshold line.
pub fn time_curves(
    path: &Path,
    title: &str,
    curves: &[(String, Vec<(f64, f64)>)],
    threshold: f64,
) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let t_max = curves
        .iter()
        .flat_map(|(_, v)| v.iter().map(|p| p.0))
        .fold(f64::MIN_POSITIVE, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT_NAME, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_max, 0.0..1.05)
        .map_err(fail(path))?;
    chart
        .configure_mesh()
        .x_desc("t [s]")
        .y_desc("mixing index Psi")
        .label_style((FONT_NAME, 15))
        .axis_desc_style((FONT_NAME, 17))
        .draw()
        .map_err(fail(path))?;
    let n = curves.len().max(2) - 1;
    for (j, (label, v)) in curves.iter().enumerate() {
        let colour = viridis(0.9 * j as f64 / n as f64);
        chart
            .draw_series(LineSeries::new(v.iter().copied(), colour.stroke_width(2)))
            .map_err(fail(path))?
            .label(label.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    chart
        .draw_series(LineSeries::new(
            vec![(0.0, threshold), (t_max, threshold)],
            RED.stroke_width(1),
        ))
        .map_err(fail(path))?
        .label(format!("threshold {threshold}"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(1)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .label_font((FONT_NAME, 15))
        .draw()
        .map_err(fail(path))?;
    root.present().map_err(fail(path))
}
