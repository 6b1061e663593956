// Prints "N passed, N failed" on its own line from Playwright's JSON report
// (CI reads that line). Flaky tests count as passed, skipped ones as neither.
// Usage: node scripts/report-summary.mjs [playwright-report/results.json]
import { readFileSync } from 'node:fs';

const path = process.argv[2] ?? 'playwright-report/results.json';
let report;
try {
  report = JSON.parse(readFileSync(path, 'utf8'));
} catch (e) {
  console.log(`playwright: no report at ${path} (${e.message})`);
  console.log('0 passed, 1 failed');
  process.exit(0);
}
const s = report.stats ?? {};
const passed = (s.expected ?? 0) + (s.flaky ?? 0);
let failed = s.unexpected ?? 0;
// A run that failed outside any test (global setup) reports errors, no tests.
if (failed === 0 && Array.isArray(report.errors) && report.errors.length > 0) failed = report.errors.length;
if (s.skipped) console.log(`playwright: ${s.skipped} skipped`);
console.log(`${passed} passed, ${failed} failed`);
