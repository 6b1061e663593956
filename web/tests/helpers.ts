import { expect, type Locator, type Page } from '@playwright/test';

export function serverUrl(): string {
  const url = process.env.FLOWCLIP_URL;
  if (!url) throw new Error('FLOWCLIP_URL is not set (tests/global-setup.ts starts the server)');
  return url;
}

/** A status-bar readout's data-value as a number. */
export async function readNumber(locator: Locator): Promise<number> {
  return Number(await locator.getAttribute('data-value'));
}

/**
 * Pixels of a PNG within `tol` (per channel) of `rgb`, decoded in the page
 * (no image library in Node).
 */
export async function countPixelsNear(page: Page, png: Buffer, rgb: [number, number, number], tol: number) {
  return page.evaluate(
    async ({ b64, rgb, tol }) => {
      const img = new Image();
      img.src = `data:image/png;base64,${b64}`;
      await img.decode();
      const c = document.createElement('canvas');
      c.width = img.width;
      c.height = img.height;
      const ctx = c.getContext('2d')!;
      ctx.drawImage(img, 0, 0);
      const d = ctx.getImageData(0, 0, c.width, c.height).data;
      let n = 0;
      for (let i = 0; i < d.length; i += 4) {
        if (Math.abs(d[i]! - rgb[0]) <= tol && Math.abs(d[i + 1]! - rgb[1]) <= tol && Math.abs(d[i + 2]! - rgb[2]) <= tol) n++;
      }
      return { near: n, total: c.width * c.height };
    },
    { b64: png.toString('base64'), rgb, tol },
  );
}

/** Opens the editor without a scene and collects page errors. */
export async function openEditor(page: Page): Promise<string[]> {
  const errors: string[] = [];
  page.on('pageerror', (e) => errors.push(e.message));
  await page.goto(`${serverUrl()}/?scene=`);
  await expect(page.getByTestId('viewport-canvas')).toBeVisible();
  return errors;
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
