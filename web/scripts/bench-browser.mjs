// The editor's browser benchmark: decode +
// upload time per frame for about 100k and 300k liquid particles, 2D and 3D,
// in headless Chromium with software GL (SwiftShader), and the bytes per frame
// on the wire.
//
//   node scripts/bench-browser.mjs [--quick] [--reps N] [--warmup N] [--cases 2d-100k,3d-300k] [--json FILE]
//   make bench-web                      (from the top level: build, templates, web, then this)
//
// It starts `flowclip serve --port 0` ($FLOWCLIP_BIN, else $FLOWCLIP_BUILD_DIR/flowclip,
// default ../build) on temporary copies of templates/ and scenes/, into which
// it writes one dam-break block scene per case, and web/dist as the editor. A
// fresh Chromium (/usr/bin/chromium or $CHROMIUM, temporary profile) opens
// the editor at /?scene=, and for each case:
//   1. editor.openScene(NAME): the editor creates the session and receives
//      frame 0 through its own WebSocket stream and FrameDecoder into the
//      viewport's ParticleLayer (the cold decode, with the buffers growing, is
//      reported; the message size is read in the page and, from outside, from
//      the WebSocket frames Playwright sees);
//   2. the same frame's bytes are fetched once (GET .../frames/0?format=binary,
//      one Envelope{Frame}, the stream's message) and, after a warm-up, each
//      repetition times
//        decode       Envelope → Frame → editor.decoder.decode(): dequantize and
//                     colour into the ParticleLayer's attribute arrays (as the
//                     stream's onMessage does); the same bytes again, so the
//                     kinds and phases are the previous frame's and the colours
//                     are kept, as in a one-phase scene without temporary particles
//        upload+draw  viewport.render() with what that decode marked for upload,
//                     then a 1-pixel readPixels, the sync point that makes the GL
//                     work count (Chromium's gl.finish() is only a flush)
//        draw         the same render again, nothing to upload, and its readPixels
//        upload       the same marks uploaded by a render with an empty draw
//                     range, minus that empty render without uploads
//        decode*, upload*  the same with every colour looked up and uploaded
//                     (decoder.invalidateColors() before each decode)
// Median and p95 (nearest rank) over the repetitions, one table on stdout
// (--json FILE: every figure). FLOWCLIP_WEB_DIST serves another editor build
// (before/after comparisons).
// Under SwiftShader "GPU" work is CPU work on the same 2 cores: these are
// software-GL figures, not what a GPU does.
import { spawn } from 'node:child_process';
import { cpSync, createWriteStream, existsSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir, cpus, loadavg } from 'node:os';
import { join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const webDir = fileURLToPath(new URL('..', import.meta.url));
const repoDir = resolve(webDir, '..');

// ------------------------------------------------------------- options ---

const CASES = [
  // 2D: r = 2.5 mm, a 400 × 250 / 600 × 500 lattice; 3D: r = 1 cm, 50 × 50 × 40 / 100 × 60 × 50.
  { key: '2d-100k', dim: 2, r: 0.0025, cells: [400, 250] },
  { key: '2d-300k', dim: 2, r: 0.0025, cells: [600, 500] },
  { key: '3d-100k', dim: 3, r: 0.01, cells: [50, 50, 40] },
  { key: '3d-300k', dim: 3, r: 0.01, cells: [100, 60, 50] },
];

// Decodes (and uploads) timed together per repetition (performance.now() has 0.1 ms steps in the page).
const DECODE_BATCH = 10;

function usage(msg) {
  if (msg) console.error(`bench-browser: ${msg}`);
  console.error('usage: node scripts/bench-browser.mjs [--quick] [--reps N] [--warmup N] [--cases ' +
    CASES.map((c) => c.key).join(',') + '] [--json FILE]');
  process.exit(2);
}

function parseArgs(argv) {
  const o = { reps: 40, warmup: 5, cases: CASES.map((c) => c.key), json: null, quick: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const value = () => {
      if (i + 1 >= argv.length) usage(`${a} needs a value`);
      return argv[++i];
    };
    const int = (v, min) => {
      const n = Number(v);
      if (!Number.isInteger(n) || n < min) usage(`${a}: ${v} is not an integer ≥ ${min}`);
      return n;
    };
    if (a === '--quick') o.quick = true;
    else if (a === '--reps') o.repsSet = int(value(), 1);
    else if (a === '--warmup') o.warmupSet = int(value(), 0);
    else if (a === '--cases') o.cases = value().split(',').filter(Boolean);
    else if (a === '--json') o.json = resolve(value());
    else if (a === '-h' || a === '--help') usage();
    else usage(`unknown argument ${a}`);
  }
  if (o.quick) {
    o.reps = 5;
    o.warmup = 2;
  }
  if (o.repsSet !== undefined) o.reps = o.repsSet;
  if (o.warmupSet !== undefined) o.warmup = o.warmupSet;
  for (const k of o.cases) if (!CASES.some((c) => c.key === k)) usage(`unknown case ${k}`);
  return o;
}

// -------------------------------------------------------------- scenes ---

/** A block of exactly cells[0] × cells[1] (× cells[2]) particles at rest in a tank a little larger. */
function sceneFor(c) {
  const d = 2 * c.r;
  // ⌊size / 2r⌋ particles per axis: a quarter diameter of slack keeps float rounding off the count.
  const size = c.cells.map((n) => n * d + 0.25 * d);
  const round = (x) => Math.round(x * 1e6) / 1e6;
  return {
    name: `webbench_${c.key.replace('-', '_')}`,
    dimension: c.dim,
    particle_radius: c.r,
    domain: { min: c.cells.map(() => 0), max: size.map((s) => round(s * 1.2 + 4 * d)) },
    gravity: c.dim === 2 ? [0, -9.81] : [0, -9.81, 0],
    duration: 1,
    phases: [{ name: 'water', rest_density: 1000, viscosity: 0.01 }],
    fluid_blocks: [{ min: c.cells.map(() => 0), max: size.map(round), phase: 'water' }],
    effects: ['viscosity_standard'],
  };
}

// -------------------------------------------------------------- server ---

async function startServer(tmp) {
  const buildDir = resolve(webDir, process.env.FLOWCLIP_BUILD_DIR ?? '../build');
  const bin = process.env.FLOWCLIP_BIN ?? join(buildDir, 'flowclip');
  const dist = resolve(process.env.FLOWCLIP_WEB_DIST ?? join(webDir, 'dist'));
  if (!existsSync(bin)) throw new Error(`${bin} is missing: make build (or set FLOWCLIP_BUILD_DIR / FLOWCLIP_BIN)`);
  if (!existsSync(join(dist, 'index.html'))) throw new Error(`${dist} is missing: make web`);
  const logPath = join(tmp, 'server.log');
  const log = createWriteStream(logPath);
  const server = spawn(bin, ['serve', '--port', '0', '--web', dist, '--templates', join(tmp, 'templates'),
    '--scenes', join(tmp, 'scenes'), '--exports', join(tmp, 'exports')], { stdio: ['ignore', 'pipe', 'pipe'] });
  server.stderr.pipe(log);
  const url = await new Promise((resolveUrl, reject) => {
    let out = '';
    let listening = false;
    const timer = setTimeout(() => reject(new Error(`flowclip serve did not start in 15 s:\n${out}`)), 15_000);
    server.stdout.on('data', (chunk) => {
      log.write(chunk);
      if (listening) return;
      out += chunk.toString();
      const m = /listening on (http:\/\/\S+)/.exec(out);
      if (m) {
        listening = true;
        clearTimeout(timer);
        resolveUrl(m[1]);
      }
    });
    server.once('exit', (code) => {
      clearTimeout(timer);
      let err = '';
      try {
        err = readFileSync(logPath, 'utf8');
      } catch { /* none */ }
      reject(new Error(`flowclip serve exited (${code}) before listening:\n${out}\n${err}`));
    });
  });
  const stop = async () => {
    if (server.exitCode === null && server.signalCode === null) {
      const exited = new Promise((r) => server.once('exit', r));
      server.kill('SIGTERM');
      await Promise.race([exited, new Promise((r) => setTimeout(r, 5000))]);
      if (server.exitCode === null && server.signalCode === null) server.kill('SIGKILL');
    }
    log.end();
  };
  return { url, stop, logPath };
}

// ------------------------------------------------------------- in page ---

// Runs in the page: fetches the session's frame 0 as the stream's message and
// times decode, upload+draw, draw and the sync point, `reps` times after `warmup`.
async function measureInPage({ id, reps, warmup, batch }) {
  const { editor, viewport, wire } = window.flowclip;
  const res = await fetch(`/api/sessions/${encodeURIComponent(id)}/frames/0?format=binary`);
  if (!res.ok) throw new Error(`GET /api/sessions/${id}/frames/0?format=binary: ${res.status}`);
  const bytes = new Uint8Array(await res.arrayBuffer());
  const decoder = editor.decoder;
  const envelope = new wire.Envelope();
  const frame = new wire.Frame();
  // As Stream.onMessage: Envelope → Frame → decoder.decode (into viewport.particles).
  const decode = () => {
    const bb = new wire.ByteBuffer(bytes);
    if (!wire.Envelope.bufferHasIdentifier(bb)) throw new Error('the frame has no FCW1 identifier');
    wire.Envelope.getRootAsEnvelope(bb, envelope).message(frame);
    return decoder.decode(frame, bytes.byteLength);
  };
  const gl = viewport.renderer.getContext();
  const pixel = new Uint8Array(4);
  const sync = () => gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
  const heap = () => (performance.memory ? performance.memory.usedJSHeapSize : NaN);
  const now = () => performance.now();

  // Frames whose particles keep their kinds and phases (one phase, no temporary
  // particles, however the simulation reorders them) reuse every colour;
  // invalidateColors() before a decode makes it write and upload them all, as
  // when the kinds change from the first particle on. (A decoder without
  // colour reuse, an older build, does that every time.)
  const invalidate = typeof decoder.invalidateColors === 'function' ? () => decoder.invalidateColors() : () => undefined;
  const decodeNew = () => {
    invalidate();
    return decode();
  };
  const layer = viewport.particles;
  const geometry = layer.points.geometry;
  viewport.render();
  sync();
  const t = {
    decode: [], uploadDraw: [], draw: [], uploadDiff: [], upload: [],
    decodeNew: [], uploadDrawNew: [], uploadNew: [], empty: [], sync: [],
  };
  let peakHeap = heap();
  let drawn = 0;
  for (let i = -warmup; i < reps; i++) {
    // performance.now() is coarsened to 0.1 ms here (no cross-origin isolation): time a batch of decodes.
    const t0 = now();
    for (let k = 0; k < batch; k++) decode();
    const t1 = now();
    viewport.render(); // uploads what the decode marked, draws
    sync();
    const t2 = now();
    drawn = viewport.renderer.info.render.points;
    viewport.render(); // nothing to upload
    sync();
    const t3 = now();
    for (let k = 0; k < batch; k++) decodeNew();
    const t4 = now();
    viewport.render(); // every colour uploaded too
    sync();
    const t5 = now();
    // The uploads alone: the frame's range marked again as each decode marks
    // it, rendered with an empty draw range; minus the same empty render.
    const n = layer.count;
    geometry.setDrawRange(0, 0);
    viewport.render(); // untimed: the first empty render after a full one costs more
    sync();
    const t5b = now();
    for (let k = 0; k < batch; k++) {
      layer.commit(n, n);
      geometry.setDrawRange(0, 0);
      viewport.render();
      sync();
    }
    const t6 = now();
    for (let k = 0; k < batch; k++) {
      layer.commit(n, 0);
      geometry.setDrawRange(0, 0);
      viewport.render();
      sync();
    }
    const t7 = now();
    for (let k = 0; k < batch; k++) {
      viewport.render();
      sync();
    }
    const t8 = now();
    geometry.setDrawRange(0, n);
    sync();
    const t9 = now();
    peakHeap = Math.max(peakHeap, heap());
    if (i < 0) continue;
    const empty = (t8 - t7) / batch;
    t.decode.push((t1 - t0) / batch);
    t.uploadDraw.push(t2 - t1);
    t.draw.push(t3 - t2);
    t.uploadDiff.push(t2 - t1 - (t3 - t2));
    t.upload.push((t6 - t5b) / batch - empty);
    t.decodeNew.push((t4 - t3) / batch);
    t.uploadDrawNew.push(t5 - t4);
    t.uploadNew.push((t7 - t6) / batch - empty);
    t.empty.push(empty);
    t.sync.push(t9 - t8);
  }

  // Bytes one render after a decode sends with bufferSubData / bufferData (counted once, untimed).
  const sub = gl.bufferSubData, full = gl.bufferData;
  const countUpload = (decodeFn) => {
    const up = { bytes: 0, calls: 0 };
    gl.bufferSubData = function (target, offset, src, srcOffset, length) {
      up.calls++;
      if (src && src.BYTES_PER_ELEMENT) up.bytes += (length || src.length - (srcOffset ?? 0)) * src.BYTES_PER_ELEMENT;
      else if (src) up.bytes += src.byteLength;
      return sub.apply(this, arguments);
    };
    gl.bufferData = function (target, src) {
      up.calls++;
      if (src && typeof src === 'object') up.bytes += src.byteLength;
      return full.apply(this, arguments);
    };
    try {
      decodeFn();
      viewport.render();
      sync();
    } finally {
      gl.bufferSubData = sub;
      gl.bufferData = full;
    }
    return up;
  };
  const uploaded = countUpload(decode);
  const uploadedNew = countUpload(decodeNew);

  // JS heap allocated per decode (needs --js-flags=--expose-gc; 200 decodes allocate too little to trigger a GC).
  let allocPerDecode = null;
  if (typeof window.gc === 'function' && performance.memory) {
    window.gc();
    const h0 = heap();
    for (let k = 0; k < 200; k++) decode();
    allocPerDecode = (heap() - h0) / 200;
  }
  const info = decoder.info;
  const ext = gl.getExtension('WEBGL_debug_renderer_info');
  return {
    times: t,
    restBytes: bytes.byteLength,
    count: info.count,
    frame: info.frame,
    dimension: info.dimension,
    drawnPoints: drawn,
    peakHeap,
    allocPerDecode,
    uploaded,
    uploadedNew,
    layerCapacity: layer.capacity,
    canvas: [gl.drawingBufferWidth, gl.drawingBufferHeight],
    pixelRatio: viewport.renderer.getPixelRatio(),
    webgl: gl instanceof WebGL2RenderingContext ? 2 : 1,
    renderer: ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
  };
}

// --------------------------------------------------------------- stats ---

function stat(xs) {
  const s = [...xs].sort((a, b) => a - b);
  const rank = (p) => s[Math.min(s.length - 1, Math.max(0, Math.ceil(p * s.length) - 1))];
  return { median: s.length % 2 ? s[(s.length - 1) / 2] : (s[s.length / 2 - 1] + s[s.length / 2]) / 2, p95: rank(0.95), n: s.length };
}

const ms = (x) => (x < 10 ? x.toFixed(2) : x < 100 ? x.toFixed(1) : x.toFixed(0));
const pair = (s) => `${ms(s.median)} / ${ms(s.p95)}`;
const mb = (b) => (b / 1e6).toFixed(2);

function table(rows) {
  const widths = rows[0].map((_, j) => Math.max(...rows.map((r) => String(r[j]).length)));
  return rows.map((r, i) => {
    const line = r.map((c, j) => (j === 0 ? String(c).padEnd(widths[j]) : String(c).padStart(widths[j]))).join('  ');
    return i === 0 ? `${line}\n${widths.map((w) => '-'.repeat(w)).join('  ')}` : line;
  }).join('\n');
}

// ---------------------------------------------------------------- main ---

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const loadStart = loadavg()[0];
  const cases = CASES.filter((c) => opts.cases.includes(c.key));
  const tmp = mkdtempSync(join(tmpdir(), 'flowclip-bench-web-'));
  let server = null, context = null;
  const cleanup = async () => {
    try {
      await context?.close();
    } catch { /* already gone */ }
    await server?.stop();
    if (!process.env.FLOWCLIP_KEEP_TMP) rmSync(tmp, { recursive: true, force: true });
  };
  const onSignal = () => void cleanup().finally(() => process.exit(130));
  process.once('SIGINT', onSignal);
  process.once('SIGTERM', onSignal);
  try {
    if (existsSync(join(repoDir, 'templates'))) cpSync(join(repoDir, 'templates'), join(tmp, 'templates'), { recursive: true });
    cpSync(join(repoDir, 'scenes'), join(tmp, 'scenes'), { recursive: true });
    for (const c of cases) {
      c.scene = sceneFor(c);
      c.expected = c.cells.reduce((a, b) => a * b, 1);
      writeFileSync(join(tmp, 'scenes', `${c.scene.name}.json`), JSON.stringify(c.scene, null, 2));
    }
    server = await startServer(tmp);
    const profile = join(tmp, 'chromium-profile');
    context = await chromium.launchPersistentContext(profile, {
      executablePath: process.env.CHROMIUM ?? '/usr/bin/chromium',
      headless: true,
      viewport: { width: 960, height: 640 },
      args: [
        '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
        '--disable-background-networking', '--disable-component-update', '--disable-sync',
        '--enable-unsafe-swiftshader',
        // performance.memory unrounded, and window.gc() for the allocation-per-decode figure.
        '--enable-precise-memory-info', '--js-flags=--expose-gc',
      ],
    });
    const browserVersion = context.browser()?.version() ?? '';
    const page = context.pages()[0] ?? (await context.newPage());
    const pageErrors = [];
    page.on('pageerror', (e) => pageErrors.push(e.message));
    // The stream's messages as Chromium received them (bytes on the wire, before any decoding).
    const wsFrames = new Map(); // stream URL → largest binary message
    page.on('websocket', (ws) => {
      ws.on('framereceived', ({ payload }) => {
        const n = typeof payload === 'string' ? Buffer.byteLength(payload) : payload.length;
        wsFrames.set(ws.url(), Math.max(wsFrames.get(ws.url()) ?? 0, n));
      });
    });
    await page.goto(`${server.url}/?scene=`);
    await page.waitForFunction(() => window.flowclip?.viewport && window.flowclip.editor);
    await page.evaluate(() => {
      const { editor } = window.flowclip;
      window.__benchFirst = {};
      editor.signals.frameDecoded.add((f) => {
        if (!window.__benchFirst[f.sessionId]) {
          window.__benchFirst[f.sessionId] = { decodeMs: f.decodeMs, bytes: f.bytes, count: f.count, frame: f.frame };
        }
      });
    });

    const results = [];
    for (const c of cases) {
      process.stderr.write(`bench-browser: ${c.key} (${c.expected} particles)… `);
      const id = await page.evaluate(async (name) => {
        const s = await window.flowclip.editor.openScene(name);
        if (!s) throw new Error(`openScene(${name}) failed (see the editor's messages)`);
        return s.id;
      }, c.scene.name);
      await page.waitForFunction((sid) => window.__benchFirst[sid] && window.flowclip.viewport.renders > 0, id, { timeout: 60_000 });
      // Let the editor's own render of the frame happen before timing.
      await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
      const first = await page.evaluate((sid) => window.__benchFirst[sid], id);
      const m = await page.evaluate(measureInPage, { id, reps: opts.reps, warmup: opts.warmup, batch: DECODE_BATCH });
      const wsUrl = [...wsFrames.keys()].find((u) => u.includes(`/sessions/${encodeURIComponent(id)}/stream`));
      const r = {
        case: c.key, dimension: c.dim, particleRadius: c.r, expected: c.expected, sessionId: id,
        count: m.count, streamBytes: first.bytes, wsBytes: wsUrl ? wsFrames.get(wsUrl) : null, restBytes: m.restBytes,
        firstDecodeMs: first.decodeMs, drawnPoints: m.drawnPoints,
        decode: stat(m.times.decode), uploadDraw: stat(m.times.uploadDraw), draw: stat(m.times.draw),
        uploadDiff: stat(m.times.uploadDiff), upload: stat(m.times.upload),
        decodeNew: stat(m.times.decodeNew), uploadDrawNew: stat(m.times.uploadDrawNew), uploadNew: stat(m.times.uploadNew),
        empty: stat(m.times.empty), sync: stat(m.times.sync),
        uploadedBytes: m.uploaded.bytes, uploadedNewBytes: m.uploadedNew.bytes,
        peakHeap: m.peakHeap, allocPerDecode: m.allocPerDecode, layerCapacity: m.layerCapacity,
        canvas: m.canvas, pixelRatio: m.pixelRatio, renderer: m.renderer, webgl: m.webgl,
      };
      if (first.count !== c.expected || m.count !== c.expected) {
        throw new Error(`${c.key}: expected ${c.expected} liquid particles, the stream decoded ${first.count}, the benchmark ${m.count}`);
      }
      if (r.streamBytes !== r.restBytes) {
        process.stderr.write(`(note: stream message ${r.streamBytes} B, REST binary ${r.restBytes} B) `);
      }
      results.push(r);
      process.stderr.write(`decode ${ms(r.decode.median)} ms, upload+draw ${ms(r.uploadDraw.median)} ms\n`);
    }
    await page.evaluate(() => window.flowclip.editor.closeSession());
    if (pageErrors.length) throw new Error(`page errors: ${pageErrors.join('; ')}`);

    // ---------------------------------------------------------- report ---
    const r0 = results[0];
    const software = /swiftshader/i.test(r0?.renderer ?? '');
    const out = [];
    out.push('FlowClip editor, browser benchmark (web/scripts/bench-browser.mjs)');
    out.push(software
      ? 'SOFTWARE GL: WebGL runs on SwiftShader (CPU rasteriser, no GPU); upload and draw are CPU work on the same cores.'
      : 'WARNING: the WebGL renderer is not SwiftShader; these are not the documented software-GL figures.');
    out.push(`machine: ${cpus().length} cores (${cpus()[0]?.model.trim() ?? '?'}), shared with other work; 1-min load average ${loadStart.toFixed(2)} at the start, ${loadavg()[0].toFixed(2)} at the end`);
    out.push(`browser: headless Chromium ${browserVersion}, WebGL${r0.webgl}: ${r0.renderer}`);
    out.push(`canvas ${r0.canvas[0]}×${r0.canvas[1]} px (pixel ratio ${r0.pixelRatio}); frame 0 of each session, liquid only (the editor's default layers)`);
    out.push(`${opts.reps} repetitions after ${opts.warmup} warm-up; median / p95 ms`);
    out.push('');
    const rows = [['scene', 'particles', 'bytes/frame', 'B/particle', 'decode ms', 'upload+draw ms', 'draw ms', 'upload ms', 'uploaded MB',
      'decode* ms', 'upload* ms', 'uploaded* MB', 'first decode ms']];
    for (const r of results) {
      rows.push([
        `${r.dimension}D r=${r.particleRadius}`, r.count.toLocaleString('en-US'), r.streamBytes.toLocaleString('en-US'),
        (r.streamBytes / r.count).toFixed(2), pair(r.decode), pair(r.uploadDraw), pair(r.draw), pair(r.upload), mb(r.uploadedBytes),
        pair(r.decodeNew), pair(r.uploadNew), mb(r.uploadedNewBytes), ms(r.firstDecodeMs),
      ]);
    }
    out.push(table(rows));
    out.push('');
    out.push('bytes/frame: the stream\'s Frame message as the decoder received it' +
      (results.every((r) => r.wsBytes === r.streamBytes) ? ' (= the WebSocket message Chromium received' : ' (WebSocket message: ' + results.map((r) => r.wsBytes).join(', ')) +
      (results.every((r) => r.restBytes === r.streamBytes) ? '; = GET .../frames/0?format=binary)' : `; REST binary: ${results.map((r) => r.restBytes).join(', ')})`));
    out.push(`decode: Envelope → Frame → FrameDecoder.decode into the ParticleLayer's arrays, the frame's kinds and phases those of the previous frame ` +
      `(colours kept: one phase, no temporary particles); mean of ${DECODE_BATCH} back-to-back decodes per repetition`);
    out.push('upload+draw: viewport.render() after that decode, then a 1-pixel readPixels (the sync point); draw: the same render again, nothing to upload');
    out.push(`upload: what that decode marked, uploaded by a render with an empty draw range, minus the same empty render (means of ${DECODE_BATCH}); ` +
      'uploaded: the bytes bufferSubData/bufferData sent by one render after the decode');
    out.push('*: every colour looked up and uploaded as well (kinds or phases changed from the first particle on, or a new palette: invalidateColors() before each decode)');
    out.push(`sync: the readPixels round trip alone, in every render figure: ${results.map((r) => `${r.case} ${ms(r.sync.median)}`).join(', ')} ms (median); ` +
      `(upload+draw) − draw: ${results.map((r) => `${r.case} ${ms(r.uploadDiff.median)}`).join(', ')} ms (median, within the draw's noise)`);
    out.push('first decode: frame 0 as it arrived on the editor\'s stream, buffers grown for it (cold)');
    const peak = Math.max(...results.map((r) => r.peakHeap));
    out.push(Number.isFinite(peak)
      ? `peak JS heap (performance.memory.usedJSHeapSize, sampled after each repetition): ${mb(peak)} MB; ` +
        `particle buffers outside it: ${results.map((r) => `${r.case} ${mb(r.layerCapacity * 24)} MB`).join(', ')} (capacity × 2 attributes × 12 B)`
      : 'peak JS heap: performance.memory is not available');
    if (results.every((r) => r.allocPerDecode !== null)) {
      out.push(`JS heap allocated per decode: ${results.map((r) => `${r.case} ${Math.round(r.allocPerDecode)} B`).join(', ')}`);
    }
    console.log(out.join('\n'));
    if (opts.json) {
      writeFileSync(opts.json, JSON.stringify({ software, browser: browserVersion, cores: cpus().length, load: [loadStart, loadavg()[0]], reps: opts.reps, warmup: opts.warmup, results }, null, 2));
      console.log(`results: ${opts.json}`);
    }
  } finally {
    await cleanup();
  }
}

main().catch((e) => {
  console.error(`bench-browser: ${e instanceof Error ? e.stack ?? e.message : String(e)}`);
  process.exit(1);
});
