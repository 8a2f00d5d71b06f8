//! Message hygiene (issue 10, "Messages"): what a user typed is echoed back short. A 1 MB scene
//! name or `--set` value is clipped to [`CLIP`] characters, and a number printed in full by
//! `{}` (`1e300` is 301 digits) is rewritten in the shortest exponent form (`{:e}`).
//!
//! A leaf: used by [`crate::error`] on every message it builds and by the command line on
//! clap's messages, so no caller has to remember it.

/// A number is rewritten in the exponent form only when that saves this many characters.
const SAVED: usize = 4;

/// Longest echoed word (characters) before it is clipped.
pub const CLIP: usize = 60;

/// `s` shortened for a message: every word that is a long number becomes `{:e}`
/// (`100000000000000000000000000` -> `1e26`), every word longer than [`CLIP`] characters keeps
/// its first [`CLIP`] characters plus `... (N chars)`. Words are separated by whitespace;
/// brackets and punctuation around a number stay in place.
pub fn shorten(s: &str) -> String {
    let mut out = String::with_capacity(s.len().min(4096));
    for (i, word) in s.split(' ').enumerate() {
        if i > 0 {
            out.push(' ');
        }
        out.push_str(&shorten_word(word));
    }
    out
}

/// Longest message (characters) before its tail is clipped.
pub const MAX_MESSAGE: usize = 2_000;

/// `s` with at most [`MAX_MESSAGE`] characters: the rest becomes `... (N chars)`. Words are
/// clipped one by one by [`shorten`]; this bounds their number (a `series.csv` with CR-only
/// line endings once echoed its whole 5 MB as the "header" of an error, in short words).
pub fn clip_message(s: &str) -> String {
    let n = s.chars().count();
    if n <= MAX_MESSAGE {
        return s.to_string();
    }
    let head: String = s.chars().take(MAX_MESSAGE).collect();
    format!("{head}... ({n} chars)")
}

fn shorten_word(word: &str) -> String {
    let word = short_numbers(word);
    let n = word.chars().count();
    if n <= CLIP + 16 {
        return word;
    }
    let head: String = word.chars().take(CLIP).collect();
    format!("{head}... ({n} chars)")
}

/// Rewrites each maximal run of number characters (`0-9 . e E + -`) that parses as a finite
/// f64 in the `{:e}` form (the shortest that reads back the same) when that form is at least
/// [`SAVED`] characters shorter: `{}` writes 1e-15 as `0.000000000000001` and 1e300 with 301
/// digits, while `0.0123` or `123456789` read better as they are.
fn short_numbers(word: &str) -> String {
    let is_num = |c: char| c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '+' | '-');
    if word.len() < 8 {
        return word.to_string();
    }
    let mut out = String::with_capacity(word.len());
    let mut run = String::new();
    let flush = |run: &mut String, out: &mut String| {
        match run.parse::<f64>() {
            Ok(x) if x.is_finite() && format!("{x:e}").len() + SAVED <= run.len() => {
                out.push_str(&format!("{x:e}"))
            }
            _ => out.push_str(run),
        }
        run.clear();
    };
    for c in word.chars() {
        if is_num(c) {
            run.push(c);
        } else {
            flush(&mut run, &mut out);
            out.push(c);
        }
    }
    flush(&mut run, &mut out);
    out
}

/// A number for a message: `{:e}` shortest form outside `1e-3 ..= 1e6`, plain `{}` inside.
pub fn num(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-3..=1e6).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// A number for a bound in a message, to 4 significant digits: `1.000e295` -> `1e295`,
/// `0.0123456` -> `0.01235`; plain `{}` when that is as short.
pub fn approx(x: f64) -> String {
    let plain = format!("{x}");
    if plain.len() <= 8 || !x.is_finite() {
        return plain;
    }
    let e = format!("{x:.3e}");
    match e.split_once('e') {
        Some((m, exp)) => {
            let m = m.trim_end_matches('0').trim_end_matches('.');
            format!("{m}e{exp}")
        }
        None => e,
    }
}
