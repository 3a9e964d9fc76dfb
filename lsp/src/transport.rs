//! The server's end of the connection, bounded and forgiving.
//!
//! lsp-server's own stdio transport ends the session at the first message it cannot read (a
//! malformed header, a body that is not JSON) and allocates whatever `Content-Length` says
//! before reading it (`Content-Length: 99999999999` aborts the process). An editor sends a
//! malformed message when it has a bug, and the user then loses diagnostics for the rest of the
//! session. Here every header line and body is bounded; a message that cannot be read is
//! answered — an error response to its `id` when it has one, else a `window/logMessage` — and
//! the session goes on. Only the end of the input (or `exit`) ends the reader.

use std::io::{self, BufRead, Read, Write};
use std::thread;

use crossbeam_channel::{Receiver, Sender};
use lsp_server::{Connection, ErrorCode, Message, Notification, RequestId, Response};

/// The longest header line read; a longer one is skipped to its end and reported.
const MAX_HEADER_LINE: u64 = 8 * 1024;
/// The largest body read; a larger one is skipped (as its bytes arrive) and reported.
const MAX_BODY: usize = 64 * 1024 * 1024;

/// The two threads of the connection.
pub struct IoThreads<'scope> {
    reader: thread::ScopedJoinHandle<'scope, ()>,
    writer: thread::ScopedJoinHandle<'scope, io::Result<()>>,
}

impl IoThreads<'_> {
    /// Waits for both threads; a writer that failed (the output closed) is the error.
    pub fn join(self) -> Result<(), String> {
        self.reader
            .join()
            .map_err(|_| "the reader thread failed".to_string())?;
        match self.writer.join() {
            Ok(r) => r.map_err(|e| e.to_string()),
            Err(_) => Err("the writer thread failed".into()),
        }
    }
}

/// A connection over `input` and `output`, read and written by two threads of `scope`.
pub fn spawn<'scope>(
    scope: &'scope thread::Scope<'scope, '_>,
    mut input: impl BufRead + Send + 'scope,
    output: impl Write + Send + 'scope,
) -> (Connection, IoThreads<'scope>) {
    let (to_writer, from_server) = crossbeam_channel::unbounded::<Message>();
    let (to_server, from_reader) = crossbeam_channel::unbounded::<Message>();
    let writer = scope.spawn(move || write_all(&from_server, output));
    let replies = to_writer.clone();
    let reader = scope.spawn(move || read_all(&mut input, &to_server, &replies));
    (
        Connection {
            sender: to_writer,
            receiver: from_reader,
        },
        IoThreads { reader, writer },
    )
}

fn write_all(messages: &Receiver<Message>, mut out: impl Write) -> io::Result<()> {
    for m in messages {
        m.write(&mut out)?;
        out.flush()?;
    }
    Ok(())
}

/// What one framed read gave.
enum Read1 {
    Message(Message),
    /// The stream ended.
    End,
    /// A message that could not be read, with what to say and, when known, its request id.
    Bad(String, Option<RequestId>),
}

/// Reads messages until the input ends or `exit` arrives; answers what it cannot read.
pub fn read_all(input: &mut impl BufRead, server: &Sender<Message>, replies: &Sender<Message>) {
    loop {
        match read_one(input) {
            Read1::End => return,
            Read1::Message(m) => {
                let exit = matches!(&m, Message::Notification(n) if n.method == "exit");
                if server.send(m).is_err() || exit {
                    return;
                }
            }
            Read1::Bad(why, id) => {
                let reply = match id {
                    Some(id) => Message::Response(Response::new_err(
                        id,
                        ErrorCode::InvalidRequest as i32,
                        why,
                    )),
                    None => Message::Notification(Notification::new(
                        "window/logMessage".into(),
                        serde_json::json!({ "type": 1, "message": format!("kin lsp: {why}") }),
                    )),
                };
                if replies.send(reply).is_err() {
                    return;
                }
            }
        }
    }
}

fn read_one(input: &mut impl BufRead) -> Read1 {
    let mut size: Option<usize> = None;
    let mut bad: Option<String> = None;
    loop {
        let mut line = Vec::new();
        match input
            .by_ref()
            .take(MAX_HEADER_LINE)
            .read_until(b'\n', &mut line)
        {
            Ok(0) => return Read1::End,
            Ok(_) => {}
            Err(_) => return Read1::End,
        }
        if !line.ends_with(b"\n") {
            // Longer than any header: skip to its end.
            if skip_line(input).is_err() {
                return Read1::End;
            }
            bad.get_or_insert_with(|| format!("a header line longer than {MAX_HEADER_LINE} bytes"));
            continue;
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim_end_matches(['\r', '\n']);
        if text.is_empty() {
            break;
        }
        if let Some((name, value)) = text.split_once(':') {
            if name.trim().eq_ignore_ascii_case("content-length") {
                match value.trim().parse::<usize>() {
                    Ok(n) => size = Some(n),
                    Err(_) => {
                        bad.get_or_insert_with(|| {
                            format!("Content-Length `{}` is not a size", value.trim())
                        });
                    }
                }
            }
        } else {
            bad.get_or_insert_with(|| format!("a malformed header line `{}`", clip(text)));
        }
    }
    let Some(size) = size else {
        return Read1::Bad(
            bad.unwrap_or_else(|| "a message without Content-Length".into()),
            None,
        );
    };
    if size > MAX_BODY {
        // Skipped as it arrives, never held: the stream stays in step with the client.
        if io::copy(&mut input.by_ref().take(size as u64), &mut io::sink()).is_err() {
            return Read1::End;
        }
        return Read1::Bad(
            format!("a message of {size} bytes, above the {MAX_BODY} this server reads"),
            None,
        );
    }
    let mut body = vec![0u8; size];
    if input.read_exact(&mut body).is_err() {
        return Read1::End;
    }
    if let Some(why) = bad {
        return Read1::Bad(why, None);
    }
    let value: serde_json::Value = match serde_json::from_slice(&body) {
        Ok(v) => v,
        Err(e) => return Read1::Bad(format!("a body that is not JSON ({e})"), None),
    };
    let id = value.get("id").and_then(|id| match id {
        serde_json::Value::Number(n) => n
            .as_i64()
            .and_then(|n| i32::try_from(n).ok())
            .map(RequestId::from),
        serde_json::Value::String(s) => Some(RequestId::from(s.clone())),
        _ => None,
    });
    match serde_json::from_value::<Message>(value) {
        Ok(m) => Read1::Message(m),
        Err(e) => Read1::Bad(format!("not a JSON-RPC message ({e})"), id),
    }
}

/// Discards input up to and including the next newline, in bounded chunks.
fn skip_line(input: &mut impl BufRead) -> io::Result<()> {
    loop {
        let (done, used) = {
            let buf = input.fill_buf()?;
            if buf.is_empty() {
                return Ok(());
            }
            match buf.iter().position(|b| *b == b'\n') {
                Some(i) => (true, i + 1),
                None => (false, buf.len()),
            }
        };
        input.consume(used);
        if done {
            return Ok(());
        }
    }
}

/// At most 80 characters of a line, for a message.
fn clip(text: &str) -> String {
    text.chars().take(80).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(body: &str) -> String {
        format!("Content-Length: {}\r\n\r\n{body}", body.len())
    }

    /// Malformed messages are answered and the next good one is still read.
    #[test]
    fn bad_messages_are_answered_and_the_session_goes_on() {
        let good = r#"{"jsonrpc":"2.0","id":7,"method":"shutdown"}"#;
        let mut input = String::new();
        input.push_str(&frame("{not json"));
        input.push_str(&format!("{}\r\n\r\n", "X".repeat(20_000)));
        input.push_str("Content-Length: ten\r\n\r\n");
        input.push_str("Content-Length: 99999999999\r\n\r\n");
        let (to_server, from_reader) = crossbeam_channel::unbounded();
        let (to_writer, from_server) = crossbeam_channel::unbounded();
        // The huge body swallows what follows, as the client said it would: a good message
        // after it is only read in a second session.
        read_all(&mut input.as_bytes(), &to_server, &to_writer);
        let replies: Vec<Message> = from_server.try_iter().collect();
        let early: Vec<Message> = from_reader.try_iter().collect();
        assert!(early.is_empty(), "{early:?}");
        assert_eq!(replies.len(), 4, "{replies:?}");
        assert!(from_reader.try_iter().next().is_none());
        let mut again = String::new();
        again.push_str(&frame("[]"));
        again.push_str(&frame(good));
        read_all(&mut again.as_bytes(), &to_server, &to_writer);
        let read: Vec<Message> = from_reader.try_iter().collect();
        assert!(
            matches!(&read[..], [Message::Request(r)] if r.method == "shutdown"),
            "{read:?}"
        );
    }
}
