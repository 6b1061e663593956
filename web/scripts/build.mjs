// npm run build: generates the editor's wire and REST types (scripts/wire.mjs:
// the C++ build's flatc output, proto/openapi.yaml), type-checks the editor
// against them, then bundles it into web/dist.
import { resolve } from 'node:path';
import { execFileSync } from 'node:child_process';
import { syncGenerated, webDir } from './wire.mjs';

await syncGenerated();
const bin = (name) => resolve(webDir, 'node_modules/.bin', name);
const run = (cmd, args) => execFileSync(cmd, args, { cwd: webDir, stdio: 'inherit', env: process.env });
try {
  run(bin('tsc'), ['-p', resolve(webDir, 'tsconfig.json')]);
  run(bin('tsc'), ['-p', resolve(webDir, 'tsconfig.node.json')]);
  run(bin('vite'), ['build', '--logLevel', 'warn']);
} catch (e) {
  process.exit(typeof e.status === 'number' && e.status ? e.status : 1);
}
console.log(`web: built ${resolve(webDir, 'dist')}`);
