//! Every bundled example compiles without diagnostics.
use kin_compiler::compile;

fn check(path: &str) -> kin_compiler::Compiled {
    let src = std::fs::read_to_string(path).expect("example readable");
    let out = compile(&src);
    assert!(out.diagnostics.is_empty(), "{path}: {:#?}", out.diagnostics);
    out.compiled.expect("compiled")
}

#[test]
fn bridge_cmm_checks_clean() {
    let c = check("../examples/bridge_cmm.kin");
    let m = &c.machine;
    assert_eq!(m.axes.len(), 3);
    assert_eq!(m.tools.len(), 2);
    assert_eq!(m.coefficients.len(), c.map.coefficients.len());
    for coef in &m.coefficients {
        eprintln!("{:12} {:10} {}", coef.name, coef.unit.name, coef.label);
    }
    eprintln!("{} coefficients; nonlinear {:?}", m.coefficients.len(), m.nonlinear);
}
