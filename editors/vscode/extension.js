// Starts `kin lsp` (the path is the `kin.path` setting) for .kin files and stops it with the
// editor. Everything else (diagnostics, hover, definitions, completion, outline, formatting)
// is the server's.
'use strict';

const vscode = require('vscode');
const { LanguageClient, TransportKind } = require('vscode-languageclient/node');

let client;

function activate(context) {
  const command = vscode.workspace.getConfiguration('kin').get('path') || 'kin';
  const server = { command, args: ['lsp'], transport: TransportKind.stdio };
  client = new LanguageClient(
    'kin',
    'kin language server',
    { run: server, debug: server },
    { documentSelector: [{ scheme: 'file', language: 'kin' }, { scheme: 'untitled', language: 'kin' }] }
  );
  context.subscriptions.push(client);
  return client.start();
}

function deactivate() {
  return client ? client.stop() : undefined;
}

module.exports = { activate, deactivate };
