//! The numbers the README (and docs/soft-sensor.md) state, read from the documents themselves,
//! so that a test asserts what the document says and editing one without the other fails
//! (issue 10, "Tests that hold the README's numbers").
//!
//! A stated number holds as many digits as were measured: `check` asserts that the computed
//! value rounds to the stated one (within half a unit of its last written digit). The runs
//! are bit-reproducible (README, "Determinism"), so this is exact, not flaky.
#![allow(dead_code)]

/// The README, as committed next to the tests.
pub fn readme() -> &'static str {
    include_str!("../../../README.md")
}

/// docs/soft-sensor.md.
pub fn soft_sensor_doc() -> &'static str {
    include_str!("../../../docs/soft-sensor.md")
}

/// `doc` with every run of whitespace (line breaks included) made one space, for markers in
/// wrapped prose.
pub fn prose(doc: &str) -> String {
    doc.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// The table row of `doc` whose first cell starts with `first_cell` (one row exactly).
pub fn table_row<'a>(doc: &'a str, first_cell: &str) -> &'a str {
    let key = format!("| {first_cell}");
    let rows: Vec<&str> = doc.lines().filter(|l| l.starts_with(&key)).collect();
    assert_eq!(
        rows.len(),
        1,
        "expected one table row starting with {key:?}"
    );
    rows[0]
}

/// The text of `s` after the first `marker` (which must be there).
pub fn after<'a>(s: &'a str, marker: &str) -> &'a str {
    let k = s
        .find(marker)
        .unwrap_or_else(|| panic!("{marker:?} not found in {s:?}"));
    &s[k + marker.len()..]
}

/// The text of `s` between `from` and the next `to`.
pub fn between<'a>(s: &'a str, from: &str, to: &str) -> &'a str {
    let rest = after(s, from);
    let k = rest
        .find(to)
        .unwrap_or_else(|| panic!("{to:?} not found after {from:?}"));
    &rest[..k]
}

/// A number as the document writes it.
#[derive(Clone, Debug)]
pub struct Stated {
    pub text: String,
    pub value: f64,
    /// Half a unit of the last written digit: the rounding of the measured value.
    pub half_unit: f64,
}

/// Every number in `s`, in order: `12,033`, `0.961`, `6.9e-16`, `2.0e-11`, `-3.5`. A comma
/// followed by three digits is a thousands separator; other characters end a number.
pub fn numbers(s: &str) -> Vec<Stated> {
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'));
        if !starts {
            i += 1;
            continue;
        }
        let neg = i > 0 && b[i - 1] == b'-' && (i == 1 || !b[i - 2].is_ascii_alphanumeric());
        let mut j = i;
        let mut mant = String::new();
        let mut decimals: i32 = 0;
        let mut in_frac = false;
        while j < b.len() {
            let ch = b[j];
            if ch.is_ascii_digit() {
                mant.push(ch as char);
                if in_frac {
                    decimals += 1;
                }
                j += 1;
            } else if ch == b'.' && !in_frac && j + 1 < b.len() && b[j + 1].is_ascii_digit() {
                in_frac = true;
                mant.push('.');
                j += 1;
            } else if ch == b','
                && !in_frac
                && b.len() >= j + 4
                && b[j + 1..j + 4].iter().all(u8::is_ascii_digit)
                && !b.get(j + 4).is_some_and(u8::is_ascii_digit)
            {
                j += 1; // thousands separator
            } else {
                break;
            }
        }
        let mut exp: i32 = 0;
        if j + 1 < b.len() && (b[j] == b'e' || b[j] == b'E') {
            let mut k = j + 1;
            let eneg = b[k] == b'-';
            if b[k] == b'-' || b[k] == b'+' {
                k += 1;
            }
            let s0 = k;
            while k < b.len() && b[k].is_ascii_digit() {
                k += 1;
            }
            if k > s0 {
                exp = s[s0..k].parse::<i32>().unwrap();
                if eneg {
                    exp = -exp;
                }
                j = k;
            }
        }
        let v: f64 = mant.parse::<f64>().unwrap() * 10f64.powi(exp);
        out.push(Stated {
            text: s[if neg { i - 1 } else { i }..j].to_string(),
            value: if neg { -v } else { v },
            half_unit: 0.5 * 10f64.powi(exp - decimals),
        });
        i = j;
    }
    out
}

/// The numbers of `s` between `from` and `to` (see [`numbers`]), exactly `n` of them.
pub fn stated(s: &str, from: &str, to: &str, n: usize) -> Vec<Stated> {
    let v = numbers(between(s, from, to));
    assert_eq!(
        v.len(),
        n,
        "expected {n} numbers between {from:?} and {to:?}: {v:?}"
    );
    v
}

/// Asserts that `computed` rounds to the stated number (what the document claims).
pub fn check(what: &str, computed: f64, stated: &Stated) {
    let tol = stated.half_unit * (1.0 + 1e-9) + 1e-300;
    println!("{what}: computed {computed:.6e}, stated {}", stated.text);
    assert!(
        (computed - stated.value).abs() <= tol,
        "{what}: computed {computed:e}, the document states {} (to +-{:e})",
        stated.text,
        stated.half_unit
    );
}

/// Asserts that `computed` is at most the stated bound (a claim "below X" / "within X").
pub fn check_at_most(what: &str, computed: f64, stated: &Stated) {
    println!(
        "{what}: computed {computed:.6e}, stated bound {}",
        stated.text
    );
    assert!(
        computed <= stated.value,
        "{what}: computed {computed:e} exceeds the stated {}",
        stated.text
    );
}
