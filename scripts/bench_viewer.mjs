// The viewer's figures for docs/BENCH.md: drag the frame for ~150 mouse moves in headless
// Chromium against a running daemon, then let go; prints the frames per second the page showed
// and received while orbiting, and the ms from mouse-up to the full (anti-aliased) frame.
//
//   node scripts/bench_viewer.mjs MODEL PORT     (arbord serve --port PORT must serve MODEL)
import { chromium } from '../tests/e2e/node_modules/playwright-core/index.mjs';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

const model = process.argv[2] || 'castle';
const port = process.argv[3] || '8080';
const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'arbor-bench-viewer-'));
const ctx = await chromium.launchPersistentContext(dir, {
  executablePath: '/usr/bin/chromium', headless: true, viewport: { width: 1280, height: 800 },
  args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
    '--disable-component-update', '--disable-sync'],
});
try {
  const page = ctx.pages()[0];
  await page.goto(`http://127.0.0.1:${port}/?model=${model}`);
  await page.waitForSelector('canvas.image[data-frame="full"]', { state: 'attached', timeout: 120000 });
  const box = await page.locator('.frame').first().boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  let frames = 0;
  page.on('response', (r) => { if (r.url().includes('/api/render')) frames++; });
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  const t0 = Date.now();
  const shown = [];
  for (let i = 0; i < 150; i++) {
    await page.mouse.move(cx + 150 * Math.sin(i / 20), cy + 40 * Math.cos(i / 25));
    await page.waitForTimeout(16);
    if (i % 30 === 29) shown.push(await page.$eval('#stats-table tr[data-key="fps"] td', (t) => t.textContent));
  }
  const dragMs = Date.now() - t0, during = frames;
  await page.mouse.up();
  const up = Date.now();
  await page.waitForFunction(() => document.querySelector('canvas.image').dataset.frame === 'full', null,
    { timeout: 120000 });
  console.log(JSON.stringify({ model, dragMs, framesDuringDrag: during,
    framesPerSecond: +(during * 1000 / dragMs).toFixed(1), fpsShown: shown, mouseUpToFullFrameMs: Date.now() - up }));
} finally {
  await ctx.close();
  fs.rmSync(dir, { recursive: true, force: true });
}
