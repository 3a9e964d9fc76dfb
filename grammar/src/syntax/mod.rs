//! Syntax: source text to a typed tree. Knows nothing of later stages.
pub mod ast;
pub(crate) mod parse;
mod recover;

pub use parse::{parse_file, parse_file_all, parse_params};

/// The words `grammar/kin.pest`'s `keyword` rule reserves: never a name of an axis, input, tool,
/// frame or parameter. One list for every tool that needs it (the language server's completion,
/// the URDF importer's renaming); a test keeps it equal to the grammar.
pub const KEYWORDS: [&str; 24] = [
    "machine",
    "params",
    "task",
    "units",
    "axis",
    "input",
    "tool",
    "workpiece",
    "chain",
    "errors",
    "prismatic",
    "revolute",
    "along",
    "about",
    "range",
    "continuous",
    "moving",
    "fixed",
    "at",
    "rot",
    "const",
    "fit",
    "measure",
    "position",
];

/// The unit words unit text is built from (`um/m/K`), for "did you mean" suggestions where a
/// unit was expected. The units themselves (dimensions, scales) are the compiler's
/// (`kin_compiler::units`), whose tests keep its atoms equal to this list.
pub const UNIT_WORDS: [&str; 21] = [
    "nm", "um", "mm", "m", "urad", "mrad", "rad", "deg", "arcsec", "s", "min", "h", "degC", "K",
    "N", "kN", "rev", "rpm", "W", "kW", "1",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_bridge_example() {
        let src = include_str!("../../../examples/bridge_cmm.kin");
        let file = parse_file(src).expect("parses");
        assert_eq!(file.machine.name.node, "bridge_cmm");
        assert_eq!(file.machine.items.len(), 10);
    }

    #[test]
    fn keywords_are_the_grammars() {
        let grammar = include_str!("../../../grammar/kin.pest");
        let rule = grammar
            .split("keyword = @{")
            .nth(1)
            .and_then(|r| r.split("~ !ident_char").next())
            .expect("the keyword rule");
        let mut words: Vec<&str> = rule.split('"').skip(1).step_by(2).collect();
        words.sort_unstable();
        let mut ours = KEYWORDS.to_vec();
        ours.sort_unstable();
        assert_eq!(words, ours);
        // And the parser refuses each as an axis name.
        for k in KEYWORDS {
            let src = format!("machine m {{ axis {k} prismatic along x }}");
            assert!(parse_file(&src).is_err(), "`{k}` accepted as a name");
        }
    }

    #[test]
    fn syntax_error_is_located() {
        let err = parse_file("machine m { axis X prismatic alongg x }").unwrap_err();
        assert_eq!(err.code, "E0001");
        assert_eq!(
            &"machine m { axis X prismatic alongg x }"
                [err.primary_span().start..err.primary_span().end],
            "alongg"
        );
    }
}
