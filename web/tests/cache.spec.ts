// Editing against time, as an animator works: the viewport answers every
// edit at once while paused (pixels read from the canvas), the timeline
// shows the cache (valid, stale, re-simulated), the playhead goes where
// nothing is simulated yet and the instance boxes are drawn there, playback
// stops at the play range's end, key diamonds drag in time, and the
// keyboard works whatever has the focus.
import { expect, test, type Page } from '@playwright/test';
import { countPixelsBetween, expectNoErrors, getJson, holdRequests, openDrop, readNumber, serverUrl } from './helpers';

const SCENE_FPS = 60;

/** Client pixel of world point (x, y) (2D: z = 0). */
function screenOf(page: Page, x: number, y: number) {
  return page.evaluate(([x, y]) => {
    const { viewport } = (window as any).flowclip;
    return viewport.screenOf(viewport.gizmo.proxy.position.clone().set(x, y, 0)) as { x: number; y: number };
  }, [x, y]);
}

/**
 * Warm pixels (instance boxes: orange when active, red when it steers no
 * liquid) in a vertical strip of the canvas, 7 px wide, around client x
 * between client y0 and y1: the box's edge is there when it counts tens.
 */
async function warmPixelsInStrip(page: Page, x: number, y0: number, y1: number): Promise<number> {
  const canvas = page.getByTestId('viewport-canvas');
  const png = await canvas.screenshot();
  const box = (await canvas.boundingBox())!;
  // Warm: red above 200, blue below 150.
  const { count } = await countPixelsBetween(page, png, [201, 0, 0], [255, 255, 149], {
    left: Math.round(x - box.x - 3), right: Math.round(x - box.x + 4),
    top: Math.round(Math.min(y0, y1) - box.y), bottom: Math.round(Math.max(y0, y1) - box.y),
  });
  return count;
}

/** The shown box of `name` (viewport.boxes.shown): its world left edge x and its vertical middle band. */
async function boxEdges(page: Page, name: string) {
  return page.evaluate((name) => {
    const { viewport } = (window as any).flowclip;
    const b = viewport.boxes.shown.find((x: any) => x.name === name);
    if (!b) return null;
    const m = b.matrix as number[];
    const world = (u: number, v: number) => [m[0]! * u + m[4]! * v + m[12]!, m[1]! * u + m[5]! * v + m[13]!];
    const lo = world(b.templateMin[0], b.templateMin[1]), hi = world(b.templateMax[0], b.templateMax[1]);
    return { left: Math.min(lo[0]!, hi[0]!), right: Math.max(lo[0]!, hi[0]!), bottom: Math.min(lo[1]!, hi[1]!), top: Math.max(lo[1]!, hi[1]!), active: b.active as boolean };
  }, name);
}

/** Client pixels of the middle half of the box's left edge. */
async function leftEdgeStrip(page: Page, e: { left: number; bottom: number; top: number }) {
  const h = e.top - e.bottom;
  const a = await screenOf(page, e.left, e.bottom + 0.3 * h), b = await screenOf(page, e.left, e.top - 0.3 * h);
  return { x: a.x, y0: a.y, y1: b.y };
}

test('the box follows a gizmo drag at once and an inspector edit while paused (pixels)', async ({ page, request }) => {
  const { errors, url } = await openDrop(page);
  await page.getByTestId('library-add-jet2d').click();
  await expect(page.getByTestId('outliner-item-jet2d')).toHaveClass(/selected/);
  // jet2d's region (1.2 × 0.9 m) is larger than drop2d's domain (1.2 × 0.8 m): scaled down to fit.
  const added = (await getJson(request, `${url}/instances/jet2d`)).transform[0];
  expect(added.scale[0]).toBeLessThan(1);
  const e0 = (await boxEdges(page, 'jet2d'))!;
  expect(e0.left).toBeGreaterThanOrEqual(-1e-9);
  expect(e0.right).toBeLessThanOrEqual(1.2 + 1e-9);
  expect(e0.top - e0.bottom).toBeLessThanOrEqual(0.8 + 1e-9);

  const strip0 = await leftEdgeStrip(page, e0);
  const metresPerPixel = await page.evaluate(() => {
    const { viewport } = (window as any).flowclip;
    const cam = viewport.camera;
    return (cam.right - cam.left) / cam.zoom / (viewport.renderer.domElement as HTMLCanvasElement).clientWidth;
  });
  // Drawn where it is, and not yet 90 px to its right.
  await expect.poll(() => warmPixelsInStrip(page, strip0.x, strip0.y0, strip0.y1)).toBeGreaterThan(10);
  expect(await warmPixelsInStrip(page, strip0.x + 90, strip0.y0, strip0.y1)).toBeLessThan(5);

  // A slow server: every PATCH held back until the box has been checked. The box must follow the pointer, not the answers.
  const held = await holdRequests(page, '**/instances/jet2d', 'PATCH');
  const handle = await page.evaluate(() => {
    const { viewport } = (window as any).flowclip;
    const cam = viewport.camera, g = viewport.gizmo;
    const unit = ((cam.top - cam.bottom) / cam.zoom) * g.controls.size / 4;
    const p = g.proxy.position.clone();
    p.x += 0.35 * unit;
    return viewport.screenOf(p) as { x: number; y: number };
  });
  await page.mouse.move(handle.x, handle.y);
  await page.mouse.down();
  for (let k = 1; k <= 9; k++) await page.mouse.move(handle.x + 10 * k, handle.y, { steps: 2 });
  // Still held, no PATCH answered: the box's left edge is 90 px to the right.
  await expect.poll(() => warmPixelsInStrip(page, strip0.x + 90, strip0.y0, strip0.y1)).toBeGreaterThan(10);
  expect(await warmPixelsInStrip(page, strip0.x, strip0.y0, strip0.y1)).toBeLessThan(5);
  held.release();
  await page.mouse.up();
  await page.unrouteAll({ behavior: 'wait' });
  await expect.poll(async () => (await getJson(request, `${url}/instances/jet2d`)).transform[0].translation[0], { timeout: 15_000 })
    .toBeCloseTo(added.translation[0] + 90 * metresPerPixel, 2);
  await page.evaluate(() => (window as any).flowclip.editor.history.idle());

  // The inspector: x one decimetre less; the box's edge moves there (nothing is simulated meanwhile).
  const x1 = (await getJson(request, `${url}/instances/jet2d`)).transform[0].translation[0] as number;
  const e1 = (await boxEdges(page, 'jet2d'))!;
  const field = page.getByTestId('inspector-translation-0');
  await field.fill(String(Number((x1 - 0.1).toFixed(4))));
  await field.press('Enter');
  const moved = { ...e1, left: e1.left - 0.1 };
  const strip1 = await leftEdgeStrip(page, moved), stripOld = await leftEdgeStrip(page, e1);
  await expect.poll(() => warmPixelsInStrip(page, strip1.x, strip1.y0, strip1.y1)).toBeGreaterThan(10);
  expect(await warmPixelsInStrip(page, stripOld.x, stripOld.y0, stripOld.y1)).toBeLessThan(5);
  const state = await getJson(request, url);
  expect(state.status).toBe('paused');
  expect(state.frame).toBe(0);

  // Undo (the button: the field keeps the keyboard focus): back at once.
  await page.getByTestId('undo').click();
  await expect.poll(() => warmPixelsInStrip(page, stripOld.x, stripOld.y0, stripOld.y1)).toBeGreaterThan(10);
  await expectNoErrors(page, errors);
});

test('the timeline shows the edited frames stale, then valid again once re-simulated', async ({ page, request }) => {
  test.setTimeout(90_000);
  const { errors, url } = await openDrop(page);
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 30 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 40_000 }).toBe(30);
  const cache = page.getByTestId('timeline-cache');
  expect((await getJson(request, url)).cache).toBeDefined();
  await expect(cache).toHaveAttribute('data-valid', '0-30');
  await expect(page.getByTestId('timeline-cache-valid-0')).toBeVisible();
  // Hold the stream's state back? No: watch the cache attribute change as the server reports it.
  const seen = page.evaluate(() => new Promise<{ stale: string; valid: string }>((resolve) => {
    const node = document.querySelector('[data-testid=timeline-cache]')!;
    const obs = new MutationObserver(() => {
      const stale = node.getAttribute('data-stale') ?? '';
      if (stale) {
        obs.disconnect();
        resolve({ stale, valid: node.getAttribute('data-valid') ?? '' });
      }
    });
    obs.observe(node, { attributes: true });
  }));
  // Start 0.2 s → 0.3 s: frames from 12 on change.
  await page.getByTestId('outliner-item-drop').click();
  await page.getByTestId('inspector-start').fill('0.3');
  await page.getByTestId('inspector-start').press('Enter');
  // Stale from the first frame the edit changes (0.2 s: frame 12, or later once re-simulation has begun replacing them), valid before it.
  const { stale, valid } = await seen;
  const [a, b] = stale.split(',')[0]!.split('-').map(Number);
  expect(a).toBeGreaterThanOrEqual(12);
  expect(a).toBeLessThanOrEqual(30);
  expect(b).toBe(30);
  expect(valid).toBe(`0-${a! - 1}`);
  // Re-simulated by the server itself: valid up to 30 again, nothing stale.
  await expect(cache).toHaveAttribute('data-stale', '', { timeout: 60_000 });
  await expect(cache).toHaveAttribute('data-valid', '0-30', { timeout: 60_000 });
  expect((await getJson(request, url)).status).toBe('paused');
  await expectNoErrors(page, errors);
});

test('the playhead goes past the simulated frames; the instance box is drawn there from its track', async ({ page, request }) => {
  const { errors, url } = await openDrop(page);
  // An animated drop, active over 0.8–1.8 s: x 0.45 at 0.9 s → 0.75 at 1.5 s.
  await page.evaluate(async () => {
    const { editor, commands } = (window as any).flowclip;
    await editor.execute(new commands.SetInstanceValuesCommand(editor, 'drop', { start: 0.8 }, { start: 0.2 }));
    const keys = [{ time: 0.9, translation: [0.45, 0.35] }, { time: 1.5, translation: [0.75, 0.35] }];
    await editor.execute(new commands.SetInstanceTransformCommand(editor, 'drop', keys, []));
  });
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 5 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBe(5);
  const seeks: number[] = [];
  await page.route('**/transport', async (route) => {
    const body = route.request().postDataJSON();
    if (body?.command === 'seek') seeks.push(body.frame);
    await route.continue();
  });
  // Click the ruler at 1.5 s (frame 90): nothing recorded there.
  const t = page.getByTestId('timeline');
  const viewStart = Number(await t.getAttribute('data-view-start')), pps = Number(await t.getAttribute('data-px-per-second'));
  const ruler = (await page.getByTestId('timeline-ruler').boundingBox())!;
  await page.mouse.click(ruler.x + (1.5 - viewStart) * pps, ruler.y + ruler.height / 2);
  const playhead = page.getByTestId('timeline-playhead');
  await expect(playhead).toHaveAttribute('data-value', '90');
  await expect(playhead).toHaveAttribute('data-recorded', 'false');
  await expect(page.getByTestId('viewport-note')).toBeVisible();
  await expect(page.getByTestId('viewport-note')).toContainText('Frame 90 is not simulated');
  // The box at 1.5 s: centred at x 0.75 (region 0.7 m wide), active (orange).
  await expect.poll(async () => (await boxEdges(page, 'drop'))?.left).toBeCloseTo(0.4, 6);
  expect((await boxEdges(page, 'drop'))!.active).toBe(true);
  const e = (await boxEdges(page, 'drop'))!;
  const there = await leftEdgeStrip(page, e), before = await leftEdgeStrip(page, { ...e, left: 0.1 });
  await expect.poll(() => warmPixelsInStrip(page, there.x, there.y0, there.y1)).toBeGreaterThan(10);
  expect(await warmPixelsInStrip(page, before.x, before.y0, before.y1)).toBeLessThan(5);
  // The inspector shows the interpolated values there, rounded.
  await page.getByTestId('outliner-item-drop').click();
  await expect(page.getByTestId('inspector-translation-0')).toHaveAttribute('data-value', '0.75');
  // Nothing was asked of the server; it still shows frame 5.
  expect(seeks).toEqual([]);
  expect((await getJson(request, url)).shown.frame).toBe(5);
  await page.unroute('**/transport');
  // Live leaves it (the server was live at frame 5); Home: the start of the play range (frame 0, recorded: a seek).
  await expect(page.getByTestId('live')).toBeEnabled();
  await page.getByTestId('live').click();
  await expect(playhead).toHaveAttribute('data-value', '5');
  await expect(playhead).toHaveAttribute('data-recorded', 'true');
  await page.locator('body').press('Home');
  await expect(playhead).toHaveAttribute('data-value', '0');
  await expect(playhead).toHaveAttribute('data-recorded', 'true');
  await expect(page.getByTestId('viewport-note')).toBeHidden();
  await expectNoErrors(page, errors);
});

test('playback stops at the end of the play range; play asks the server to stop at the scene\'s end by default', async ({ page, request }) => {
  test.setTimeout(90_000);
  const { errors, url } = await openDrop(page);
  const end = page.getByTestId('timeline-range-end');
  await expect(end).toHaveAttribute('data-value', String(2 * SCENE_FPS)); // drop2d: 2 s at 60 frames/s
  await expect(page.getByTestId('timeline-scene-end')).toHaveAttribute('data-value', '120');
  const plays: any[] = [];
  await page.route('**/transport', async (route) => {
    const body = route.request().postDataJSON();
    if (body?.command === 'play') plays.push(body);
    await route.continue();
  });
  // Drag the range's end marker to about frame 12.
  const t = page.getByTestId('timeline');
  const viewStart = Number(await t.getAttribute('data-view-start')), pps = Number(await t.getAttribute('data-px-per-second'));
  const left = (await t.boundingBox())!.x;
  const b = (await end.boundingBox())!;
  await page.mouse.move(b.x + b.width / 2, b.y + b.height / 2);
  await page.mouse.down();
  await page.mouse.move(left + (12 / SCENE_FPS - viewStart) * pps, b.y + b.height / 2, { steps: 8 });
  await page.mouse.up();
  const stopAt = Number(await end.getAttribute('data-value'));
  expect(Math.abs(stopAt - 12)).toBeLessThanOrEqual(1);
  await page.getByTestId('play').click();
  // A 12-frame play can end before a loaded machine shows "playing": the server's frame says it ran.
  await expect.poll(() => plays.length).toBeGreaterThan(0);
  await expect.poll(async () => (await getJson(request, url)).frame, { timeout: 40_000 }).toBe(stopAt);
  await expect(page.getByTestId('session-status')).toHaveAttribute('data-value', 'paused', { timeout: 40_000 });
  await expect.poll(async () => (await getJson(request, url)).computing).toBe(false);
  const state = await getJson(request, url);
  expect(state.frame).toBe(stopAt);
  expect(plays[0].until).toBe(stopAt);
  // It stays stopped: paused at the range's end with nothing left to do.
  expect(state.status).toBe('paused');
  expect(state.play_until).toBe(stopAt);
  expect(state.steps_left).toBe(0);
  expect(state.cache.simulating).toBeNull();

  // The whole scene: the range's end back to the scene's end; play sends until = end_frame.
  await page.evaluate(() => (window as any).flowclip.editor.setPlayRange({ end: null }));
  await expect(end).toHaveAttribute('data-value', '120');
  plays.length = 0;
  await page.getByTestId('play').click();
  await expect(page.getByTestId('session-status')).toHaveAttribute('data-value', 'playing');
  expect(plays[0].until).toBe(120);
  await page.getByTestId('pause').click();
  await expect(page.getByTestId('session-status')).toHaveAttribute('data-value', 'paused');
  await page.unroute('**/transport');
  await expectNoErrors(page, errors);
});

test('a key diamond dragged in time is one undo step; keys are jumped to with Up and Down', async ({ page, request }) => {
  const { errors, url } = await openDrop(page);
  await page.evaluate(async () => {
    const { editor, commands } = (window as any).flowclip;
    const keys = [{ time: 0.3, translation: [0.6, 0.35] }, { time: 0.9, translation: [0.7, 0.35] }];
    await editor.execute(new commands.SetInstanceTransformCommand(editor, 'drop', keys, []));
    editor.history.clear();
  });
  const key = page.getByTestId('timeline-key-drop-1');
  await expect(key).toHaveAttribute('data-value', '0.9');
  const t = page.getByTestId('timeline');
  const pps = Number(await t.getAttribute('data-px-per-second'));
  const dx = Math.round(0.2 * pps);
  // Slow PATCHes (300 ms each): several are sent, one at a time, and merge.
  await page.route('**/instances/drop', async (route) => {
    if (route.request().method() === 'PATCH') await new Promise((r) => setTimeout(r, 300));
    await route.continue();
  });
  const b = (await key.boundingBox())!;
  const x = b.x + b.width / 2, y = b.y + b.height / 2;
  await page.mouse.move(x, y);
  await page.mouse.down();
  await page.mouse.move(x + dx / 3, y, { steps: 4 });
  await page.waitForTimeout(800); // held still longer than the history's merge window: still one drag
  await page.mouse.move(x + dx, y, { steps: 8 });
  await page.mouse.up();
  await expect(t).toHaveAttribute('data-pending', 'false');
  await page.evaluate(() => (window as any).flowclip.editor.history.idle());
  await page.unrouteAll({ behavior: 'wait' });
  const moved = (await getJson(request, `${url}/instances/drop`)).transform;
  expect(Math.abs(moved[1].time - 1.1)).toBeLessThanOrEqual(0.5 / SCENE_FPS + 1 / pps + 1e-9);
  expect(moved[0].time).toBe(0.3);
  expect(moved[1].translation).toEqual([0.7, 0.35]);
  const entries = await page.evaluate(() => (window as any).flowclip.editor.history.undoEntries.map((e: any) => e.name));
  expect(entries).toEqual(['Move key 1 of drop']);
  await expect(page.getByTestId('undo')).toHaveAttribute('title', 'Undo Move key 1 of drop (Ctrl+Z)');
  await page.locator('body').press('Control+z');
  await expect.poll(async () => (await getJson(request, `${url}/instances/drop`)).transform[1].time).toBe(0.9);
  await expect(key).toHaveAttribute('data-value', '0.9');

  // Up: the next key (frame 18 = 0.3 s), again Up: 54 (0.9 s); Down: back to 18.
  const playhead = page.getByTestId('timeline-playhead');
  await page.locator('body').press('ArrowUp');
  await expect(playhead).toHaveAttribute('data-value', '18');
  await page.locator('body').press('ArrowUp');
  await expect(playhead).toHaveAttribute('data-value', '54');
  await page.locator('body').press('ArrowDown');
  await expect(playhead).toHaveAttribute('data-value', '18');
  await page.getByTestId('timeline-next-key').click();
  await expect(playhead).toHaveAttribute('data-value', '54');
  await expectNoErrors(page, errors);
});

test('auto-key: off, an edit moves the whole animated track; on, it keys at the playhead', async ({ page, request }) => {
  const { errors, url } = await openDrop(page);
  await page.evaluate(async () => {
    const { editor, commands } = (window as any).flowclip;
    const keys = [{ time: 0.5, translation: [0.5, 0.35] }, { time: 1.0, translation: [0.7, 0.35] }];
    await editor.execute(new commands.SetInstanceTransformCommand(editor, 'drop', keys, []));
    editor.setPlayhead(45); // 0.75 s: halfway, x = 0.6 (nothing recorded there)
  });
  await page.getByTestId('outliner-item-drop').click();
  const x = page.getByTestId('inspector-translation-0');
  await expect(x).toHaveAttribute('data-value', '0.6');
  await expect(page.getByTestId('inspector-translation-0-row')).toHaveAttribute('data-state', 'animated');
  await expect(page.getByTestId('timeline-autokey')).toHaveAttribute('data-value', 'false');
  await x.fill('0.65');
  await x.press('Enter');
  await expect.poll(async () => (await getJson(request, `${url}/instances/drop`)).transform.map((k: any) => k.translation[0]))
    .toEqual([0.55, 0.75]);
  await page.getByTestId('timeline-autokey').click();
  await expect(page.getByTestId('timeline-autokey')).toHaveAttribute('data-value', 'true');
  await x.fill('0.6');
  await x.press('Enter');
  await expect.poll(async () => (await getJson(request, `${url}/instances/drop`)).transform.map((k: any) => [k.time, k.translation[0]]))
    .toEqual([[0.5, 0.55], [0.75, 0.6], [1.0, 0.75]]);
  await expect(page.getByTestId('inspector-translation-0-row')).toHaveAttribute('data-state', 'keyed');
  await expectNoErrors(page, errors);
});

test('Space plays and pauses while a checkbox has the focus, without toggling it', async ({ page }) => {
  const { errors } = await openDrop(page);
  const liquid = page.getByTestId('layer-liquid');
  await liquid.focus();
  await expect(liquid).toBeFocused();
  await expect(liquid).toBeChecked();
  await page.keyboard.press('Space');
  await expect(page.getByTestId('session-status')).toHaveAttribute('data-value', /playing|stepping/);
  await expect(liquid).toBeChecked();
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBeGreaterThan(2);
  await page.keyboard.press('Space');
  await expect(page.getByTestId('session-status')).toHaveAttribute('data-value', 'paused');
  await expect(liquid).toBeChecked();
  await expect(liquid).toBeFocused();
  await expectNoErrors(page, errors);
});

test('an instance dropped into mid-air is marked as steering no liquid, with the reason', async ({ page }) => {
  const { errors } = await openDrop(page);
  await page.evaluate(async () => {
    const { editor, commands } = (window as any).flowclip;
    // jet2d, small, high in the air of drop2d (its pool is at the bottom), from t = 0.
    await editor.execute(new commands.AddInstanceCommand(editor, {
      name: 'jet2d', template: 'jet2d', start: 0, transform: [{ time: 0, translation: [0.6, 0.62], scale: [0.3, 0.3] }],
    }));
  });
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 6 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBe(6);
  const warning = page.getByTestId('outliner-warning-jet2d');
  await expect(warning).toBeVisible();
  await expect(warning).toHaveAttribute('title', /steers no liquid/);
  await expect(page.getByTestId('timeline-track-jet2d')).toHaveAttribute('data-warning', /no water liquid/);
  await expect(page.getByTestId('timeline-track-jet2d')).toContainText('⚠');
  await page.getByTestId('outliner-item-jet2d').click();
  await expect(page.getByTestId('inspector-warning')).toContainText('steers no liquid');
  // The drop instance, over the liquid, is not marked.
  await expect(page.getByTestId('outliner-warning-drop')).toHaveCount(0);
  await expectNoErrors(page, errors);
});

test('keyboard: Delete removes the selection, Ctrl+S saves; the undo button names what it undoes', async ({ page, request }) => {
  const { errors, url } = await openDrop(page);
  await expect(page.getByTestId('undo')).toHaveAttribute('title', 'Nothing to undo');
  await page.getByTestId('outliner-item-drop').click();
  await page.locator('body').press('Delete');
  await expect.poll(async () => (await getJson(request, `${url}/instances`)).instances.length).toBe(0);
  await expect(page.getByTestId('undo')).toHaveAttribute('title', 'Undo Remove drop (Ctrl+Z)');
  await expect(page.getByTestId('undo')).toContainText('Remove drop');
  await page.getByTestId('undo').click();
  await expect.poll(async () => (await getJson(request, `${url}/instances`)).instances.length).toBe(1);
  await expect(page.getByTestId('redo')).toHaveAttribute('title', 'Redo Remove drop (Ctrl+Shift+Z)');
  const name = `keys_${Date.now() % 100000}`;
  await page.getByTestId('scene-save-name').fill(name);
  await page.locator('body').press('Control+s');
  await expect(page.getByTestId('message-info').filter({ hasText: `saved scene ${name}` })).toHaveCount(1);
  expect((await getJson(request, `${serverUrl()}/api/scenes/${name}`)).instances.map((i: any) => i.name)).toEqual(['drop']);
  await expectNoErrors(page, errors);
});

test('messages do not pile up over the viewport and are cleared when another scene opens', async ({ page }) => {
  await openDrop(page);
  await page.evaluate(() => {
    const { editor } = (window as any).flowclip;
    for (let i = 0; i < 5; i++) editor.message('warning', 'the same warning');
    for (let i = 0; i < 5; i++) editor.message('error', `error ${i}`);
  });
  const all = page.getByTestId('messages').locator('.message');
  await expect(all).toHaveCount(3);
  await expect(page.getByTestId('message-error').last()).toContainText('error 4');
  await page.evaluate(() => {
    const { editor } = (window as any).flowclip;
    for (let i = 0; i < 4; i++) editor.message('warning', 'the same warning');
  });
  await expect(page.getByTestId('message-warning')).toHaveCount(1);
  await expect(page.getByTestId('message-warning')).toHaveAttribute('data-count', '4');
  await page.getByTestId('scene-picker').selectOption('dambreak2d');
  await expect(page.getByTestId('session')).toContainText('dambreak2d');
  await expect(all).toHaveCount(0);
});

test('the frames/s readout is the rate frames arrive at', async ({ page }) => {
  const { errors } = await openDrop(page);
  const arrivals: number[] = [];
  await page.exposeFunction('noteArrival', (t: number) => arrivals.push(t));
  await page.evaluate(() => (window as any).flowclip.editor.signals.frameDecoded.add(() => (window as any).noteArrival(performance.now())));
  await page.getByTestId('play').click();
  await expect.poll(() => arrivals.length, { timeout: 30_000 }).toBeGreaterThan(25);
  const shown = await readNumber(page.getByTestId('stats-fps'));
  const now = await page.evaluate(() => performance.now());
  const recent = arrivals.filter((t) => now - t <= 2000);
  const measured = ((recent.length - 1) * 1000) / (recent[recent.length - 1]! - recent[0]!);
  console.log(`frames/s shown ${shown.toFixed(1)}, measured ${measured.toFixed(1)}`);
  expect(shown).toBeGreaterThan(0);
  expect(shown).toBeLessThanOrEqual(31); // the stream sends at most 30 per second
  expect(Math.abs(shown - measured)).toBeLessThan(0.35 * measured + 1);
  await page.evaluate(() => (window as any).flowclip.editor.pause()); // (it may have stopped at the scene's end)
  await expectNoErrors(page, errors);
});

test('a looping play range replays its recorded frames on the client until paused', async ({ page, request }) => {
  test.setTimeout(90_000);
  const { errors, url } = await openDrop(page);
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 20 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 40_000 }).toBe(20);
  await page.evaluate(() => (window as any).flowclip.editor.setPlayRange({ start: 5, end: 15 }));
  await page.getByTestId('timeline-loop').click();
  await expect(page.getByTestId('timeline-loop')).toHaveAttribute('data-value', 'true');
  // Record the playhead's frames while it loops.
  await page.evaluate(() => {
    const w = window as any;
    w.playheadSeen = [];
    w.flowclip.editor.signals.playheadChanged.add(() => w.playheadSeen.push(w.flowclip.editor.playheadFrame));
  });
  await page.getByTestId('play').click();
  // Wrapped around at least once: a frame lower than the one before it.
  await expect.poll(() => page.evaluate(() => {
    const seen: number[] = (window as any).playheadSeen;
    return seen.some((f, i) => i > 0 && f < seen[i - 1]!);
  }), { timeout: 30_000 }).toBe(true);
  const seen: number[] = await page.evaluate(() => (window as any).playheadSeen);
  expect(Math.min(...seen)).toBeGreaterThanOrEqual(5);
  expect(Math.max(...seen)).toBeLessThanOrEqual(15);
  // The server only replayed: nothing new was simulated.
  expect((await getJson(request, url)).frame).toBe(20);
  await expect(page.getByTestId('pause')).toBeEnabled();
  await page.locator('body').press('Space');
  await expect(page.getByTestId('play')).toBeEnabled();
  const stopped = await page.evaluate(() => (window as any).playheadSeen.length);
  await expect(page.getByTestId('timeline')).toHaveAttribute('data-pending', 'false');
  // The client's loop is stopped: nothing moves the playhead any more.
  expect(await page.evaluate(() => (window as any).flowclip.editor.looping)).toBe(false);
  expect(await page.evaluate(() => (window as any).playheadSeen.length)).toBeLessThanOrEqual(stopped + 1);
  await expectNoErrors(page, errors);
});

test('the ruler counts frames or seconds at whole frames; F frames the selection', async ({ page }) => {
  const { errors } = await openDrop(page);
  const units = page.getByTestId('timeline-units');
  const ticks = page.getByTestId('timeline-ruler').locator('.tick.major');
  await expect(units).toHaveAttribute('data-value', /frames|seconds/);
  if ((await units.getAttribute('data-value')) === 'seconds') await units.click();
  await expect(units).toHaveAttribute('data-value', 'frames');
  const frameLabels = await ticks.allTextContents();
  expect(frameLabels.length).toBeGreaterThan(3);
  for (const t of frameLabels) expect(t).toMatch(/^-?\d+$/);
  await units.click();
  await expect(units).toHaveAttribute('data-value', 'seconds');
  await expect(ticks.first()).toContainText('s');
  const frames = await ticks.evaluateAll((n) => n.map((e) => Number((e as HTMLElement).dataset['frame'])));
  for (let i = 0; i < frames.length; i++) {
    expect(Number.isInteger(frames[i])).toBe(true); // on whole frames
    const label = (await ticks.nth(i).textContent())!;
    expect(Number(label.replace('s', ''))).toBeCloseTo(frames[i]! / SCENE_FPS, 3);
  }
  // F: the selected instance's box fills the view (smaller than the domain: the view closes in).
  const height = () => page.evaluate(() => {
    const cam = (window as any).flowclip.viewport.camera;
    return (cam.top - cam.bottom) / cam.zoom;
  });
  const h0 = await height();
  await page.getByTestId('outliner-item-drop').click();
  await page.locator('body').press('f');
  await expect.poll(height).toBeLessThan(h0);
  await expectNoErrors(page, errors);
});

test('new users: scenes missing templates are marked, the empty 3D library says how to record one, uncovered control particles are not black', async ({ page }) => {
  const { errors } = await openDrop(page);
  const picker = page.getByTestId('scene-picker');
  // blade2d's instance needs the blade2d template, which the test database lacks.
  await expect(picker.locator('option[value="blade2d"]')).toHaveAttribute('data-missing', 'blade2d');
  await expect(picker.locator('option[value="blade2d"]')).toContainText('missing template blade2d');
  await expect(picker.locator('option[value="drop2d"]')).not.toHaveAttribute('data-missing', /./);
  // Control particles: covered green to uncovered magenta, none near the black background.
  await page.getByTestId('layer-control').check();
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 16 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBe(16);
  await expect.poll(() => page.evaluate(() => (window as any).flowclip.viewport.control.count as number)).toBeGreaterThan(0);
  const darkest = await page.evaluate(() => {
    const { viewport } = (window as any).flowclip;
    const c = viewport.control.points.geometry.getAttribute('color').array as Float32Array;
    let min = Infinity;
    for (let i = 0; i < viewport.control.count; i++) min = Math.min(min, Math.max(c[3 * i]!, c[3 * i + 1]!, c[3 * i + 2]!));
    return min;
  });
  expect(darkest).toBeGreaterThan(0.5);
  // A 3D scene without 3D templates: the library says how to get one.
  await picker.selectOption('dambreak3d');
  await expect(page.getByTestId('session')).toContainText('dambreak3d');
  await expect(page.getByTestId('library-empty')).toContainText('flowclip record templates/recipes/');
  await expect(page.getByTestId('library-empty')).toContainText('No 3D template');
  expect(errors).toEqual([]);
});

test('a replayed frame shows its control and boundary layers as the live run did', async ({ page }) => {
  const { errors } = await openDrop(page);
  await page.getByTestId('layer-boundary').check();
  await page.getByTestId('layer-control').check();
  const counts = () =>
    page.evaluate(() => {
      const { viewport } = (window as any).flowclip;
      return { control: viewport.control.count as number, boundary: viewport.boundary.count as number };
    });
  // The instance starts at 0.2 s: frame 16 has control particles.
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 16 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBe(16);
  await expect.poll(async () => (await counts()).control, { timeout: 20_000 }).toBeGreaterThan(0);
  const live16 = await counts();
  expect(live16.boundary).toBeGreaterThan(0);
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 4 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBe(20);
  // Back to frame 16: the server re-computes its layers from a checkpoint.
  await page.evaluate(() => (window as any).flowclip.editor.setPlayhead(16));
  await expect(page.getByTestId('frame')).toHaveAttribute('data-value', '16');
  await expect.poll(counts, { timeout: 20_000 }).toEqual(live16);
  for (const key of ['boundary', 'control']) {
    const row = page.locator('label.layer').filter({ has: page.getByTestId(`layer-${key}`) });
    await expect(row).not.toHaveClass(/unavailable/);
  }
  await page.getByTestId('live').click();
  await expect(page.getByTestId('frame')).toHaveAttribute('data-value', '20');
  await expect.poll(async () => (await counts()).control, { timeout: 20_000 }).toBeGreaterThan(0);
  await expectNoErrors(page, errors);
});
