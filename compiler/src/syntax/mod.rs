//! Syntax: source text to a typed tree. Knows nothing of later stages.
pub mod ast;
pub(crate) mod parse;
mod recover;

pub use parse::{parse_file, parse_file_all, parse_params};
pub use recover::MAX_SYNTAX_ERRORS;

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
