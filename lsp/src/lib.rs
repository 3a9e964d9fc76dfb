//! `kin lsp`: a Language Server Protocol server for `.kin` files.
//!
//! [`run`] serves an editor on standard input and output; [`serve`] serves any pair of byte
//! streams (a socket, a test's buffers, the fuzz target's input). One thread reads messages in
//! order through a bounded, forgiving framing (`transport`); documents are synchronised
//! whole (`TextDocumentSyncKind::FULL`). After each change the document is compiled and its
//! diagnostics published at once; the identifiability analysis, which evaluates the model at
//! sampled poses, runs only once the document has been left alone for a quiet period
//! ([`Identify`]), and its warnings are published then (a newer edit cancels the pending run).
//! The answers themselves are the pure functions of `analysis`.

mod analysis;
mod transport;

use std::collections::HashMap;
use std::io::{BufRead, Write};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use kin_compiler::{compile, Compiled};
use lsp_server::{Connection, ErrorCode, Message, Notification, Request, Response};
use lsp_types::notification::{
    DidChangeTextDocument, DidCloseTextDocument, DidOpenTextDocument, Notification as _,
    PublishDiagnostics,
};
use lsp_types::request::{
    Completion, DocumentSymbolRequest, Formatting, GotoDefinition, HoverRequest, References,
    Request as _,
};
use lsp_types::{
    CompletionOptions, CompletionResponse, DocumentSymbolResponse, GotoDefinitionResponse,
    HoverProviderCapability, Location, OneOf, PublishDiagnosticsParams, ServerCapabilities,
    ServerInfo, TextDocumentSyncCapability, TextDocumentSyncKind, Uri,
};

/// How long a document must stay unchanged before `kin lsp` runs its identifiability analysis.
pub const QUIET: Duration = Duration::from_millis(300);

/// When the identifiability analysis of a changed document runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Identify {
    /// Once the document has been left alone this long ([`QUIET`] for an editor).
    After(Duration),
    /// Never: only the compiler's diagnostics are published (the analysis evaluates the model
    /// at sampled poses, which a harness feeding thousands of sessions cannot afford).
    Never,
}

/// Why a session ended other than by `shutdown` and `exit`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input ended, or the client went away, before `shutdown`.
    #[error("the client closed the connection")]
    Closed,
    /// The client broke the protocol's order (lsp-server's initialisation handshake).
    #[error(transparent)]
    Protocol(lsp_server::ProtocolError),
    /// The output could not be written.
    #[error("writing to the client: {0}")]
    Output(String),
}

impl From<lsp_server::ProtocolError> for Error {
    fn from(e: lsp_server::ProtocolError) -> Error {
        // lsp-server reports the end of the input in the handshake as a protocol error.
        if e.channel_is_disconnected() {
            Error::Closed
        } else {
            Error::Protocol(e)
        }
    }
}

impl<T> From<crossbeam_channel::SendError<T>> for Error {
    fn from(_: crossbeam_channel::SendError<T>) -> Error {
        Error::Closed
    }
}

/// The open documents, by their URI's text.
type Docs = HashMap<String, Doc>;

struct Doc {
    uri: Uri,
    text: String,
    version: i32,
    /// The last compiled form of this text (hover on model facts needs it).
    compiled: Option<Compiled>,
    /// The compiler's diagnostics of `text`.
    found: Vec<kin_compiler::Diagnostic>,
    /// When the identifiability analysis is due, if it is.
    identify_at: Option<Instant>,
}

/// Runs the server on standard input and output until the client says `exit`. Exit code 0
/// after a `shutdown` request, 2 if the connection broke or the client exited without one.
pub fn run() -> ExitCode {
    // The reader runs on its own thread, which a lock of standard input cannot be sent to.
    let stdin = std::io::BufReader::new(std::io::stdin());
    match serve(stdin, std::io::stdout(), Identify::After(QUIET)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: kin lsp: {e}");
            ExitCode::from(2)
        }
    }
}

/// Serves one session: reads framed JSON-RPC messages from `input`, writes the answers to
/// `output`, until the client says `exit` after `shutdown` (`Ok`) or the input ends. A message
/// that cannot be read is answered and the session goes on.
pub fn serve(
    input: impl BufRead + Send,
    output: impl Write + Send,
    identify: Identify,
) -> Result<(), Error> {
    std::thread::scope(|scope| {
        let (connection, io_threads) = transport::spawn(scope, input, output);
        let served = session(&connection, identify);
        drop(connection);
        let joined = io_threads.join().map_err(Error::Output);
        served.and(joined)
    })
}

fn capabilities() -> ServerCapabilities {
    ServerCapabilities {
        text_document_sync: Some(TextDocumentSyncCapability::Kind(TextDocumentSyncKind::FULL)),
        hover_provider: Some(HoverProviderCapability::Simple(true)),
        definition_provider: Some(OneOf::Left(true)),
        references_provider: Some(OneOf::Left(true)),
        completion_provider: Some(CompletionOptions {
            trigger_characters: Some(vec![".".into()]),
            ..Default::default()
        }),
        document_symbol_provider: Some(OneOf::Left(true)),
        document_formatting_provider: Some(OneOf::Left(true)),
        ..Default::default()
    }
}

/// A notification that could not be applied: reported, and the session goes on.
type Skipped = Box<dyn std::error::Error + Send + Sync>;

fn session(connection: &Connection, identify: Identify) -> Result<(), Error> {
    let (id, _params) = connection.initialize_start()?;
    let result = serde_json::json!({
        "capabilities": capabilities(),
        "serverInfo": ServerInfo {
            name: "kin".into(),
            version: Some(env!("CARGO_PKG_VERSION").into()),
        },
    });
    connection.initialize_finish(id, result)?;
    let mut docs: Docs = HashMap::new();
    loop {
        let due = docs.values().filter_map(|d| d.identify_at).min();
        let msg = match due {
            Some(at) => {
                let wait = at.saturating_duration_since(Instant::now());
                match connection.receiver.recv_timeout(wait) {
                    Ok(m) => m,
                    Err(crossbeam_timeout) if crossbeam_timeout.is_timeout() => {
                        identify_due(connection, &mut docs)?;
                        continue;
                    }
                    Err(_) => return Err(Error::Closed),
                }
            }
            None => connection.receiver.recv().map_err(|_| Error::Closed)?,
        };
        match msg {
            Message::Request(req) => {
                if connection.handle_shutdown(&req)? {
                    return Ok(());
                }
                let response = answer(&docs, req);
                connection.sender.send(Message::Response(response))?;
            }
            // A notification the server cannot read is reported and skipped: there is no one to
            // answer, and the session goes on (a closed connection ends it at the next read).
            Message::Notification(n) => {
                if let Err(e) = notified(connection, &mut docs, n, identify) {
                    eprintln!("kin lsp: {e}");
                }
            }
            Message::Response(_) => {}
        }
    }
}

fn notified(
    connection: &Connection,
    docs: &mut Docs,
    n: Notification,
    identify: Identify,
) -> Result<(), Skipped> {
    match n.method.as_str() {
        DidOpenTextDocument::METHOD => {
            let p: lsp_types::DidOpenTextDocumentParams = serde_json::from_value(n.params)?;
            let doc = p.text_document;
            changed(connection, docs, doc.uri, doc.text, doc.version, identify)?;
        }
        DidChangeTextDocument::METHOD => {
            let p: lsp_types::DidChangeTextDocumentParams = serde_json::from_value(n.params)?;
            // Full synchronisation: the last change holds the whole text.
            if let Some(change) = p.content_changes.into_iter().last() {
                changed(
                    connection,
                    docs,
                    p.text_document.uri,
                    change.text,
                    p.text_document.version,
                    identify,
                )?;
            }
        }
        DidCloseTextDocument::METHOD => {
            let p: lsp_types::DidCloseTextDocumentParams = serde_json::from_value(n.params)?;
            docs.remove(p.text_document.uri.as_str());
            publish(connection, &p.text_document.uri, Vec::new(), None)?;
        }
        _ => {}
    }
    Ok(())
}

/// A document's new text: compiled, its diagnostics published, the identifiability analysis
/// scheduled.
fn changed(
    connection: &Connection,
    docs: &mut Docs,
    uri: Uri,
    text: String,
    version: i32,
    identify: Identify,
) -> Result<(), Error> {
    let out = compile(&text);
    let previous = docs.remove(uri.as_str()).and_then(|d| d.compiled);
    let identify_at = out
        .compiled
        .as_ref()
        .filter(|c| !c.machine.coefficients.is_empty())
        .and_then(|_| match identify {
            Identify::After(quiet) => Some(Instant::now() + quiet),
            Identify::Never => None,
        });
    let diagnostics = analysis::diagnostics(&text, &uri, &out.diagnostics);
    publish(connection, &uri, diagnostics, Some(version))?;
    docs.insert(
        uri.as_str().to_string(),
        Doc {
            uri,
            // A text that does not compile keeps the last compiled model for hover.
            compiled: out.compiled.or(previous),
            found: out.diagnostics,
            text,
            version,
            identify_at,
        },
    );
    Ok(())
}

/// Runs the identifiability analysis of every document that has been quiet long enough and
/// publishes its diagnostics with the compiler's.
fn identify_due(connection: &Connection, docs: &mut Docs) -> Result<(), Error> {
    let now = Instant::now();
    for doc in docs.values_mut() {
        if doc.identify_at.is_none_or(|at| at > now) {
            continue;
        }
        doc.identify_at = None;
        let Some(c) = &doc.compiled else { continue };
        let mut all = doc.found.clone();
        all.extend(kin_estimate::identify::checked(
            c,
            kin_estimate::identify::Observe::Pose,
            false,
            kin_model::engine::Engine::Jit,
        ));
        let diagnostics = analysis::diagnostics(&doc.text, &doc.uri, &all);
        publish(connection, &doc.uri, diagnostics, Some(doc.version))?;
    }
    Ok(())
}

fn publish(
    connection: &Connection,
    uri: &Uri,
    diagnostics: Vec<lsp_types::Diagnostic>,
    version: Option<i32>,
) -> Result<(), Error> {
    let params = PublishDiagnosticsParams {
        uri: uri.clone(),
        diagnostics,
        version,
    };
    connection
        .sender
        .send(Message::Notification(Notification::new(
            PublishDiagnostics::METHOD.into(),
            params,
        )))?;
    Ok(())
}

fn answer(docs: &Docs, req: Request) -> Response {
    match respond(docs, &req) {
        Ok(value) => Response::new_ok(req.id, value),
        Err((code, message)) => Response::new_err(req.id, code as i32, message),
    }
}

/// A failed request: the JSON-RPC error code and a message.
type Refusal = (ErrorCode, String);

fn params<P: serde::de::DeserializeOwned>(req: &Request) -> Result<P, Refusal> {
    serde_json::from_value(req.params.clone())
        .map_err(|e| (ErrorCode::InvalidParams, format!("{}: {e}", req.method)))
}

fn not_open(uri: &Uri) -> Refusal {
    (
        ErrorCode::InvalidParams,
        format!("`{}` is not open", uri.as_str()),
    )
}

/// The document and byte offset a position request points at.
fn locate<'d>(
    docs: &'d Docs,
    p: &lsp_types::TextDocumentPositionParams,
) -> Result<(&'d Doc, usize), Refusal> {
    let doc = docs
        .get(p.text_document.uri.as_str())
        .ok_or_else(|| not_open(&p.text_document.uri))?;
    Ok((doc, analysis::offset(&doc.text, p.position)))
}

fn respond(docs: &Docs, req: &Request) -> Result<serde_json::Value, Refusal> {
    let json = |v: serde_json::Result<serde_json::Value>| {
        v.map_err(|e| (ErrorCode::InternalError, e.to_string()))
    };
    match req.method.as_str() {
        HoverRequest::METHOD => {
            let p: lsp_types::HoverParams = params(req)?;
            let (doc, at) = locate(docs, &p.text_document_position_params)?;
            json(serde_json::to_value(analysis::hover(
                &doc.text,
                doc.compiled.as_ref(),
                at,
            )))
        }
        GotoDefinition::METHOD => {
            let p: lsp_types::GotoDefinitionParams = params(req)?;
            let uri = p.text_document_position_params.text_document.uri.clone();
            let (doc, at) = locate(docs, &p.text_document_position_params)?;
            let found = analysis::definition(&doc.text, at).map(|s| {
                GotoDefinitionResponse::Scalar(Location::new(uri, analysis::range(&doc.text, s)))
            });
            json(serde_json::to_value(found))
        }
        References::METHOD => {
            let p: lsp_types::ReferenceParams = params(req)?;
            let uri = p.text_document_position.text_document.uri.clone();
            let (doc, at) = locate(docs, &p.text_document_position)?;
            let found: Vec<Location> =
                analysis::references(&doc.text, at, p.context.include_declaration)
                    .into_iter()
                    .map(|s| Location::new(uri.clone(), analysis::range(&doc.text, s)))
                    .collect();
            json(serde_json::to_value(found))
        }
        Completion::METHOD => {
            let p: lsp_types::CompletionParams = params(req)?;
            let (doc, at) = locate(docs, &p.text_document_position)?;
            json(serde_json::to_value(CompletionResponse::Array(
                analysis::completion(&doc.text, at),
            )))
        }
        DocumentSymbolRequest::METHOD => {
            let p: lsp_types::DocumentSymbolParams = params(req)?;
            let doc = docs
                .get(p.text_document.uri.as_str())
                .ok_or_else(|| not_open(&p.text_document.uri))?;
            json(serde_json::to_value(DocumentSymbolResponse::Nested(
                analysis::symbols(&doc.text),
            )))
        }
        Formatting::METHOD => {
            let p: lsp_types::DocumentFormattingParams = params(req)?;
            let doc = docs
                .get(p.text_document.uri.as_str())
                .ok_or_else(|| not_open(&p.text_document.uri))?;
            json(serde_json::to_value(analysis::formatting(&doc.text)))
        }
        _ => Err((
            ErrorCode::MethodNotFound,
            format!("`{}` is not supported", req.method),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(body: &serde_json::Value) -> Vec<u8> {
        let body = body.to_string();
        format!("Content-Length: {}\r\n\r\n{body}", body.len()).into_bytes()
    }

    /// A session over byte buffers: initialised, a document opened and hovered, shut down; every
    /// request answered under its id, the diagnostics published, and `Ok` after `exit`.
    #[test]
    fn a_session_over_buffers_answers_every_request() {
        let uri = "file:///t/m.kin";
        let text = "machine m {\n  axis X prismatic along x range 0 mm .. 100 mm\n  tool chain { X moving tool t at (0, 0, 0) mm }\n  errors { X.tx = spline(X, knots 2) }\n}\n";
        let messages = [
            serde_json::json!({"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {"capabilities": {}}}),
            serde_json::json!({"jsonrpc": "2.0", "method": "initialized", "params": {}}),
            serde_json::json!({"jsonrpc": "2.0", "method": "textDocument/didOpen", "params": {"textDocument": {"uri": uri, "languageId": "kin", "version": 1, "text": text}}}),
            serde_json::json!({"jsonrpc": "2.0", "id": 2, "method": "textDocument/hover", "params": {"textDocument": {"uri": uri}, "position": {"line": 1, "character": 8}}}),
            serde_json::json!({"jsonrpc": "2.0", "id": 3, "method": "no/such", "params": {}}),
            serde_json::json!({"jsonrpc": "2.0", "id": 4, "method": "shutdown"}),
            serde_json::json!({"jsonrpc": "2.0", "method": "exit"}),
        ];
        let input: Vec<u8> = messages.iter().flat_map(frame).collect();
        let mut output = Vec::new();
        serve(input.as_slice(), &mut output, Identify::Never).expect("a clean session");
        let text = String::from_utf8(output).expect("UTF-8");
        let bodies: Vec<serde_json::Value> = text
            .split("Content-Length: ")
            .filter(|s| !s.is_empty())
            .map(|s| {
                let (_, body) = s.split_once("\r\n\r\n").expect("a header end");
                serde_json::from_str(body).expect("JSON")
            })
            .collect();
        for id in 1..=4 {
            assert!(
                bodies.iter().any(|b| b["id"] == id),
                "no answer to {id}: {bodies:?}"
            );
        }
        let hover = bodies.iter().find(|b| b["id"] == 2).expect("hover");
        assert!(hover["result"]["contents"].is_object(), "{hover}");
        let unknown = bodies.iter().find(|b| b["id"] == 3).expect("unknown");
        assert_eq!(unknown["error"]["code"], -32601, "{unknown}");
        assert!(bodies
            .iter()
            .any(|b| b["method"] == "textDocument/publishDiagnostics"));
    }

    /// An input that ends before `shutdown` is a closed connection, reported as such.
    #[test]
    fn an_input_that_ends_early_is_a_closed_connection() {
        let init = frame(
            &serde_json::json!({"jsonrpc": "2.0", "id": 1, "method": "initialize", "params": {"capabilities": {}}}),
        );
        let mut output = Vec::new();
        let ended = serve(init.as_slice(), &mut output, Identify::Never);
        assert!(matches!(ended, Err(Error::Closed)), "{ended:?}");
    }
}
