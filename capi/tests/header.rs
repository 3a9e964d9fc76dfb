//! `include/kin.h` is written by hand, so only these tests keep it in step with `src/lib.rs`: a
//! status code, constant, function or parameter type that differs would make a C caller misread a
//! failure, fail to link, or pass arguments the library reads as something else.
//!
//! Both texts are read with small scanners: Rust source as tokens (comments dropped, literals kept
//! whole), the header as the C compiler sees it (comments, preprocessor lines and the C++-only
//! `extern "C" {` wrapper dropped) split into declarations. Each Rust type of an exported
//! signature is mapped to its C spelling through an explicit table, [`RUST_TO_C`]. When the shared
//! library has been built and `nm` is on the PATH, the header is also compared with the symbols
//! the library really exports.

use std::collections::{BTreeMap, BTreeSet};
use std::ffi::{c_char, c_int, CStr};
use std::path::{Path, PathBuf};
use std::process::Command;

use kin_capi::*;

const HEADER: &str = include_str!("../include/kin.h");
const LIB_RS: &str = include_str!("../src/lib.rs");

/// How each Rust type of an exported signature is spelled in C (spacing around `*` is free on
/// both sides). A Rust type missing here fails the comparison by name: add it, after checking that
/// its C spelling has the same layout, rather than letting it pass unchecked.
const RUST_TO_C: &[(&str, &str)] = &[
    ("()", "void"),
    ("c_int", "int"),
    ("usize", "size_t"),
    ("u32", "unsigned int"),
    ("f64", "double"),
    ("*const c_char", "const char *"),
    ("*mut c_char", "char *"),
    ("*const f64", "const double *"),
    ("*mut f64", "double *"),
    ("*mut usize", "size_t *"),
    ("*const u8", "const unsigned char *"),
    ("*const kin_model", "const kin_model *"),
    ("*mut kin_model", "kin_model *"),
    ("*mut *mut kin_model", "kin_model **"),
    ("*const kin_state", "const kin_state *"),
    ("*const kin_rows", "const kin_rows *"),
    ("*const kin_compensator", "const kin_compensator *"),
    ("*mut kin_compensator", "kin_compensator *"),
    ("*mut *mut kin_compensator", "kin_compensator **"),
];

/// The `KIN_NAME_*` selectors of `kin_model_name` have no Rust constant (the library matches on
/// 0..=3), so their header values are checked by what they select in [`NAMED_MODEL`]: the name
/// each one must return for index 0.
const NAME_SELECTORS: &[(&str, &str)] = &[
    ("KIN_NAME_AXIS", "X"),
    ("KIN_NAME_INPUT", "T_room"),
    ("KIN_NAME_TOOL", "probe"),
    ("KIN_NAME_COEFFICIENT", "X.ry[0]"),
];

/// A model whose first axis, input, tool and coefficient all have different names.
const NAMED_MODEL: &str = "machine m {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    input T_room : temperature rise
    tool chain { X moving tool probe at (0, 0, -100) mm }
    errors { X.ry = const }
}";

/// The library's status codes by name.
fn status_codes() -> [(&'static str, c_int); 15] {
    [
        ("KIN_OK", KIN_OK),
        ("KIN_ERR_POINTER", KIN_ERR_POINTER),
        ("KIN_ERR_SIZE", KIN_ERR_SIZE),
        ("KIN_ERR_UTF8", KIN_ERR_UTF8),
        ("KIN_ERR_COMPILE", KIN_ERR_COMPILE),
        ("KIN_ERR_PARAMS", KIN_ERR_PARAMS),
        ("KIN_ERR_EVAL", KIN_ERR_EVAL),
        ("KIN_ERR_IO", KIN_ERR_IO),
        ("KIN_ERR_INDEX", KIN_ERR_INDEX),
        ("KIN_ERR_PANIC", KIN_ERR_PANIC),
        ("KIN_ERR_VALUE", KIN_ERR_VALUE),
        ("KIN_ERR_OVERLAP", KIN_ERR_OVERLAP),
        ("KIN_ERR_RANGE", KIN_ERR_RANGE),
        ("KIN_ERR_MACHINE", KIN_ERR_MACHINE),
        ("KIN_ERR_DIVERGES", KIN_ERR_DIVERGES),
    ]
}

/// Every public constant of lib.rs with its value: the status codes and the limits.
fn library_constants() -> BTreeMap<&'static str, i128> {
    let mut constants: BTreeMap<&str, i128> = status_codes()
        .into_iter()
        .map(|(name, value)| (name, i128::from(value)))
        .collect();
    let max_axes = i128::try_from(KIN_COMPENSATOR_MAX_AXES).expect("a usize fits in i128");
    constants.insert("KIN_COMPENSATOR_MAX_AXES", max_axes);
    constants
}

/// The value `#define NAME value` gives in the header, if it defines it.
fn defined(header: &str, name: &str) -> Option<i32> {
    header.lines().find_map(|line| {
        let mut words = line.split_whitespace();
        if words.next() == Some("#define") && words.next() == Some(name) {
            words.next()?.parse().ok()
        } else {
            None
        }
    })
}

// ---------------------------------------------------------------------------------------------
// Tokens

/// A token of Rust or C source; comments are gone, string literals kept whole.
#[derive(Debug, Clone, PartialEq)]
enum Token {
    /// An identifier, keyword or number.
    Word(String),
    /// A string literal's text between its quotes (escapes as written).
    Str(String),
    /// Any other character: `*`, `(`, `:`, …
    Punct(char),
}

impl Token {
    fn is(&self, c: char) -> bool {
        *self == Token::Punct(c)
    }

    fn word(&self) -> Option<&str> {
        match self {
            Token::Word(w) => Some(w),
            _ => None,
        }
    }
}

fn is_word_char(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// "unterminated {what} at line N", for a literal or comment opening at `i`.
fn unterminated(what: &str, chars: &[char], i: usize) -> String {
    let line = chars[..i].iter().filter(|&&c| c == '\n').count() + 1;
    format!("unterminated {what} at line {line}")
}

/// The index of the newline that ends the line holding `i` (or the end of the text).
fn line_end(chars: &[char], i: usize) -> usize {
    chars[i..]
        .iter()
        .position(|&c| c == '\n')
        .map_or(chars.len(), |n| i + n)
}

/// Scans Rust source into tokens, dropping comments (nested block comments included) and keeping
/// string and character literals whole, so that text inside them (lib.rs's own tests quote
/// `extern "C" fn`) is never read as code.
fn rust_tokens(src: &str) -> Result<Vec<Token>, String> {
    let chars: Vec<char> = src.chars().collect();
    let mut tokens = Vec::new();
    let mut i = 0;
    while let Some(&c) = chars.get(i) {
        let next = chars.get(i + 1).copied();
        i = match c {
            _ if c.is_whitespace() => i + 1,
            '/' if next == Some('/') => line_end(&chars, i),
            '/' if next == Some('*') => rust_comment_end(&chars, i)?,
            '"' => quoted(&chars, i, &mut tokens)?,
            '\'' => char_or_lifetime(&chars, i, &mut tokens)?,
            _ if is_word_char(c) => word_or_prefixed_literal(&chars, i, &mut tokens)?,
            _ => {
                tokens.push(Token::Punct(c));
                i + 1
            }
        };
    }
    Ok(tokens)
}

/// The index just past the block comment opening at `i`; Rust block comments nest.
fn rust_comment_end(chars: &[char], i: usize) -> Result<usize, String> {
    let mut depth = 0;
    let mut j = i;
    while j + 1 < chars.len() {
        match (chars[j], chars[j + 1]) {
            ('/', '*') => {
                depth += 1;
                j += 2;
            }
            ('*', '/') => {
                depth -= 1;
                j += 2;
                if depth == 0 {
                    return Ok(j);
                }
            }
            _ => j += 1,
        }
    }
    Err(unterminated("block comment", chars, i))
}

/// Reads the string literal whose opening quote is at `i`; returns the index past its close.
fn quoted(chars: &[char], i: usize, tokens: &mut Vec<Token>) -> Result<usize, String> {
    let mut j = i + 1;
    while let Some(&c) = chars.get(j) {
        match c {
            '\\' => j += 2,
            '"' => {
                tokens.push(Token::Str(chars[i + 1..j].iter().collect()));
                return Ok(j + 1);
            }
            _ => j += 1,
        }
    }
    Err(unterminated("string", chars, i))
}

/// `'x'`, `'\n'`, `'"'` are character literals, skipped (no exported signature holds one);
/// `'a` is a lifetime, kept as a `'` before the word.
fn char_or_lifetime(chars: &[char], i: usize, tokens: &mut Vec<Token>) -> Result<usize, String> {
    match (chars.get(i + 1), chars.get(i + 2)) {
        (Some('\\'), _) => {
            // The escaped character is at i + 2; the closing quote is the next one after it.
            let from = i + 3;
            chars
                .get(from..)
                .and_then(|rest| rest.iter().position(|&c| c == '\''))
                .map(|n| from + n + 1)
                .ok_or_else(|| unterminated("character literal", chars, i))
        }
        (Some(_), Some('\'')) => Ok(i + 3),
        _ => {
            tokens.push(Token::Punct('\''));
            Ok(i + 1)
        }
    }
}

/// A word at `i`, unless it is the prefix of a byte or raw string (`b"…"`, `r#"…"#`) or of a
/// byte (`b'x'`).
fn word_or_prefixed_literal(
    chars: &[char],
    i: usize,
    tokens: &mut Vec<Token>,
) -> Result<usize, String> {
    let end = chars[i..]
        .iter()
        .position(|&c| !is_word_char(c))
        .map_or(chars.len(), |n| i + n);
    let word: String = chars[i..end].iter().collect();
    let raw = match (word.as_str(), chars.get(end)) {
        ("b", Some('"')) => return quoted(chars, end, tokens),
        ("b", Some('\'')) => return char_or_lifetime(chars, end, tokens),
        ("r" | "br", Some('"' | '#')) => raw_string(chars, end, tokens)?,
        _ => None,
    };
    Ok(raw.unwrap_or_else(|| {
        tokens.push(Token::Word(word));
        end
    }))
}

/// Reads the raw string whose hashes or quote start at `i` (after its `r`); returns the index past
/// its close, or `None` when no quote follows the hashes (a raw identifier such as `r#type`).
fn raw_string(chars: &[char], i: usize, tokens: &mut Vec<Token>) -> Result<Option<usize>, String> {
    let hashes = chars[i..].iter().take_while(|&&c| c == '#').count();
    let open = i + hashes;
    if chars.get(open) != Some(&'"') {
        return Ok(None);
    }
    let closes_at = |j: usize| {
        chars[j] == '"'
            && chars[j + 1..]
                .iter()
                .take(hashes)
                .filter(|&&c| c == '#')
                .count()
                == hashes
    };
    let close = (open + 1..chars.len())
        .find(|&j| closes_at(j))
        .ok_or_else(|| unterminated("raw string", chars, i))?;
    tokens.push(Token::Str(chars[open + 1..close].iter().collect()));
    Ok(Some(close + 1 + hashes))
}

/// The index of the bracket closing the one at `open` (`(`, `[` or `{`).
fn matching(tokens: &[Token], open: usize) -> Result<usize, String> {
    let (opener, closer) = match tokens.get(open) {
        Some(Token::Punct('(')) => ('(', ')'),
        Some(Token::Punct('[')) => ('[', ']'),
        Some(Token::Punct('{')) => ('{', '}'),
        other => return Err(format!("expected a bracket, found {other:?}")),
    };
    let mut depth = 0usize;
    for (k, token) in tokens.iter().enumerate().skip(open) {
        if token.is(opener) {
            depth += 1;
        } else if token.is(closer) {
            depth -= 1;
            if depth == 0 {
                return Ok(k);
            }
        }
    }
    Err(format!("`{opener}` without its `{closer}`"))
}

/// `tokens` split at the commas outside brackets; a trailing comma makes no empty last piece.
fn split_commas(tokens: &[Token]) -> Vec<&[Token]> {
    let mut pieces = Vec::new();
    let (mut depth, mut start) = (0i32, 0);
    for (k, token) in tokens.iter().enumerate() {
        match token {
            Token::Punct('(' | '[' | '{') => depth += 1,
            Token::Punct(')' | ']' | '}') => depth -= 1,
            Token::Punct(',') if depth == 0 => {
                pieces.push(&tokens[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    if start < tokens.len() {
        pieces.push(&tokens[start..]);
    }
    pieces
}

// ---------------------------------------------------------------------------------------------
// Rust exports

/// A function as a C caller sees it: name, parameter types and return type, each type in the
/// canonical spelling of its language (see [`render_rust`] and [`render_c`]).
#[derive(Debug, Clone, PartialEq)]
struct Function {
    name: String,
    params: Vec<String>,
    ret: String,
}

/// A Rust type written with single spaces between words and none after `*`, `&` or around `::`:
/// `*mut *mut kin_model`, `std::ffi::c_int`.
fn render_rust(tokens: &[Token]) -> String {
    let mut text = String::new();
    let mut previous_is_word = false;
    for token in tokens {
        let (piece, is_word) = match token {
            Token::Word(w) => (w.clone(), true),
            Token::Str(s) => (format!("{s:?}"), false),
            Token::Punct(c) => (c.to_string(), false),
        };
        if previous_is_word && (is_word || token.is('*') || token.is('&')) {
            text.push(' ');
        }
        text.push_str(&piece);
        previous_is_word = is_word;
    }
    text
}

/// What an `extern` function's header says before its name.
struct FnHeader {
    /// Tokens from the start of the header to the `fn`, exclusive.
    len: usize,
    public: bool,
    abi: String,
}

/// The `[pub] [unsafe] extern "ABI" fn name` header at the start of `tokens`, if there is one
/// (`extern "C" fn(…)` as a type has no name and is not one).
fn fn_header(tokens: &[Token]) -> Option<FnHeader> {
    let public = tokens.first()?.word() == Some("pub");
    let mut k = usize::from(public);
    if tokens.get(k)?.word() == Some("unsafe") {
        k += 1;
    }
    if tokens.get(k)?.word() != Some("extern") {
        return None;
    }
    let Token::Str(abi) = tokens.get(k + 1)? else {
        return None;
    };
    if tokens.get(k + 2)?.word() != Some("fn") {
        return None;
    }
    tokens.get(k + 3)?.word()?;
    Some(FnHeader {
        len: k + 2,
        public,
        abi: abi.clone(),
    })
}

/// The functions `src` exports to C: each `pub [unsafe] extern "C" fn` marked `#[no_mangle]` or
/// `#[unsafe(no_mangle)]`. Anything this test could not map to what C links against is an error:
/// a public `extern "C" fn` without `no_mangle` (C cannot name it), `no_mangle` on anything but a
/// public `extern "C" fn`, `export_name`.
fn rust_exports(src: &str) -> Result<Vec<Function>, String> {
    let tokens = rust_tokens(src)?;
    let mut exports = Vec::new();
    let mut attributes: Vec<String> = Vec::new();
    let mut i = 0;
    while i < tokens.len() {
        if tokens[i].is('#') && tokens.get(i + 1).is_some_and(|t| t.is('[')) {
            let close = matching(&tokens, i + 1)?;
            attributes.push(render_rust(&tokens[i + 2..close]));
            i = close + 1;
            continue;
        }
        let no_mangle = attributes
            .iter()
            .any(|a| a == "no_mangle" || a == "unsafe(no_mangle)");
        if let Some(a) = attributes.iter().find(|a| a.starts_with("export_name")) {
            return Err(format!(
                "`#[{a}]` is not handled: the test reads names from `fn`s"
            ));
        }
        if let Some(header) = fn_header(&tokens[i..]) {
            let (function, body) = rust_signature(&tokens, i + header.len)?;
            match (no_mangle, header.public, header.abi == "C") {
                (true, true, true) => exports.push(function),
                (false, true, true) => {
                    return Err(format!(
                        "`{}` is pub extern \"C\" but not #[no_mangle]",
                        function.name
                    ))
                }
                (true, _, _) => {
                    return Err(format!(
                        "`{}` is #[no_mangle] but not a pub extern \"C\" fn",
                        function.name
                    ))
                }
                (false, _, _) => {}
            }
            i = body;
        } else if no_mangle {
            let item = render_rust(&tokens[i..tokens.len().min(i + 6)]);
            return Err(format!(
                "#[no_mangle] on `{item} …`, which is not an extern \"C\" fn"
            ));
        } else {
            i += 1;
        }
        attributes.clear();
    }
    Ok(exports)
}

/// Reads `fn name(params) [-> type]` whose `fn` is at `at`; returns it and the index of its
/// body's `{`.
fn rust_signature(tokens: &[Token], at: usize) -> Result<(Function, usize), String> {
    let name = tokens
        .get(at + 1)
        .and_then(Token::word)
        .ok_or("`fn` without a name")?
        .to_string();
    let open = at + 2;
    if !tokens.get(open).is_some_and(|t| t.is('(')) {
        return Err(format!(
            "`{name}` is generic or not `fn {name}(…)`: C has no such signature"
        ));
    }
    let close = matching(tokens, open)?;
    let params = split_commas(&tokens[open + 1..close])
        .into_iter()
        .map(|param| rust_param(&name, param))
        .collect::<Result<_, _>>()?;
    let (ret, body) = rust_return(&name, tokens, close + 1)?;
    Ok((Function { name, params, ret }, body))
}

/// The type of the parameter `pattern: type` of function `name`.
fn rust_param(name: &str, tokens: &[Token]) -> Result<String, String> {
    let colon = tokens.iter().position(|t| t.is(':'));
    let pattern_is_a_name = |pattern: &[Token]| match pattern {
        [Token::Word(_)] => true,
        [Token::Word(m), Token::Word(_)] => m == "mut",
        _ => false,
    };
    match colon {
        Some(k) if pattern_is_a_name(&tokens[..k]) => rust_type(name, &tokens[k + 1..]),
        _ => Err(format!(
            "`{name}`: cannot read the parameter `{}` as `name: type`",
            render_rust(tokens)
        )),
    }
}

/// The return type after the parameters of `name` (at `at`): `()` when there is no `->`.
/// Returns it with the index of the body's `{`.
fn rust_return(name: &str, tokens: &[Token], at: usize) -> Result<(String, usize), String> {
    let arrow =
        tokens.get(at).is_some_and(|t| t.is('-')) && tokens.get(at + 1).is_some_and(|t| t.is('>'));
    let start = if arrow { at + 2 } else { at };
    let body = (start..tokens.len())
        .find(|&k| tokens[k].is('{') || tokens[k].word() == Some("where"))
        .ok_or_else(|| format!("`{name}` has no body"))?;
    if tokens[body].word() == Some("where") {
        return Err(format!(
            "`{name}` has a `where` clause: C has no such signature"
        ));
    }
    match (arrow, body == start) {
        (true, _) => Ok((rust_type(name, &tokens[start..body])?, body)),
        (false, true) => Ok(("()".to_string(), body)),
        (false, false) => Err(format!(
            "`{name}`: cannot read `{}` after the parameters",
            render_rust(&tokens[start..body])
        )),
    }
}

/// A parameter or return type of `name`; generic and `impl`/`dyn` types have no C spelling and
/// fail here.
fn rust_type(name: &str, tokens: &[Token]) -> Result<String, String> {
    let text = render_rust(tokens);
    let generic = tokens
        .iter()
        .any(|t| t.is('<') || matches!(t.word(), Some("impl" | "dyn")));
    if generic || tokens.is_empty() {
        return Err(format!(
            "`{name}`: the type `{text}` is generic, `impl` or missing: C has no such type"
        ));
    }
    Ok(text)
}

/// The names of lib.rs's public constants (`pub const NAME: …`).
fn rust_public_constants(src: &str) -> Result<BTreeSet<String>, String> {
    let tokens = rust_tokens(src)?;
    Ok(tokens
        .windows(4)
        .filter_map(|w| match w {
            [Token::Word(p), Token::Word(c), Token::Word(name), Token::Punct(':')]
                if p == "pub" && c == "const" =>
            {
                Some(name.clone())
            }
            _ => None,
        })
        .collect())
}

// ---------------------------------------------------------------------------------------------
// C declarations

/// `text` with each C comment replaced by a space (string and character literals are copied,
/// so a `/*` inside one opens nothing).
fn strip_c_comments(text: &str) -> Result<String, String> {
    let chars: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while let Some(&c) = chars.get(i) {
        let next = chars.get(i + 1).copied();
        if c == '/' && next == Some('*') {
            let close = (i + 2..chars.len().saturating_sub(1))
                .find(|&j| chars[j] == '*' && chars[j + 1] == '/')
                .ok_or_else(|| unterminated("comment", &chars, i))?;
            out.push(' ');
            i = close + 2;
        } else if c == '/' && next == Some('/') {
            out.push(' ');
            i = line_end(&chars, i);
        } else if c == '"' || c == '\'' {
            let mut j = i + 1;
            while chars.get(j).is_some_and(|&d| d != c && d != '\n') {
                j += if chars[j] == '\\' { 2 } else { 1 };
            }
            if chars.get(j) != Some(&c) {
                return Err(unterminated("literal", &chars, i));
            }
            out.extend(&chars[i..=j]);
            i = j + 1;
        } else {
            out.push(c);
            i += 1;
        }
    }
    Ok(out)
}

/// One `#if…` group of the header while its lines are read.
struct Group {
    /// Whether the condition is about `__cplusplus`, the only one whose value this test knows.
    about_cplusplus: bool,
    /// Whether a C compiler reads the lines of the group.
    read_by_c: bool,
}

/// The code of `header` as a C compiler sees it: lines continued with `\` joined, comments
/// replaced by a space, preprocessor lines dropped, and the groups under `#ifdef __cplusplus`
/// (the `extern "C" {` wrapper) left out. Other conditions (the include guard) are taken as
/// true; an `#else` or `#elif` of one is an error, since the test cannot tell which group C reads.
fn c_code(header: &str) -> Result<String, String> {
    let text = strip_c_comments(&header.replace("\\\n", ""))?;
    let mut groups: Vec<Group> = Vec::new();
    let mut code = String::new();
    for line in text.lines() {
        let Some(directive) = line.trim_start().strip_prefix('#') else {
            if groups.iter().all(|g| g.read_by_c) {
                code.push_str(line);
                code.push('\n');
            }
            continue;
        };
        let mut words = directive.split_whitespace();
        let (keyword, argument) = (words.next(), words.next());
        match keyword {
            Some("if" | "ifdef" | "ifndef") => {
                let about_cplusplus = argument == Some("__cplusplus");
                let read_by_c = !about_cplusplus || keyword == Some("ifndef");
                groups.push(Group {
                    about_cplusplus,
                    read_by_c,
                });
            }
            Some("else") => match groups.last_mut() {
                Some(g) if g.about_cplusplus => g.read_by_c = !g.read_by_c,
                _ => return Err(format!("`{line}`: only #else of __cplusplus is handled")),
            },
            Some("elif" | "elifdef" | "elifndef") => {
                return Err(format!("`{line}`: #elif is not handled"))
            }
            Some("endif") => {
                groups.pop().ok_or("#endif without its #if")?;
            }
            _ => {} // #define, #include: no declarations
        }
    }
    if !groups.is_empty() {
        return Err("#if without its #endif".to_string());
    }
    Ok(code)
}

/// The tokens of C code: words and single punctuation characters.
fn c_tokens(code: &str) -> Vec<Token> {
    let mut tokens = Vec::new();
    let mut word = String::new();
    for c in code.chars() {
        if is_word_char(c) {
            word.push(c);
            continue;
        }
        if !word.is_empty() {
            tokens.push(Token::Word(std::mem::take(&mut word)));
        }
        if !c.is_whitespace() {
            tokens.push(Token::Punct(c));
        }
    }
    if !word.is_empty() {
        tokens.push(Token::Word(word));
    }
    tokens
}

/// A C type written with single spaces between words, one before a run of `*` and one after it:
/// `const char *`, `kin_model **`.
fn render_c(tokens: &[Token]) -> String {
    let mut text = String::new();
    let mut previous: Option<&Token> = None;
    for token in tokens {
        let space = matches!(
            (previous, token),
            (Some(Token::Word(_)), Token::Word(_) | Token::Punct('*'))
                | (Some(Token::Punct('*')), Token::Word(_))
        );
        if space {
            text.push(' ');
        }
        match token {
            Token::Word(w) => text.push_str(w),
            Token::Str(s) => text.push_str(&format!("{s:?}")),
            Token::Punct(c) => text.push(*c),
        }
        previous = Some(token);
    }
    text
}

/// The declarations at file level, each without its `;`: a struct's members stay inside the
/// declaration of the struct.
fn c_declarations(tokens: &[Token]) -> Result<Vec<&[Token]>, String> {
    let mut declarations = Vec::new();
    let (mut depth, mut start) = (0i32, 0);
    for (k, token) in tokens.iter().enumerate() {
        match token {
            Token::Punct('(' | '[' | '{') => depth += 1,
            Token::Punct(')' | ']' | '}') => depth -= 1,
            Token::Punct(';') if depth == 0 => {
                declarations.push(&tokens[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    if start < tokens.len() {
        let rest = render_c(&tokens[start..]);
        return Err(format!("kin.h ends without the `;` of `{rest}`"));
    }
    Ok(declarations)
}

/// Words C reads as part of a type, never as a parameter's name.
const C_TYPE_WORDS: &[&str] = &[
    "void", "char", "short", "int", "long", "float", "double", "signed", "unsigned", "_Bool",
    "const", "volatile", "restrict", "struct", "union", "enum",
];

/// Of those, the ones that cannot be a whole type on their own.
const C_QUALIFIERS: &[&str] = &["const", "volatile", "restrict", "struct", "union", "enum"];

/// The functions `header` declares (`type name(params)`), with their C types; typedefs and
/// struct, union or enum declarations are types, not functions. Anything else at file level
/// (a variable, a definition with a body, a declarator this test cannot read) is an error.
fn header_functions(header: &str) -> Result<Vec<Function>, String> {
    let tokens = c_tokens(&c_code(header)?);
    let mut functions = Vec::new();
    for declaration in c_declarations(&tokens)? {
        if let Some(function) = c_function(declaration)? {
            functions.push(function);
        }
    }
    Ok(functions)
}

/// The prototype `declaration`, or `None` when it declares a type.
fn c_function(declaration: &[Token]) -> Result<Option<Function>, String> {
    let text = render_c(declaration);
    let first = declaration.first().and_then(Token::word);
    let is_type = matches!(first, Some("typedef" | "struct" | "union" | "enum"));
    let open = declaration.iter().position(|t| t.is('('));
    let has_body = declaration.iter().any(|t| t.is('{'));
    let open = match (is_type, open, has_body) {
        (true, _, _) => return Ok(None),
        (false, Some(open), false) if open > 0 => open,
        _ => return Err(format!("kin.h: `{text}` is neither a prototype nor a type")),
    };
    let unreadable = || format!("kin.h: cannot read `{text}` as `type name(params)`");
    let name = declaration[open - 1]
        .word()
        .filter(|w| !C_TYPE_WORDS.contains(w))
        .ok_or_else(unreadable)?
        .to_string();
    let ret_tokens = match &declaration[..open - 1] {
        [Token::Word(e), rest @ ..] if e == "extern" => rest,
        all => all,
    };
    let close = matching(declaration, open)?;
    if ret_tokens.is_empty() || close + 1 != declaration.len() {
        return Err(unreadable());
    }
    let params = c_params(&name, &declaration[open + 1..close])?;
    let ret = render_c(ret_tokens);
    Ok(Some(Function { name, params, ret }))
}

/// The parameter types between the parentheses of `name`: `(void)` is none, `()` (no prototype)
/// an error.
fn c_params(name: &str, tokens: &[Token]) -> Result<Vec<String>, String> {
    match tokens {
        [] => Err(format!(
            "kin.h: `{name}()` is no prototype; write `{name}(void)`"
        )),
        [Token::Word(v)] if v == "void" => Ok(Vec::new()),
        _ => split_commas(tokens)
            .into_iter()
            .map(|param| c_param(name, param))
            .collect(),
    }
}

/// The type of one parameter of `name`, without its name when it has one.
fn c_param(name: &str, tokens: &[Token]) -> Result<String, String> {
    if tokens.iter().any(|t| t.is('[') || t.is('(') || t.is('.')) {
        return Err(format!(
            "kin.h: `{name}` has the array, function or variadic parameter `{}`, which the test \
             does not map",
            render_c(tokens)
        ));
    }
    let names_a_type = |t: &Token| t.word().is_some_and(|w| !C_QUALIFIERS.contains(&w));
    let ty = match tokens {
        [rest @ .., Token::Word(last)]
            if !C_TYPE_WORDS.contains(&last.as_str()) && rest.iter().any(names_a_type) =>
        {
            rest
        }
        all => all,
    };
    if ty.is_empty() {
        return Err(format!("kin.h: `{name}` has an empty parameter"));
    }
    Ok(render_c(ty))
}

// ---------------------------------------------------------------------------------------------
// Comparison

/// `ty` in the canonical spelling [`render_rust`] gives parsed types.
fn canonical_rust(ty: &str) -> String {
    render_rust(&rust_tokens(ty).expect("a Rust type of RUST_TO_C scans"))
}

/// The C spelling of the Rust type `rust`, from [`RUST_TO_C`], in [`render_c`]'s spelling.
fn c_spelling(rust: &str) -> Option<String> {
    RUST_TO_C
        .iter()
        .find(|(r, _)| canonical_rust(r) == rust)
        .map(|(_, c)| render_c(&c_tokens(c)))
}

/// Every name `functions` holds more than once, as a sentence.
fn duplicates(functions: &[Function], holder: &str) -> Vec<String> {
    let mut seen = BTreeSet::new();
    functions
        .iter()
        .filter(|f| !seen.insert(f.name.as_str()))
        .map(|f| format!("{holder} `{}` twice", f.name))
        .collect()
}

/// Every way the header's prototypes `declared` differ from the library's `exports`, one sentence
/// each; empty when they agree.
fn mismatches(exports: &[Function], declared: &[Function]) -> Vec<String> {
    let mut problems = duplicates(exports, "lib.rs exports");
    problems.extend(duplicates(declared, "kin.h declares"));
    let rust: BTreeMap<&str, &Function> = exports.iter().map(|f| (f.name.as_str(), f)).collect();
    let c: BTreeMap<&str, &Function> = declared.iter().map(|f| (f.name.as_str(), f)).collect();
    for name in rust.keys().filter(|name| !c.contains_key(*name)) {
        problems.push(format!(
            "`{name}` is exported by lib.rs but not declared in kin.h"
        ));
    }
    for name in c.keys().filter(|name| !rust.contains_key(*name)) {
        problems.push(format!(
            "kin.h declares `{name}`, which lib.rs does not export"
        ));
    }
    for (name, export) in &rust {
        if let Some(declaration) = c.get(name) {
            problems.extend(signature_mismatches(export, declaration));
        }
    }
    problems
}

/// How the C prototype `c` of a function differs from its Rust signature `rust`.
fn signature_mismatches(rust: &Function, c: &Function) -> Vec<String> {
    let name = &rust.name;
    let mut problems = Vec::new();
    if rust.params.len() != c.params.len() {
        problems.push(format!(
            "`{name}` takes {} parameters in lib.rs but {} in kin.h",
            rust.params.len(),
            c.params.len()
        ));
    }
    let params = rust
        .params
        .iter()
        .zip(&c.params)
        .enumerate()
        .map(|(k, pair)| (format!("parameter {}", k + 1), pair));
    let ret = ("the return type".to_string(), (&rust.ret, &c.ret));
    for (what, (rust_type, c_type)) in params.chain([ret]) {
        match c_spelling(rust_type) {
            None => problems.push(format!(
                "`{name}`, {what}: the Rust type `{rust_type}` is not in RUST_TO_C; add its C \
                 spelling"
            )),
            Some(expected) if expected != *c_type => problems.push(format!(
                "`{name}`, {what}: lib.rs has `{rust_type}`, which C spells `{expected}`, but \
                 kin.h has `{c_type}`"
            )),
            Some(_) => {}
        }
    }
    problems
}

/// The value text of every `#define KIN_… value` in `header` (comments dropped); the include
/// guard `KIN_H` has none and is left out.
fn header_defines(header: &str) -> Result<BTreeMap<String, String>, String> {
    let text = strip_c_comments(&header.replace("\\\n", ""))?;
    let defines = text.lines().filter_map(|line| {
        let mut words = line.split_whitespace();
        if words.next() != Some("#define") {
            return None;
        }
        let name = words.next().filter(|n| n.starts_with("KIN_"))?;
        let value = words.collect::<Vec<_>>().join(" ");
        (!value.is_empty()).then(|| (name.to_string(), value))
    });
    Ok(defines.collect())
}

/// `text` with its one occurrence of `from` replaced by `to` (a scratch copy for the tests that
/// show the comparison can fail).
fn replace_once(text: &str, from: &str, to: &str) -> String {
    assert_eq!(text.matches(from).count(), 1, "`{from}` occurs once");
    text.replacen(from, to, 1)
}

// ---------------------------------------------------------------------------------------------
// The shared library

/// The shared library cargo built: in the profile folder above this test's `deps` (put there by
/// `cargo build`) or in `deps` itself (`cargo test`); the newer when both exist, since the other
/// may be left from an older build.
fn shared_library() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let deps = exe.parent()?;
    let name = format!(
        "{}kin_capi{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    );
    let modified = |dir: &Path| {
        std::fs::metadata(dir.join(&name))
            .and_then(|m| m.modified())
            .ok()
    };
    [deps.parent()?, deps]
        .into_iter()
        .filter_map(|dir| Some((modified(dir)?, dir.join(&name))))
        .max_by_key(|(time, _)| *time)
        .map(|(_, path)| path)
}

/// The `kin_*` functions `library` exports: the text (`T`) symbols `nm -D --defined-only` lists.
/// `None` when there is no `nm` to run.
fn exported_functions(library: &Path) -> Option<BTreeSet<String>> {
    let output = match Command::new("nm")
        .args(["-D", "--defined-only"])
        .arg(library)
        .output()
    {
        Ok(output) => output,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => panic!("cannot run nm: {e}"),
    };
    assert!(
        output.status.success(),
        "nm -D --defined-only {}: {}",
        library.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    let listing = String::from_utf8_lossy(&output.stdout);
    let symbols =
        listing.lines().filter_map(
            |line| match line.split_whitespace().collect::<Vec<_>>()[..] {
                [_, "T", name] | ["T", name] => {
                    let name = name.split('@').next().unwrap_or(name);
                    name.starts_with("kin_").then(|| name.to_string())
                }
                _ => None,
            },
        );
    Some(symbols.collect())
}

// ---------------------------------------------------------------------------------------------
// Tests

/// Every status code the library returns is defined in kin.h with the same value, or a C caller
/// would misread a failure.
#[test]
fn the_header_defines_every_status_code_with_the_librarys_value() {
    let header = HEADER;
    let codes = status_codes();
    for (name, value) in codes {
        assert_eq!(defined(header, name), Some(value), "{name}");
    }
    // No two codes share a value.
    let mut values: Vec<i32> = codes.iter().map(|(_, v)| *v).collect();
    values.sort_unstable();
    values.dedup();
    assert_eq!(values.len(), codes.len());
}

/// kin.h declares exactly the functions lib.rs exports, each with as many parameters, and each
/// parameter and return type the C spelling of the Rust one.
#[test]
fn the_header_declares_every_export_with_the_same_signature() {
    let exports = rust_exports(LIB_RS).expect("lib.rs scans");
    let declared = header_functions(HEADER).expect("kin.h scans");
    let problems = mismatches(&exports, &declared);
    assert!(
        problems.is_empty(),
        "kin.h differs from lib.rs:\n{}",
        problems.join("\n")
    );
    assert!(!exports.is_empty(), "no exports found in lib.rs");
    let params: usize = exports.iter().map(|f| f.params.len()).sum();
    eprintln!(
        "kin.h: {} functions, {params} parameters, agree with lib.rs",
        exports.len()
    );
}

/// Every `#define KIN_…` with a value is a library constant with that value (or a
/// `KIN_NAME_*` selector, checked by what it selects), and every public constant of lib.rs is
/// defined: a value that differs would make C and Rust disagree on a limit or a code.
#[test]
fn every_constant_the_header_defines_has_the_librarys_value() {
    let library = library_constants();
    let public = rust_public_constants(LIB_RS).expect("lib.rs scans");
    let listed: BTreeSet<String> = library.keys().map(|name| name.to_string()).collect();
    assert_eq!(
        public, listed,
        "library_constants() lists every public constant of lib.rs"
    );
    let defines = header_defines(HEADER).expect("kin.h scans");
    for (name, value) in &defines {
        if NAME_SELECTORS.iter().any(|(selector, _)| selector == name) {
            continue;
        }
        let expected = library
            .get(name.as_str())
            .unwrap_or_else(|| panic!("kin.h defines {name}, which mirrors no library constant"));
        assert_eq!(
            value.parse::<i128>().ok(),
            Some(*expected),
            "kin.h: {name} is `{value}`"
        );
    }
    for name in library.keys() {
        assert!(defines.contains_key(*name), "kin.h does not define {name}");
    }
    eprintln!(
        "kin.h: {} constants agree with lib.rs, {} name selectors checked separately",
        library.len(),
        NAME_SELECTORS.len()
    );
}

/// Each `KIN_NAME_*` value of kin.h makes `kin_model_name` return the kind of name it says.
#[test]
fn the_name_selectors_select_what_the_header_says() {
    let defines = header_defines(HEADER).expect("kin.h scans");
    let mut model = std::ptr::null_mut();
    // SAFETY: the source is valid for its length, `model` for writing one pointer; no error buffer.
    let code = unsafe {
        kin_model_compile(
            NAMED_MODEL.as_ptr().cast(),
            NAMED_MODEL.len(),
            &mut model,
            std::ptr::null_mut(),
            0,
        )
    };
    assert_eq!(code, KIN_OK, "the test model compiles");
    for (selector, expected) in NAME_SELECTORS {
        let what: c_int = defines
            .get(*selector)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("kin.h defines {selector} as an int"));
        let mut buf = [0 as c_char; 64];
        // SAFETY: a live model; `buf` is valid for its length.
        let len = unsafe { kin_model_name(model, what, 0, buf.as_mut_ptr(), buf.len()) };
        assert_ne!(len, usize::MAX, "{selector} = {what} selects nothing");
        // SAFETY: `kin_model_name` NUL-terminates what it writes.
        let name = unsafe { CStr::from_ptr(buf.as_ptr()) }.to_string_lossy();
        assert_eq!(name, *expected, "{selector} = {what}");
    }
    // SAFETY: a live model, freed once.
    unsafe { kin_model_free(model) };
}

/// The functions the built library really exports are those kin.h declares. Skipped (with a
/// note) when the library has not been built or `nm` is missing.
#[test]
fn the_shared_library_exports_exactly_the_headers_functions() {
    let Some(library) = shared_library() else {
        eprintln!("skipped: no shared library next to the test (run `cargo build -p kin-capi`)");
        return;
    };
    let Some(exported) = exported_functions(&library) else {
        eprintln!("skipped: no `nm` on the PATH to list {}", library.display());
        return;
    };
    let declared: BTreeSet<String> = header_functions(HEADER)
        .expect("kin.h scans")
        .into_iter()
        .map(|f| f.name)
        .collect();
    let missing: Vec<_> = declared.difference(&exported).collect();
    let extra: Vec<_> = exported.difference(&declared).collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "{}: declared in kin.h but not exported: {missing:?}; exported but not declared: {extra:?}",
        library.display()
    );
    eprintln!(
        "{}: its {} kin_* functions are kin.h's",
        library.display(),
        exported.len()
    );
}

/// The comparison can fail: a header with a parameter type changed, a declaration left out, a
/// parameter or a function too many is reported, naming the function.
#[test]
fn a_header_that_differs_from_the_library_is_reported() {
    let exports = rust_exports(LIB_RS).expect("lib.rs scans");
    let problems_with = |header: &str| {
        let declared = header_functions(header).expect("the altered kin.h scans");
        mismatches(&exports, &declared).join("\n")
    };
    let wrong_type = replace_once(
        HEADER,
        "size_t lag, size_t *input",
        "size_t lag, double *input",
    );
    let problems = problems_with(&wrong_type);
    assert!(
        problems.contains("`kin_model_lag_input`, parameter 3")
            && problems.contains("`size_t *`, but kin.h has `double *`"),
        "{problems}"
    );
    let left_out = replace_once(HEADER, "void kin_model_free(kin_model *model);", "");
    assert!(
        problems_with(&left_out)
            .contains("`kin_model_free` is exported by lib.rs but not declared"),
        "{}",
        problems_with(&left_out)
    );
    let extra_param = replace_once(
        HEADER,
        "size_t kin_model_axes(const kin_model *model);",
        "size_t kin_model_axes(const kin_model *model, int);",
    );
    assert!(
        problems_with(&extra_param).contains("`kin_model_axes` takes 1 parameters in lib.rs but 2"),
        "{}",
        problems_with(&extra_param)
    );
    let extra_function = format!("{HEADER}\nint kin_model_extra(const kin_model *model);\n");
    assert!(
        problems_with(&extra_function).contains("kin.h declares `kin_model_extra`, which lib.rs"),
        "{}",
        problems_with(&extra_function)
    );
    assert_eq!(problems_with(HEADER), "", "the real header agrees");
}

/// A Rust type the table does not know fails the comparison by name, and a generic export
/// cannot be read at all: neither is skipped.
#[test]
fn an_unknown_or_generic_rust_type_is_reported() {
    let declared = header_functions(HEADER).expect("kin.h scans");
    let unknown = replace_once(
        LIB_RS,
        "fn kin_last_error(buf: *mut c_char, len: usize)",
        "fn kin_last_error(buf: *mut c_char, len: u16)",
    );
    let exports = rust_exports(&unknown).expect("the altered lib.rs scans");
    let problems = mismatches(&exports, &declared).join("\n");
    assert!(
        problems.contains("`kin_last_error`, parameter 2: the Rust type `u16` is not in RUST_TO_C"),
        "{problems}"
    );
    let generic = replace_once(LIB_RS, "fn kin_model_axes(", "fn kin_model_axes<T>(");
    let error = rust_exports(&generic).expect_err("a generic export is refused");
    assert!(error.contains("`kin_model_axes` is generic"), "{error}");
}
