// The TextMate grammar on every example model: tokenised with vscode-textmate and the Oniguruma
// engine VS Code uses, each comment, keyword, number with its unit, factor family and declared
// name must get its scope. What is expected is found by this test's own small lexer, not by
// the grammar's patterns. Run from editors/vscode after `npm install vscode-textmate
// vscode-oniguruma`: `node --test test/` (KIN_EXAMPLES names the folder of models).
'use strict';

const test = require('node:test');
const assert = require('node:assert');
const fs = require('node:fs');
const path = require('node:path');
const vsctm = require('vscode-textmate');
const onig = require('vscode-oniguruma');

const grammarPath = path.join(__dirname, '..', 'syntaxes', 'kin.tmLanguage.json');
const examples = process.env.KIN_EXAMPLES || path.join(__dirname, '..', '..', '..', 'examples');

async function loadGrammar() {
  const wasm = fs.readFileSync(path.join(path.dirname(require.resolve('vscode-oniguruma')), 'onig.wasm'));
  await onig.loadWASM(wasm.buffer.slice(wasm.byteOffset, wasm.byteOffset + wasm.byteLength));
  const registry = new vsctm.Registry({
    onigLib: Promise.resolve({
      createOnigScanner: (patterns) => new onig.OnigScanner(patterns),
      createOnigString: (s) => new onig.OnigString(s),
    }),
    loadGrammar: async (scope) =>
      scope === 'source.kin' ? vsctm.parseRawGrammar(fs.readFileSync(grammarPath, 'utf8'), grammarPath) : null,
  });
  return registry.loadGrammar('source.kin');
}

function kinFiles(dir) {
  const out = [];
  for (const e of fs.readdirSync(dir, { withFileTypes: true })) {
    const p = path.join(dir, e.name);
    if (e.isDirectory()) out.push(...kinFiles(p));
    else if (e.name.endsWith('.kin')) out.push(p);
  }
  return out.sort();
}

// The scopes at column `col` of line `i`.
function scopesAt(lines, i, col) {
  const t = lines[i].tokens.find((t) => t.startIndex <= col && col < t.endIndex);
  return t ? t.scopes : [];
}

function has(scopes, prefix) {
  return scopes.some((s) => s.startsWith(prefix));
}

// Where the code of each line ends: the start of a `//` comment outside a block comment (this
// test's own lexer), and which columns lie inside block comments.
function split(text) {
  const result = [];
  let inBlock = false;
  for (const line of text.split('\n')) {
    const blocked = new Set();
    let commentAt = -1;
    for (let c = 0; c < line.length; c++) {
      if (inBlock) {
        blocked.add(c);
        if (line.startsWith('*/', c)) { blocked.add(c + 1); c++; inBlock = false; }
      } else if (line.startsWith('/*', c)) {
        inBlock = true; blocked.add(c); blocked.add(c + 1); c++;
      } else if (line.startsWith('//', c)) {
        commentAt = c; break;
      }
    }
    result.push({ line, commentAt, blocked });
  }
  return result;
}

const UNITS = 'nm|um|µm|μm|mm|urad|µrad|μrad|mrad|rad|degC|deg|arcsec|min|kN|m|s|h|K|N';
const FAMILIES = ['linear', 'poly', 'spline', 'straightness', 'fourier', 'periodic', 'backlash', 'lag', 'sin', 'cos'];
const KEYWORDS = ['machine', 'units', 'axis', 'input', 'chain', 'errors', 'task', 'prismatic', 'revolute', 'moving', 'fixed', 'range'];

test('the grammar scopes every example', async () => {
  const grammar = await loadGrammar();
  const files = kinFiles(examples);
  assert.ok(files.length >= 4, `examples in ${examples}`);
  const total = { family: 0 };
  for (const file of files) {
    const text = fs.readFileSync(file, 'utf8');
    let stack = vsctm.INITIAL;
    const lines = split(text).map((l) => {
      const r = grammar.tokenizeLine(l.line, stack);
      stack = r.ruleStack;
      return { ...l, tokens: r.tokens };
    });
    const counts = { comment: 0, keyword: 0, number: 0, unit: 0, family: 0, name: 0 };
    const declared = new Set();
    lines.forEach((l, i) => {
      const where = `${path.basename(file)}:${i + 1}`;
      if (l.commentAt >= 0) {
        for (let c = l.commentAt; c < l.line.length; c++) {
          assert.ok(has(scopesAt(lines, i, c), 'comment.'), `${where}:${c + 1} is in a comment`);
        }
        counts.comment++;
      }
      const code = l.commentAt >= 0 ? l.line.slice(0, l.commentAt) : l.line;
      const visible = (c) => !l.blocked.has(c);
      for (const m of code.matchAll(/[A-Za-z_][A-Za-z0-9_]*/g)) {
        if (!visible(m.index) || (m.index > 0 && /[0-9.]/.test(code[m.index - 1]))) continue;
        const word = m[0];
        const scopes = scopesAt(lines, i, m.index);
        if (KEYWORDS.includes(word)) {
          assert.ok(has(scopes, 'keyword.'), `${where}: keyword ${word}: ${scopes}`);
          counts.keyword++;
        }
        const after = code.slice(m.index + word.length);
        if (FAMILIES.includes(word) && /^\s*\(/.test(after)) {
          assert.ok(has(scopes, 'support.function.'), `${where}: family ${word}: ${scopes}`);
          counts.family++;
        }
        const before = code.slice(0, m.index);
        if (/\b(axis|input)\s+$/.test(before)) declared.add(word);
        if (/\b(axis|input)\s+$/.test(before)) {
          assert.ok(has(scopes, 'entity.name.'), `${where}: declared ${word}: ${scopes}`);
          counts.name++;
        }
      }
      const number = new RegExp(`(^|[^A-Za-z0-9_.])([+-]?\\d+(?:\\.\\d+)?)([ \\t]+)(${UNITS})(?![A-Za-z0-9_])`, 'g');
      for (const m of code.matchAll(number)) {
        const at = m.index + m[1].length;
        if (!visible(at)) continue;
        assert.ok(has(scopesAt(lines, i, at), 'constant.numeric.'), `${where}: number ${m[2]}`);
        const unitAt = at + m[2].length + m[3].length;
        assert.ok(has(scopesAt(lines, i, unitAt), 'keyword.other.unit.'), `${where}: unit ${m[4]}`);
        counts.number++;
        counts.unit++;
      }
    });
    // Every file shows comments, keywords, numbers with units and declared names; a model of
    // constants alone (a calibrator's first model) calls no factor family, so families are
    // required over the examples together.
    for (const [what, n] of Object.entries(counts)) {
      if (what === 'family') {
        total.family += n;
        continue;
      }
      assert.ok(n > 0, `${path.basename(file)}: no ${what} checked`);
    }
  }
  assert.ok(total.family > 0, 'no family checked in any example');
});
