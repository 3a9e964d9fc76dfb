//! The fuzz harnesses: one function per target, each feeding arbitrary bytes to the entry points
//! the `kin` command line and the C ABI use. A harness returns normally on every input the code
//! rejects with an error; a panic, an abort, a hang or runaway memory is the bug being looked for.
//! The same functions run under libFuzzer (`fuzz/fuzz_targets/*.rs`, nightly features through
//! cargo-fuzz) and on stable in `tests/fuzz_regressions.rs`, which replays every kept input.
//!
//! Beyond "no panic" the harnesses assert what the CLI relies on: diagnostics carry a label whose
//! spans lie inside the text on character boundaries, and a model compiles exactly when no
//! diagnostic is an error.

use std::path::Path;
use std::sync::OnceLock;

use kin_compiler::{bind_params, compile, Compiled, Diagnostic};
use kin_data::data::{self, Observations, ReadOptions};
use kin_estimate::simulate;
use kin_model::engine::Engine;
use kin_model::Model;

/// The CLI's diagnostic renderer, compiled in so that its output on odd spans is fuzzed too.
#[allow(dead_code)]
#[path = "../../src/render.rs"]
mod render;

mod capi;

pub use capi::capi;

/// Machines the data and report harnesses read files for: a CMM with inputs and a lag, a 5-axis
/// machine tool with a rotary table, and a revolute robot. Compiled once per process.
const MACHINES: [(&str, &str); 3] = [
    ("bridge_cmm", include_str!("../../examples/bridge_cmm.kin")),
    (
        "milling_5axis",
        include_str!("../../examples/milling_5axis.kin"),
    ),
    (
        "robot_6axis",
        include_str!("../../examples/robot_6axis.kin"),
    ),
];

fn machines() -> &'static [Compiled] {
    static COMPILED: OnceLock<Vec<Compiled>> = OnceLock::new();
    COMPILED.get_or_init(|| {
        MACHINES
            .iter()
            .map(|(name, source)| match compile(source).compiled {
                Some(mut c) => {
                    // As `kin`'s loader does for a machine without bound values.
                    if c.machine.beta.is_empty() {
                        c.machine.beta = vec![0.0; c.machine.coefficients.len()];
                    }
                    c
                }
                None => panic!("examples/{name}.kin does not compile"),
            })
            .collect()
    })
}

/// Checks what every consumer of diagnostics relies on, then renders them both ways the CLI does
/// (ariadne text and `--format json`).
fn diagnostics_hold(source: &str, diagnostics: &[Diagnostic], compiled: Option<bool>) {
    for d in diagnostics {
        assert!(
            !d.labels.is_empty(),
            "{} has no label: {}",
            d.code,
            d.message
        );
        for l in &d.labels {
            let s = l.span;
            assert!(
                s.start <= s.end && s.end <= source.len(),
                "{} span {}..{} outside the {}-byte text ({})",
                d.code,
                s.start,
                s.end,
                source.len(),
                d.message
            );
            assert!(
                source.is_char_boundary(s.start) && source.is_char_boundary(s.end),
                "{} span {}..{} splits a character ({})",
                d.code,
                s.start,
                s.end,
                d.message
            );
        }
    }
    if let Some(compiled) = compiled {
        let errors = diagnostics.iter().any(Diagnostic::is_error);
        assert!(
            compiled != errors,
            "compiled = {compiled} but errors = {errors}"
        );
    }
    let mut sink = Vec::new();
    render::human("fuzz.kin", source, diagnostics, false, &mut sink)
        .unwrap_or_else(|e| panic!("rendering to memory failed: {e}"));
    let json = render::json_diagnostics("fuzz.kin", source, diagnostics);
    serde_json::to_string(&json).unwrap_or_else(|e| panic!("diagnostics as JSON: {e}"));
}

/// `.kin` front end: the input (lossily UTF-8, as nothing else reaches the compiler) is a machine,
/// optionally followed by a NUL byte and a parameter file to bind on it (`--params P.params`).
pub fn kin_source(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let (source, params) = match text.split_once('\0') {
        Some((s, p)) => (s, Some(p)),
        None => (text.as_ref(), None),
    };
    let out = compile(source);
    diagnostics_hold(source, &out.diagnostics, Some(out.compiled.is_some()));
    if let (Some(mut compiled), Some(params)) = (out.compiled, params) {
        let diagnostics = bind_params(&mut compiled.machine, params);
        diagnostics_hold(params, &diagnostics, None);
    }
}

/// Measurement files: the first byte picks the machine (low four bits, modulo 3: bridge CMM,
/// 5-axis, robot) and the reader's options (0x10: a file of poses, as `kin eval` and
/// `kin simulate --poses` read it; 0x20: `--ignore note,operator`); the rest is the file. What reads is then evaluated as `kin eval`
/// does (with the interpreter, the reference engine).
pub fn measurement_csv(data: &[u8]) {
    let Some((&selector, bytes)) = data.split_first() else {
        return;
    };
    let compiled = machines();
    let Some(c) = compiled.get(usize::from(selector & 0x0f) % compiled.len()) else {
        return;
    };
    let options = ReadOptions {
        poses: selector & 0x10 != 0,
        ignore: if selector & 0x20 != 0 {
            vec!["note".into(), "operator".into()]
        } else {
            Vec::new()
        },
        // Detected from the header, so the fuzzer reaches every separator and quoting.
        delimiter: None,
        series: selector & 0x40 != 0,
        // One thread or a piece per 256 KiB, so that larger inputs reach the pieces' merge.
        threads: (selector & 0x80 != 0).then_some(1),
    };
    let m = &c.machine;
    match data::read(bytes, Path::new("fuzz.csv"), m, &options) {
        Ok(observations) => {
            // Every accepted row must be evaluable or rejected with an error.
            let _ = simulate::predict_with(m, &m.beta, &observations, [true; 6], Engine::Interp);
            let half: Vec<usize> = (0..observations.len()).step_by(2).collect();
            let _ = observations.select(&half);
        }
        Err(e) => {
            // The message names file, row and column; building it must not panic either.
            let _ = e.to_string();
        }
    }
}

/// A small machine (one axis, an input with a fitted lag): the JSON harness evaluates a FIT.json's
/// covariance against it, and its saved model recompiles quickly.
pub const TINY: &str = include_str!("tiny.kin");

fn tiny() -> Option<&'static Compiled> {
    static COMPILED: OnceLock<Option<Compiled>> = OnceLock::new();
    COMPILED.get_or_init(|| compile(TINY).compiled).as_ref()
}

/// Poses of the small machine, for the uncertainty `kin eval --uncertainty` computes from a
/// FIT.json's covariance.
const TINY_POSES: &str = "X[mm],T[degC],time[s]\n171.06,1.81,0\n0,0,60\n500,-3,120\n";

fn tiny_poses() -> Option<&'static Observations> {
    static POSES: OnceLock<Option<Observations>> = OnceLock::new();
    POSES
        .get_or_init(|| {
            let options = ReadOptions {
                poses: true,
                ignore: Vec::new(),
                delimiter: None,
                series: false,
                threads: None,
            };
            let m = &tiny()?.machine;
            data::read(TINY_POSES.as_bytes(), Path::new("poses.csv"), m, &options).ok()
        })
        .as_ref()
}

/// JSON files kin reads back: FIT.json (as `kin report --fit`, `kin eval --uncertainty` and
/// `--params FIT.json` read it), DIAGNOSE.json (`kin report --diagnose`) and a saved model
/// (`Model::from_json`, what `Model::load` and `kin_model_load` read). Every reader gets every
/// input.
pub fn fit_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        // Every reader takes a `&str` (the CLI's `read_to_string` stops at invalid UTF-8).
        return;
    };
    if let Ok(fit) = serde_json::from_str::<kin_estimate::fit::report::FitReport>(text) {
        if let (Some(c), Some(poses)) = (tiny(), tiny_poses()) {
            let m = &c.machine;
            let _ = fit.covariance_mismatch(m);
            let _ = simulate::uncertainty(m, &fit, poses, [true; 6], Engine::Interp);
        }
    }
    let _ = serde_json::from_str::<kin_diagnose::Diagnosis>(text);
    // `--params FIT.json`: the fitted values are the report's `params` text (src/load.rs).
    if let Some(params) = serde_json::from_str::<serde_json::Value>(text)
        .ok()
        .and_then(|v| v.get("params")?.as_str().map(str::to_string))
    {
        for c in tiny().into_iter().chain(machines().first()) {
            let mut machine = c.machine.clone();
            let diagnostics = bind_params(&mut machine, &params);
            diagnostics_hold(&params, &diagnostics, None);
        }
    }
    if let Ok(model) = Model::from_json(text) {
        // A model that loads saves again.
        if let Err(e) = model.to_json() {
            panic!("a loaded model does not save: {e}");
        }
    }
}

/// Robot descriptions `kin import` reads: every input as a URDF and as a DH table in both
/// conventions. What is imported must compile clean (kin wrote it), and a compiled import must
/// export again as URDF and, when it is one serial chain, as a DH table (`kin export`), whose
/// re-import compiles too.
pub fn robot_description(data: &[u8]) {
    use kin_standards::{dh, urdf};
    let Ok(text) = std::str::from_utf8(data) else {
        // `kin import` reads UTF-8 text and refuses anything else before parsing.
        return;
    };
    let options = urdf::Options::default();
    let mut imported = Vec::new();
    imported.extend(urdf::import(text, Path::new("robot.urdf"), &options).ok());
    for convention in [dh::Convention::Standard, dh::Convention::Modified] {
        imported.extend(dh::import(text, Path::new("robot.csv"), convention, &options).ok());
    }
    for i in imported {
        let out = compile(&i.source);
        let Some(c) = out.compiled else {
            panic!(
                "an imported model does not compile: {:?}\n{}",
                out.diagnostics, i.source
            );
        };
        if let Err(e) = urdf::export(&c.machine, "robot") {
            panic!("an imported model does not export as URDF: {e}");
        }
        if let Ok(table) = dh::export(&c.machine) {
            let text = dh::text(&table, &c.machine.name);
            let back = dh::import(
                &text,
                Path::new("back.csv"),
                dh::Convention::Standard,
                &options,
            )
            .unwrap_or_else(|e| panic!("an exported DH table does not import: {e}\n{text}"));
            if compile(&back.source).compiled.is_none() {
                panic!("a re-imported DH table does not compile:\n{}", back.source);
            }
        }
    }
}

/// The language server (`kin lsp`): one session fed a message stream after a fixed
/// `initialize` handshake. The input is split at NUL bytes into messages; each is framed with
/// its own correct `Content-Length`, except one that starts with `#`, whose remaining bytes go
/// to the server as they are (broken headers, wrong lengths, missing bodies). The identifiability
/// analysis is off ([`kin_lsp::Identify::Never`]): it evaluates the model at sampled poses and is
/// fuzzed through the model's own targets. The server must end (no hang), and everything it
/// writes must be framed JSON-RPC: `Content-Length` headers whose bodies are JSON objects with
/// `"jsonrpc": "2.0"`.
pub fn lsp(data: &[u8]) {
    const HANDSHAKE: [&str; 2] = [
        r#"{"jsonrpc":"2.0","id":0,"method":"initialize","params":{"capabilities":{}}}"#,
        r#"{"jsonrpc":"2.0","method":"initialized","params":{}}"#,
    ];
    let frame = |body: &[u8], out: &mut Vec<u8>| {
        out.extend_from_slice(format!("Content-Length: {}\r\n\r\n", body.len()).as_bytes());
        out.extend_from_slice(body);
    };
    let mut stream = Vec::with_capacity(data.len() + 256);
    for m in HANDSHAKE {
        frame(m.as_bytes(), &mut stream);
    }
    for message in data.split(|b| *b == 0) {
        match message.strip_prefix(b"#") {
            Some(raw) => stream.extend_from_slice(raw),
            None => frame(message, &mut stream),
        }
    }
    let mut written = Vec::new();
    // An input that ends before `shutdown` and `exit` is a closed connection: an `Err`, not a bug.
    let _ = kin_lsp::serve(stream.as_slice(), &mut written, kin_lsp::Identify::Never);
    let mut rest = written.as_slice();
    while !rest.is_empty() {
        let header_end = rest
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .unwrap_or_else(|| panic!("output without a header end: {:?}", clip(rest)));
        let header = std::str::from_utf8(&rest[..header_end])
            .unwrap_or_else(|e| panic!("a header that is not UTF-8: {e}"));
        let length: usize = header
            .strip_prefix("Content-Length: ")
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("a header that is not Content-Length: {header:?}"));
        let body = rest
            .get(header_end + 4..header_end + 4 + length)
            .unwrap_or_else(|| panic!("a body shorter than its Content-Length {length}"));
        let value: serde_json::Value = serde_json::from_slice(body)
            .unwrap_or_else(|e| panic!("a body that is not JSON ({e}): {:?}", clip(body)));
        assert_eq!(
            value.get("jsonrpc").and_then(|v| v.as_str()),
            Some("2.0"),
            "not a JSON-RPC message: {value}"
        );
        rest = &rest[header_end + 4 + length..];
    }
}

/// At most 200 bytes of an output, for a message.
fn clip(bytes: &[u8]) -> String {
    String::from_utf8_lossy(&bytes[..bytes.len().min(200)]).into_owned()
}
