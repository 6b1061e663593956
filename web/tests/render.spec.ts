// The Render final dialog and the jobs panel: the session's scene run again
// as a render job (POST /api/jobs) on the test server's two local workers
// (global-setup.ts passes --batch-command). A wedge of two values is two
// task bars that fill from the stream's state "jobs" and end done with their
// files to download; a long job is cancelled from the panel; a bad wedge is
// refused in the dialog, and the server's 422 is shown naming its key.
import { readFile } from 'node:fs/promises';
import { expect, test, type Page } from '@playwright/test';
import { expectNoErrors, getJson, openDrop, openEditor, serverUrl } from './helpers';

/** The newest render job of session `sid` on the server (undefined: none). */
async function newestJob(page: Page, sid: string) {
  const list = await getJson(page.request, `${serverUrl()}/api/jobs`);
  return (list.jobs as { id: string; session: string; state: string }[]).filter((j) => j.session === sid).at(-1);
}

/** Records every value the task bars' data-progress takes (testid → values), from now on. */
async function recordTaskProgress(page: Page) {
  await page.evaluate(() => {
    const seen: Record<string, number[]> = {};
    (window as unknown as { taskProgress: typeof seen }).taskProgress = seen;
    new MutationObserver((records) => {
      for (const r of records) {
        const e = r.target as HTMLElement;
        const id = e.dataset['testid'];
        if (id?.startsWith('job-task-')) (seen[id] ??= []).push(Number(e.dataset['progress']));
      }
    }).observe(document.querySelector('[data-testid=jobs-panel]')!, { subtree: true, attributes: true, attributeFilter: ['data-progress'] });
  });
}

test('render final: a wedge job fills two task bars to done, its files download, a long job is cancelled', async ({ page }) => {
  test.setTimeout(600_000);
  const { errors, sid } = await openDrop(page);
  const open = page.getByTestId('render-open');
  await expect(open).toBeEnabled();
  await expect(open).toHaveAttribute('title', /local \(2 workers\)/);
  await expect(page.getByTestId('jobs-empty')).toContainText('Render final');

  await open.click();
  const dialog = page.getByTestId('render-dialog');
  await expect(dialog).toBeVisible();
  await expect(page.getByTestId('render-name')).toHaveValue('drop2d_final');
  await expect(page.getByTestId('render-seconds')).toHaveValue('2'); // the scene's duration
  const radius = page.getByTestId('render-radius');
  await page.getByTestId('render-resolution').selectOption('2');
  await expect(radius).toHaveAttribute('data-value', '0.002');
  await page.getByTestId('render-resolution').selectOption('1');
  await expect(radius).toHaveAttribute('data-value', '0.004');
  await page.getByTestId('render-seconds').fill('0.1');
  await expect(page.getByTestId('render-frames')).toContainText('6 frames');
  for (const box of await page.getByTestId('render-formats').locator('input[type=checkbox]').all()) await box.uncheck();
  await page.getByTestId('render-format-ply').check();
  await expect(page.getByTestId('render-frames-export')).toBeChecked();
  await page.getByTestId('render-wedge-pick').selectOption('instances[drop].start');
  await expect(page.getByTestId('render-wedge-key')).toHaveValue('instances[drop].start');
  const error = page.getByTestId('render-error');

  // A value that is not a number is refused here: nothing reaches the server.
  await page.getByTestId('render-wedge-values').fill('0, abc');
  await page.getByTestId('render-submit').click();
  await expect(error).toContainText('"abc" is not a number');
  await expect(error).toHaveAttribute('data-path', 'wedge.values');
  expect(await newestJob(page, sid)).toBeUndefined();

  // A key path the scene does not have: the server's 422 names it.
  await page.getByTestId('render-wedge-key').fill('instances[nope].speed');
  await page.getByTestId('render-wedge-values').fill('1');
  await page.getByTestId('render-submit').click();
  await expect(error).toHaveAttribute('data-path', 'wedge.key');
  await expect(error).toContainText('422');
  await expect(error).toContainText('instances[nope].speed');
  await expect(dialog).toBeVisible();
  expect(await newestJob(page, sid)).toBeUndefined();

  // The wedge: the drop starts at 0 s in one task, at 0.05 s in the other.
  await page.getByTestId('render-wedge-pick').selectOption('instances[drop].start');
  await page.getByTestId('render-wedge-values').fill('0, 0.05');
  await recordTaskProgress(page);
  await page.getByTestId('render-submit').click();
  await expect(dialog).toBeHidden();
  await expect(error).toHaveText('');
  const job = (await newestJob(page, sid))!;
  expect(job).toBeTruthy();
  const row = page.getByTestId(`job-${job.id}`);
  await expect(row).toBeVisible();
  await expect(page.getByTestId(`job-name-${job.id}`)).toHaveText('drop2d_final');
  await expect(page.getByTestId(`job-where-${job.id}`)).toHaveText('on local (2 workers)');
  await expect(page.getByTestId(`job-tasks-${job.id}`).locator('progress')).toHaveCount(2);
  await expect(page.getByTestId(`job-task-label-${job.id}-0`)).toHaveText('drop start = 0');
  await expect(page.getByTestId(`job-task-label-${job.id}-1`)).toHaveText('drop start = 0.05');

  // The bars fill from the stream's state and the job ends done.
  await expect(page.getByTestId(`job-state-${job.id}`)).toHaveText('done', { timeout: 300_000 });
  await expect(page.getByTestId(`job-progress-${job.id}`)).toHaveJSProperty('value', 1);
  await expect(page.getByTestId(`job-cancel-${job.id}`)).toBeHidden();
  for (const i of [0, 1]) await expect(page.getByTestId(`job-task-${job.id}-${i}`)).toHaveAttribute('data-progress', '1');
  const seen = await page.evaluate(() => (window as unknown as { taskProgress: Record<string, number[]> }).taskProgress);
  for (const i of [0, 1]) {
    const values = seen[`job-task-${job.id}-${i}`] ?? [];
    expect(values, `task ${i}'s progress never goes back`).toEqual([...values].sort((a, b) => a - b));
    expect(values.at(-1)).toBe(1);
  }

  // Each task's files: stats.json downloads and parses, frames.h5 and the surfaces are listed.
  const done = await getJson(page.request, `${serverUrl()}/api/jobs/${job.id}`);
  for (const [i, task] of (done.tasks as { id: string; frames: number; files: string[] }[]).entries()) {
    const files = page.getByTestId(`job-files-${job.id}-${i}`);
    await expect(page.getByTestId(`job-file-${job.id}-${i}-frames.h5`)).toBeVisible();
    const more = page.getByTestId(`job-files-more-${job.id}-${i}`);
    await more.click();
    await expect(files.locator('a')).toHaveCount(task.files.length);
    await expect(page.getByTestId(`job-file-${job.id}-${i}-surface/scene.0006.ply`)).toBeVisible();
    const [download] = await Promise.all([page.waitForEvent('download'), page.getByTestId(`job-file-${job.id}-${i}-stats.json`).click()]);
    expect(download.suggestedFilename()).toBe(`drop2d_final_${task.id}_stats.json`);
    const stats = JSON.parse(await readFile((await download.path())!, 'utf8'));
    expect(stats.summary.frames).toBe(task.frames);
  }

  // A long job: cancelled from the panel once a task has started.
  await open.click();
  await expect(dialog).toBeVisible();
  await page.getByTestId('render-seconds').fill('100');
  await page.getByTestId('render-wedge-pick').selectOption('');
  await expect(page.getByTestId('render-wedge-key')).toHaveValue('');
  await page.getByTestId('render-format-ply').uncheck();
  await page.getByTestId('render-submit').click();
  await expect(dialog).toBeHidden();
  const long = (await newestJob(page, sid))!;
  expect(long.id).not.toBe(job.id);
  const bar = page.getByTestId(`job-task-${long.id}-0`);
  await expect.poll(async () => Number(await bar.getAttribute('data-progress')), { timeout: 300_000 }).toBeGreaterThan(0);
  await expect(page.getByTestId(`job-state-${long.id}`)).toHaveText('running');
  await page.getByTestId(`job-cancel-${long.id}`).click();
  await expect(page.getByTestId(`job-state-${long.id}`)).toHaveText('cancelled', { timeout: 120_000 });
  await expect(page.getByTestId(`job-error-${long.id}`)).toHaveText('cancelled: nothing was kept');
  await expect(bar).toHaveAttribute('data-state', 'cancelled');
  await expect(page.getByTestId(`job-cancel-${long.id}`)).toBeHidden();
  // Newest on top; the first job is still listed, done.
  await expect(page.getByTestId('jobs-list').locator('.job').first()).toHaveAttribute('data-testid', `job-${long.id}`);
  await expect(page.getByTestId(`job-state-${job.id}`)).toHaveText('done');
  expect((await getJson(page.request, `${serverUrl()}/api/jobs/${long.id}`)).state).toBe('cancelled');
  await expectNoErrors(page, errors);
});

test('render final is disabled without a session, and its tooltip says why', async ({ page }) => {
  const errors = await openEditor(page);
  const open = page.getByTestId('render-open');
  await expect(open).toBeDisabled();
  await expect(open).toHaveAttribute('title', /open a scene first/);
  await expect(page.getByTestId('jobs-empty')).toHaveText('No session open.');
  await expectNoErrors(page, errors);
});
