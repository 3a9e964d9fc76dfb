//! What the language server knows about one document: pure functions from its text (and its
//! compiled form, when it compiles) to LSP answers. No I/O here, so each answer is testable.
//!
//! Names are found lexically (words outside comments), not from the syntax tree, so go to
//! definition, references and completion keep working while the user types a line that does
//! not parse yet. Hover on model facts (ranges, coefficients, aliases) needs the last text
//! that compiled.

use kin_compiler::ir::{self, JointKind, Machine};
use kin_compiler::{Compiled, Severity, Span};
use kin_syntax::syntax::{ast, KEYWORDS};
use lsp_types::{
    CompletionItem, CompletionItemKind, DiagnosticRelatedInformation, DiagnosticSeverity,
    DocumentSymbol, Hover, HoverContents, Location, MarkupContent, MarkupKind, NumberOrString,
    Position, Range, SymbolKind, TextEdit, Uri,
};

/// The reference text of the factor families: hover shows a family's section, completion
/// offers the families and options its headings name. One text, so the two cannot drift.
const FACTORS_MD: &str = include_str!("../../spec/factors.md");

// ---------------------------------------------------------------- positions

/// The LSP position (line, UTF-16 code unit) of byte `at` of `text`.
pub fn position(text: &str, at: usize) -> Position {
    let mut at = at.min(text.len());
    while !text.is_char_boundary(at) {
        at -= 1;
    }
    let before = &text[..at];
    let line = before.matches('\n').count();
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let character = text[line_start..at].encode_utf16().count();
    Position::new(
        u32::try_from(line).unwrap_or(u32::MAX),
        u32::try_from(character).unwrap_or(u32::MAX),
    )
}

/// The byte offset of an LSP position (clamped to its line and to the text).
pub fn offset(text: &str, pos: Position) -> usize {
    let mut line_start = 0;
    for _ in 0..pos.line {
        match text[line_start..].find('\n') {
            Some(i) => line_start += i + 1,
            None => return text.len(),
        }
    }
    let line_end = text[line_start..]
        .find('\n')
        .map_or(text.len(), |i| line_start + i);
    let mut units = 0u32;
    for (i, c) in text[line_start..line_end].char_indices() {
        if units >= pos.character {
            return line_start + i;
        }
        units += u32::try_from(c.len_utf16()).unwrap_or(2);
    }
    line_end
}

pub fn range(text: &str, span: Span) -> Range {
    Range::new(position(text, span.start), position(text, span.end))
}

// ---------------------------------------------------------------- diagnostics

/// `kin check`'s diagnostics as LSP diagnostics: the same codes, the primary label's span as
/// the range, the other labels as related information, notes and help in the message.
pub fn diagnostics(
    text: &str,
    uri: &Uri,
    found: &[kin_compiler::Diagnostic],
) -> Vec<lsp_types::Diagnostic> {
    found
        .iter()
        .map(|d| {
            let mut message = d.message.clone();
            if let Some(label) = d.labels.first().filter(|l| !l.message.is_empty()) {
                message.push_str(&format!(" ({})", label.message));
            }
            for note in &d.notes {
                message.push_str(&format!("\nnote: {note}"));
            }
            if let Some(help) = &d.help {
                message.push_str(&format!("\nhelp: {help}"));
            }
            let related: Vec<_> = d
                .labels
                .iter()
                .skip(1)
                .map(|l| DiagnosticRelatedInformation {
                    location: Location::new(uri.clone(), range(text, l.span)),
                    message: l.message.clone(),
                })
                .collect();
            lsp_types::Diagnostic {
                range: range(text, d.primary_span()),
                severity: Some(match d.severity {
                    Severity::Error => DiagnosticSeverity::ERROR,
                    Severity::Warning => DiagnosticSeverity::WARNING,
                }),
                code: Some(NumberOrString::String(d.code.to_string())),
                source: Some("kin".into()),
                message,
                related_information: (!related.is_empty()).then_some(related),
                ..Default::default()
            }
        })
        .collect()
}

// ---------------------------------------------------------------- words

/// An identifier in the text, outside comments.
#[derive(Debug, Clone, Copy)]
pub struct Word {
    pub start: usize,
    pub end: usize,
    /// Right after a `.`: a component (`X.tx`) or a parameter's part, not a name.
    pub after_dot: bool,
}

/// Every identifier outside comments. A word glued to a number (`5mm`) is a unit, not a name.
pub fn words(text: &str) -> Vec<Word> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    let is_start = |c: u8| c.is_ascii_alphabetic() || c == b'_';
    let is_char = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            i += 2;
            while i < b.len() && !b[i..].starts_with(b"*/") {
                i += 1;
            }
            i += 2;
        } else if is_char(b[i]) {
            let start = i;
            while i < b.len() && is_char(b[i]) {
                i += 1;
            }
            if is_start(b[start]) {
                let mut j = start;
                while j > 0 && matches!(b[j - 1], b' ' | b'\t') {
                    j -= 1;
                }
                let after_dot = j > 0 && b[j - 1] == b'.' && !(j > 1 && b[j - 2] == b'.');
                out.push(Word {
                    start,
                    end: i,
                    after_dot,
                });
            }
        } else {
            i += 1;
        }
    }
    out
}

/// What a declared name is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeclKind {
    Axis,
    Input,
    Tool,
}

/// A name's declaration: `axis X`, `input T`, `tool probe`.
#[derive(Debug, Clone, Copy)]
pub struct Decl {
    pub kind: DeclKind,
    pub word: Word,
}

pub fn declarations(text: &str, words: &[Word]) -> Vec<Decl> {
    let mut out = Vec::new();
    for pair in words.windows(2) {
        let (kw, name) = (pair[0], pair[1]);
        let name_text = &text[name.start..name.end];
        let kind = match &text[kw.start..kw.end] {
            "axis" => DeclKind::Axis,
            "input" => DeclKind::Input,
            "tool" if name_text != "chain" => DeclKind::Tool,
            _ => continue,
        };
        if !kw.after_dot && !name.after_dot {
            out.push(Decl { kind, word: name });
        }
    }
    out
}

fn word_at(words: &[Word], at: usize) -> Option<Word> {
    words.iter().copied().find(|w| w.start <= at && at <= w.end)
}

/// The declaration of the name under the cursor.
pub fn definition(text: &str, at: usize) -> Option<Span> {
    let ws = words(text);
    let w = word_at(&ws, at)?;
    if w.after_dot {
        return None;
    }
    let name = &text[w.start..w.end];
    declarations(text, &ws)
        .into_iter()
        .find(|d| &text[d.word.start..d.word.end] == name)
        .map(|d| Span::new(d.word.start, d.word.end))
}

/// Every use of the declared name under the cursor (with its declaration if asked).
pub fn references(text: &str, at: usize, with_declaration: bool) -> Vec<Span> {
    let ws = words(text);
    let Some(w) = word_at(&ws, at).filter(|w| !w.after_dot) else {
        return Vec::new();
    };
    let name = &text[w.start..w.end];
    let decls = declarations(text, &ws);
    let Some(decl) = decls
        .iter()
        .find(|d| &text[d.word.start..d.word.end] == name)
    else {
        return Vec::new();
    };
    ws.iter()
        .filter(|u| !u.after_dot && &text[u.start..u.end] == name)
        .filter(|u| with_declaration || u.start != decl.word.start)
        .map(|u| Span::new(u.start, u.end))
        .collect()
}

// ---------------------------------------------------------------- hover

/// The section of spec/factors.md on `family`, from its heading to the next.
fn family_section(family: &str) -> Option<String> {
    let heading = format!("## `{family}(");
    let alt = format!("## `{family}`");
    let mut out = String::new();
    let mut inside = false;
    for line in FACTORS_MD.lines() {
        if line.starts_with("## ") {
            if inside {
                break;
            }
            inside = line.starts_with(&heading) || line.starts_with(&alt);
            if !inside {
                // `## `sin(e)`, `cos(e)``: a heading may name several families.
                inside = line.contains(&format!("`{family}(")) && line.starts_with("## `");
            }
        }
        if inside {
            out.push_str(line);
            out.push('\n');
        }
    }
    (!out.is_empty()).then(|| {
        let mut s = out.trim_end().to_string();
        s = s.replacen("## ", "### ", 1);
        s
    })
}

/// Family names (the headings of spec/factors.md) and the options their headings name.
pub fn families_and_options() -> (Vec<String>, Vec<String>) {
    let mut families = Vec::new();
    let mut options = vec!["fit".to_string()];
    for line in FACTORS_MD.lines() {
        let Some(rest) = line.strip_prefix("## `") else {
            continue;
        };
        for code in rest.split("`, `").map(|c| c.trim_end_matches('`')) {
            let name: String = code
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() && !families.contains(&name) {
                families.push(name);
            }
            let Some(args) = code.find('(').map(|i| &code[i + 1..]) else {
                continue;
            };
            for seg in args.split(',').skip(1) {
                let first = seg.split_whitespace().next().unwrap_or("");
                let first = first.trim_end_matches([')', '`']);
                if !first.is_empty()
                    && first.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                    && first.starts_with(|c: char| c.is_ascii_alphabetic())
                    && !options.iter().any(|o| o == first)
                {
                    options.push(first.to_string());
                }
            }
        }
    }
    (families, options)
}

fn unit_value(v: f64, unit: &kin_compiler::units::Unit) -> String {
    let x = (v - unit.offset) / unit.scale;
    format!("{} {}", trim_number(x), unit.name)
}

fn trim_number(x: f64) -> String {
    let s = format!("{x:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

fn axis_hover(m: &Machine, name: &str) -> Option<String> {
    let a = m.axes.iter().find(|a| a.name == name)?;
    let (kind, unit) = match a.kind {
        JointKind::Prismatic => ("prismatic", &m.units.length),
        JointKind::Revolute => ("revolute", &m.units.angle),
    };
    let d = a.direction;
    let range = if a.continuous {
        "continuous".to_string()
    } else {
        format!(
            "range {} .. {}",
            unit_value(a.range[0], unit),
            unit_value(a.range[1], unit)
        )
    };
    let chain = if m
        .tool_chain
        .iter()
        .any(|e| m.axes.get(e.axis).is_some_and(|x| x.name == name))
    {
        "tool chain"
    } else if m
        .workpiece_chain
        .iter()
        .any(|e| m.axes.get(e.axis).is_some_and(|x| x.name == name))
    {
        "workpiece chain"
    } else {
        "no chain"
    };
    let errors = m
        .coefficients
        .iter()
        .filter(|c| c.name.starts_with(&format!("{name}.")))
        .count();
    Some(format!(
        "**axis {name}** — {kind}, direction ({}, {}, {}), {range}; positions in {}\n\nIn the {chain}; {errors} error coefficient{} on its frame.",
        trim_number(d[0]),
        trim_number(d[1]),
        trim_number(d[2]),
        unit.name,
        if errors == 1 { "" } else { "s" }
    ))
}

fn input_hover(m: &Machine, name: &str) -> Option<String> {
    let i = m.inputs.iter().find(|i| i.name == name)?;
    let mut s = format!("**input {name}** — in {}", i.unit.name);
    if i.absolute {
        s.push_str(", absolute");
    }
    if let Some(r) = i.range {
        s.push_str(&format!(
            ", range {} .. {}",
            unit_value(r[0], &i.unit),
            unit_value(r[1], &i.unit)
        ));
    }
    Some(s)
}

fn tool_hover(m: &Machine, name: &str) -> Option<String> {
    m.tools.iter().find(|t| t.name == name)?;
    Some(format!(
        "**tool {name}** — a tool frame at the end of the tool chain; its error components are `{name}.tx` … `{name}.rz`."
    ))
}

fn component_meaning(c: ir::Component) -> &'static str {
    match c {
        ir::Component::Tx => "translation error along x",
        ir::Component::Ty => "translation error along y",
        ir::Component::Tz => "translation error along z",
        ir::Component::Rx => "rotation error about x",
        ir::Component::Ry => "rotation error about y",
        ir::Component::Rz => "rotation error about z",
    }
}

fn alias_hover(m: &Machine, name: &str) -> Option<String> {
    let layout = ir::Layout {
        axes: &m.axes,
        tool_chain: &m.tool_chain,
        workpiece_chain: &m.workpiece_chain,
    };
    let a = ir::alias(name, layout).ok()??;
    let sign = if a.sign < 0.0 { "−" } else { "" };
    Some(format!(
        "**{name}** — ISO 230-1 / VDI 2617 name for `{sign}{}.{}`: the {} of the frame of axis {}.",
        a.axis,
        a.component.name(),
        component_meaning(a.component),
        a.axis
    ))
}

/// The coefficients brought by the terms under the cursor.
fn coefficients_hover(c: &Compiled, at: usize) -> Option<String> {
    let hits: Vec<&ir::Coefficient> = c
        .map
        .coefficients
        .iter()
        .zip(&c.machine.coefficients)
        .filter(|(s, _)| s.start <= at && at <= s.end)
        .map(|(_, k)| k)
        .collect();
    let first = hits.first()?;
    let mut s = format!(
        "{} coefficient{} ({}), each in {}:",
        hits.len(),
        if hits.len() == 1 { "" } else { "s" },
        first.name.split('[').next().unwrap_or(&first.name),
        first.unit
    );
    for k in hits.iter().take(12) {
        s.push_str(&format!("\n- `{}` × {}", k.name, k.label));
    }
    if hits.len() > 12 {
        s.push_str(&format!("\n- … {} more", hits.len() - 12));
    }
    Some(s)
}

/// The hover text at byte `at`: a name's declaration facts, an alias's canonical name, a
/// family's formula and thesis equation with the coefficients its term brings.
pub fn hover(text: &str, compiled: Option<&Compiled>, at: usize) -> Option<Hover> {
    let ws = words(text);
    let w = word_at(&ws, at)?;
    let word = &text[w.start..w.end];
    let mut parts: Vec<String> = Vec::new();
    if w.after_dot {
        if let Some(c) = ir::Component::ALL.iter().find(|c| c.name() == word) {
            parts.push(format!(
                "**{word}** — the {} of this frame.",
                component_meaning(*c)
            ));
        }
    } else if let Some(m) = compiled.map(|c| &c.machine) {
        if let Some(s) = axis_hover(m, word)
            .or_else(|| input_hover(m, word))
            .or_else(|| tool_hover(m, word))
            .or_else(|| alias_hover(m, word))
        {
            parts.push(s);
        }
    }
    let is_call = text[w.end..].trim_start().starts_with('(');
    if parts.is_empty() && (is_call || word == "const") {
        if let Some(section) = family_section(word) {
            parts.push(section);
        }
        if let Some(s) = compiled.and_then(|c| coefficients_hover(c, w.start)) {
            parts.push(s);
        }
    }
    if parts.is_empty() {
        if let Some(d) = declarations(text, &ws)
            .into_iter()
            .find(|d| &text[d.word.start..d.word.end] == word)
        {
            // Not compiled (yet): the declaration's line as written.
            let line_start = text[..d.word.start].rfind('\n').map_or(0, |i| i + 1);
            let line_end = text[d.word.end..]
                .find('\n')
                .map_or(text.len(), |i| d.word.end + i);
            parts.push(format!(
                "```kin\n{}\n```",
                text[line_start..line_end].trim()
            ));
        }
    }
    if parts.is_empty() {
        return None;
    }
    Some(Hover {
        contents: HoverContents::Markup(MarkupContent {
            kind: MarkupKind::Markdown,
            value: parts.join("\n\n---\n\n"),
        }),
        range: Some(range(text, Span::new(w.start, w.end))),
    })
}

// ---------------------------------------------------------------- completion

/// Completions at byte `at`: components after a `.`; otherwise the declared names, the factor
/// families, their options and the keywords.
pub fn completion(text: &str, at: usize) -> Vec<CompletionItem> {
    let at = at.min(text.len());
    let before = text[..at].trim_end_matches(|c: char| c.is_ascii_alphanumeric() || c == '_');
    let item = |label: &str, kind: CompletionItemKind, detail: &str| CompletionItem {
        label: label.to_string(),
        kind: Some(kind),
        detail: (!detail.is_empty()).then(|| detail.to_string()),
        ..Default::default()
    };
    if before.ends_with('.') && !before.ends_with("..") {
        return ir::Component::ALL
            .iter()
            .map(|c| item(c.name(), CompletionItemKind::FIELD, component_meaning(*c)))
            .collect();
    }
    let ws = words(text);
    let mut out: Vec<CompletionItem> = declarations(text, &ws)
        .iter()
        .map(|d| {
            let (kind, detail) = match d.kind {
                DeclKind::Axis => (CompletionItemKind::VARIABLE, "axis"),
                DeclKind::Input => (CompletionItemKind::VARIABLE, "input"),
                DeclKind::Tool => (CompletionItemKind::VARIABLE, "tool"),
            };
            item(&text[d.word.start..d.word.end], kind, detail)
        })
        .collect();
    let (families, options) = families_and_options();
    out.extend(
        families
            .iter()
            .map(|f| item(f, CompletionItemKind::FUNCTION, "factor family")),
    );
    out.extend(
        options
            .iter()
            .map(|o| item(o, CompletionItemKind::PROPERTY, "option")),
    );
    out.extend(
        KEYWORDS
            .iter()
            .map(|k| item(k, CompletionItemKind::KEYWORD, "")),
    );
    let mut seen = std::collections::HashSet::new();
    out.retain(|i| seen.insert(i.label.clone()));
    out
}

// ---------------------------------------------------------------- outline

#[allow(deprecated)] // `DocumentSymbol::deprecated` must be set; it is `None`
fn symbol(
    text: &str,
    name: String,
    detail: Option<String>,
    kind: SymbolKind,
    span: Span,
    name_span: Span,
    children: Vec<DocumentSymbol>,
) -> DocumentSymbol {
    DocumentSymbol {
        name,
        detail,
        kind,
        tags: None,
        deprecated: None,
        range: range(text, span),
        selection_range: range(text, name_span),
        children: (!children.is_empty()).then_some(children),
    }
}

/// The machine's outline: axes, inputs, chains with their frames and tools, error definitions.
pub fn symbols(text: &str) -> Vec<DocumentSymbol> {
    let Ok(file) = kin_syntax::syntax::parse_file(text) else {
        return Vec::new();
    };
    let m = &file.machine;
    let mut children = Vec::new();
    for item in &m.items {
        match item {
            ast::Item::Axis(a) => children.push(symbol(
                text,
                a.name.node.clone(),
                Some("axis".into()),
                SymbolKind::FIELD,
                a.span,
                a.name.span,
                vec![],
            )),
            ast::Item::Input(i) => children.push(symbol(
                text,
                i.name.node.clone(),
                Some(format!("input: {}", i.dimension.node)),
                SymbolKind::VARIABLE,
                i.span,
                i.name.span,
                vec![],
            )),
            ast::Item::Chain(c) => {
                let label = match c.kind.node {
                    ast::ChainKind::Tool => "tool chain",
                    ast::ChainKind::Workpiece => "workpiece chain",
                };
                let frames = c
                    .items
                    .iter()
                    .map(|e| match e {
                        ast::ChainItem::Element { axis, span, .. } => symbol(
                            text,
                            axis.node.clone(),
                            Some("frame".into()),
                            SymbolKind::OBJECT,
                            *span,
                            axis.span,
                            vec![],
                        ),
                        ast::ChainItem::Tool { name, span, .. } => symbol(
                            text,
                            name.node.clone(),
                            Some("tool".into()),
                            SymbolKind::OBJECT,
                            *span,
                            name.span,
                            vec![],
                        ),
                        ast::ChainItem::Workpiece { span, .. } => symbol(
                            text,
                            "workpiece".into(),
                            None,
                            SymbolKind::OBJECT,
                            *span,
                            *span,
                            vec![],
                        ),
                    })
                    .collect();
                children.push(symbol(
                    text,
                    label.into(),
                    None,
                    SymbolKind::NAMESPACE,
                    c.span,
                    c.kind.span,
                    frames,
                ));
            }
            ast::Item::Errors(e) => {
                let defs = e
                    .defs
                    .iter()
                    .filter_map(|d| {
                        let first = d.targets.first()?;
                        let last = d.targets.last()?;
                        let names = Span::new(first.span.start, last.span.end);
                        Some(symbol(
                            text,
                            text[names.start..names.end].to_string(),
                            Some(if d.add { "+=" } else { "=" }.into()),
                            SymbolKind::PROPERTY,
                            d.span,
                            names,
                            vec![],
                        ))
                    })
                    .collect();
                children.push(symbol(
                    text,
                    "errors".into(),
                    None,
                    SymbolKind::NAMESPACE,
                    e.span,
                    Span::new(e.span.start, e.span.start + "errors".len()),
                    defs,
                ));
            }
            ast::Item::Task(_) | ast::Item::Units(_) | ast::Item::Gravity(_) => {}
        }
    }
    vec![symbol(
        text,
        m.name.node.clone(),
        Some("machine".into()),
        SymbolKind::MODULE,
        m.span,
        m.name.span,
        children,
    )]
}

// ---------------------------------------------------------------- formatting

/// `kin fmt`'s result as one edit over the whole document; none when it is already formatted;
/// `None` when it cannot be formatted (syntax errors: the diagnostics say where).
pub fn formatting(text: &str) -> Option<Vec<TextEdit>> {
    let formatted = kin_syntax::format::format_source(text).ok()?;
    if formatted == text {
        return Some(Vec::new());
    }
    Some(vec![TextEdit::new(
        Range::new(Position::new(0, 0), position(text, text.len())),
        formatted,
    )])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_count_utf16_units() {
        let text = "a µm\n𝛼b x\n";
        assert_eq!(
            position(text, text.find('x').unwrap_or(0)),
            Position::new(1, 4)
        );
        assert_eq!(
            offset(text, Position::new(1, 4)),
            text.find('x').unwrap_or(0)
        );
        assert_eq!(offset(text, Position::new(9, 0)), text.len());
        assert_eq!(position(text, 3), Position::new(0, 2)); // inside `µ`: its start
    }

    #[test]
    fn families_and_options_come_from_the_spec() {
        let (f, o) = families_and_options();
        for name in [
            "spline", "fourier", "periodic", "lag", "warmup", "backlash", "const",
        ] {
            assert!(f.iter().any(|x| x == name), "{name} in {f:?}");
        }
        for name in ["knots", "degree", "harmonics", "wavelength", "tau", "fit"] {
            assert!(o.iter().any(|x| x == name), "{name} in {o:?}");
        }
        assert!(family_section("fourier").is_some_and(|s| s.contains("harmonics")));
        assert!(family_section("warmup").is_some_and(|s| s.contains("1 − e^{−(t − t₀)/τ}")));
    }

    #[test]
    fn names_and_references_skip_comments_and_components() {
        let text = "machine m { axis X prismatic along x // X here\n input T : temperature\n tool chain { X moving tool p at (0,0,1) mm }\n errors { X.tx = spline(X, knots 2) * T }\n}";
        let at = text.find("X.tx").unwrap_or(0);
        let def = definition(text, at).map(|s| &text[s.start..s.end]);
        assert_eq!(def, Some("X"));
        assert_eq!(references(text, at, true).len(), 4);
        assert_eq!(references(text, at, false).len(), 3);
        assert!(definition(text, text.find("tx").unwrap_or(0)).is_none());
        let p = text.find("tool p").unwrap_or(0) + 5;
        assert_eq!(definition(text, p).map(|s| s.start), Some(p));
    }
}
