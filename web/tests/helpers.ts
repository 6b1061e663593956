import { expect, type APIRequestContext, type Locator, type Page } from '@playwright/test';

export function serverUrl(): string {
  const url = process.env.FLOWCLIP_URL;
  if (!url) throw new Error('FLOWCLIP_URL is not set (tests/global-setup.ts starts the server)');
  return url;
}

/** A status-bar readout's data-value as a number. */
export async function readNumber(locator: Locator): Promise<number> {
  return Number(await locator.getAttribute('data-value'));
}

type Rgb = [number, number, number];

/** Image pixels [left, right) × [top, bottom). */
export interface PixelRect {
  left: number;
  right: number;
  top: number;
  bottom: number;
}

/**
 * Pixels of a PNG whose every channel lies between `min` and `max`
 * (inclusive), within `rect` (default: all of it), decoded in the page (no
 * image library in Node). `total`: the image's pixels.
 */
export async function countPixelsBetween(page: Page, png: Buffer, min: Rgb, max: Rgb, rect?: PixelRect) {
  return page.evaluate(
    async ({ b64, min, max, rect }) => {
      const img = new Image();
      img.src = `data:image/png;base64,${b64}`;
      await img.decode();
      const c = document.createElement('canvas');
      c.width = img.width;
      c.height = img.height;
      const ctx = c.getContext('2d')!;
      ctx.drawImage(img, 0, 0);
      const d = ctx.getImageData(0, 0, c.width, c.height).data;
      const r = rect ?? { left: 0, right: c.width, top: 0, bottom: c.height };
      let n = 0;
      for (let y = Math.max(0, r.top); y < Math.min(c.height, r.bottom); y++)
        for (let x = Math.max(0, r.left); x < Math.min(c.width, r.right); x++) {
          const i = 4 * (y * c.width + x);
          if ([0, 1, 2].every((k) => d[i + k]! >= min[k]! && d[i + k]! <= max[k]!)) n++;
        }
      return { count: n, total: c.width * c.height };
    },
    { b64: png.toString('base64'), min, max, rect },
  );
}

/** Pixels of a PNG within `tol` (per channel) of `rgb`. */
export async function countPixelsNear(page: Page, png: Buffer, rgb: Rgb, tol: number) {
  const { count, total } = await countPixelsBetween(page, png, rgb.map((v) => v - tol) as Rgb, rgb.map((v) => v + tol) as Rgb);
  return { near: count, total };
}

/** Opens the editor without a scene and collects page errors. */
export async function openEditor(page: Page): Promise<string[]> {
  const errors: string[] = [];
  page.on('pageerror', (e) => errors.push(e.message));
  await page.goto(`${serverUrl()}/?scene=`);
  await expect(page.getByTestId('viewport-canvas')).toBeVisible();
  return errors;
}

export interface OpenedDrop {
  /** Page errors so far and from now on (openEditor). */
  errors: string[];
  sid: string;
  /** The session's REST address. */
  url: string;
  /** The drop instance's REST address. */
  instanceUrl: string;
}

/**
 * Opens the editor on the drop2d scene (picked as a user would) and waits
 * until its session is made, its stream is open and the timeline has drawn
 * the drop instance's track (its length comes from the template list).
 */
export async function openDrop(page: Page): Promise<OpenedDrop> {
  const errors = await openEditor(page);
  await page.getByTestId('scene-picker').selectOption('drop2d');
  const session = page.getByTestId('session');
  await expect(session).toHaveAttribute('data-value', /^[A-Za-z0-9_-]+$/);
  const sid = (await session.getAttribute('data-value'))!;
  await expect(page.getByTestId('connection')).toHaveAttribute('data-value', 'open');
  await expect(page.getByTestId('timeline-track-drop')).toHaveAttribute('data-end', /\d/);
  const url = `${serverUrl()}/api/sessions/${sid}`;
  return { errors, sid, url, instanceUrl: `${url}/instances/drop` };
}

/** GET `url`'s JSON; a failed request fails the test with its status and body. */
export async function getJson(request: APIRequestContext, url: string) {
  const res = await request.get(url);
  expect(res.ok(), `GET ${url}: ${res.status()} ${await res.text()}`).toBeTruthy();
  return res.json();
}

/** No page error and no error message shown. */
export async function expectNoErrors(page: Page, errors: string[]) {
  expect(errors).toEqual([]);
  await expect(page.getByTestId('message-error')).toHaveCount(0);
}

/**
 * Resolves after `n` animation frames of the page. A render loop renders
 * once an animation frame: a test that nothing renders while nothing
 * changes lets this many go by, whatever the machine's speed.
 */
export async function animationFrames(page: Page, n: number): Promise<void> {
  await page.evaluate(
    (n) =>
      new Promise<void>((resolve) => {
        let left = n;
        const tick = () => (--left > 0 ? requestAnimationFrame(tick) : resolve());
        requestAnimationFrame(tick);
      }),
    n,
  );
}

/**
 * Holds `method` requests to `url` back on their way to the server until
 * release() (the first `passing` of them go through at once): a server that
 * has not answered yet for as long as the test needs it, not for a time.
 */
export async function holdRequests(page: Page, url: string, method: string, passing = 0) {
  let release!: () => void;
  const released = new Promise<void>((r) => (release = r));
  let seen = 0;
  await page.route(url, async (route) => {
    if (route.request().method() === method && ++seen > passing) await released;
    await route.continue();
  });
  return { release };
}
