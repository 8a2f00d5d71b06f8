//! `[physics]`: gravity (one finite number per axis), the segregation direction (model.md 3)
//! and the source of T (given, or from the shear rate with the material's a, eta0, eps0:
//! model.md 2).

use super::{finite, vector, Direction, Problems, Temperature};
use crate::error::Error;
use crate::scene::{DirectionSpec, SceneFile, TemperatureSpec};

/// Validated `[physics]`.
pub(super) struct Physics {
    pub gravity: Vec<f64>,
    pub direction: Direction,
    pub temperature: Temperature,
}

/// Largest gravity component the validation accepts.
const MAX_GRAVITY: f64 = 1e6;

/// Checks `[physics]` (and the material keys `temperature = "shear"` needs).
pub(super) fn check(
    p: &mut Problems,
    l: &str,
    f: &SceneFile,
    dim: usize,
    has_flow: bool,
) -> Option<Physics> {
    // |g| up to 1e6 (a centrifuge at 1e5 g in SI units): beyond it |g|^2 overflows the
    // direction's normalisation in f64 and S silently becomes 0 (gravity = [-1e155] once ran
    // to "complete" without segregating).
    let gravity = p
        .ok(vector(l, "physics.gravity", &f.physics.gravity, dim))
        .and_then(|g| {
            let bad = g.iter().position(|x| x.abs() > MAX_GRAVITY);
            match bad {
                Some(i) => {
                    p.push(Error::range(
                        l,
                        &format!("physics.gravity[{i}]"),
                        g[i],
                        "-1e6..=1e6 (in the scene's units: 9.81 m/s^2 on earth, 1 in the dimensionless scenes)",
                    ));
                    None
                }
                None => Some(g),
            }
        });
    let direction = match &f.physics.direction {
        DirectionSpec::Name(n) if n == "gravity" => Some(Direction::Gravity),
        DirectionSpec::Name(n) if n == "flow" => Some(Direction::Flow),
        DirectionSpec::Name(n) => {
            p.push(Error::range(
                l,
                "physics.direction",
                format!("{n:?}"),
                "\"gravity\", \"flow\" or a vector of one number per axis",
            ));
            None
        }
        DirectionSpec::Vector(v) => match p.ok(vector(l, "physics.direction", v, dim)) {
            Some(v) if v.iter().all(|&x| x == 0.0) => {
                p.push(Error::range(
                    l,
                    "physics.direction",
                    format!("{v:?}"),
                    "a non-zero vector",
                ));
                None
            }
            Some(v) => Some(Direction::Fixed(v)),
            None => None,
        },
    };
    if has_flow {
        if direction.as_ref().is_some_and(|d| *d != Direction::Flow) {
            p.push(Error::range(
                l,
                "physics.direction",
                match &f.physics.direction {
                    DirectionSpec::Name(n) => format!("{n:?}"),
                    DirectionSpec::Vector(v) => format!("{v:?}"),
                },
                "\"flow\" with a solved flow (model.equations)",
            ));
        }
        if f.physics.temperature != TemperatureSpec::Given {
            p.push(Error::range(
                l,
                "physics.temperature",
                "\"shear\"",
                "\"given\" with a solved flow (T comes from the flow)",
            ));
            return None;
        }
    }
    let temperature = temperature(p, l, f);
    Some(Physics {
        gravity: gravity?,
        direction: direction?,
        temperature: temperature?,
    })
}

/// `physics.temperature` with the material constants `"shear"` needs.
fn temperature(p: &mut Problems, l: &str, f: &SceneFile) -> Option<Temperature> {
    let m = &f.material;
    match f.physics.temperature {
        TemperatureSpec::Given => Some(Temperature::Given),
        TemperatureSpec::Shear => {
            let heating = p
                .ok(finite(l, "material.heating", m.heating))
                .and_then(|h| {
                    if h < 0.0 {
                        p.push(Error::range(l, "material.heating", h, "heating >= 0"));
                        None
                    } else {
                        Some(h)
                    }
                });
            let required =
                |key: &str| Error::at(l, key, "required with physics.temperature = \"shear\"");
            let eta0 = match m.eta0 {
                None => {
                    p.push(required("material.eta0"));
                    None
                }
                Some(e) if !(e.is_finite() && e >= 0.0) => {
                    p.push(Error::range(l, "material.eta0", e, "eta0 >= 0 [m]"));
                    None
                }
                Some(e) => Some(e),
            };
            let eps0 = match m.eps0 {
                None => {
                    p.push(required("material.eps0"));
                    None
                }
                Some(e) if !(e.is_finite() && e > 0.0) => {
                    p.push(Error::range(l, "material.eps0", e, "eps0 > 0 [1/m]"));
                    None
                }
                Some(e) => Some(e),
            };
            Some(Temperature::Shear {
                heating: heating?,
                eta0: eta0?,
                eps0: eps0?,
            })
        }
    }
}
