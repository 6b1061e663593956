// Template library, gizmo, inspector, outliner and scene saving against a
// real server: every change the editor makes is read back over REST.
import { expect, test, type Page } from '@playwright/test';
import { openDrop, readNumber, serverUrl } from './helpers';

/** Client pixels of the gizmo's centre and of a point on its X arrow (2D: orthographic camera). */
async function gizmoHandles(page: Page) {
  return page.evaluate(() => {
    const { viewport } = (window as any).flowclip;
    const cam = viewport.camera, g = viewport.gizmo;
    const p = g.proxy.position.clone();
    // TransformControls scales its handles to (top − bottom) / zoom · size / 4 world units (orthographic).
    const unit = ((cam.top - cam.bottom) / cam.zoom) * g.controls.size / 4;
    const onX = p.clone();
    onX.x += 0.35 * unit;
    const canvas = viewport.renderer.domElement as HTMLCanvasElement;
    return {
      centre: viewport.screenOf(p), onX: viewport.screenOf(onX),
      metresPerPixel: (cam.right - cam.left) / cam.zoom / canvas.clientWidth,
    };
  });
}

test('instance a template from the library, move it with the gizmo, undo and redo on the server', async ({ page, request }) => {
  const { errors, sid } = await openDrop(page);
  const instances = async () => (await (await request.get(`${serverUrl()}/api/sessions/${sid}/instances`)).json()).instances;
  expect((await instances()).map((i: any) => i.name)).toEqual(['drop']);

  // The library lists the server's templates with their facts and a drawn thumbnail.
  const item = page.getByTestId('library-item-jet2d');
  await expect(item).toHaveAttribute('data-dimension', '2');
  await expect(item).toHaveAttribute('data-duration', '0.6');
  await expect(page.getByTestId('library-thumb-jet2d')).toHaveAttribute('data-points', /^[1-9][0-9]*$/);

  // "+": instanced at the view centre, selected, at the playhead.
  const centre = await page.evaluate(() => (window as any).flowclip.editor.viewCentre as number[]);
  await page.getByTestId('library-add-jet2d').click();
  await expect(page.getByTestId('outliner-item-jet2d')).toHaveClass(/selected/);
  let list = await instances();
  expect(list.map((i: any) => i.name)).toEqual(['drop', 'jet2d']);
  const added = list[1];
  expect(added.template).toBe('jet2d');
  expect(added.transform).toHaveLength(1);
  expect(added.transform[0].translation[0]).toBeCloseTo(centre[0]!, 3);
  expect(added.transform[0].translation[1]).toBeCloseTo(centre[1]!, 3);
  const x0 = added.transform[0].translation[0] as number, y0 = added.transform[0].translation[1] as number;
  await expect(page.getByTestId('inspector-translation-0')).toHaveAttribute('data-value', String(Number(x0.toPrecision(6))));

  // A real mouse drag on the gizmo's X arrow: +90 px.
  const h = await gizmoHandles(page);
  expect(Math.abs(h.centre.x - (await page.getByTestId('viewport-canvas').boundingBox())!.x)).toBeGreaterThan(0);
  await page.mouse.move(h.onX.x, h.onX.y);
  await page.mouse.down();
  for (let k = 1; k <= 9; k++) await page.mouse.move(h.onX.x + 10 * k, h.onX.y, { steps: 2 });
  await page.mouse.up();
  const expectedX = x0 + 90 * h.metresPerPixel;
  const track = async () => (await instances()).find((i: any) => i.name === 'jet2d').transform;
  await expect.poll(async () => (await track())[0].translation[0], { timeout: 10_000 }).toBeCloseTo(expectedX, 2);
  const moved = await track();
  expect(Math.abs(moved[0].translation[0] - expectedX)).toBeLessThan(3 * h.metresPerPixel);
  expect(moved[0].translation[1]).toBeCloseTo(y0, 4); // the X arrow constrains to x
  console.log(`gizmo drag: x ${x0.toFixed(4)} → ${moved[0].translation[0].toFixed(4)} (expected ${expectedX.toFixed(4)}), ` +
    `${await page.evaluate(() => (window as any).flowclip.viewport.gizmo.sent)} PATCHes`);
  // The whole drag is one history entry (after the add).
  const entries = await page.evaluate(() => (window as any).flowclip.editor.history.undoEntries.map((e: any) => e.name));
  expect(entries).toEqual(['Add jet2d', 'Move jet2d']);

  await page.locator('body').press('Control+z');
  await expect.poll(async () => (await track())[0].translation[0]).toBeCloseTo(x0, 4);
  await page.locator('body').press('Control+Shift+z');
  await expect.poll(async () => (await track())[0].translation[0]).toBeCloseTo(moved[0].translation[0], 4);
  // Undo twice: the move, then the add (the instance is gone on the server).
  await page.locator('body').press('Control+z');
  await page.locator('body').press('Control+z');
  await expect.poll(async () => (await instances()).map((i: any) => i.name)).toEqual(['drop']);
  await expect(page.getByTestId('outliner-item-jet2d')).toHaveCount(0);
  expect(errors).toEqual([]);
  await expect(page.getByTestId('message-error')).toHaveCount(0);
});

test('inspector: speed, reverse, a parameter and a keyframe go to the server; a bad value is shown, the session goes on', async ({ page, request }) => {
  const { errors, sid, instanceUrl: url } = await openDrop(page);
  const drop = async () => (await request.get(url)).json();
  await page.getByTestId('outliner-item-drop').click();
  await expect(page.getByTestId('inspector-header')).toHaveAttribute('data-value', 'drop');

  await page.getByTestId('inspector-speed').fill('1.5');
  await page.getByTestId('inspector-speed').press('Enter');
  await expect.poll(async () => (await drop()).speed).toBe(1.5);
  await page.getByTestId('inspector-reverse').check();
  await expect.poll(async () => (await drop()).reverse).toBe(true);
  // A declared parameter (GET /api/parameters builds these fields).
  await expect(page.getByTestId('inspector-falloff_width')).toHaveAttribute('data-value', '0.05');
  await page.getByTestId('inspector-falloff_width').fill('0.08');
  await page.getByTestId('inspector-falloff_width').press('Enter');
  await expect.poll(async () => (await drop()).falloff_width).toBe(0.08);
  await page.getByTestId('inspector-crop_end').fill('0.75');
  await page.getByTestId('inspector-crop_end').press('Enter');
  await expect.poll(async () => (await drop()).crop_end).toBe(0.75);

  // A keyframe at the playhead (frame 0): the empty track becomes one key at the recording place.
  await page.getByTestId('inspector-add-key').click();
  await expect.poll(async () => (await drop()).transform.length).toBe(1);
  const t0 = (await drop()).transform[0];
  expect(t0.time).toBe(0);
  expect(t0.translation[0]).toBeCloseTo(0.6, 6); // drop2d's region centre x: (0.25 + 0.95) / 2
  await expect(page.getByTestId('inspector-key-info')).toHaveAttribute('data-here', 'true');
  // Typing a position edits that key.
  await page.getByTestId('inspector-translation-1').fill('0.42');
  await page.getByTestId('inspector-translation-1').press('Enter');
  await expect.poll(async () => (await drop()).transform[0].translation[1]).toBe(0.42);

  // An invalid value: the server's 422 is shown, nothing changes, the field shows the server's value again.
  await page.getByTestId('inspector-speed').fill('-2');
  await page.getByTestId('inspector-speed').press('Enter');
  const msg = page.getByTestId('message-error');
  await expect(msg).toHaveCount(1);
  await expect(msg).toContainText('speed');
  expect((await drop()).speed).toBe(1.5);
  await expect(page.getByTestId('inspector-speed')).toHaveValue('1.5');
  // Not a number at all: said by the editor, nothing sent.
  await page.getByTestId('inspector-start').fill('soon');
  await page.getByTestId('inspector-start').press('Enter');
  await expect(msg.filter({ hasText: 'not a number' })).toHaveCount(1);
  expect((await drop()).start).toBe(0.2);
  // The session continues.
  const frame = page.getByTestId('frame');
  const f0 = await readNumber(frame);
  await page.getByTestId('step').click();
  await expect.poll(() => readNumber(frame)).toBe(f0 + 1);

  // Scene settings: a solver tolerance from the declarations.
  const tol = page.getByTestId('scene-solver-density_tolerance_pct');
  await expect(tol).toHaveAttribute('data-value', '0.05');
  await tol.fill('0.1');
  await tol.press('Enter');
  await expect.poll(async () => (await (await request.get(`${serverUrl()}/api/sessions/${sid}/scene`)).json()).solver.density_tolerance_pct).toBe(0.1);
  expect(errors).toEqual([]);
});

// The accuracy study's presets (bench/accuracy/presets.json via GET
// /api/presets): offered with their measured cost and error, applied as one
// undoable settings edit that the server's scene then holds.
test('accuracy presets: offered with their figures, applied to the scene, undone', async ({ page, request }) => {
  const { errors, sid } = await openDrop(page);
  const { presets } = await (await request.get(`${serverUrl()}/api/presets`)).json();
  expect(presets.map((p: any) => p.name)).toEqual(['draft', 'preview', 'final']);
  const select = page.getByTestId('scene-preset');
  await expect(select).toHaveAttribute('data-value', 'custom');  // drop2d's own tolerances are not a preset
  const scene = async () => (await (await request.get(`${serverUrl()}/api/sessions/${sid}/scene`)).json());
  const before = await scene();
  for (const p of presets) {
    // The option shows the preset's measured cost.
    await expect(select.locator(`option[value="${p.name}"]`)).toContainText(`${p.cost.us_per_particle_step.toFixed(2)} µs per particle-step`);
    await select.selectOption(p.name);
    await expect.poll(async () => {
      const s = await scene();
      return Object.entries(p.solver).every(([k, v]) => s.solver[k] === v) && Object.entries(p.settings).every(([k, v]) => s.settings[k] === v);
    }, { timeout: 20_000 }).toBe(true);
    await expect(select).toHaveAttribute('data-value', p.name);
    await expect(page.getByTestId('scene-preset-figures')).toContainText(`${p.error.avg_density_error_pct.toFixed(3)} % average density error`);
  }
  // Undo, one preset at a time, back to the scene's own settings (keys go to the page, not the select).
  await page.getByTestId('viewport-canvas').click({ position: { x: 5, y: 5 } });
  for (let i = 0; i < presets.length; ++i) await page.keyboard.press('Control+z');
  await expect.poll(async () => {
    const s = await scene();
    return s.solver.density_tolerance_pct === before.solver.density_tolerance_pct && s.settings.cfl_factor === before.settings.cfl_factor &&
      s.solver.method === before.solver.method;
  }, { timeout: 20_000 }).toBe(true);
  await expect(select).toHaveAttribute('data-value', 'custom');
  expect(errors).toEqual([]);
});

test('the scene is saved on the server and downloaded with its instances', async ({ page, request }) => {
  const { errors, sid } = await openDrop(page);
  await page.getByTestId('library-add-column2d').click();
  await expect(page.getByTestId('outliner-item-column2d')).toBeVisible();
  const name = `saved_${Date.now() % 100000}`;
  await page.getByTestId('scene-save-name').fill(name);
  await page.getByTestId('save-scene').click();
  await expect(page.getByTestId('message-info').filter({ hasText: `saved scene ${name}` })).toHaveCount(1);
  const saved = await (await request.get(`${serverUrl()}/api/scenes/${name}`)).json();
  expect(saved.instances.map((i: any) => i.name)).toEqual(['drop', 'column2d']);
  await expect(page.getByTestId('scene-picker').locator(`option[value="${name}"]`)).toHaveCount(1);
  // Saving again asks before overwriting (accepted here).
  page.once('dialog', (d) => void d.accept());
  await page.getByTestId('save-scene').click();
  // The same message again is counted on the one shown (messages do not pile up).
  const savedMessage = page.getByTestId("message-info").filter({ hasText: `saved scene ${name}` });
  await expect(savedMessage).toHaveAttribute("data-count", "2");
  await expect(savedMessage).toHaveCount(1);

  const [download] = await Promise.all([page.waitForEvent('download'), page.getByTestId('download-scene').click()]);
  expect(download.suggestedFilename()).toBe(`${name}.json`);
  const text = await (await download.createReadStream()).toArray();
  const scene = JSON.parse(Buffer.concat(text).toString('utf8'));
  expect(scene.instances.map((i: any) => i.name)).toEqual(['drop', 'column2d']);
  expect(scene.dimension).toBe(2);
  // The downloaded file is a scene the server accepts.
  const res = await request.post(`${serverUrl()}/api/sessions`, { data: { scene } });
  expect(res.status(), await res.text()).toBe(201);
  await request.delete(`${serverUrl()}/api/sessions/${(await res.json()).id}`);
  void sid;
  expect(errors).toEqual([]);
  await expect(page.getByTestId('message-error')).toHaveCount(0);
});

test('colour by speed: the server sends |v| per particle and the liquid takes the ramp', async ({ page }) => {
  const { errors } = await openDrop(page);
  // Let the liquid move (the drop instance starts at 0.2 s: frame 12).
  await page.evaluate(() => (window as any).flowclip.editor.transport('step', { frames: 20 }));
  await expect.poll(() => readNumber(page.getByTestId('frame')), { timeout: 20_000 }).toBeGreaterThanOrEqual(20);
  const distinctColours = () => page.evaluate(() => {
    const { viewport, editor } = (window as any).flowclip;
    const c = viewport.particles.points.geometry.getAttribute('color').array as Float32Array;
    const seen = new Set<string>();
    for (let i = 0; i < viewport.particles.count; i++) seen.add(`${c[3 * i]!.toFixed(3)},${c[3 * i + 1]!.toFixed(3)},${c[3 * i + 2]!.toFixed(3)}`);
    return { colours: seen.size, speedLayer: (editor.decoder.info.layers & 16) !== 0, scale: editor.decoder.speedScale as number };
  });
  const before = await distinctColours();
  expect(before.speedLayer).toBe(false);
  expect(before.colours).toBeLessThanOrEqual(2); // phase colour (+ orange temporary particles)
  await page.getByTestId('layer-speed').check();
  await expect.poll(async () => (await distinctColours()).colours, { timeout: 10_000 }).toBeGreaterThan(20);
  const after = await distinctColours();
  expect(after.speedLayer).toBe(true);
  expect(after.scale).toBeGreaterThan(0.05); // m/s: the splash moves
  console.log(`colour by speed: ${after.colours} distinct colours, scale ${after.scale.toFixed(2)} m/s`);
  await page.getByTestId('layer-speed').uncheck();
  await expect.poll(async () => (await distinctColours()).colours, { timeout: 10_000 }).toBeLessThanOrEqual(2);
  expect(errors).toEqual([]);
  await expect(page.getByTestId('message-error')).toHaveCount(0);
});

test('clicking an instance box in the viewport selects it; clicking nothing deselects', async ({ page }) => {
  const { errors } = await openDrop(page);
  await expect.poll(() => page.evaluate(() => (window as any).flowclip.editor.decoder.info.instanceCount)).toBe(1);
  const at = (x: number, y: number) => page.evaluate(([x, y]) => {
    const { viewport } = (window as any).flowclip;
    const p = viewport.gizmo.proxy.position.clone().set(x, y, 0);
    return viewport.screenOf(p);
  }, [x, y]);
  // drop2d's box: its template region [0.25, 0.95] × [0, 0.7] where it was recorded.
  const inside = await at(0.4, 0.5);
  await page.mouse.click(inside.x, inside.y);
  await expect(page.getByTestId('outliner-item-drop')).toHaveClass(/selected/);
  await expect(page.getByTestId('inspector-header')).toHaveAttribute('data-value', 'drop');
  // Right of the box, mid-height: clear of the messages (top right), however
  // tall the timeline leaves the viewport.
  const outside = await at(1.1, 0.4);
  await page.mouse.click(outside.x, outside.y);
  await expect(page.getByTestId('outliner-item-drop')).not.toHaveClass(/selected/);
  expect(await page.evaluate(() => (window as any).flowclip.editor.selected)).toBeNull();
  expect(errors).toEqual([]);
});
