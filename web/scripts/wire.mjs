// The editor's generated code, never committed, kept in node_modules/.flowclip/wire/:
//
// * `@wire`: the flatbuffers code the C++ build generates from proto/flowclip.fbs
//   (flatc --ts into $FLOWCLIP_BUILD_DIR/generated/ts, default ../build), copied
//   here so that its `import 'flatbuffers'` resolves to web/node_modules, with
//   `// @ts-nocheck` on top (flatc 2.0.8's output does not pass TypeScript's
//   strict checks, e.g. a bit_flags enum field defaulting to 0); its
//   declarations still type the editor.
// * `@openapi`: the REST contract's types (`paths`, `components`, `operations`),
//   generated from proto/openapi.yaml by openapi-typescript. src/net/types.ts
//   names them for the editor; src/net/Api.ts takes its routes from `paths`.
//
// Run by `npm run build` (scripts/build.mjs), `npm run dev` and `npm run
// typecheck`; `node scripts/wire.mjs` alone refreshes both.
import { existsSync, mkdirSync, readFileSync, writeFileSync } from 'node:fs';
import { dirname, relative, resolve } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

export const webDir = resolve(dirname(fileURLToPath(import.meta.url)), '..');
const generatedDir = resolve(webDir, 'node_modules/.flowclip/wire');
export const wireCopy = resolve(generatedDir, 'flowclip_generated.ts');
export const openapiTypes = resolve(generatedDir, 'openapi.ts');
export const openapiSpec = resolve(webDir, '../proto/openapi.yaml');

function writeIfChanged(path, text) {
  mkdirSync(dirname(path), { recursive: true });
  if (!existsSync(path) || readFileSync(path, 'utf8') !== text) writeFileSync(path, text);
}

export function syncWire() {
  const buildDir = resolve(webDir, process.env.FLOWCLIP_BUILD_DIR ?? '../build');
  const source = resolve(buildDir, 'generated/ts/flowclip_generated.ts');
  if (!existsSync(source)) {
    console.error(`web: ${source} is missing: build the server first (make build), ` +
      'or point FLOWCLIP_BUILD_DIR at a build directory');
    process.exit(2);
  }
  const text = `// @ts-nocheck\n// Copied from ${source} by web/scripts/wire.mjs; do not edit.\n` + readFileSync(source, 'utf8');
  writeIfChanged(wireCopy, text);
  return source;
}

// `{type: object}` without properties (a scene's `settings`, a merge patch) is
// an open object, Record<string, unknown>, not Record<string, never>.
export async function syncOpenApi() {
  const { default: openapiTS } = await import('openapi-typescript');
  const types = await openapiTS(pathToFileURL(openapiSpec), {
    emptyObjectsUnknown: true,
    silent: true,
    commentHeader: `// Generated from proto/openapi.yaml by web/scripts/wire.mjs (openapi-typescript); do not edit.\n`,
  });
  writeIfChanged(openapiTypes, types);
  return openapiSpec;
}

/** Both: what build.mjs, `npm run dev` and `npm run typecheck` call. */
export async function syncGenerated() {
  const wire = syncWire();
  const spec = await syncOpenApi();
  return { wire, spec };
}

if (process.argv[1] && resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
  const { wire, spec } = await syncGenerated();
  console.log(`web: @wire <- ${wire}\nweb: @openapi <- ${relative(process.cwd(), spec) || spec}`);
}
