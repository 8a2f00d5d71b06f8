//! A one-of key of the scene format answers a wrong value with the words it accepts and the
//! value as written, whatever the value's type (hostile-inputs: errors in the user's words).
//! serde alone says "invalid type: unit variant, expected string only" to a number, and
//! "unknown variant `a`" to a table: neither tells a user what to write.

/// Every one-of key, a scene that has its table, and the words it accepts as the message
/// lists them. A new variant fails this test until it is listed here.
const KEYS: &[(&str, &str, &str)] = &[
    (
        "silo",
        "model.equations",
        "one of the words `prescribed`, `frozen-flow`, `coupled`",
    ),
    ("silo", "model.precision", "one of the words `f64` or `f32`"),
    (
        "silo",
        "model.back_coupling",
        "one of the words `off`, `r0`, `half`",
    ),
    (
        "silo",
        "initial.fill",
        "one of the words `given` or `settled`",
    ),
    (
        "silo",
        "flow.pressure",
        "one of the words `explicit` or `implicit`",
    ),
    ("silo", "flow.spin_up", "one of the words `auto` or `full`"),
    (
        "silo",
        "flow.stress",
        "one of the words `spec` or `objective`",
    ),
    (
        "silo",
        "boundary.flow.z_low.outlet.pressure",
        "one of the words `zero` or `zero-gradient`",
    ),
    (
        "chute",
        "boundary.flow.z_low.wall",
        "one of the words `no-slip`, `slip`, `friction`",
    ),
    (
        "column-a",
        "physics.temperature",
        "one of the words `given` or `shear`",
    ),
    (
        "column-a",
        "numerics.scheme",
        "one of the words `modified`, `godunov`, `upwind`",
    ),
    (
        "column-a",
        "numerics.phase",
        "one of the words `small` or `large`",
    ),
    (
        "column-a",
        "numerics.transport",
        "one of the words `donor` or `limited`",
    ),
    ("column-a", "run.exact", "the word `column-a`"),
    (
        "tumbler",
        "frame.kind",
        "one of the words `lab` or `rotating`",
    ),
    (
        "tumbler",
        "geometry.shape",
        "one of the words `drum`, `square-drum`, `drum-baffle`, `hopper`",
    ),
];

/// Values of every TOML type, none of them an accepted word, and how the message quotes them.
const VALUES: &[(&str, &str)] = &[
    ("1", "1"),
    ("-2.5", "-2.5"),
    ("true", "true"),
    ("[1]", "a list"),
    ("[]", "an empty list"),
    ("{a = 1}", "a table"),
    ("\"nope\"", "\"nope\""),
    ("1979-05-27", "the date 1979-05-27"),
];

#[test]
fn one_of_keys_list_their_words_and_quote_the_value_for_every_type() {
    for (scene, key, words) in KEYS {
        for (value, quoted) in VALUES {
            let set = format!("{key}={value}");
            let err = sieve::scene::load(scene, std::slice::from_ref(&set))
                .expect_err(&set)
                .to_string();
            assert_eq!(
                err,
                format!("scenes/{scene}.toml: {key}: expected {words}, got {quoted}"),
                "--set {set} on {scene}"
            );
        }
    }
}

#[test]
fn a_word_in_a_list_and_a_number_list_name_the_element() {
    // `boundary.z` is a pair of words: the bad element is named by its index.
    let err = sieve::scene::load("column-a", &["boundary.z=[1, \"wall\"]".into()])
        .expect_err("a number as a boundary kind")
        .to_string();
    assert_eq!(
        err,
        "scenes/column-a.toml: boundary.z[0]: expected one of the words `wall`, `inflow`, `outflow`, `periodic`, got 1"
    );
    // An outlet's width: a number or one per axis along the side (was "data did not match any
    // variant of untagged enum Coords").
    let err = sieve::scene::load("silo", &["boundary.flow.z_low.outlet.width=\"x\"".into()])
        .expect_err("a word as a width")
        .to_string();
    assert_eq!(
        err,
        "scenes/silo.toml: boundary.flow.z_low.outlet.width: expected a number or a list of numbers, one per axis along the side, got \"x\""
    );
    let err = sieve::scene::load("silo", &["boundary.flow.z_low.outlet.width=[\"x\"]".into()])
        .expect_err("a word in the width's list")
        .to_string();
    assert_eq!(
        err,
        "scenes/silo.toml: boundary.flow.z_low.outlet.width[0]: expected a number, got \"x\""
    );
    let err = sieve::scene::load("column-a", &["boundary.z=1".into()])
        .expect_err("a number as the pair")
        .to_string();
    assert_eq!(
        err,
        "scenes/column-a.toml: boundary.z: expected a list of length 2, got 1"
    );
    let err = sieve::scene::load("column-a", &["run.t_end=\"soon\"".into()])
        .expect_err("a word as a time")
        .to_string();
    assert_eq!(
        err,
        "scenes/column-a.toml: run.t_end: expected a number, got \"soon\""
    );
}

/// A `--set` value with a newline and another assignment in it is one value, not two: the
/// assignment after the newline was once dropped without a word (exit 0), though an unknown
/// key is an error.
#[test]
fn a_set_value_with_a_newline_is_refused_whole() {
    let err = sieve::scene::load("column-b", &["material.s0=2\nbogus=7".into()])
        .expect_err("a number followed by a hidden assignment");
    assert_eq!(err.exit_code(), 2);
    let text = err.to_string();
    assert!(text.contains("material.s0"), "{text}");
    assert_eq!(text.lines().count(), 1, "{text}");
    // The single value still parses as before.
    sieve::scene::load("column-b", &["material.s0=2".into()]).expect("a number");
}
