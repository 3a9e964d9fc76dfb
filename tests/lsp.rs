//! `kin lsp` spoken to over stdio with JSON-RPC framing and `lsp-types` messages, as an editor
//! would: initialize, open, change, hover, definition, references, completion, symbols,
//! formatting, shutdown and exit.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use lsp_types::*;
use serde_json::{json, Value};

struct Client {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    next_id: i64,
    /// Notifications received while waiting for responses.
    notifications: Vec<Value>,
}

impl Client {
    fn start() -> Client {
        let mut child = Command::new(env!("CARGO_BIN_EXE_kin"))
            .arg("lsp")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("kin lsp starts: {e}"));
        let stdin = child.stdin.take().unwrap_or_else(|| panic!("stdin"));
        let stdout = BufReader::new(child.stdout.take().unwrap_or_else(|| panic!("stdout")));
        Client {
            child,
            stdin,
            stdout,
            next_id: 1,
            notifications: Vec::new(),
        }
    }

    fn send(&mut self, msg: &Value) {
        let body = msg.to_string();
        write!(self.stdin, "Content-Length: {}\r\n\r\n{body}", body.len())
            .unwrap_or_else(|e| panic!("write: {e}"));
        self.stdin.flush().unwrap_or_else(|e| panic!("flush: {e}"));
    }

    fn receive(&mut self) -> Value {
        let mut length = None;
        loop {
            let mut line = String::new();
            let n = self.stdout.read_line(&mut line).unwrap_or(0);
            assert!(n > 0, "the server closed its output");
            let line = line.trim_end();
            if line.is_empty() {
                break;
            }
            if let Some(v) = line.strip_prefix("Content-Length: ") {
                length = v.parse::<usize>().ok();
            }
        }
        let mut body = vec![0; length.unwrap_or_else(|| panic!("no Content-Length"))];
        self.stdout
            .read_exact(&mut body)
            .unwrap_or_else(|e| panic!("read: {e}"));
        serde_json::from_slice(&body).unwrap_or_else(|e| panic!("JSON: {e}"))
    }

    /// The whole response (`result` or `error`).
    fn response(&mut self, method: &str, params: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        self.send(&json!({"jsonrpc": "2.0", "id": id, "method": method, "params": params}));
        loop {
            let msg = self.receive();
            if msg.get("id") == Some(&json!(id)) {
                return msg;
            }
            self.notifications.push(msg);
        }
    }

    fn request(&mut self, method: &str, params: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        self.send(&json!({"jsonrpc": "2.0", "id": id, "method": method, "params": params}));
        loop {
            let msg = self.receive();
            if msg.get("id") == Some(&json!(id)) {
                assert!(msg.get("error").is_none(), "{method}: {msg}");
                return msg.get("result").cloned().unwrap_or(Value::Null);
            }
            self.notifications.push(msg);
        }
    }

    fn notify(&mut self, method: &str, params: Value) {
        self.send(&json!({"jsonrpc": "2.0", "method": method, "params": params}));
    }

    /// The next diagnostics published for `version` (earlier ones are skipped).
    fn diagnostics(&mut self, version: i32) -> PublishDiagnosticsParams {
        loop {
            let msg = if self.notifications.is_empty() {
                self.receive()
            } else {
                self.notifications.remove(0)
            };
            if msg.get("method") == Some(&json!("textDocument/publishDiagnostics")) {
                let p: PublishDiagnosticsParams =
                    serde_json::from_value(msg["params"].clone()).unwrap_or_else(|e| panic!("{e}"));
                if p.version == Some(version) {
                    return p;
                }
            }
        }
    }
}

fn pos(text: &str, needle: &str, plus: usize) -> Value {
    let at = text
        .find(needle)
        .unwrap_or_else(|| panic!("{needle} in text"))
        + plus;
    let line = text[..at].matches('\n').count();
    let start = text[..at].rfind('\n').map_or(0, |i| i + 1);
    let character = text[start..at].encode_utf16().count();
    json!({"line": line, "character": character})
}

#[test]
fn an_editor_session() {
    let uri = "file:///work/mill.kin";
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/milling_5axis.kin"
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    let mut c = Client::start();
    let init = c.request(
        "initialize",
        json!({"processId": null, "rootUri": null, "capabilities": {}}),
    );
    let caps: ServerCapabilities =
        serde_json::from_value(init["capabilities"].clone()).unwrap_or_else(|e| panic!("{e}"));
    assert!(caps.hover_provider.is_some() && caps.document_formatting_provider.is_some());
    assert_eq!(init["serverInfo"]["name"], "kin");
    c.notify("initialized", json!({}));
    c.notify(
        "textDocument/didOpen",
        json!({"textDocument": {"uri": uri, "languageId": "kin", "version": 1, "text": text}}),
    );
    let d = c.diagnostics(1);
    assert!(
        d.diagnostics
            .iter()
            .all(|d| d.severity != Some(DiagnosticSeverity::ERROR)),
        "{:?}",
        d.diagnostics
    );

    // An edit with a typo: the same code and span as `kin check` gives, in UTF-16 positions.
    let broken = text.replacen("Y.ry = spline(Y, knots 3)", "Y.ry = splin(Y, knots 3)", 1);
    assert_ne!(broken, text);
    c.notify(
        "textDocument/didChange",
        json!({"textDocument": {"uri": uri, "version": 2}, "contentChanges": [{"text": broken}]}),
    );
    let d = c.diagnostics(2);
    let expected = kin_compiler::compile(&broken).diagnostics;
    let first = expected
        .iter()
        .find(|d| d.is_error())
        .unwrap_or_else(|| panic!("an error"));
    let got = d
        .diagnostics
        .iter()
        .find(|d| d.severity == Some(DiagnosticSeverity::ERROR))
        .unwrap_or_else(|| panic!("{:?}", d.diagnostics));
    assert_eq!(got.code, Some(NumberOrString::String(first.code.into())));
    let start = pos(&broken, "splin(", 0);
    assert_eq!(
        serde_json::to_value(got.range.start).unwrap_or_default(),
        start
    );
    assert!(got.message.contains("spline"), "{}", got.message);

    // Back to the good text.
    c.notify(
        "textDocument/didChange",
        json!({"textDocument": {"uri": uri, "version": 3}, "contentChanges": [{"text": text}]}),
    );
    let _ = c.diagnostics(3);
    let doc = json!({"uri": uri});

    // Hover: an axis's range and unit; a family's formula and equation with its coefficients.
    let h = c.request(
        "textDocument/hover",
        json!({"textDocument": doc, "position": pos(&text, "axis A", 5)}),
    );
    let s = h["contents"]["value"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(
        s.contains("revolute") && s.contains("-120 deg .. 30 deg"),
        "{s}"
    );
    let h = c.request(
        "textDocument/hover",
        json!({"textDocument": doc, "position": pos(&text, "periodic(Y", 2)}),
    );
    let s = h["contents"]["value"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(s.contains("eq. 3.1") && s.contains("2 coefficients"), "{s}");

    // Definition and references of an axis used in a target and in terms.
    let at = pos(&text, "X.tx = spline(X", 0);
    let def = c.request(
        "textDocument/definition",
        json!({"textDocument": doc, "position": at}),
    );
    assert_eq!(def["range"]["start"], pos(&text, "axis X", 5));
    let refs = c.request(
        "textDocument/references",
        json!({"textDocument": doc, "position": at, "context": {"includeDeclaration": true}}),
    );
    let n = refs.as_array().map_or(0, Vec::len);
    assert!(n > 10, "{refs}");

    // Completion: families, options, names; components after a dot.
    let items = c.request(
        "textDocument/completion",
        json!({"textDocument": doc, "position": pos(&text, "errors {", 8)}),
    );
    let labels: Vec<&str> = items
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|i| i["label"].as_str())
        .collect();
    for want in ["spline", "fourier", "knots", "T_spindle", "spindle", "A"] {
        assert!(labels.contains(&want), "{want} in {labels:?}");
    }
    let items = c.request(
        "textDocument/completion",
        json!({"textDocument": doc, "position": pos(&text, "Y.ty = spline", 2)}),
    );
    let labels: Vec<&str> = items
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|i| i["label"].as_str())
        .collect();
    assert_eq!(labels, ["tx", "ty", "tz", "rx", "ry", "rz"]);

    // The outline.
    let syms = c.request("textDocument/documentSymbol", json!({"textDocument": doc}));
    let machine = &syms[0];
    assert_eq!(machine["name"], "milling_5axis");
    let names: Vec<&str> = machine["children"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|s| s["name"].as_str())
        .collect();
    for want in [
        "Y",
        "C",
        "T_spindle",
        "tool chain",
        "workpiece chain",
        "errors",
    ] {
        assert!(names.contains(&want), "{want} in {names:?}");
    }

    // Formatting: the example is formatted already; a messy version gets kin fmt's text.
    let f = c.request(
        "textDocument/formatting",
        json!({"textDocument": doc, "options": {"tabSize": 4, "insertSpaces": true}}),
    );
    assert_eq!(f, json!([]));
    let messy = text.replacen("    axis A", "axis    A", 1);
    c.notify(
        "textDocument/didChange",
        json!({"textDocument": {"uri": uri, "version": 4}, "contentChanges": [{"text": messy}]}),
    );
    let f = c.request(
        "textDocument/formatting",
        json!({"textDocument": doc, "options": {"tabSize": 4, "insertSpaces": true}}),
    );
    assert_eq!(f[0]["newText"].as_str(), Some(text.as_str()));

    // Identifiability findings arrive after a quiet moment: a model whose terms the observations
    // cannot tell apart.
    let twins = "machine m {\n    task position\n    axis X prismatic along x range 0 mm .. 100 mm\n    tool chain {\n        X moving\n        tool t\n    }\n    workpiece chain {\n        workpiece\n    }\n    errors {\n        X.tx = linear(X)\n        tool.tx = linear(X)\n    }\n}\n";
    c.notify(
        "textDocument/didChange",
        json!({"textDocument": {"uri": uri, "version": 5}, "contentChanges": [{"text": twins}]}),
    );
    let first = c.diagnostics(5);
    let later = c.diagnostics(5);
    assert!(
        first.diagnostics.len() < later.diagnostics.len(),
        "{:?}",
        later.diagnostics
    );
    // `kin check` reports coefficients that cannot be told apart as E0601.
    let e0601 = Some(NumberOrString::String("E0601".into()));
    assert!(first.diagnostics.iter().all(|d| d.code != e0601));
    assert!(
        later.diagnostics.iter().any(|d| d.code == e0601),
        "{:?}",
        later.diagnostics
    );

    // Bad input is answered with an error, or skipped, and the session goes on.
    c.notify("textDocument/didOpen", json!({"nonsense": true}));
    let r = c.response(
        "textDocument/hover",
        json!({"textDocument": {"uri": "file:///nowhere.kin"}, "position": {"line": 0, "character": 0}}),
    );
    assert!(
        r["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("not open")),
        "{r}"
    );
    let r = c.response("kin/unknown", json!({}));
    assert_eq!(r["error"]["code"], json!(-32601), "{r}");
    let r = c.response("textDocument/hover", json!({"textDocument": 5}));
    assert_eq!(r["error"]["code"], json!(-32602), "{r}");
    let h = c.request(
        "textDocument/hover",
        json!({"textDocument": doc, "position": {"line": 100000, "character": 99999}}),
    );
    assert_eq!(h, Value::Null);

    let _ = c.request("shutdown", Value::Null);
    c.notify("exit", Value::Null);
    let status = c.child.wait().unwrap_or_else(|e| panic!("{e}"));
    assert!(status.success());
}
