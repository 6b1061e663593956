// Recording templates from the library: a server of its own with an empty
// database, two small recipes (tiny: 5 frames, recorded at once; endless: runs
// until cancelled) and a scene that needs tiny's template. The library offers
// both; Record shows the job's progress, Cancel stops it with nothing written,
// and a finished recording's template joins the library and the scene is no
// longer marked as missing it.
import { expect, test } from '@playwright/test';
import { spawn, type ChildProcess } from 'node:child_process';
import { existsSync, mkdirSync, mkdtempSync, readdirSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

const webDir = fileURLToPath(new URL('..', import.meta.url));

/** The small 2D tank of the service tests (100 particles, ~1 ms a frame) capturing `frames` frames. */
function recipe(name: string, template: string, frames: number) {
  return {
    name, dimension: 2, particle_radius: 0.02,
    domain: { min: [0, 0], max: [1, 1] },
    fluid_blocks: [{ min: [0, 0], max: [0.4, 0.4] }],
    capture: { name: template, region: { min: [0, 0], max: [1, 1] }, frames },
  };
}

let server: ChildProcess | null = null;
let url = '';
let tmp = '';

test.beforeAll(async () => {
  const buildDir = resolve(webDir, process.env.FLOWCLIP_BUILD_DIR ?? '../build');
  const bin = process.env.FLOWCLIP_BIN ?? join(buildDir, 'flowclip');
  if (!existsSync(bin)) throw new Error(`${bin} is missing: make build`);
  tmp = mkdtempSync(join(tmpdir(), 'flowclip-recipes-'));
  for (const d of ['templates', 'scenes', 'recipes']) mkdirSync(join(tmp, d));
  writeFileSync(join(tmp, 'recipes', 'tiny.json'), JSON.stringify(recipe('tiny', 'tiny_tpl', 5)));
  writeFileSync(join(tmp, 'recipes', 'endless.json'), JSON.stringify(recipe('endless', 'endless_tpl', 100000)));
  const scene = { ...recipe('needs_tiny', '', 0), capture: undefined, instances: [{ name: 'tiny', template: 'tiny_tpl', start: 0 }] };
  writeFileSync(join(tmp, 'scenes', 'needs_tiny.json'), JSON.stringify(scene));
  server = spawn(bin, ['serve', '--port', '0', '--web', join(webDir, 'dist'), '--templates', join(tmp, 'templates'),
    '--scenes', join(tmp, 'scenes'), '--exports', join(tmp, 'exports'), '--recipes', join(tmp, 'recipes')],
  { stdio: ['ignore', 'pipe', 'inherit'] });
  url = await new Promise<string>((resolveUrl, reject) => {
    let out = '';
    server!.stdout!.on('data', (chunk: Buffer) => {
      out += chunk.toString();
      const m = /listening on (http:\/\/\S+)/.exec(out);
      if (m) resolveUrl(m[1]!);
    });
    server!.once('exit', (code) => reject(new Error(`flowclip serve exited (${code}) before listening:\n${out}`)));
  });
});

test.afterAll(async () => {
  if (server && server.exitCode === null) {
    const exited = new Promise((r) => server!.once('exit', r));
    server.kill('SIGINT');
    await exited;
  }
  if (tmp) rmSync(tmp, { recursive: true, force: true });
});

test('the library records a missing template from its recipe with progress, cancel, and the template appears', async ({ page }) => {
  const errors: string[] = [];
  page.on('pageerror', (e) => errors.push(e.message));
  await page.goto(`${url}/?scene=`);
  const picker = page.getByTestId('scene-picker');
  await expect(picker.locator('option[value="needs_tiny"]')).toHaveAttribute('data-missing', 'tiny_tpl');
  await expect(page.getByTestId('library-empty')).toContainText('Record one below');
  const tiny = page.getByTestId('recipe-tiny'), endless = page.getByTestId('recipe-endless');
  await expect(tiny).toContainText('needed by needs_tiny');
  await expect(endless).toBeVisible(); // the library is empty: every recipe is offered

  // A long recording: its progress bar moves, Cancel stops it and writes nothing.
  await expect(page.getByTestId('recipe-progress-endless')).toBeHidden();
  await page.getByTestId('recipe-record-endless').click();
  await expect(page.getByTestId('recipe-record-endless')).toBeHidden();
  await expect(page.getByTestId('recipe-progress-endless')).toBeVisible();
  await expect.poll(async () => Number(await endless.getAttribute('data-frames-done')), { timeout: 60_000 }).toBeGreaterThan(1);
  await expect.poll(() => page.getByTestId('recipe-progress-endless').evaluate((p) => (p as HTMLProgressElement).value)).toBeGreaterThan(0);
  await expect(page.getByTestId('recipe-status-endless')).toContainText(/frame \d+\/99999/);
  await page.getByTestId('recipe-cancel-endless').click();
  await expect(endless).toHaveAttribute('data-state', 'cancelled', { timeout: 60_000 });
  await expect(page.getByTestId('recipe-progress-endless')).toBeHidden();
  await expect(page.getByTestId('recipe-record-endless')).toBeVisible();
  await expect(page.getByTestId('recipe-status-endless')).toContainText('nothing written');
  expect(readdirSync(join(tmp, 'templates'))).toEqual([]);

  // A short one: its template joins the library, the scene no longer misses it.
  await page.getByTestId('recipe-record-tiny').click();
  await expect(page.getByTestId('library-item-tiny_tpl')).toBeVisible({ timeout: 60_000 });
  await expect(page.getByTestId('library-thumb-tiny_tpl')).toHaveAttribute('data-points', /^[1-9]/);
  await expect(picker.locator('option[value="needs_tiny"]')).not.toHaveAttribute('data-missing', /./);
  await expect(tiny).toHaveCount(0); // nothing is missing any more: no recipe is offered
  await expect(page.getByTestId('library-empty')).toHaveCount(0);
  expect(readdirSync(join(tmp, 'templates'))).toEqual(['tiny_tpl.h5']);
  expect(errors).toEqual([]);
});
