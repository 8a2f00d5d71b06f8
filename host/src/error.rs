//! The one error type of the host crate and its exit codes.
//!
//! Bad input (a scene the user can fix) exits with code 2 and one line per problem naming the
//! file, the key and the allowed range; anything else (I/O, a failed thread) exits with code 1.

use std::fmt;

/// Why a command failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// The input is wrong (exit code 2). The text is one line per problem, without the
    /// `error: ` prefix.
    Input(String),
    /// Anything else: I/O, plotting, an internal failure (exit code 1).
    Failure(String),
    /// Stopped by SIGINT or SIGTERM (exit code 130 or 143, `code`); the message says what was
    /// kept.
    Interrupted {
        /// 128 + the signal number.
        code: i32,
        /// One line.
        message: String,
    },
    /// The run failed numerically: a non-finite time step or state (exit code 3).
    Numerical(String),
}

/// Result alias of the host crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Bad input in `file` at `key`: `file: key: message`.
    pub fn at(file: &str, key: &str, message: impl fmt::Display) -> Self {
        if key.is_empty() {
            Error::Input(one_line(&format!("{file}: {message}")))
        } else {
            Error::Input(one_line(&format!("{file}: {key}: {message}")))
        }
    }

    /// A value outside its allowed range: `file: key = value is out of range: allowed range`.
    pub fn range(file: &str, key: &str, value: impl fmt::Display, allowed: &str) -> Self {
        Error::Input(one_line(&format!(
            "{file}: {key} = {value} is out of range: allowed {allowed}"
        )))
    }

    /// Several problems as one error, one line each (exit code 2 if every one is bad input,
    /// else 1). One problem stays as it is.
    pub fn many(mut errors: Vec<Error>) -> Self {
        if errors.len() == 1 {
            return errors.remove(0);
        }
        let input = errors.iter().all(|e| matches!(e, Error::Input(_)));
        let text = errors
            .iter()
            .map(|e| e.to_string())
            .collect::<Vec<_>>()
            .join("\n");
        if input {
            Error::Input(text)
        } else {
            Error::Failure(text)
        }
    }

    /// The lines of the message (several for [`Error::many`]).
    pub fn lines(&self) -> impl Iterator<Item = &str> {
        match self {
            Error::Input(m) | Error::Failure(m) | Error::Numerical(m) => m.lines(),
            Error::Interrupted { message, .. } => message.lines(),
        }
    }

    /// Bad input as one line, without file or key (exit code 2).
    pub fn input(message: impl fmt::Display) -> Self {
        Error::Input(one_line(&message.to_string()))
    }

    /// A failure that is not the user's input (exit code 1).
    pub fn failure(message: impl fmt::Display) -> Self {
        Error::Failure(one_line(&message.to_string()))
    }

    /// An I/O failure on `path`.
    pub fn io(path: &std::path::Path, e: std::io::Error) -> Self {
        Error::failure(format!("{}: {e}", path.display()))
    }

    /// The process exit code: 2 for bad input, 3 for a numerical failure, 130/143 for
    /// SIGINT/SIGTERM, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input(_) => 2,
            Error::Failure(_) => 1,
            Error::Numerical(_) => 3,
            Error::Interrupted { code, .. } => *code,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Input(m) | Error::Failure(m) | Error::Numerical(m) => f.write_str(m),
            Error::Interrupted { message, .. } => f.write_str(message),
        }
    }
}

impl std::error::Error for Error {}

/// Scripts parse the message as one line: fold any line breaks a library put in; echo what
/// the user typed short ([`crate::text::shorten`]: long numbers as `1e300`, long words clipped).
fn one_line(s: &str) -> String {
    crate::text::clip_message(&crate::text::shorten(
        &s.split_whitespace().collect::<Vec<_>>().join(" "),
    ))
}

#[cfg(test)]
mod tests {
    /// Many short words are clipped as a whole: the message of a damaged file that echoes it
    /// stays a line, not megabytes (here, not in text.rs: text must not import error).
    #[test]
    fn a_message_of_many_short_words_is_clipped() {
        let long = "0,0.5,1 ".repeat(100_000);
        let m =
            super::Error::failure(format!("series.csv: unexpected header `{long}`")).to_string();
        assert_eq!(m.lines().count(), 1);
        assert!(
            m.chars().count() <= crate::text::MAX_MESSAGE + 30,
            "{}",
            m.len()
        );
        assert!(m.ends_with("... (800032 chars)"), "{}", &m[m.len() - 40..]);
        // A message within the bound is left as it is.
        assert_eq!(crate::text::clip_message("short"), "short");
    }
}
