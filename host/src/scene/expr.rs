//! Analytic expressions of scene files (evalexpr), evaluated at cell centres in f64.
//!
//! evalexpr keeps integers and floats apart (`1/2` is integer division, 0). Scene authors
//! write physics, not programs, so every integer literal is read as a float before parsing:
//! `1/2` is 0.5 and `z^2` is a float power. Variables: `x`, `y`, `z` (axes a scene does not
//! have are 0), `pi`, and `c` where the key allows it (`initial.phi`, `boundary.inflow.phi`).
//! Functions: evalexpr's built-ins, e.g. `if(cond, a, b)`, `min`, `max`, `math::sqrt`,
//! `math::exp`, `math::sin`, `math::abs`; the transcendental ones are evaluated with the pinned
//! `libm` crate for bit-reproducibility. The power operator `^` uses std's `powf`: write
//! `z * z` or `math::pow(z, 2)` where the last bit matters.

use super::ExprSrc;
use crate::error::{Error, Result};
use evalexpr::{
    ContextWithMutableFunctions, ContextWithMutableVariables, DefaultNumericTypes, Function,
    HashMapContext, Node, Value,
};

/// A compiled expression (or a constant).
#[derive(Debug, Clone)]
pub struct Expr {
    source: String,
    kind: Kind,
}

#[derive(Debug, Clone)]
enum Kind {
    Constant(f64),
    Tree(Box<Node<DefaultNumericTypes>>),
}

type Unary = fn(f64) -> f64;
type Binary = fn(f64, f64) -> f64;

/// The evaluation context: variable values of one point.
pub struct Vars {
    ctx: HashMapContext<DefaultNumericTypes>,
}

impl Default for Vars {
    fn default() -> Self {
        Self::new()
    }
}

impl Vars {
    /// A context with `pi` defined.
    pub fn new() -> Self {
        let mut ctx = HashMapContext::new();
        // Setting values and functions of a fresh HashMapContext cannot fail.
        let _ = ctx.set_value("pi".into(), Value::Float(std::f64::consts::PI));
        // Context functions shadow evalexpr's built-ins, which call std's libm-like functions
        // whose last bits differ between platforms; these go through the pinned `libm` crate
        // like the core, so initial fields (and so state hashes) are the same everywhere.
        let unary: [(&str, Unary); 18] = [
            ("math::ln", libm::log),
            ("math::log2", libm::log2),
            ("math::log10", libm::log10),
            ("math::exp", libm::exp),
            ("math::exp2", libm::exp2),
            ("math::cos", libm::cos),
            ("math::acos", libm::acos),
            ("math::cosh", libm::cosh),
            ("math::acosh", libm::acosh),
            ("math::sin", libm::sin),
            ("math::asin", libm::asin),
            ("math::sinh", libm::sinh),
            ("math::asinh", libm::asinh),
            ("math::tan", libm::tan),
            ("math::atan", libm::atan),
            ("math::tanh", libm::tanh),
            ("math::atanh", libm::atanh),
            ("math::cbrt", libm::cbrt),
        ];
        for (name, f) in unary {
            let _ = ctx.set_function(
                name.into(),
                Function::new(move |a: &Value| Ok(Value::Float(f(a.as_number()?)))),
            );
        }
        let binary: [(&str, Binary); 4] = [
            ("math::pow", libm::pow),
            ("math::atan2", libm::atan2),
            ("math::hypot", libm::hypot),
            ("math::log", |x, base| libm::log(x) / libm::log(base)),
        ];
        for (name, f) in binary {
            let _ = ctx.set_function(
                name.into(),
                Function::new(move |a: &Value| {
                    let t = a.as_fixed_len_tuple(2)?;
                    Ok(Value::Float(f(t[0].as_number()?, t[1].as_number()?)))
                }),
            );
        }
        Self { ctx }
    }
    fn set(&mut self, name: &str, v: f64) {
        let _ = self.ctx.set_value(name.into(), Value::Float(v));
    }
}

impl Expr {
    /// Compiles `src` for the key `key` of `file`; `allow_c` admits the variable `c`.
    pub fn compile(file: &str, key: &str, src: &ExprSrc, allow_c: bool) -> Result<Self> {
        let text = match src {
            ExprSrc::Number(v) => {
                return Ok(Self {
                    source: format!("{v}"),
                    kind: Kind::Constant(*v),
                })
            }
            ExprSrc::Text(t) => t.clone(),
        };
        check_size(&text).map_err(|m| Error::at(file, key, m))?;
        let tree = evalexpr::build_operator_tree::<DefaultNumericTypes>(&floatify(&text))
            .map_err(|e| Error::at(file, key, format!("bad expression `{text}`: {e}")))?;
        let allowed: &[&str] = if allow_c {
            &["x", "y", "z", "pi", "c"]
        } else {
            &["x", "y", "z", "pi"]
        };
        if let Some(v) = tree
            .iter_variable_identifiers()
            .find(|v| !allowed.contains(v))
        {
            return Err(Error::at(
                file,
                key,
                format!(
                    "unknown variable `{v}` in `{text}`: allowed {}",
                    allowed.join(", ")
                ),
            ));
        }
        Ok(Self {
            source: text,
            kind: Kind::Tree(Box::new(tree)),
        })
    }

    /// The expression as written.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The constant value, if the expression is a plain number.
    pub fn constant(&self) -> Option<f64> {
        match self.kind {
            Kind::Constant(v) => Some(v),
            Kind::Tree(_) => None,
        }
    }

    /// Value at the point `p = (x, y, z)` with volume fraction `c`. An evaluation error (a
    /// boolean result, an unknown function) is a scene error naming `key`.
    pub fn eval(&self, vars: &mut Vars, p: [f64; 3], c: f64, file: &str, key: &str) -> Result<f64> {
        let tree = match &self.kind {
            Kind::Constant(v) => return Ok(*v),
            Kind::Tree(t) => t,
        };
        vars.set("x", p[0]);
        vars.set("y", p[1]);
        vars.set("z", p[2]);
        vars.set("c", c);
        let v = tree
            .eval_with_context(&vars.ctx)
            .map_err(|e| Error::at(file, key, format!("cannot evaluate `{}`: {e}", self.source)))?;
        match v {
            Value::Float(f) => Ok(f),
            Value::Int(i) => Ok(i as f64),
            other => Err(Error::at(
                file,
                key,
                format!("`{}` gives {other:?}, not a number", self.source),
            )),
        }
    }
}

/// Longest expression accepted, in bytes. The longest in the built-in scenes is under 60; a
/// physics formula that needs more belongs in several keys or a field file.
pub const MAX_EXPR_BYTES: usize = 1024;
/// Deepest nesting of parentheses accepted.
pub const MAX_EXPR_DEPTH: usize = 32;
/// Most operators (binary and unary, and argument commas) in one expression.
pub const MAX_EXPR_OPERATORS: usize = 256;

/// Bounds an expression before evalexpr sees it (issue 10): evalexpr builds and evaluates its
/// tree recursively, so 40,000 `+0` terms or 50,000 nested parentheses overflowed the stack
/// (an abort, no message) and 100,000 unary minus signs took minutes to parse. With at most
/// [`MAX_EXPR_OPERATORS`] operators and [`MAX_EXPR_DEPTH`] levels of parentheses, no tree is
/// deeper than a few hundred nodes, whatever the text. The scan itself is one loop: it never
/// recurses.
pub fn check_size(text: &str) -> std::result::Result<(), String> {
    if text.len() > MAX_EXPR_BYTES {
        return Err(format!(
            "the expression is {} bytes long: allowed at most {MAX_EXPR_BYTES}; shorten it (e.g. define the field in fewer terms)",
            text.len()
        ));
    }
    let (mut depth, mut deepest, mut ops) = (0usize, 0usize, 0usize);
    let mut in_string = false;
    for ch in text.chars() {
        match ch {
            '"' => in_string = !in_string,
            _ if in_string => {}
            '(' => {
                depth += 1;
                deepest = deepest.max(depth);
            }
            ')' => depth = depth.saturating_sub(1),
            '+' | '-' | '*' | '/' | '%' | '^' | '<' | '>' | '=' | '!' | '&' | '|' | ',' | ';' => {
                ops += 1
            }
            _ => {}
        }
    }
    if deepest > MAX_EXPR_DEPTH {
        return Err(format!(
            "the expression nests parentheses {deepest} deep: allowed at most {MAX_EXPR_DEPTH}; remove redundant parentheses"
        ));
    }
    if ops > MAX_EXPR_OPERATORS {
        return Err(format!(
            "the expression has {ops} operators: allowed at most {MAX_EXPR_OPERATORS}; simplify it"
        ));
    }
    Ok(())
}

/// Rewrites integer literals as floats (`2` -> `2.0`), leaving identifiers (`x1`), floats
/// (`2.5`, `1e3`) and string literals alone.
pub fn floatify(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = String::with_capacity(s.len() + 8);
    let mut i = 0;
    let mut in_string = false;
    while i < b.len() {
        let ch = b[i];
        if ch == b'"' {
            in_string = !in_string;
        }
        let starts_number = !in_string
            && ch.is_ascii_digit()
            && (i == 0
                || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_' || b[i - 1] == b'.'));
        if !starts_number {
            out.push(ch as char);
            i += 1;
            continue;
        }
        let start = i;
        let digits = |i: &mut usize| {
            while *i < b.len() && b[*i].is_ascii_digit() {
                *i += 1;
            }
        };
        digits(&mut i);
        let mut is_integer = true;
        if i < b.len() && b[i] == b'.' {
            is_integer = false;
            i += 1;
            digits(&mut i);
        }
        if i < b.len() && (b[i] == b'e' || b[i] == b'E') {
            // An exponent makes a float; its sign must not start a new "number".
            let mut j = i + 1;
            if j < b.len() && (b[j] == b'+' || b[j] == b'-') {
                j += 1;
            }
            if j < b.len() && b[j].is_ascii_digit() {
                is_integer = false;
                i = j;
                digits(&mut i);
            }
        }
        out.push_str(&s[start..i]);
        let glued = matches!(b.get(i), Some(n) if *n == b'_' || n.is_ascii_alphanumeric());
        if is_integer && !glued {
            out.push_str(".0");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_literals_become_floats() {
        assert_eq!(floatify("1/2"), "1.0/2.0");
        assert_eq!(floatify("0.5*z^2 + x1"), "0.5*z^2.0 + x1");
        assert_eq!(
            floatify("1e3 + 2.5 - 1e-3 + 3E+2"),
            "1e3 + 2.5 - 1e-3 + 3E+2"
        );
        assert_eq!(floatify("math::pow(z, 3)"), "math::pow(z, 3.0)");
    }

    #[test]
    fn evaluates_with_variables() {
        let e = Expr::compile("f", "k", &ExprSrc::Text("if(z < 1/2, c, 0)".into()), true).unwrap();
        let mut v = Vars::new();
        assert_eq!(
            e.eval(&mut v, [0.0, 0.0, 0.25], 0.6, "f", "k").unwrap(),
            0.6
        );
        assert_eq!(
            e.eval(&mut v, [0.0, 0.0, 0.75], 0.6, "f", "k").unwrap(),
            0.0
        );
    }

    #[test]
    fn transcendental_functions_use_libm() {
        let e = Expr::compile(
            "f",
            "k",
            &ExprSrc::Text("math::exp(z) + math::pow(z, 3) + math::log(8, 2)".into()),
            false,
        )
        .unwrap();
        let v = e
            .eval(&mut Vars::new(), [0.0, 0.0, 0.3], 0.0, "f", "k")
            .unwrap();
        let want = libm::exp(0.3) + libm::pow(0.3, 3.0) + libm::log(8.0) / libm::log(2.0);
        assert_eq!(v.to_bits(), want.to_bits());
    }

    /// The inputs that once aborted or hung now give one line naming the key and the limit,
    /// and the largest expressions within the limits compile and evaluate.
    #[test]
    fn hostile_expressions_are_bounded() {
        let compile = |t: String| Expr::compile("s.toml", "initial.phi", &ExprSrc::Text(t), true);
        let cases = [
            (
                "0".to_string() + &"+0".repeat(40_000),
                "allowed at most 1024",
            ),
            (
                "(".repeat(50_000) + "1" + &")".repeat(50_000),
                "allowed at most 1024",
            ),
            ("-".repeat(100_000) + "1", "allowed at most 1024"),
            (
                "(".repeat(33) + "1" + &")".repeat(33),
                "nests parentheses 33 deep",
            ),
            ("1".to_string() + &"+1".repeat(257), "257 operators"),
        ];
        for (text, want) in cases {
            let t0 = std::time::Instant::now();
            let e = compile(text).unwrap_err().to_string();
            assert!(t0.elapsed().as_secs_f64() < 1.0, "{e}");
            assert!(e.starts_with("s.toml: initial.phi: "), "{e}");
            assert!(e.contains(want), "{e}");
            assert_eq!(e.lines().count(), 1);
        }
        // At the limits: 256 operators, 32 levels, 1024 bytes (nested) evaluate exactly.
        let sum = "1".to_string() + &"+1".repeat(256);
        let v = compile(sum).unwrap();
        let mut vars = Vars::new();
        assert_eq!(v.eval(&mut vars, [0.0; 3], 0.0, "f", "k").unwrap(), 257.0);
        let nested = "(".repeat(32) + "z" + &")".repeat(32);
        let v = compile(nested).unwrap();
        assert_eq!(
            v.eval(&mut vars, [0.0, 0.0, 0.25], 0.0, "f", "k").unwrap(),
            0.25
        );
        let minus = "-".repeat(256) + "z";
        let v = compile(minus).unwrap();
        assert_eq!(
            v.eval(&mut vars, [0.0, 0.0, 0.5], 0.0, "f", "k").unwrap(),
            0.5
        );
        let long = "z".to_string() + &" ".repeat(MAX_EXPR_BYTES - 1);
        assert!(compile(long).is_ok());
    }

    #[test]
    fn rejects_unknown_variables() {
        let e = Expr::compile("f", "initial.c", &ExprSrc::Text("c * 2".into()), false);
        assert!(e.unwrap_err().to_string().contains("unknown variable `c`"));
    }
}
