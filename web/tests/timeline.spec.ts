// The timeline against a real server: drags on the drop instance's track
// (crop either end, move) change the instance on the server by what the
// pixels moved at the timeline's scale, each drag is one undo step, and
// scrubbing the ruler shows a recorded frame (seek) in the viewport.
import { expect, test, type Locator, type Page, type Route } from '@playwright/test';
import { animationFrames, expectNoErrors, getJson, holdRequests, openDrop, readNumber } from './helpers';

// drop2d: the drop instance starts at 0.2 s and plays the whole drop2d
// template (1 s, 61 frames at 60 frames/s) at speed 1; the scene runs at 60 frames/s.
const TEMPLATE_FRAME = 1 / 60;
const SCENE_FPS = 60;

/** The timeline's scale: scene seconds at its left edge and pixels per second. */
async function scale(page: Page) {
  const t = page.getByTestId('timeline');
  return {
    viewStart: Number(await t.getAttribute('data-view-start')),
    pxPerSecond: Number(await t.getAttribute('data-px-per-second')),
    left: (await t.boundingBox())!.x,
  };
}

/**
 * A real mouse drag from the centre of `handle` by dx pixels, in several
 * moves (as a hand would); `hold`: the hand holds still a third of the way
 * (holdPastMergeWindow).
 */
async function dragBy(page: Page, handle: Locator, dx: number, hold = false) {
  const box = (await handle.boundingBox())!;
  const x = box.x + box.width / 2, y = box.y + box.height / 2;
  await page.mouse.move(x, y);
  await page.mouse.down();
  await page.mouse.move(x + dx / 3, y, { steps: 4 });
  if (hold) await holdPastMergeWindow(page);
  await page.mouse.move(x + dx, y, { steps: 8 });
  await page.mouse.up();
  return { x, y };
}

/**
 * The pointer held still mid-drag until the drag's commands so far have run
 * (one history entry) and then for longer than the history's merge window
 * by the page's clock: the drag's next command comes later than commands
 * merge by time, however slow the machine.
 */
async function holdPastMergeWindow(page: Page) {
  const settled = () => page.evaluate(() => {
    const { history } = (window as any).flowclip.editor;
    return { busy: history.busy as boolean, entries: history.undoEntries.length as number };
  });
  await expect.poll(settled).toEqual({ busy: false, entries: 1 });
  const { since, windowMs } = await page.evaluate(() => ({
    since: performance.now(),
    windowMs: (window as any).flowclip.editor.history.mergeWindowMs as number,
  }));
  await expect.poll(() => page.evaluate((since) => performance.now() - since, since)).toBeGreaterThan(windowMs);
  expect(await settled()).toEqual({ busy: false, entries: 1 });
}

/** Holds requests back `delayMs` on their way to the server and counts how many were in flight at once. */
function inFlightCounter() {
  const c = {
    now: 0,
    max: 0,
    async around(route: Route, delayMs: number) {
      c.now++;
      c.max = Math.max(c.max, c.now);
      await new Promise((r) => setTimeout(r, delayMs));
      const response = await route.fetch();
      // Before fulfilling: the page cannot send its next request before this answer.
      c.now--;
      await route.fulfill({ response });
    },
  };
  return c;
}

/** Resolves when the timeline's drag has sent its last PATCH and the history has run every command. */
async function historySettled(page: Page) {
  await expect(page.getByTestId('timeline')).toHaveAttribute('data-pending', 'false');
  await page.evaluate(() => (window as any).flowclip.editor.history.idle());
}

async function undoCount(page: Page): Promise<number> {
  return page.evaluate(() => (window as any).flowclip.editor.history.undoEntries.length);
}

test('timeline: one track per instance over its active scene time, selection, no render loop', async ({ page, request }) => {
  const { errors, instanceUrl } = await openDrop(page);
  const inst = await getJson(request, instanceUrl);
  const track = page.getByTestId('timeline-track-drop');
  await expect(track).toContainText('drop');
  // Active over [start, start + (end − crop_begin)/speed] = [0.2, 1.2] s.
  expect(Number(await track.getAttribute('data-start'))).toBeCloseTo(inst.start, 9);
  expect(Number(await track.getAttribute('data-end'))).toBeCloseTo(inst.start + 1.0, 9);

  // Drawn where the scale says: left edge at start, right edge at the end.
  const s = await scale(page);
  const box = (await track.boundingBox())!;
  expect(Math.abs(box.x - (s.left + (0.2 - s.viewStart) * s.pxPerSecond))).toBeLessThan(2);
  expect(Math.abs(box.x + box.width - (s.left + (1.2 - s.viewStart) * s.pxPerSecond))).toBeLessThan(2);
  // The default view fits 0 to the scene's 2 s (the latest end) with a margin.
  const width = (await page.getByTestId('timeline').boundingBox())!.width;
  const visibleEnd = s.viewStart + width / s.pxPerSecond;
  expect(s.viewStart).toBeLessThanOrEqual(0);
  expect(visibleEnd).toBeGreaterThan(2.0);
  expect(visibleEnd).toBeLessThan(2.6);

  // Clicking the track selects it; clicking the empty background clears the selection.
  await expect(track).toHaveAttribute('data-selected', 'false');
  await track.click();
  await expect(track).toHaveAttribute('data-selected', 'true');
  expect(await page.evaluate(() => (window as any).flowclip.editor.selected)).toBe('drop');
  const rows = (await page.getByTestId('timeline-tracks').boundingBox())!;
  await page.mouse.click(rows.x + 40, rows.y + 24 + 12); // the row under the track
  await expect(track).toHaveAttribute('data-selected', 'false');
  // A click is not an edit.
  expect(await undoCount(page)).toBe(0);

  // On demand: nothing changes, nothing renders.
  const timeline = page.getByTestId('timeline');
  await animationFrames(page, 2);
  const r0 = Number(await timeline.getAttribute('data-renders'));
  await animationFrames(page, 60); // a render loop would render in each
  expect(Number(await timeline.getAttribute('data-renders'))).toBe(r0);
  await expectNoErrors(page, errors);
});

test('timeline: dragging the right end crops crop_end by the distance dragged; one undo step', async ({ page, request }) => {
  const { errors, instanceUrl } = await openDrop(page);
  const before = await getJson(request, instanceUrl);
  expect(before.crop_end).toBeUndefined(); // the template's end (1 s)
  const s = await scale(page);
  const dx = -Math.round(0.3 * s.pxPerSecond); // about 0.3 s to the left
  await dragBy(page, page.getByTestId('timeline-end-drop'), dx);
  await historySettled(page);

  const after = await getJson(request, instanceUrl);
  const expected = 1.0 + (dx / s.pxPerSecond) * before.speed; // template time = crop_begin + Δscene · speed
  // Snapped to template frames; a pixel of slack either way.
  expect(Math.abs(after.crop_end - expected)).toBeLessThanOrEqual(TEMPLATE_FRAME / 2 + 1 / s.pxPerSecond + 1e-9);
  expect(after.crop_end).toBeLessThan(0.8);
  expect(after.start).toBe(before.start);
  expect(after.crop_begin).toBe(before.crop_begin);
  const track = page.getByTestId('timeline-track-drop');
  await expect.poll(async () => Number(await track.getAttribute('data-end'))).toBeCloseTo(after.start + after.crop_end, 9);

  // The whole drag is one history entry: one Ctrl+Z restores the template's end.
  expect(await undoCount(page)).toBe(1);
  await page.locator('body').press('Control+z');
  await expect.poll(async () => (await getJson(request, instanceUrl)).crop_end).toBeUndefined();
  expect(await undoCount(page)).toBe(0);
  await expect.poll(async () => Number(await track.getAttribute('data-end'))).toBeCloseTo(before.start + 1.0, 9);
  await expectNoErrors(page, errors);
});

test('timeline: dragging the left end crops crop_begin and keeps the end time', async ({ page, request }) => {
  const { errors, instanceUrl } = await openDrop(page);
  const before = await getJson(request, instanceUrl);
  const endBefore = before.start + (1.0 - before.crop_begin) / before.speed;
  const s = await scale(page);
  const dx = Math.round(0.25 * s.pxPerSecond);
  // Held still for longer than the history's merge window (0.5 s): still one drag.
  await dragBy(page, page.getByTestId('timeline-begin-drop'), dx, true);
  await historySettled(page);

  const after = await getJson(request, instanceUrl);
  const expected = before.crop_begin + (dx / s.pxPerSecond) * before.speed;
  expect(Math.abs(after.crop_begin - expected)).toBeLessThanOrEqual(TEMPLATE_FRAME / 2 + 1 / s.pxPerSecond + 1e-9);
  expect(after.crop_begin).toBeGreaterThan(0.15);
  expect(after.crop_end).toBeUndefined();
  // The end stays put: start moved by the crop (scene seconds = template seconds / speed).
  expect(after.start + (1.0 - after.crop_begin) / after.speed).toBeCloseTo(endBefore, 6);
  expect(after.start).toBeCloseTo(before.start + after.crop_begin / before.speed, 6);

  // One undo step restores both keys.
  expect(await undoCount(page)).toBe(1);
  await page.locator('body').press('Control+z');
  await expect.poll(async () => (await getJson(request, instanceUrl)).crop_begin).toBe(before.crop_begin);
  expect((await getJson(request, instanceUrl)).start).toBe(before.start);
  await expectNoErrors(page, errors);
});

test('timeline: dragging the body moves start; crops clamp to the template and to one frame', async ({ page, request }) => {
  const { errors, instanceUrl } = await openDrop(page);
  const before = await getJson(request, instanceUrl);
  const s = await scale(page);
  const track = page.getByTestId('timeline-track-drop');
  const dx = Math.round(0.4 * s.pxPerSecond);
  // The server answers slowly (each PATCH held back 150 ms): the drag sends
  // one PATCH at a time, the newest position wins, and it lands where the
  // pointer was released.
  const patches: unknown[] = [];
  const patchFlight = inFlightCounter();
  await page.route('**/instances/drop', async (route) => {
    if (route.request().method() !== 'PATCH') return route.continue();
    patches.push(route.request().postDataJSON());
    await patchFlight.around(route, 150);
  });
  // Grab the body away from its ends.
  const box = (await track.boundingBox())!;
  const x = box.x + box.width * 0.4, y = box.y + box.height / 2;
  await page.mouse.move(x, y);
  await page.mouse.down();
  await page.mouse.move(x + dx, y, { steps: 16 });
  await page.mouse.up();
  await historySettled(page);
  await page.unroute('**/instances/drop');
  console.log(`body drag: ${patches.length} PATCHes for 16 pointer moves: ${JSON.stringify(patches)}`);
  expect(patchFlight.max).toBe(1); // never two at once (how many in all depends on the machine's speed)
  const moved = await getJson(request, instanceUrl);
  expect(patches[patches.length - 1]).toEqual({ start: moved.start });
  const expected = before.start + dx / s.pxPerSecond;
  expect(Math.abs(moved.start - expected)).toBeLessThanOrEqual(0.5 / SCENE_FPS + 1 / s.pxPerSecond + 1e-9);
  expect(moved.start).toBeGreaterThan(0.5);
  expect(moved.crop_begin).toBe(before.crop_begin);
  expect(moved.crop_end).toBeUndefined();
  expect(await undoCount(page)).toBe(1);

  // Far past the template's end: crop_end stops at its duration (no 422).
  await dragBy(page, page.getByTestId('timeline-end-drop'), Math.round(1.5 * s.pxPerSecond));
  await historySettled(page);
  expect((await getJson(request, instanceUrl)).crop_end).toBeCloseTo(1.0, 9);
  // Far left of its start: at least one template frame stays.
  await dragBy(page, page.getByTestId('timeline-end-drop'), -Math.round(1.6 * s.pxPerSecond));
  await historySettled(page);
  const shortest = await getJson(request, instanceUrl);
  expect(shortest.crop_end - shortest.crop_begin).toBeCloseTo(TEMPLATE_FRAME, 9);
  expect(await undoCount(page)).toBe(3);
  await expectNoErrors(page, errors);
});

test('timeline: an undo pressed while a drag\'s last PATCH is on its way undoes the whole drag', async ({ page, request }) => {
  const { errors, instanceUrl } = await openDrop(page);
  const before = await getJson(request, instanceUrl);
  const s = await scale(page);
  // A slow server: the drag's PATCHes after the first are held back until
  // the key press has come, so that it comes while the drag's second PATCH
  // is in flight and its last values wait (an undo run between them would
  // let the last PATCH put the drag back as a new entry).
  const held = await holdRequests(page, '**/instances/drop', 'PATCH', 1);
  const box = (await page.getByTestId('timeline-track-drop').boundingBox())!;
  const x = box.x + box.width * 0.4, y = box.y + box.height / 2;
  await page.mouse.move(x, y);
  await page.mouse.down();
  const firstLanded = page.waitForResponse((r) => r.request().method() === 'PATCH' && r.url().includes('/instances/drop'));
  await page.mouse.move(x + 0.1 * s.pxPerSecond, y, { steps: 3 });
  await firstLanded; // the drag's first PATCH has landed
  await page.mouse.move(x + 0.3 * s.pxPerSecond, y, { steps: 6 });
  await page.mouse.up();
  await page.keyboard.press('Control+z'); // at once (no actionability wait): the last PATCHes are on their way
  held.release();
  await historySettled(page);
  await page.unroute('**/instances/drop');
  expect((await getJson(request, instanceUrl)).start).toBe(before.start);
  expect(await undoCount(page)).toBe(0);
  expect(await page.evaluate(() => (window as any).flowclip.editor.history.redoEntries.length)).toBe(1);
  await expect(page.getByTestId('timeline-track-drop')).toHaveAttribute('data-start', String(before.start));
  // Redo applies where the drag ended.
  await page.locator('body').press('Control+Shift+z');
  await expect.poll(async () => (await getJson(request, instanceUrl)).start).toBeGreaterThan(before.start + 0.25);
  await expectNoErrors(page, errors);
});

test('timeline: a reversed instance is marked; its ends crop what plays there', async ({ page, request }) => {
  const { errors, instanceUrl } = await openDrop(page);
  // Reverse it through the hub (as an inspector would).
  await page.evaluate(async () => {
    const { editor, commands } = (window as any).flowclip;
    await editor.execute(new commands.SetInstanceValuesCommand(editor, 'drop', { reverse: true }, { reverse: false }));
  });
  const track = page.getByTestId('timeline-track-drop');
  await expect(track).toHaveClass(/reverse/);
  await expect(track).toContainText('◀');
  const s = await scale(page);
  // Its right end plays crop_begin (last): dragging it left raises crop_begin, start stays.
  const dx = -Math.round(0.2 * s.pxPerSecond);
  await dragBy(page, page.getByTestId('timeline-end-drop'), dx);
  await historySettled(page);
  const after = await getJson(request, instanceUrl);
  expect(Math.abs(after.crop_begin - (-dx / s.pxPerSecond))).toBeLessThanOrEqual(TEMPLATE_FRAME / 2 + 1 / s.pxPerSecond + 1e-9);
  expect(after.crop_end).toBeUndefined();
  expect(after.start).toBe(0.2);
  await expectNoErrors(page, errors);
});

test('timeline: keyframe diamonds at the transform keys\' times', async ({ page }) => {
  const { errors } = await openDrop(page);
  await expect(page.getByTestId('timeline-key-drop-0')).toHaveCount(0); // no keys: none drawn
  await page.evaluate(async () => {
    const { editor, commands } = (window as any).flowclip;
    const keys = [{ time: 0.3, translation: [0.6, 0.35] }, { time: 0.9, translation: [0.7, 0.35] }];
    await editor.execute(new commands.SetInstanceTransformCommand(editor, 'drop', keys, []));
  });
  const s = await scale(page);
  for (const [k, t] of [[0, 0.3], [1, 0.9]] as const) {
    const key = page.getByTestId(`timeline-key-drop-${k}`);
    await expect(key).toHaveAttribute('data-value', String(t));
    const b = (await key.boundingBox())!;
    expect(Math.abs(b.x + b.width / 2 - (s.left + (t - s.viewStart) * s.pxPerSecond))).toBeLessThan(2);
  }
  await expectNoErrors(page, errors);
});

test('timeline: zoom around the cursor, Shift+wheel pans', async ({ page }) => {
  const { errors } = await openDrop(page);
  const s0 = await scale(page);
  const box = (await page.getByTestId('timeline-tracks').boundingBox())!;
  const cx = box.x + 300;
  const tAt = (s: { viewStart: number; pxPerSecond: number; left: number }) => s.viewStart + (cx - s.left) / s.pxPerSecond;
  await page.mouse.move(cx, box.y + 10);
  await page.mouse.wheel(0, -200);
  await expect.poll(async () => (await scale(page)).pxPerSecond).toBeGreaterThan(s0.pxPerSecond * 1.2);
  const s1 = await scale(page);
  expect(tAt(s1)).toBeCloseTo(tAt(s0), 6); // the time under the cursor stays
  await page.keyboard.down('Shift');
  await page.mouse.wheel(0, 100);
  await page.keyboard.up('Shift');
  await expect.poll(async () => (await scale(page)).viewStart).toBeCloseTo(s1.viewStart + 100 / s1.pxPerSecond, 6);
  expect((await scale(page)).pxPerSecond).toBe(s1.pxPerSecond);
  // Dragging the empty background pans too (to the right: earlier times come into view).
  const s2 = await scale(page);
  const emptyY = box.y + 24 + 12; // the row under the drop track's (there is one instance)
  await page.mouse.move(box.x + 100, emptyY);
  await page.mouse.down();
  await page.mouse.move(box.x + 180, emptyY, { steps: 5 });
  await page.mouse.up();
  await expect.poll(async () => (await scale(page)).viewStart).toBeCloseTo(s2.viewStart - 80 / s2.pxPerSecond, 6);
  // Fit restores the default view.
  await page.getByTestId('timeline-fit').click();
  await expect.poll(async () => (await scale(page)).pxPerSecond).toBeCloseTo(s0.pxPerSecond, 6);
  await expectNoErrors(page, errors);
});

test('timeline: scrubbing the ruler shows a recorded frame (seek), the playhead on it', async ({ page, request }) => {
  test.setTimeout(60_000);
  const { errors, url } = await openDrop(page);
  const frame = page.getByTestId('frame');
  const playhead = page.getByTestId('timeline-playhead');
  await expect(playhead).toHaveAttribute('data-live', 'true');
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 20 }));
  await expect.poll(() => readNumber(frame), { timeout: 30_000 }).toBe(20);
  await expect(page.getByTestId('session-status')).toHaveAttribute('data-value', 'paused');
  await expect(playhead).toHaveAttribute('data-value', '20');
  // The simulated range is shaded: frames 0 to 20.
  await expect(page.getByTestId('timeline-simulated')).toHaveAttribute('data-last', '20');

  // Drag on the ruler from about frame 15 to about frame 8; the nearest recorded frame wins.
  const s = await scale(page);
  const ruler = (await page.getByTestId('timeline-ruler').boundingBox())!;
  const xOf = (t: number) => s.left + (t - s.viewStart) * s.pxPerSecond;
  const y = ruler.y + ruler.height / 2;
  // Seeks are held back 150 ms on their way to the server, so that the drag's
  // moves outrun them: one seek in flight at a time, the latest position wins.
  const seeks: number[] = [];
  const seekFlight = inFlightCounter();
  await page.route('**/transport', async (route) => {
    const body = route.request().postDataJSON();
    if (body?.command !== 'seek') return route.continue();
    seeks.push(body.frame);
    await seekFlight.around(route, 150);
  });
  await page.mouse.move(xOf(15 / SCENE_FPS), y);
  await page.mouse.down();
  await page.mouse.move(xOf(8.2 / SCENE_FPS), y, { steps: 12 });
  await page.mouse.up();
  const target = Math.round((xOf(8.2 / SCENE_FPS) - s.left) / s.pxPerSecond * SCENE_FPS + s.viewStart * SCENE_FPS);
  expect(target).toBeGreaterThanOrEqual(7);
  expect(target).toBeLessThanOrEqual(9);

  await expect(playhead).toHaveAttribute('data-live', 'false');
  await expect(playhead).toHaveAttribute('data-value', String(target));
  await expect.poll(async () => (await getJson(request, url)).shown).toEqual({ live: false, frame: target });
  await page.unroute('**/transport');
  console.log(`scrub: seeks sent ${JSON.stringify(seeks)}`);
  expect(seeks[seeks.length - 1]).toBe(target);
  expect(seekFlight.max).toBe(1); // one seek in flight at a time (13 pointer events over 8 frames)
  const state = await getJson(request, url);
  expect(state.frame).toBe(20); // the simulation did not move; only the frame shown did
  // The viewport shows that recorded frame.
  await expect.poll(() => page.evaluate(() => (window as any).flowclip.editor.decoder.info.frame)).toBe(target);
  await expect(frame).toHaveAttribute('data-value', String(target));
  // The playhead is drawn at that frame's time.
  const p = (await playhead.boundingBox())!;
  expect(Math.abs(p.x + p.width / 2 - xOf(target / SCENE_FPS))).toBeLessThan(2);

  // Stepping goes live again (and simulates on from the newest frame).
  await page.getByTestId('step').click();
  await expect(playhead).toHaveAttribute('data-live', 'true');
  await expect.poll(() => readNumber(frame)).toBe(21);
  await expect(playhead).toHaveAttribute('data-value', '21');
  await expect(page.getByTestId('timeline-simulated')).toHaveAttribute('data-last', '21');

  // Back to a recorded frame, then a click past the history: the playhead
  // goes there (frame 90) without a seek; the server still shows frame 4.
  await page.mouse.click(xOf(4 / SCENE_FPS), y);
  await expect(playhead).toHaveAttribute('data-live', 'false');
  await expect(playhead).toHaveAttribute('data-value', '4');
  await expect(frame).toHaveAttribute('data-value', '4');
  await page.mouse.click(xOf(1.5), y);
  await expect(playhead).toHaveAttribute('data-value', '90');
  await expect(playhead).toHaveAttribute('data-recorded', 'false');
  await expect(page.getByTestId('viewport-note')).toHaveAttribute('data-value', '90');
  expect((await getJson(request, url)).shown).toEqual({ live: false, frame: 4 });
  // Live: the newest frame again.
  await page.getByTestId('live').click();
  await expect.poll(async () => (await getJson(request, url)).shown).toEqual({ live: true, frame: 21 });
  await expect(playhead).toHaveAttribute('data-live', 'true');
  await expect(playhead).toHaveAttribute('data-value', '21');
  await expect(frame).toHaveAttribute('data-value', '21');
  await expect(page.getByTestId('viewport-note')).toBeHidden();
  await expectNoErrors(page, errors);
});
