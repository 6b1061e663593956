// Starts `flowclip serve --port 0` on copies of scenes/ and of the templates
// `make templates` records (the tests must not touch the repository's, and
// expect exactly those: not the 3D ones `make gallery` adds), with web/dist as the editor, and
// hands its URL to the tests in FLOWCLIP_URL. Returns the teardown.
//   FLOWCLIP_BIN        the executable (default $FLOWCLIP_BUILD_DIR/flowclip, ../build/flowclip)
//   FLOWCLIP_BATCH      flowclip-batch, which runs render jobs (default: the build's venv, $FLOWCLIP_BUILD_DIR/venv/bin)
//   FLOWCLIP_URL        a server already running: used as is, nothing started
import { spawn, type ChildProcess } from 'node:child_process';
import { cpSync, mkdtempSync, rmSync, existsSync, createWriteStream, readFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

const webDir = fileURLToPath(new URL('..', import.meta.url));
const repoDir = resolve(webDir, '..');

export default async function globalSetup(): Promise<(() => Promise<void>) | void> {
  if (process.env.FLOWCLIP_URL) return;
  const buildDir = resolve(webDir, process.env.FLOWCLIP_BUILD_DIR ?? '../build');
  const bin = process.env.FLOWCLIP_BIN ?? join(buildDir, 'flowclip');
  const dist = join(webDir, 'dist');
  if (!existsSync(bin)) throw new Error(`${bin} is missing: make build`);
  if (!existsSync(join(dist, 'index.html'))) throw new Error(`${dist} is missing: make web (npm run build)`);

  // Render jobs on (render.spec.ts), on two local workers: a wedge's two tasks run side by side.
  const batch = process.env.FLOWCLIP_BATCH ?? join(buildDir, 'venv', 'bin', 'flowclip-batch');
  if (!existsSync(batch)) throw new Error(`${batch} is missing: make setup (the Python venv) or set FLOWCLIP_BATCH`);

  const tmp = mkdtempSync(join(tmpdir(), 'flowclip-e2e-'));
  for (const name of ['drop2d', 'column2d', 'jet2d']) {
    const file = join(repoDir, 'templates', `${name}.h5`);
    if (!existsSync(file)) throw new Error(`${file} is missing: make templates`);
    cpSync(file, join(tmp, 'templates', `${name}.h5`));
  }
  cpSync(join(repoDir, 'scenes'), join(tmp, 'scenes'), { recursive: true });
  const logPath = join(tmp, 'server.log');
  const log = createWriteStream(logPath);
  const server: ChildProcess = spawn(
    bin,
    ['serve', '--port', '0', '--web', dist, '--templates', join(tmp, 'templates'),
      '--scenes', join(tmp, 'scenes'), '--exports', join(tmp, 'exports'),
      '--presets', join(repoDir, 'bench', 'accuracy', 'presets.json'),
      '--batch-command', batch, '--job-workers', '2'],
    { stdio: ['ignore', 'pipe', 'pipe'] },
  );
  server.stderr!.pipe(log);

  const url = await new Promise<string>((resolveUrl, reject) => {
    let out = '';
    const timer = setTimeout(() => reject(new Error(`flowclip serve did not start in 15 s:\n${out}`)), 15_000);
    server.stdout!.on('data', (chunk: Buffer) => {
      out += chunk.toString();
      log.write(chunk);
      const m = /listening on (http:\/\/\S+)/.exec(out);
      if (m) {
        clearTimeout(timer);
        resolveUrl(m[1]!);
      }
    });
    server.once('exit', (code) => {
      clearTimeout(timer);
      reject(new Error(`flowclip serve exited (${code}) before listening:\n${out}\n${safeRead(logPath)}`));
    });
  });
  process.env.FLOWCLIP_URL = url;
  process.env.FLOWCLIP_SERVER_LOG = logPath;
  console.log(`flowclip serve: ${url} (log ${logPath})`);

  return async () => {
    if (server.exitCode === null) {
      const exited = new Promise((r) => server.once('exit', r));
      server.kill('SIGTERM');
      const timeout = new Promise((r) => setTimeout(r, 5000));
      await Promise.race([exited, timeout]);
      if (server.exitCode === null) server.kill('SIGKILL');
    }
    log.end();
    if (!process.env.FLOWCLIP_KEEP_TMP) rmSync(tmp, { recursive: true, force: true });
  };
}

function safeRead(p: string): string {
  try {
    return readFileSync(p, 'utf8');
  } catch {
    return '';
  }
}
