#[test]
fn scratch() {
    let src = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/milling_5axis.kin")).unwrap();
    let m = kin_compiler::compile(&src).compiled.unwrap().machine;
    let model = kin_runtime::jit::compile(&m).unwrap();
    eprintln!("{:?}", model);
}
