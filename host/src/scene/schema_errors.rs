//! serde's refusals of a scene file in the user's words: one line `file: key: message` that
//! says what is allowed first, then the value as written (`expected one of the words `given`
//! or `settled`, got 1`), where serde would say "invalid type: unit variant, expected string
//! only" or name Rust's types (docs/scene-file.md; asserted in host/tests/scene_words.rs).

use super::SceneFile;
use crate::error::Error;
use serde_path_to_error::{Path, Segment};

/// The one line for a refused table `root` (the scene as written, after the `--set`s).
pub fn worded(
    label: &str,
    root: &toml::Value,
    e: &serde_path_to_error::Error<toml::de::Error>,
) -> Error {
    let path = e.path().to_string();
    let key = if path == "." { String::new() } else { path };
    let msg = without_key_suffix(e.inner().to_string());
    let msg = match value_at(root, e.path()) {
        Some(given) => in_user_words(&msg, given, || allowed_words(root, e.path())),
        None => msg,
    };
    Error::at(label, &key, plain_types(&msg))
}

/// toml appends " in `key`" to some messages; the key is already named in front.
fn without_key_suffix(msg: String) -> String {
    let mut msg = msg.trim_end().to_string();
    if let Some(cut) = msg
        .rfind("in `")
        .filter(|&c| msg.ends_with('`') && msg[..c].ends_with(char::is_whitespace))
    {
        msg.truncate(cut);
    }
    msg.trim_end().to_string()
}

/// The value a serde path points at in the table as written (`None` where the path leaves it).
fn value_at<'v>(root: &'v toml::Value, path: &Path) -> Option<&'v toml::Value> {
    path.iter().try_fold(root, |node, seg| match seg {
        Segment::Map { key } => node.as_table()?.get(key),
        Segment::Seq { index } => node.as_array()?.get(*index),
        Segment::Enum { .. } | Segment::Unknown => None,
    })
}

/// The words a one-of key accepts, as serde lists them (`` `given` or `settled` ``): found by
/// deserialising once more with a word no key accepts in the place of the bad value. serde says
/// only "invalid type: unit variant, expected string only" when a one-of key gets a number or a
/// list, so without this a user would not learn what to write.
fn allowed_words(root: &toml::Value, path: &Path) -> Option<String> {
    const PROBE: &str = "\u{7f}";
    let mut probe = root.clone();
    let mut node = &mut probe;
    for seg in path {
        node = match seg {
            Segment::Map { key } => node.as_table_mut()?.get_mut(key)?,
            Segment::Seq { index } => node.as_array_mut()?.get_mut(*index)?,
            _ => return None,
        };
    }
    *node = toml::Value::String(PROBE.into());
    let err = serde_path_to_error::deserialize::<_, SceneFile>(probe).err()?;
    let msg = err.inner().to_string();
    let rest = msg.strip_prefix(&format!("unknown variant `{PROBE}`, expected "))?;
    (err.path().to_string() == path.to_string()).then(|| without_key_suffix(rest.to_string()))
}

/// serde's "invalid type: boolean `true`, expected a number" and "unknown variant `x`,
/// expected `a` or `b`" rewritten as "expected a number, got true": what is allowed first, then
/// what was written, quoted from the table (hostile-inputs: errors in the user's words).
fn in_user_words(
    msg: &str,
    given: &toml::Value,
    allowed: impl FnOnce() -> Option<String>,
) -> String {
    let got = describe(given);
    // serde lists one word as "`a`", two as "`a` or `b`" and more as "one of `a`, `b`, `c`".
    let words = |w: &str| match w.strip_prefix("one of ") {
        Some(list) => format!("one of the words {list}"),
        None if w.contains(" or ") => format!("one of the words {w}"),
        None => format!("the word {w}"),
    };
    if msg.starts_with("invalid type: unit variant, expected string only") {
        return match allowed() {
            Some(w) => format!("expected {}, got {got}", words(&w)),
            None => format!("expected a word in quotes, got {got}"),
        };
    }
    if let Some(rest) = msg.strip_prefix("unknown variant `") {
        if let Some((_, w)) = rest.split_once("`, expected ") {
            return format!("expected {}, got {got}", words(w));
        }
    }
    for kind in ["invalid type: ", "invalid value: "] {
        if let Some((_, expected)) = msg
            .strip_prefix(kind)
            .and_then(|rest| rest.split_once(", expected "))
        {
            return format!("expected {expected}, got {got}");
        }
    }
    msg.to_string()
}

/// A value as the user wrote it, in a few words: numbers, words and true/false verbatim (long
/// text cut), lists and tables by their kind.
fn describe(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) if s.chars().count() > 40 => {
            format!("{:?}...", s.chars().take(40).collect::<String>())
        }
        toml::Value::String(s) => format!("{s:?}"),
        toml::Value::Integer(i) => i.to_string(),
        toml::Value::Float(x) => x.to_string(),
        toml::Value::Boolean(b) => b.to_string(),
        toml::Value::Datetime(d) => format!("the date {d}"),
        toml::Value::Array(a) if a.is_empty() => "an empty list".into(),
        toml::Value::Array(_) => "a list".into(),
        toml::Value::Table(_) => "a table".into(),
    }
}

/// serde names Rust's types (`expected f64`); a user reads "a number".
fn plain_types(msg: &str) -> String {
    let mut out = msg.to_string();
    for (rust, user) in [
        ("expected f64", "expected a number"),
        ("expected f32", "expected a number"),
        ("expected usize", "expected a whole number"),
        ("expected u64", "expected a whole number"),
        ("expected u32", "expected a whole number"),
        ("expected i64", "expected a whole number"),
        ("expected an array", "expected a list"),
        ("expected a sequence", "expected a list"),
    ] {
        out = out.replace(rust, user);
    }
    out
}
