"""`kin lsp` driven by pygls's LSP client over stdio, as an editor would drive it.

    python lsp_client.py PATH/TO/kin PATH/TO/examples/milling_5axis.kin

Opens the 5-axis example, edits it (a typo, then back), and checks the diagnostics, hover,
definition, references, completion, outline and formatting answers against facts of the file
found here independently (by text search), then shuts the server down. Prints
`N passed, M failed` and exits non-zero if any check failed.
"""

import asyncio
import sys

from lsprotocol import types as t
from pygls.lsp.client import LanguageClient

KIN, EXAMPLE = sys.argv[1], sys.argv[2]
URI = "file:///tmp/milling_5axis.kin"
results = []


def check(name, ok, detail=""):
    results.append(bool(ok))
    print(("ok   " if ok else "FAIL ") + name + ("" if ok else f": {detail}"))


def position(text, needle, plus=0):
    at = text.index(needle) + plus
    line = text.count("\n", 0, at)
    start = text.rfind("\n", 0, at) + 1
    # LSP columns count UTF-16 code units.
    return t.Position(line=line, character=len(text[start:at].encode("utf-16-le")) // 2)


async def main():
    text = open(EXAMPLE, encoding="utf-8").read()
    client = LanguageClient("kin-lsp-test", "1")
    published = {}
    arrived = asyncio.Condition()

    @client.feature(t.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS)
    async def diagnostics(params):
        async with arrived:
            published.setdefault(params.version, []).append(params.diagnostics)
            arrived.notify_all()

    async def diagnostics_of(version, count=1):
        async with arrived:
            await asyncio.wait_for(
                arrived.wait_for(lambda: len(published.get(version, [])) >= count), 30
            )
        return published[version][count - 1]

    await client.start_io(KIN, "lsp")
    init = await client.initialize_async(
        t.InitializeParams(capabilities=t.ClientCapabilities(), process_id=None)
    )
    check("initialize: hover and formatting offered",
          init.capabilities.hover_provider and init.capabilities.document_formatting_provider)
    client.initialized(t.InitializedParams())
    doc = t.TextDocumentIdentifier(uri=URI)
    client.text_document_did_open(t.DidOpenTextDocumentParams(
        text_document=t.TextDocumentItem(uri=URI, language_id="kin", version=1, text=text)))
    first = await diagnostics_of(1)
    check("didOpen: no error on the example",
          all(d.severity != t.DiagnosticSeverity.Error for d in first), first)

    broken = text.replace("axis A revolute", "axis A revolutee", 1)
    client.text_document_did_change(t.DidChangeTextDocumentParams(
        text_document=t.VersionedTextDocumentIdentifier(uri=URI, version=2),
        content_changes=[t.TextDocumentContentChangeWholeDocument(text=broken)]))
    errors = [d for d in await diagnostics_of(2) if d.severity == t.DiagnosticSeverity.Error]
    check("didChange: a typo is an E0001 at its place",
          errors and errors[0].code == "E0001"
          and errors[0].range.start == position(broken, "revolutee"), errors)

    client.text_document_did_change(t.DidChangeTextDocumentParams(
        text_document=t.VersionedTextDocumentIdentifier(uri=URI, version=3),
        content_changes=[t.TextDocumentContentChangeWholeDocument(text=text)]))
    await diagnostics_of(3)

    hover = await client.text_document_hover_async(
        t.HoverParams(text_document=doc, position=position(text, "axis Z", 5)))
    value = hover.contents.value if hover else ""
    check("hover: an axis's range and unit", "prismatic" in value and "-450 mm .. 0 mm" in value, value)
    hover = await client.text_document_hover_async(
        t.HoverParams(text_document=doc, position=position(text, "fourier(", 1)))
    value = hover.contents.value if hover else ""
    check("hover: a family's formula and thesis equation", "fourier" in value and "eq. 3." in value, value)

    at = position(text, "Z.tx", 0)
    found = await client.text_document_definition_async(
        t.DefinitionParams(text_document=doc, position=at))
    where = found if isinstance(found, t.Location) else (found[0] if found else None)
    check("definition: Z is declared by `axis Z`",
          where and where.range.start == position(text, "axis Z", 5), found)
    refs = await client.text_document_references_async(t.ReferenceParams(
        text_document=doc, position=at, context=t.ReferenceContext(include_declaration=False)))
    check("references: every use of Z", refs and len(refs) >= 5, refs)

    items = await client.text_document_completion_async(
        t.CompletionParams(text_document=doc, position=position(text, "errors {", 8)))
    items = items.items if isinstance(items, t.CompletionList) else items
    labels = {i.label for i in items or []}
    check("completion: families, options and names",
          {"spline", "periodic", "wavelength", "load", "C"} <= labels, sorted(labels))

    symbols = await client.text_document_document_symbol_async(
        t.DocumentSymbolParams(text_document=doc))
    names = {s.name for s in (symbols[0].children or [])} if symbols else set()
    check("documentSymbol: the machine's outline", {"A", "load", "errors"} <= names, names)

    messy = text.replace("    axis C", "axis   C", 1)
    client.text_document_did_change(t.DidChangeTextDocumentParams(
        text_document=t.VersionedTextDocumentIdentifier(uri=URI, version=4),
        content_changes=[t.TextDocumentContentChangeWholeDocument(text=messy)]))
    edits = await client.text_document_formatting_async(t.DocumentFormattingParams(
        text_document=doc, options=t.FormattingOptions(tab_size=4, insert_spaces=True)))
    check("formatting: kin fmt's text", edits and edits[0].new_text == text, edits)

    await client.shutdown_async(None)
    client.exit(None)
    await client.stop()


asyncio.run(main())
passed = sum(results)
print(f"lsp client: {passed} passed, {len(results) - passed} failed")
sys.exit(0 if results and all(results) else 1)
