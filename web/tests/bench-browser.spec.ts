// Smoke check of the browser benchmark (scripts/bench-browser.mjs, `make
// bench-web`): one case, two repetitions, and its output is complete. No
// timing is asserted: only that every figure is there and finite, and that the
// bytes agree between the stream, the WebSocket and the REST frame.
import { expect, test } from '@playwright/test';
import { execFile } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';

const webDir = fileURLToPath(new URL('..', import.meta.url));

test('bench-browser --cases 2d-100k: a complete table and JSON', async () => {
  test.setTimeout(90_000);
  const tmp = mkdtempSync(join(tmpdir(), 'flowclip-bench-smoke-'));
  try {
    const json = join(tmp, 'bench.json');
    const { code, stdout, stderr } = await new Promise<{ code: number | null; stdout: string; stderr: string }>((resolve) => {
      execFile(process.execPath, ['scripts/bench-browser.mjs', '--cases', '2d-100k', '--reps', '2', '--warmup', '0', '--json', json],
        { cwd: webDir, env: process.env, timeout: 80_000 },
        (err, out, errOut) => resolve({ code: err ? ((err as { code?: number }).code ?? 1) : 0, stdout: out, stderr: errOut }));
    });
    expect(code, `${stdout}\n${stderr}`).toBe(0);
    expect(stdout).toMatch(/^SOFTWARE GL: .*SwiftShader/m);
    expect(stdout).toMatch(/^2D r=0\.0025 +100,000 /m);
    const report = JSON.parse(readFileSync(json, 'utf8'));
    expect(report.software).toBe(true);
    expect(report.results).toHaveLength(1);
    const r = report.results[0];
    expect(r.count).toBe(100_000);
    expect(r.streamBytes).toBe(r.restBytes);
    expect(r.wsBytes).toBe(r.streamBytes);
    expect(r.streamBytes / r.count).toBeGreaterThanOrEqual(6); // 2 × uint16 + kind + phase per particle
    expect(r.drawnPoints).toBe(100_000);
    for (const k of ['decode', 'uploadDraw', 'draw', 'upload', 'decodeNew', 'uploadDrawNew', 'uploadNew', 'sync']) {
      expect(r[k].n, k).toBe(2);
      expect(Number.isFinite(r[k].median) && Number.isFinite(r[k].p95), k).toBe(true);
    }
    expect(r.uploadedBytes).toBe(12 * r.count); // positions (colours kept)
    expect(r.uploadedNewBytes).toBe(24 * r.count); // positions and colours
  } finally {
    rmSync(tmp, { recursive: true, force: true });
  }
});
