//! PNG and GIF plots (plotters, bitmap backend, embedded DejaVu Sans font): the series of a run
//! (mixing index Psi, mass drift, bound violations against time), phihat at output times
//! (profiles phihat(z) in 1D; colour maps with a labelled colour bar and masked empty cells in
//! 2D, the mid-plane y slice in 3D; an animation over the output times), flow profiles, and
//! the work-precision and readout pictures of `sieve converge`. Every function takes plain data: what is
//! drawn is decided by `output::redraw`, which reads a run's files.

use crate::data::{Profiles, SeriesRow};
use crate::error::{Error, Result};
use plotters::prelude::*;
use std::path::Path;

/// DejaVu Sans (Bitstream Vera licence, see `host/assets/DejaVuSans-LICENSE.txt`): a fresh
/// machine has no system fonts, so the font travels with the binary.
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
const FONT_NAME: &str = "sans-serif";

/// At most this many profile curves in one 1D picture: more cannot be told apart.
pub const MAX_FRAMES_1D: usize = 6;
/// At most this many still colour maps (2D/3D) per run; the animation has every output time
/// up to [`MAX_FRAMES_GIF`].
pub const MAX_FRAMES_MAP: usize = 12;
/// At most this many frames in the animation (evenly spread over the output times).
pub const MAX_FRAMES_GIF: usize = 100;
/// Width of the animation's frames in pixels.
const GIF_WIDTH: u32 = 640;
/// Cells with c at or below this are empty (the solvers' vacuum threshold, 1e-6): drawn in
/// [`EMPTY`], not as phihat = 0.
pub const VACUUM: f64 = 1e-6;
/// The value that marks a cell inside a container's wall (open volume 0): drawn white, so the
/// container's outline shows against the grey of empty cells.
pub const SOLID_CELL: f64 = f64::NEG_INFINITY;
/// The colour of empty cells: a neutral grey outside the colour map.
pub const EMPTY: RGBColor = RGBColor(190, 190, 190);
/// Distinct colours for curves that must be told apart (Okabe-Ito, colour-blind safe).
pub const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(86, 180, 233),
    RGBColor(230, 159, 0),
    RGBColor(0, 0, 0),
];

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

/// A drawing error as text (generic backends: PNG file, GIF frame).
fn text<E: std::fmt::Debug>(e: E) -> String {
    format!("{e:?}")
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

/// The series of a run in three panels over t: the mixing index Psi with the threshold of the
/// segregation time; the relative drift of the small-phase mass `(m - m0)/|m0|` (round-off
/// for closed scenes; inflow/outflow scenes exchange mass); the bound violations
/// `max(phi - c)` and `max(-phi)` (0 for the modified flux, model.md 5).
pub fn psi(path: &Path, series: &[SeriesRow], threshold: f64, title: &str) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, (800, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let root = root.titled(title, (FONT_NAME, 22)).map_err(fail(path))?;
    let panels = root.split_evenly((3, 1));
    let t_max = series.last().map_or(1.0, |r| r.t).max(f64::MIN_POSITIVE);
    let m0 = series.first().map_or(0.0, |r| r.mass);
    let drift: Vec<(f64, f64)> = series
        .iter()
        .map(|r| {
            let d = if m0 != 0.0 {
                (r.mass - m0) / m0.abs()
            } else {
                r.mass - m0
            };
            (r.t, d)
        })
        .collect();
    let over: Vec<(f64, f64)> = series.iter().map(|r| (r.t, r.overshoot_max)).collect();
    let under: Vec<(f64, f64)> = series.iter().map(|r| (r.t, r.undershoot_max)).collect();
    let y_pair = |v: &[(f64, f64)]| {
        let (lo, hi) = v
            .iter()
            .map(|p| p.1)
            .filter(|y| y.is_finite())
            .fold((0.0f64, 0.0f64), |(a, b), y| (a.min(y), b.max(y)));
        let pad = ((hi - lo) * 0.1).max(1e-16);
        (lo - pad, hi + pad)
    };
    let y_range = |v: &[(f64, f64)]| {
        let (lo, hi) = y_pair(v);
        lo..hi
    };
    let near_axes = |v: &[(f64, f64)]| -> Vec<(f64, f64)> {
        let r = y_pair(v);
        v.iter()
            .map(|&(t, y)| (near_axis(t, (0.0, t_max)), near_axis(y, r)))
            .collect()
    };
    check_axes(
        path,
        &[
            (0.0, t_max),
            y_pair(&drift),
            y_pair(&over.iter().chain(&under).copied().collect::<Vec<_>>()),
        ],
    )?;
    // Psi.
    {
        let mut c = ChartBuilder::on(&panels[0])
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..t_max, 0.0..1.05)
            .map_err(fail(path))?;
        c.configure_mesh()
            .x_desc("t")
            .y_desc("mixing index Psi")
            .label_style((FONT_NAME, 13))
            .axis_desc_style((FONT_NAME, 15))
            .draw()
            .map_err(fail(path))?;
        c.draw_series(LineSeries::new(
            series
                .iter()
                .map(|r| (near_axis(r.t, (0.0, t_max)), near_axis(r.psi, (0.0, 1.05)))),
            PALETTE[0].stroke_width(2),
        ))
        .map_err(fail(path))?
        .label("Psi")
        .legend(swatch(PALETTE[0].stroke_width(2)));
        let level = near_axis(threshold, (0.0, 1.05));
        c.draw_series(LineSeries::new(
            vec![(0.0, level), (t_max, level)],
            PALETTE[1].stroke_width(1),
        ))
        .map_err(fail(path))?
        .label(format!("threshold {threshold} (segregation time)"))
        .legend(swatch(PALETTE[1].stroke_width(1)));
        legend(&mut c, SeriesLabelPosition::UpperRight).map_err(fail(path))?;
    }
    // Mass drift.
    {
        let mut c = ChartBuilder::on(&panels[1])
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..t_max, y_range(&drift))
            .map_err(fail(path))?;
        c.configure_mesh()
            .x_desc("t")
            .y_desc("(m - m0) / m0")
            .y_label_formatter(&|y: &f64| format!("{y:.1e}"))
            .label_style((FONT_NAME, 13))
            .axis_desc_style((FONT_NAME, 15))
            .draw()
            .map_err(fail(path))?;
        c.draw_series(LineSeries::new(
            near_axes(&drift),
            PALETTE[2].stroke_width(2),
        ))
        .map_err(fail(path))?;
    }
    // Bound violations.
    {
        let both: Vec<(f64, f64)> = over.iter().chain(&under).copied().collect();
        let mut c = ChartBuilder::on(&panels[2])
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..t_max, y_range(&both))
            .map_err(fail(path))?;
        c.configure_mesh()
            .x_desc("t")
            .y_desc("bound violation")
            .y_label_formatter(&|y: &f64| format!("{y:.1e}"))
            .label_style((FONT_NAME, 13))
            .axis_desc_style((FONT_NAME, 15))
            .draw()
            .map_err(fail(path))?;
        c.draw_series(LineSeries::new(
            near_axes(&both)[..over.len()].to_vec(),
            PALETTE[3].stroke_width(2),
        ))
        .map_err(fail(path))?
        .label(format!(
            "max(phi - c): above c (largest {:.1e})",
            series.iter().map(|r| r.overshoot_max).fold(0.0, f64::max)
        ))
        .legend(swatch(PALETTE[3].stroke_width(2)));
        c.draw_series(LineSeries::new(
            near_axes(&both)[over.len()..].to_vec(),
            PALETTE[5].stroke_width(2),
        ))
        .map_err(fail(path))?
        .label(format!(
            "max(-phi): below 0 (largest {:.1e})",
            series.iter().map(|r| r.undershoot_max).fold(0.0, f64::max)
        ))
        .legend(swatch(PALETTE[5].stroke_width(2)));
        legend(&mut c, SeriesLabelPosition::UpperRight).map_err(fail(path))?;
    }
    root.present().map_err(fail(path))
}

/// The legend's sample of a line drawn in `style`.
fn swatch(style: ShapeStyle) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style)
}

/// Draws each curve as a 2 px line in its palette colour, labelled for the legend; points
/// whose x fails `keep` are left out (a log axis has no place for x <= 0).
fn labelled_lines<'a, DB: DrawingBackend + 'a, CT: CoordTranslate<From = (f64, f64)>>(
    chart: &mut ChartContext<'a, DB, CT>,
    curves: &[Curve],
    keep: impl Fn(f64) -> bool,
    path: &Path,
) -> Result<()> {
    for (j, (label, v)) in curves.iter().enumerate() {
        let colour = PALETTE[j % PALETTE.len()];
        let line: Vec<(f64, f64)> = v.iter().copied().filter(|&(x, _)| keep(x)).collect();
        chart
            .draw_series(LineSeries::new(line, colour.stroke_width(2)))
            .map_err(fail(path))?
            .label(label.clone())
            .legend(swatch(colour.stroke_width(2)));
    }
    Ok(())
}

/// `v` held within 100 axis widths of the axis `(lo, hi)`: the plotting library maps a
/// point to pixels in `i32` and overflows on a value far outside its axis (a damaged file's
/// 1e20 in a phihat of at most 1); such a point is drawn at the edge, off the chart as before.
fn near_axis(v: f64, (lo, hi): (f64, f64)) -> f64 {
    let w = hi - lo;
    if v.is_finite() {
        v.clamp(lo - 100.0 * w, hi + 100.0 * w)
    } else if v > 0.0 {
        hi + 100.0 * w
    } else if v < 0.0 {
        lo - 100.0 * w
    } else {
        v
    }
}

/// The largest magnitude an axis may reach: beyond it the plotting library's tick
/// computation overflows or loops (values read from a damaged file).
pub const MAX_PLOTTABLE: f64 = crate::scene::validate::MAX_COORDINATE;

/// Why the axis ranges `axes` (low, high) cannot be drawn, if they cannot: the plotting
/// library's tick computation overflows or loops on spans that are not finite, vanish against
/// their magnitude or exceed [`MAX_PLOTTABLE`] (values read from a damaged file; found by the
/// plot reader fuzz test). `None` when every range is fine.
fn unplottable(axes: &[(f64, f64)]) -> Option<String> {
    axes.iter().find_map(|&(lo, hi)| {
        let mag = lo.abs().max(hi.abs());
        let span = hi - lo;
        let ok = lo.is_finite()
            && hi.is_finite()
            && span.is_finite()
            && mag <= MAX_PLOTTABLE
            && span > 0.0
            && span >= 1e-15 * mag;
        (!ok).then(|| format!("values out of the plottable range ({lo:e} .. {hi:e}); not drawn"))
    })
}

/// [`unplottable`] as the error of a plot written to `path`.
fn check_axes(path: &Path, axes: &[(f64, f64)]) -> Result<()> {
    match unplottable(axes) {
        Some(why) => Err(crate::error::Error::failure(format!(
            "{}: {why}",
            path.display()
        ))),
        None => Ok(()),
    }
}

/// Draws the legend box of a chart.
fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    c: &mut ChartContext<'a, DB, CT>,
    pos: SeriesLabelPosition,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    c.configure_series_labels()
        .position(pos)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .label_font((FONT_NAME, 14))
        .draw()
}

/// 1D: phihat(z) profiles, one curve per frame `(t, phihat per cell)` (NaN in empty cells,
/// left out), in distinct colours with distinct markers; at most [`MAX_FRAMES_1D`] frames
/// should be passed. `z` holds the cell centres.
pub fn profiles(
    path: &Path,
    title: &str,
    z: &[f64],
    (z0, z1): (f64, f64),
    frames: &[(f64, Vec<f64>)],
) -> Result<()> {
    ensure_font()?;
    check_axes(path, &[(z0, z1)])?;
    let root = BitMapBackend::new(path, (700, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT_NAME, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.02..1.02, z0..z1)
        .map_err(fail(path))?;
    chart
        .configure_mesh()
        .x_desc("phihat = phi / c: fraction of small grains")
        .y_desc("z")
        .label_style((FONT_NAME, 15))
        .axis_desc_style((FONT_NAME, 17))
        .draw()
        .map_err(fail(path))?;
    let marks = (z.len() / 10).max(1);
    for (j, (t, ph)) in frames.iter().enumerate() {
        let colour = PALETTE[j % PALETTE.len()];
        let pts: Vec<(f64, f64)> = ph
            .iter()
            .zip(z)
            .filter(|(v, _)| v.is_finite())
            .map(|(&v, &z)| (near_axis(v, (-0.02, 1.02)), z))
            .collect();
        let shape = j % 4;
        let offset = (j * marks / frames.len().max(1)) % marks;
        let marker_pts: Vec<(f64, f64)> = pts.iter().skip(offset).step_by(marks).copied().collect();
        chart
            .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
            .map_err(fail(path))?
            .label(format!("t = {}", crate::output::num(*t)))
            .legend(swatch(colour.stroke_width(3)));
        // Markers of four shapes along each curve, staggered so that coinciding curves
        // (a steady state) still show each other.
        let m = marker_pts.into_iter();
        match shape {
            0 => chart.draw_series(m.map(|p| Circle::new(p, 4, colour.filled()))),
            1 => chart.draw_series(m.map(|p| TriangleMarker::new(p, 6, colour.filled()))),
            2 => chart.draw_series(m.map(|p| Cross::new(p, 5, colour.stroke_width(2)))),
            _ => chart.draw_series(m.map(|p| Circle::new(p, 5, colour.stroke_width(2)))),
        }
        .map_err(fail(path))?;
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight).map_err(fail(path))?;
    root.present().map_err(fail(path))
}

/// The grid of a colour map: `nx` x `nz` cells (x fastest) over `[x0, x1] x [z0, z1]`.
#[derive(Debug, Clone)]
pub struct MapGrid {
    /// Cells along the horizontal and the vertical axis.
    pub cells: (usize, usize),
    /// Horizontal extent.
    pub x: (f64, f64),
    /// Vertical extent.
    pub z: (f64, f64),
    /// Axis labels.
    pub labels: (String, String),
}

impl MapGrid {
    /// Picture size in pixels: 900 wide (700 for the map), the height after the box's aspect.
    pub fn size(&self) -> (u32, u32) {
        self.size_for(900)
    }

    /// Picture size for a total width (the colour bar keeps 170 px, the map gets the rest).
    pub fn size_for(&self, width: u32) -> (u32, u32) {
        let aspect = ((self.z.1 - self.z.0) / (self.x.1 - self.x.0)).clamp(0.25, 2.0);
        let map = width.saturating_sub(200) as f64;
        (width, (map * aspect + 120.0) as u32)
    }
}

/// Draws a colour map of phihat (NaN = empty cell, drawn in [`EMPTY`]) with a colour bar
/// labelled "phihat: fraction of small grains" and a swatch for empty cells. Large grids are
/// averaged down to at most 300 blocks per axis (empty cells left out of the average; a block
/// of empty cells only is empty).
pub fn draw_colour_map<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    g: &MapGrid,
    values: &[f64],
) -> std::result::Result<(), String> {
    let (nx, nz) = g.cells;
    let ((x0, x1), (z0, z1)) = (g.x, g.z);
    if let Some(why) = unplottable(&[(x0, x1), (z0, z1)]) {
        return Err(why);
    }
    root.fill(&WHITE).map_err(text)?;
    let (w, _) = root.dim_in_pixel();
    let (main, bar) = root.split_horizontally(w.saturating_sub(170));
    let mut chart = ChartBuilder::on(&main)
        .caption(title, (FONT_NAME, 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, z0..z1)
        .map_err(text)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(g.labels.0.as_str())
        .y_desc(g.labels.1.as_str())
        .label_style((FONT_NAME, 14))
        .axis_desc_style((FONT_NAME, 16))
        .draw()
        .map_err(text)?;
    let bx = nx.div_ceil(300).max(1);
    let bz = nz.div_ceil(300).max(1);
    let (hx, hz) = ((x1 - x0) / nx as f64, (z1 - z0) / nz as f64);
    let mut rects = Vec::with_capacity(nx.div_ceil(bx) * nz.div_ceil(bz));
    for jz in (0..nz).step_by(bz) {
        for jx in (0..nx).step_by(bx) {
            let (ex, ez) = ((jx + bx).min(nx), (jz + bz).min(nz));
            let (mut sum, mut count, mut solid) = (0.0, 0usize, 0usize);
            for iz in jz..ez {
                for ix in jx..ex {
                    let v = values[ix + nx * iz];
                    if v.is_finite() {
                        sum += v;
                        count += 1;
                    } else if v == SOLID_CELL {
                        solid += 1;
                    }
                }
            }
            let colour = if count == 0 && solid > 0 {
                WHITE
            } else if count == 0 {
                EMPTY
            } else {
                viridis(sum / count as f64)
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
    chart.draw_series(rects).map_err(text)?;
    // Colour bar with its label, and the swatch of empty cells below it.
    let (_, bar_h) = bar.dim_in_pixel();
    let (bar_top, swatch) = bar.split_vertically(bar_h.saturating_sub(72));
    let mut cb = ChartBuilder::on(&bar_top)
        .margin_top(40)
        .margin_bottom(10)
        .margin_left(35)
        .margin_right(5)
        .y_label_area_size(0)
        .right_y_label_area_size(40)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)
        .map_err(text)?;
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(6)
        .label_style((FONT_NAME, 13))
        .draw()
        .map_err(text)?;
    // The bar's meaning, written upwards along its left side.
    let (_, top_h) = bar_top.dim_in_pixel();
    let label_style = TextStyle::from((FONT_NAME, 14).into_font())
        .transform(FontTransform::Rotate270)
        .pos(plotters::style::text_anchor::Pos::new(
            plotters::style::text_anchor::HPos::Center,
            plotters::style::text_anchor::VPos::Top,
        ));
    bar_top
        .draw(&Text::new(
            "phihat: fraction of small grains",
            (8, (top_h as i32 + 30) / 2),
            label_style,
        ))
        .map_err(text)?;
    cb.draw_series((0..100).map(|k| {
        let v = k as f64 / 100.0;
        Rectangle::new([(0.0, v), (1.0, v + 0.01)], viridis(v + 0.005).filled())
    }))
    .map_err(text)?;
    swatch
        .draw(&Rectangle::new([(40, 10), (70, 30)], EMPTY.filled()))
        .map_err(text)?;
    swatch
        .draw(&Rectangle::new([(40, 10), (70, 30)], BLACK.stroke_width(1)))
        .map_err(text)?;
    swatch
        .draw(&Text::new("empty", (76, 12), (FONT_NAME, 13)))
        .map_err(text)?;
    swatch
        .draw(&Text::new(
            format!("c <= {VACUUM:e}"),
            (40, 36),
            (FONT_NAME, 12),
        ))
        .map_err(text)?;
    if values.contains(&SOLID_CELL) {
        swatch
            .draw(&Rectangle::new([(40, 50), (70, 66)], BLACK.stroke_width(1)))
            .map_err(text)?;
        swatch
            .draw(&Text::new("wall (solid)", (76, 51), (FONT_NAME, 13)))
            .map_err(text)?;
    }
    Ok(())
}

/// A colour map as a PNG (see [`draw_colour_map`]).
pub fn colour_map(path: &Path, title: &str, g: &MapGrid, values: &[f64]) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, g.size()).into_drawing_area();
    draw_colour_map(&root, title, g, values).map_err(fail(path))?;
    root.present().map_err(fail(path))
}

/// An animated GIF of colour maps, one frame per [`Animation::frame`]. Each frame is drawn
/// into an RGB buffer and mapped onto one fixed palette (`MapPalette`): the colour map's
/// own colours, greys for text and empty cells, the curve colours. Quantising every frame
/// anew (NeuQuant, plotters' GIF backend) took three quarters of a small run's time.
pub struct Animation {
    encoder: gif::Encoder<std::io::BufWriter<std::fs::File>>,
    path: std::path::PathBuf,
    grid: MapGrid,
    size: (u32, u32),
    /// Frame delay in GIF units (1/100 s).
    delay: u16,
    rgb: Vec<u8>,
    palette: MapPalette,
}

impl Animation {
    /// Starts `path` with `delay_ms` between frames.
    pub fn new(path: &Path, grid: MapGrid, delay_ms: u32) -> Result<Self> {
        ensure_font()?;
        let size = grid.size_for(GIF_WIDTH);
        let (w, h) = (
            u16::try_from(size.0).map_err(fail(path))?,
            u16::try_from(size.1).map_err(fail(path))?,
        );
        let palette = MapPalette::new();
        let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
        let mut encoder = gif::Encoder::new(std::io::BufWriter::new(file), w, h, &palette.flat())
            .map_err(fail(path))?;
        encoder
            .set_repeat(gif::Repeat::Infinite)
            .map_err(fail(path))?;
        Ok(Self {
            encoder,
            path: path.to_path_buf(),
            grid,
            size,
            delay: u16::try_from(delay_ms.div_ceil(10)).unwrap_or(u16::MAX),
            rgb: vec![0; size.0 as usize * size.1 as usize * 3],
            palette,
        })
    }

    /// Adds one frame.
    pub fn frame(&mut self, title: &str, values: &[f64]) -> Result<()> {
        {
            let root = BitMapBackend::with_buffer(&mut self.rgb, self.size).into_drawing_area();
            draw_colour_map(&root, title, &self.grid, values).map_err(fail(&self.path))?;
            root.present().map_err(fail(&self.path))?;
        }
        let palette = &mut self.palette;
        let indices: Vec<u8> = self
            .rgb
            .chunks_exact(3)
            .map(|p| palette.index([p[0], p[1], p[2]]))
            .collect();
        let mut frame =
            gif::Frame::from_indexed_pixels(self.size.0 as u16, self.size.1 as u16, &indices, None);
        frame.delay = self.delay;
        self.encoder.write_frame(&frame).map_err(fail(&self.path))
    }
}

/// The fixed palette of the animations: 200 steps of [`viridis`], 47 greys from black to
/// white, [`EMPTY`] and the curve colours ([`PALETTE`]); every other colour (anti-aliased
/// edges) goes to the nearest entry (squared RGB distance, the first of equals), remembered
/// per colour, and a run of equal pixels takes the last answer. The same frame always gives
/// the same bytes.
struct MapPalette {
    colours: Vec<[u8; 3]>,
    nearest: std::collections::HashMap<[u8; 3], u8>,
    last: ([u8; 3], u8),
}

impl MapPalette {
    fn new() -> Self {
        let mut colours: Vec<[u8; 3]> = (0..200)
            .map(|k| {
                let c = viridis(k as f64 / 199.0);
                [c.0, c.1, c.2]
            })
            .collect();
        colours.extend((0..47u32).map(|k| [(k * 255 / 46) as u8; 3]));
        colours.push([EMPTY.0, EMPTY.1, EMPTY.2]);
        colours.extend(PALETTE.iter().map(|c| [c.0, c.1, c.2]));
        colours.resize(256, [255; 3]);
        let last = (colours[0], 0);
        Self {
            colours,
            nearest: Default::default(),
            last,
        }
    }

    /// The palette as the GIF's global colour table (RGB triples).
    fn flat(&self) -> Vec<u8> {
        self.colours.iter().flatten().copied().collect()
    }

    fn index(&mut self, rgb: [u8; 3]) -> u8 {
        if rgb == self.last.0 {
            return self.last.1;
        }
        let colours = &self.colours;
        let i = *self.nearest.entry(rgb).or_insert_with(|| {
            let d = |c: &[u8; 3]| {
                (0..3)
                    .map(|i| (c[i] as i32 - rgb[i] as i32).pow(2))
                    .sum::<i32>()
            };
            let mut best = 0;
            for (k, c) in colours.iter().enumerate() {
                if d(c) < d(&colours[best]) {
                    best = k;
                }
            }
            best as u8
        });
        self.last = (rgb, i);
        i
    }
}

/// Log-log panels of the work-precision picture of `sieve converge`: error against cell size
/// `h` with the observed order of the finest pair, and error against wall time. `rows` are
/// `(h, error, wall seconds)` per level (levels without an error are left out).
pub fn work_precision(
    path: &Path,
    title: &str,
    norm: &str,
    rows: &[(f64, f64, f64)],
    order: Option<f64>,
) -> Result<()> {
    ensure_font()?;
    let pts: Vec<(f64, f64, f64)> = rows
        .iter()
        .copied()
        .filter(|r| r.0 > 0.0 && r.1 > 0.0 && r.2 > 0.0 && r.1.is_finite())
        .collect();
    let root = BitMapBackend::new(path, (1100, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let root = root.titled(title, (FONT_NAME, 20)).map_err(fail(path))?;
    let (left, right) = root.split_horizontally(550);
    let span = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v.fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x), b.max(x)));
        if lo > hi {
            (1e-3, 1.0)
        } else {
            (lo / 2.0, hi * 2.0)
        }
    };
    let (h0, h1) = span(&mut pts.iter().map(|r| r.0));
    let (e0, e1) = span(&mut pts.iter().map(|r| r.1));
    let (w0, w1) = span(&mut pts.iter().map(|r| r.2));
    check_axes(path, &[(h0, h1), (e0, e1), (w0, w1)])?;
    let label = format!("{norm} error of phihat");
    for (area, x_desc, xs, ix) in [
        (&left, "cell size h (vertical)", (h0, h1), 0usize),
        (&right, "wall time [s]", (w0, w1), 2usize),
    ] {
        let mut c = ChartBuilder::on(area)
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d((xs.0..xs.1).log_scale(), (e0..e1).log_scale())
            .map_err(fail(path))?;
        c.configure_mesh()
            .x_labels(8)
            .y_labels(12)
            .light_line_style(RGBColor(238, 238, 238))
            .x_desc(x_desc)
            .y_desc(label.as_str())
            .x_label_formatter(&|x: &f64| format!("{x:.0e}"))
            .y_label_formatter(&|y: &f64| format!("{y:.0e}"))
            .label_style((FONT_NAME, 13))
            .axis_desc_style((FONT_NAME, 15))
            .draw()
            .map_err(fail(path))?;
        let line: Vec<(f64, f64)> = pts
            .iter()
            .map(|r| (if ix == 0 { r.0 } else { r.2 }, r.1))
            .collect();
        c.draw_series(LineSeries::new(line.clone(), PALETTE[0].stroke_width(2)))
            .map_err(fail(path))?
            .label("measured")
            .legend(swatch(PALETTE[0].stroke_width(2)));
        c.draw_series(line.iter().map(|&p| Circle::new(p, 4, PALETTE[0].filled())))
            .map_err(fail(path))?;
        if ix == 0 {
            let finest = pts.iter().min_by(|a, b| a.0.total_cmp(&b.0));
            if let (Some(p), Some(&(hf, ef, _))) = (order, finest) {
                // A slope-p guide below the finest level (offset so that it does not hide
                // the measured line when they are parallel).
                let e_at = |h: f64| 0.6 * ef * (h / hf).powf(p);
                let guide = vec![(hf, e_at(hf)), (h1 / 2.0, e_at(h1 / 2.0))];
                c.draw_series(LineSeries::new(guide, PALETTE[1].stroke_width(1)))
                    .map_err(fail(path))?
                    .label(format!("slope {p:.2}: observed order, finest pair"))
                    .legend(swatch(PALETTE[1].stroke_width(1)));
            }
        }
        legend(&mut c, SeriesLabelPosition::LowerRight).map_err(fail(path))?;
    }
    root.present().map_err(fail(path))
}

/// One panel of [`readouts`]: a readout's name, its `(cell size, value)` per level, the
/// extrapolated value at `h = 0` if there is one, and a caption (what the grids say).
pub struct ReadoutPanel {
    /// Its key in summary.json.
    pub name: String,
    /// `(h, value)` per level.
    pub points: Vec<(f64, f64)>,
    /// The Richardson-extrapolated value.
    pub extrapolated: Option<f64>,
    /// The panel's caption.
    pub caption: String,
}

/// readouts.png of `sieve converge`: one panel per readout, its value against the cell size
/// (linear, from h = 0, where the extrapolated value is drawn as a line across), three panels
/// a row.
pub fn readouts(path: &Path, title: &str, panels: &[ReadoutPanel]) -> Result<()> {
    ensure_font()?;
    const COLUMNS: usize = 3;
    let rows = panels.len().div_ceil(COLUMNS).max(1);
    let root = BitMapBackend::new(path, (1200, 40 + 300 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let root = root.titled(title, (FONT_NAME, 18)).map_err(fail(path))?;
    let areas = root.split_evenly((rows, COLUMNS));
    for (panel, area) in panels.iter().zip(&areas) {
        let pts: Vec<(f64, f64)> = panel
            .points
            .iter()
            .copied()
            .filter(|p| p.0.is_finite() && p.0 > 0.0 && p.1.is_finite())
            .collect();
        let h1 = pts.iter().fold(0.0f64, |m, p| m.max(p.0)) * 1.1;
        let ys = pts.iter().map(|p| p.1).chain(panel.extrapolated);
        let (y0, y1) = ys.fold((f64::MAX, f64::MIN), |(a, b), y| (a.min(y), b.max(y)));
        if pts.is_empty() || h1 <= 0.0 || y0 > y1 {
            continue;
        }
        let pad = if y1 > y0 {
            0.08 * (y1 - y0)
        } else {
            0.05 * y0.abs().max(1e-12)
        };
        let (y0, y1) = (y0 - pad, y1 + pad);
        check_axes(path, &[(0.0, h1), (y0, y1)])?;
        let mut c = ChartBuilder::on(area)
            .caption(
                format!("{} ({})", panel.name, panel.caption),
                (FONT_NAME, 13),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..h1, y0..y1)
            .map_err(fail(path))?;
        c.configure_mesh()
            .x_labels(5)
            .y_labels(6)
            .light_line_style(RGBColor(238, 238, 238))
            .x_desc("cell size h (vertical) [m]")
            .x_label_formatter(&|x: &f64| format!("{x:.1e}"))
            .y_label_formatter(&|y: &f64| format!("{y:.3e}"))
            .label_style((FONT_NAME, 11))
            .axis_desc_style((FONT_NAME, 12))
            .draw()
            .map_err(fail(path))?;
        if let Some(e) = panel.extrapolated {
            c.draw_series(LineSeries::new(
                vec![(0.0, e), (h1, e)],
                PALETTE[1].stroke_width(1),
            ))
            .map_err(fail(path))?;
            c.draw_series(std::iter::once(Circle::new(
                (0.0, e),
                5,
                PALETTE[1].filled(),
            )))
            .map_err(fail(path))?;
        }
        c.draw_series(LineSeries::new(pts.clone(), PALETTE[0].stroke_width(2)))
            .map_err(fail(path))?;
        c.draw_series(pts.iter().map(|&p| Circle::new(p, 4, PALETTE[0].filled())))
            .map_err(fail(path))?;
    }
    root.present().map_err(fail(path))
}

/// Curves `x(z)` (one per label) against the vertical axis, linear or logarithmic in x.
pub fn vertical_curves(
    path: &Path,
    title: &str,
    xlabel: &str,
    curves: &[Curve],
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
            labelled_lines(&mut chart, curves, finite, path)?;
            // A legend with one entry only hides the curve: the title names it.
            if curves.len() > 1 {
                legend(&mut chart, SeriesLabelPosition::UpperLeft).map_err(fail(path))?;
            }
        }};
    }
    check_axes(path, &[(x0, x1), (z0, z1)])?;
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

/// Tick label: one significant digit in exponent form on a log axis and for small values
/// (|x| < 1e-3, which would not fit as decimals); at most 6 decimals otherwise.
fn tick(x: f64, log: bool) -> String {
    if log || (x != 0.0 && x.abs() < 1e-3) {
        format!("{x:.0e}")
    } else {
        format!("{}", (x * 1e6).round() / 1e6)
    }
}

/// The flow profiles of a run at time `t`: `flow_velocity.png` (mean u_x(z)),
/// `flow_temperature.png` (mean T(z), log scale) and `flow_shear_ratio.png` (sqrt(T)/shear
/// rate over its steady uniform shear value sqrt(a eta0/eps0), rows with T > 1e-12 only).
/// The titles say which time they show (the end of the run; for a frozen flow, the flow
/// frozen after its spin-up).
pub fn flow_profiles(dir: &Path, name: &str, when: &str, p: &Profiles) -> Result<()> {
    let one = |v: &[f64]| -> Vec<Curve> {
        vec![(
            name.to_string(),
            v.iter().copied().zip(p.z.iter().copied()).collect(),
        )]
    };
    vertical_curves(
        &dir.join("flow_velocity.png"),
        &format!("{name}: mean velocity u_x(z), {when}"),
        "u_x [m/s]",
        &one(&p.u),
        false,
    )?;
    vertical_curves(
        &dir.join("flow_temperature.png"),
        &format!("{name}: mean granular temperature T(z), {when}"),
        "T [m^2/s^2]",
        &one(&p.t),
        true,
    )?;
    vertical_curves(
        &dir.join("flow_shear_ratio.png"),
        &format!("{name}: sqrt(T)/shear rate / sqrt(a eta0/eps0), {when}"),
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
pub fn time_curves(path: &Path, title: &str, curves: &[Curve], threshold: f64) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let t_max = curves
        .iter()
        .flat_map(|(_, v)| v.iter().map(|p| p.0))
        .fold(f64::MIN_POSITIVE, f64::max);
    check_axes(path, &[(0.0, t_max)])?;
    // Points far off the axes (a damaged series.csv) are drawn at the edge, as in `psi`.
    let axes = ((0.0, t_max), (0.0, 1.05));
    let near: Vec<Curve> = curves
        .iter()
        .map(|(label, v)| {
            let v = v
                .iter()
                .map(|&(t, y)| (near_axis(t, axes.0), near_axis(y, axes.1)))
                .collect();
            (label.clone(), v)
        })
        .collect();
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
    labelled_lines(&mut chart, &near, |_| true, path)?;
    let level = near_axis(threshold, axes.1);
    chart
        .draw_series(LineSeries::new(
            vec![(0.0, level), (t_max, level)],
            RED.stroke_width(1),
        ))
        .map_err(fail(path))?
        .label(format!("threshold {threshold}"))
        .legend(swatch(RED.stroke_width(1)));
    legend(&mut chart, SeriesLabelPosition::UpperRight).map_err(fail(path))?;
    root.present().map_err(fail(path))
}

/// A labelled curve: its label and its (x, y) points.
pub type Curve = (String, Vec<(f64, f64)>);

/// Curves y(x) (one per label), e.g. a summary value against a swept key (`sieve sweep`).
pub fn xy_curves(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    curves: &[Curve],
    fitted: &[Curve],
) -> Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let pts = || {
        curves
            .iter()
            .chain(fitted)
            .flat_map(|(_, v)| v.iter().copied())
    };
    let (x0, x1) = pts().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (y0, y1) = pts().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    // A flat range still needs a visible axis.
    let pad = |lo: f64, hi: f64| {
        let w = (hi - lo)
            .abs()
            .max(1e-12 * lo.abs().max(hi.abs()))
            .max(1e-300);
        (lo - 0.05 * w, hi + 0.05 * w)
    };
    let (x0, x1) = pad(x0, x1);
    let (y0, y1) = pad(y0, y1);
    // A non-finite value or a span past f64 (read from a damaged file) would make the mesh
    // loop without end: refuse it instead of hanging.
    check_axes(path, &[(x0, x1), (y0, y1)])?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT_NAME, 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(fail(path))?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT_NAME, 15))
        .axis_desc_style((FONT_NAME, 17))
        .draw()
        .map_err(fail(path))?;
    let labelled = curves.len() > 1 || !fitted.is_empty();
    for (j, (label, v)) in curves.iter().enumerate() {
        let colour = PALETTE[j % PALETTE.len()];
        let series = chart
            .draw_series(LineSeries::new(v.iter().copied(), colour.stroke_width(2)))
            .map_err(fail(path))?;
        if labelled {
            let label = if label.is_empty() { "runs" } else { label };
            series
                .label(label.to_string())
                .legend(swatch(colour.stroke_width(2)));
        }
        chart
            .draw_series(v.iter().map(|&p| Circle::new(p, 4, colour.filled())))
            .map_err(fail(path))?;
    }
    // A fitted law in its curve's colour, thin and without markers: the law, not runs.
    for (j, (label, v)) in fitted.iter().enumerate() {
        if v.is_empty() {
            continue;
        }
        let colour = PALETTE[j % PALETTE.len()].mix(0.6);
        chart
            .draw_series(LineSeries::new(v.iter().copied(), colour.stroke_width(1)))
            .map_err(fail(path))?
            .label(label.clone())
            .legend(swatch(colour.stroke_width(1)));
    }
    if labelled {
        legend(&mut chart, SeriesLabelPosition::UpperRight).map_err(fail(path))?;
    }
    root.present().map_err(fail(path))
}

/// One panel of [`stacked_curves`]: its y-axis label and its curves.
pub type Panel<'a> = (&'a str, &'a [Curve]);

/// Panels of curves y(x) stacked one above the other on a common x axis (e.g. the discharge
/// rates and the mass left in a silo against time: quantities of different units that are
/// read together). Lines only, a legend per panel with more than one curve. Refuses
/// non-finite points or spans, as [`xy_curves`] does (a damaged file must not hang the mesh);
/// leave out undefined points (a fines fraction with nothing flowing out) before calling.
pub fn stacked_curves(path: &Path, title: &str, x_desc: &str, panels: &[Panel<'_>]) -> Result<()> {
    ensure_font()?;
    let refuse = |what: String| {
        Err(crate::error::Error::failure(format!(
            "{}: {what}; not drawn",
            path.display()
        )))
    };
    if panels.is_empty() || panels.iter().all(|(_, c)| c.iter().all(|v| v.1.is_empty())) {
        return refuse("nothing to draw".into());
    }
    let all = || {
        panels
            .iter()
            .flat_map(|(_, c)| c.iter().flat_map(|v| v.1.iter()))
    };
    if let Some(p) = all().find(|p| !(p.0.is_finite() && p.1.is_finite())) {
        return refuse(format!("a non-finite point ({:e}, {:e})", p.0, p.1));
    }
    let pad = |lo: f64, hi: f64| {
        let w = (hi - lo)
            .abs()
            .max(1e-12 * lo.abs().max(hi.abs()))
            .max(1e-300);
        (lo - 0.05 * w, hi + 0.05 * w)
    };
    let (x0, x1) = all().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (x0, x1) = pad(x0, x1);
    let height = 60 + 300 * panels.len() as u32;
    let root = BitMapBackend::new(path, (800, height)).into_drawing_area();
    root.fill(&WHITE).map_err(fail(path))?;
    let root = root.titled(title, (FONT_NAME, 20)).map_err(fail(path))?;
    let areas = root.split_evenly((panels.len(), 1));
    for ((y_desc, curves), area) in panels.iter().zip(&areas) {
        let pts = || curves.iter().flat_map(|(_, v)| v.iter().copied());
        let (y0, y1) = pts().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
        let (y0, y1) = if y0 <= y1 { pad(y0, y1) } else { (0.0, 1.0) };
        if let Some(why) = unplottable(&[(x0, x1), (y0, y1)]) {
            return refuse(why.trim_end_matches("; not drawn").to_string());
        }
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(fail(path))?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(*y_desc)
            .label_style((FONT_NAME, 14))
            .axis_desc_style((FONT_NAME, 16))
            .draw()
            .map_err(fail(path))?;
        labelled_lines(&mut chart, curves, |_| true, path)?;
        if curves.len() > 1 {
            let corner = quiet_corner(curves, (x0, x1), (y0, y1));
            legend(&mut chart, corner).map_err(fail(path))?;
        }
    }
    root.present().map_err(fail(path))
}

/// The corner of a panel whose legend box covers the least of its lines: each segment is
/// sampled at 16 points, and a corner's box is the outer 40 % of the width by the outer
/// 35 % of the height. Ties keep the first of upper right, upper left, lower right, lower
/// left. (A silo's outflow fraction ends high on the right, where a fixed upper-right legend
/// hid its fines-rich tail.)
fn quiet_corner(
    curves: &[Curve],
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> SeriesLabelPosition {
    let (w, h) = (x1 - x0, y1 - y0);
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let inside = |(x, y): (f64, f64), right: bool, upper: bool| {
        let fx = (x - x0) / w;
        let fy = (y - y0) / h;
        (if right { fx >= 0.6 } else { fx <= 0.4 }) && (if upper { fy >= 0.65 } else { fy <= 0.35 })
    };
    let mut best = (SeriesLabelPosition::UpperRight, usize::MAX);
    for (pos, right, upper) in corners {
        let mut hits = 0;
        for (_, pts) in curves {
            for seg in pts.windows(2) {
                let (a, b) = (seg[0], seg[1]);
                for k in 0..16 {
                    let t = k as f64 / 16.0;
                    let p = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                    hits += usize::from(inside(p, right, upper));
                }
            }
            if let [only] = pts.as_slice() {
                hits += usize::from(inside(*only, right, upper));
            }
        }
        if hits < best.1 {
            best = (pos, hits);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The legend goes where the lines are not: a curve ending high on the right (a silo's
    /// fines-rich tail) moves it off the upper right; lines through every corner but one leave
    /// that one; nothing in the way keeps the upper right.
    #[test]
    fn the_legend_takes_the_quietest_corner() {
        let curve = |pts: &[(f64, f64)]| ("c".to_string(), pts.to_vec());
        let pos = |curves: &[Curve]| format!("{:?}", quiet_corner(curves, (0.0, 1.0), (0.0, 1.0)));
        let mid = curve(&[(0.0, 0.5), (1.0, 0.5)]);
        assert_eq!(pos(std::slice::from_ref(&mid)), "UpperRight");
        let tail = curve(&[(0.0, 0.5), (0.6, 0.5), (0.7, 0.95), (1.0, 0.9)]);
        assert_eq!(pos(&[mid.clone(), tail]), "UpperLeft");
        let diag = curve(&[(0.0, 0.0), (1.0, 1.0)]);
        let anti = curve(&[(0.0, 1.0), (0.6, 0.4)]);
        assert_eq!(pos(&[diag, anti]), "LowerRight");
    }

    /// The animations' fixed palette keeps the colour map's colours, the background, the
    /// text and the empty-cell grey exactly, and puts any other value of the colour map within
    /// 4 per channel of its colour.
    #[test]
    fn animation_palette_keeps_the_map_colours() {
        let mut p = MapPalette::new();
        assert_eq!(p.flat().len(), 256 * 3);
        let rgb = |c: RGBColor| [c.0, c.1, c.2];
        let exact = (0..200)
            .map(|k| rgb(viridis(k as f64 / 199.0)))
            .chain([[255; 3], [0; 3], rgb(EMPTY)])
            .chain(PALETTE.iter().map(|&c| rgb(c)));
        for c in exact {
            let i = p.index(c) as usize;
            assert_eq!(p.colours[i], c);
        }
        for k in 0..=1000 {
            let c = rgb(viridis(k as f64 / 1000.0));
            let i = p.index(c) as usize;
            let q = p.colours[i];
            let worst = (0..3)
                .map(|j| (q[j] as i32 - c[j] as i32).abs())
                .max()
                .unwrap();
            assert!(worst <= 4, "{c:?} -> {q:?}");
        }
    }
}
