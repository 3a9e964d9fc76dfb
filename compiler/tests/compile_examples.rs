//! Every bundled example compiles without diagnostics, and the IR is consistent with itself.
use kin_compiler::compile;

#[test]
fn every_example_checks_clean() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples");
    let mut seen = 0;
    for entry in std::fs::read_dir(dir).expect("examples") {
        let path = entry.expect("entry").path();
        if path.extension().and_then(|e| e.to_str()) != Some("kin") {
            continue;
        }
        seen += 1;
        let src = std::fs::read_to_string(&path).expect("readable");
        let out = compile(&src);
        assert!(
            out.diagnostics.is_empty(),
            "{}: {:#?}",
            path.display(),
            out.diagnostics
        );
        let c = out.compiled.expect("compiled");
        let m = &c.machine;
        assert_eq!(m.coefficients.len(), c.map.coefficients.len());
        assert_eq!(m.errors.len(), c.map.errors.len());
        // Terms tile the coefficient vector exactly once.
        let mut covered = vec![0; m.coefficients.len()];
        for (e, model) in m.errors.iter().enumerate() {
            for t in &model.terms {
                let range = t.first..t.first + t.coefficients;
                for (count, c) in covered[range.clone()]
                    .iter_mut()
                    .zip(&m.coefficients[range])
                {
                    *count += 1;
                    assert_eq!(c.error, e);
                }
                let size: usize = t.factors.iter().map(|f| f.basis.size()).product();
                assert!(t.coefficients == 0 || t.coefficients == size);
            }
        }
        assert!(covered.iter().all(|&n| n == 1), "{}", path.display());
        assert!(!m.tools.is_empty());
    }
    assert!(seen >= 3);
}

/// Knot positions follow the variable: absolute for an absolute temperature, differences for a
/// temperature rise, whatever the knot's own unit text says.
#[test]
fn knots_of_temperature_inputs() {
    let src = |input: &str, knots: &str| {
        format!(
            "machine m {{ task position  axis X prismatic along x range 0 mm .. 500 mm  input T : temperature {input}
             tool chain {{ X moving  tool t }}  errors {{ X.tx = spline(T, knots at ({knots}) degC) }} }}"
        )
    };
    let ok = compile(&src("absolute range 15 degC .. 30 degC", "20, 25"));
    assert!(ok.diagnostics.is_empty(), "{:#?}", ok.diagnostics);
    let ok = compile(&src("rise range 0 degC .. 5 degC", "2.5"));
    assert!(ok.diagnostics.is_empty(), "{:#?}", ok.diagnostics);
    let bad = compile(&src("absolute range 15 degC .. 30 degC", "2.5"));
    assert_eq!(
        bad.diagnostics.first().map(|d| d.code),
        Some("E0301"),
        "2.5 °C is outside 15–30 °C"
    );
}
