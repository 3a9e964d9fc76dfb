//! How quickly `kin lsp` answers after an edit of `examples/milling_5axis.kin` (173
//! coefficients). The target: diagnostics and a hover within 50 ms of an edit.
//!
//! `cargo bench --bench lsp` (add `-- --warm-up-time 1 --measurement-time 3` for a quick run).
//! The server is the real binary spoken to over a pipe, as an editor speaks to it:
//! - `edit_to_diagnostics`: `didChange` with the whole text (one comment edited) until the
//!   diagnostics of that version arrive (compiled and checked, identifiability not yet);
//! - `edit_to_hover`: the same edit, then a hover on a family call, until its answer;
//! - `identifiability`: the same edit until the second diagnostics (with the identifiability
//!   warnings), which the server holds back for a 300 ms quiet period: the figure minus 300 ms
//!   is the analysis itself.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use serde_json::{json, Value};

struct Server {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    id: i64,
    version: i64,
}

const URI: &str = "file:///bench/milling_5axis.kin";

impl Server {
    fn start(text: &str) -> Server {
        let mut child = Command::new(env!("CARGO_BIN_EXE_kin"))
            .arg("lsp")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("kin lsp: {e}"));
        let stdin = child.stdin.take().unwrap_or_else(|| panic!("stdin"));
        let stdout = BufReader::new(child.stdout.take().unwrap_or_else(|| panic!("stdout")));
        let mut s = Server {
            child,
            stdin,
            stdout,
            id: 0,
            version: 1,
        };
        s.request("initialize", json!({"processId": null, "capabilities": {}}));
        s.send(&json!({"jsonrpc": "2.0", "method": "initialized", "params": {}}));
        s.send(
            &json!({"jsonrpc": "2.0", "method": "textDocument/didOpen", "params": {
            "textDocument": {"uri": URI, "languageId": "kin", "version": 1, "text": text}}}),
        );
        s.diagnostics(1, 2);
        s
    }

    fn send(&mut self, msg: &Value) {
        let body = msg.to_string();
        let _ = write!(self.stdin, "Content-Length: {}\r\n\r\n{body}", body.len());
        let _ = self.stdin.flush();
    }

    fn receive(&mut self) -> Value {
        let mut length = 0;
        loop {
            let mut line = String::new();
            if self.stdout.read_line(&mut line).unwrap_or(0) == 0 {
                panic!("kin lsp closed its output");
            }
            let line = line.trim_end();
            if line.is_empty() {
                break;
            }
            if let Some(v) = line.strip_prefix("Content-Length: ") {
                length = v.parse().unwrap_or(0);
            }
        }
        let mut body = vec![0; length];
        let _ = self.stdout.read_exact(&mut body);
        serde_json::from_slice(&body).unwrap_or(Value::Null)
    }

    fn request(&mut self, method: &str, params: Value) -> Value {
        self.id += 1;
        let id = self.id;
        self.send(&json!({"jsonrpc": "2.0", "id": id, "method": method, "params": params}));
        loop {
            let m = self.receive();
            if m["id"] == json!(id) {
                return m["result"].clone();
            }
        }
    }

    /// Waits for the `nth` diagnostics of `version`.
    fn diagnostics(&mut self, version: i64, nth: usize) {
        let mut seen = 0;
        while seen < nth {
            let m = self.receive();
            if m["method"] == "textDocument/publishDiagnostics" && m["params"]["version"] == version
            {
                seen += 1;
            }
        }
    }

    fn edit(&mut self, text: &str) -> i64 {
        self.version += 1;
        let v = self.version;
        // One comment edited: a different text each time, the same model.
        let edited = format!("{text}// edit {v}\n");
        self.send(
            &json!({"jsonrpc": "2.0", "method": "textDocument/didChange", "params": {
            "textDocument": {"uri": URI, "version": v},
            "contentChanges": [{"text": edited}]}}),
        );
        v
    }
}

fn bench(c: &mut Criterion) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/milling_5axis.kin");
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{e}"));
    let at = text.find("periodic(Y").unwrap_or(0);
    let line = text[..at].matches('\n').count();
    let character = at - text[..at].rfind('\n').map_or(0, |i| i + 1) + 2;
    let mut s = Server::start(&text);
    let mut g = c.benchmark_group("lsp_milling_5axis");
    g.bench_function("edit_to_diagnostics", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                let t = Instant::now();
                let v = s.edit(&text);
                s.diagnostics(v, 1);
                total += t.elapsed();
            }
            total
        })
    });
    g.bench_function("edit_to_hover", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                let t = Instant::now();
                s.edit(&text);
                let h = s.request(
                    "textDocument/hover",
                    json!({"textDocument": {"uri": URI},
                           "position": {"line": line, "character": character}}),
                );
                assert!(h["contents"]["value"]
                    .as_str()
                    .is_some_and(|v| v.contains("periodic")));
                total += t.elapsed();
            }
            total
        })
    });
    g.sample_size(10);
    g.bench_function("identifiability", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                let t = Instant::now();
                let v = s.edit(&text);
                s.diagnostics(v, 2);
                total += t.elapsed();
            }
            total
        })
    });
    g.finish();
    let _ = s.request("shutdown", Value::Null);
    s.send(&json!({"jsonrpc": "2.0", "method": "exit"}));
    let _ = s.child.wait();
}

criterion_group!(benches, bench);
criterion_main!(benches);
