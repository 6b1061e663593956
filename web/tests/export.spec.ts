// The Export dialog: the session's recorded frames meshed on the server
// (POST /api/sessions/{id}/export with formats). The progress bar follows the
// job through the stream's state, the finished job lists its files, and a
// file downloads with the bytes the server has.
import { expect, test } from '@playwright/test';
import { expectNoErrors, getJson, openDrop, serverUrl } from './helpers';

test('export dialog meshes the history with a progress bar and offers the files', async ({ page, request }) => {
  const { errors, sid, url } = await openDrop(page);
  await page.getByTestId('step').click();
  await page.getByTestId('step').click();
  await expect.poll(async () => (await getJson(request, url)).frame, { timeout: 300_000 }).toBeGreaterThanOrEqual(2);

  await page.getByTestId('export-open').click();
  const dialog = page.getByTestId('export-dialog');
  await expect(dialog).toBeVisible();
  const name = `shot_${sid}`;
  await page.getByTestId('export-name').fill(name);
  await expect(page.getByTestId('export-format-ply')).toBeChecked();
  await page.getByTestId('export-format-vdb').uncheck();
  await page.getByTestId('export-format-points').check();
  await page.getByTestId('export-start').click();

  // The bar fills from the stream and the files appear when the job is done.
  await expect(dialog).toHaveAttribute('data-state', 'done', { timeout: 300_000 });
  await expect(page.getByTestId('export-progress')).toHaveJSProperty('value', 1);
  await expect(page.getByTestId('export-status')).toContainText('done:');
  const manifest = page.getByTestId(`export-file-${name}.export.json`);
  await expect(manifest).toBeVisible();
  const session = await getJson(request, url);
  expect(session.export.state).toBe('done');
  expect(session.export.formats).toEqual(['ply', 'points']);
  const files: string[] = session.export.files;
  expect(files.some((f) => f.endsWith('.ply') && !f.includes('_points'))).toBeTruthy();
  expect(files.some((f) => f.includes('_points.'))).toBeTruthy();
  await expect(page.getByTestId('export-files').locator('li')).toHaveCount(files.length);

  // A download has the server's bytes.
  const [download] = await Promise.all([page.waitForEvent('download'), manifest.click()]);
  expect(download.suggestedFilename()).toBe(`${name}.export.json`);
  const saved = JSON.parse(await (await import('node:fs/promises')).readFile((await download.path())!, 'utf8'));
  const served = await getJson(request, `${serverUrl()}/api/exports/${name}/${name}.export.json`);
  expect(saved).toEqual(served);
  expect(saved.formats).toEqual(['ply', 'points']);
  await page.getByTestId('export-close').click();
  await expect(dialog).toBeHidden();
  await expectNoErrors(page, errors);
});
