// Playwright: Debian's headless Chromium (software GL) against a real
// `flowclip serve` started by tests/global-setup.ts on a free port.
// `make test` prints "N passed, N failed" from the JSON report
// (scripts/report-summary.mjs).
import { defineConfig } from '@playwright/test';

export default defineConfig({
  testDir: './tests',
  timeout: 60_000,
  expect: { timeout: 15_000 },
  workers: 1,
  retries: 0,
  forbidOnly: true,
  reporter: [['list'], ['json', { outputFile: 'playwright-report/results.json' }]],
  globalSetup: './tests/global-setup.ts',
  use: {
    browserName: 'chromium',
    headless: true,
    viewport: { width: 960, height: 640 },
    trace: 'retain-on-failure',
    screenshot: 'only-on-failure',
    // Every launch gets a fresh temporary profile directory.
    launchOptions: {
      executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
      args: [
        '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
        '--disable-background-networking', '--disable-component-update', '--disable-sync',
        '--enable-unsafe-swiftshader',
      ],
    },
  },
});
