// lib.mjs - helpers of the browser tests: start arbord serve on a free port
// with the repo's web/ and models, drive Debian's chromium with
// playwright-core (never a downloaded browser), read pixels of the page's
// canvases, and keep screenshots in build/e2e/ for a person to look at.

import { spawn } from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const here = path.dirname(fileURLToPath(import.meta.url));
export const repo = path.resolve(here, '..', '..');
export const shotDir = path.join(repo, 'build', 'e2e');
const arbord = path.resolve(repo, process.env.ARBORD || 'build/arbord');
const sharedModels = path.resolve(repo, process.env.ARBOR_SHARED_MODELS || '../shared/models');

export function freePort() {
    return new Promise((resolve, reject) => {
        const srv = net.createServer();
        srv.on('error', reject);
        srv.listen(0, '127.0.0.1', () => {
            const { port } = srv.address();
            srv.close(() => resolve(port));
        });
    });
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/**
 * Starts `arbord serve` and waits for /readyz. Uploads go to the first
 * --models folder, a fresh temporary one, so the repo's models/ never changes.
 * shared: names of ../shared/models files to serve too (linked from a
 * temporary folder, never copied into the repo).
 */
export async function startDaemon({ shared = [], extraArgs = [] } = {}) {
    if (!fs.existsSync(arbord)) throw new Error(`no daemon binary at ${arbord} (set ARBORD)`);
    const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'arbor-e2e-'));
    const uploads = path.join(tmp, 'uploads');
    fs.mkdirSync(uploads);
    const args = ['serve', '--bind', '127.0.0.1', '--models', uploads, '--models', path.join(repo, 'models')];
    if (shared.length) {
        const dir = path.join(tmp, 'shared');
        fs.mkdirSync(dir);
        for (const f of shared) {
            const src = path.join(sharedModels, f);
            if (!fs.existsSync(src)) throw new Error(`shared model ${src} is missing (set ARBOR_SHARED_MODELS)`);
            fs.symlinkSync(src, path.join(dir, f));
        }
        args.push('--models', dir);
    }
    const port = await freePort();
    args.push('--port', String(port), '--web', path.join(repo, 'web'), ...extraArgs);
    const proc = spawn(arbord, args, { stdio: ['ignore', 'pipe', 'pipe'] });
    let log = '';
    proc.stdout.on('data', (d) => { log += d; });
    proc.stderr.on('data', (d) => { log += d; });
    let exited = null;
    proc.on('exit', (code, signal) => { exited = { code, signal }; });
    const base = `http://127.0.0.1:${port}`;
    const deadline = Date.now() + 60000;
    for (;;) {
        if (exited) throw new Error(`arbord serve exited (${JSON.stringify(exited)}) before it was ready:\n${log.slice(-2000)}`);
        try {
            const r = await fetch(`${base}/readyz`);
            if (r.status === 200) break;
        } catch { /* not listening yet */ }
        if (Date.now() > deadline) {
            proc.kill('SIGKILL');
            throw new Error(`arbord serve was not ready within 60 s:\n${log.slice(-2000)}`);
        }
        await sleep(100);
    }
    return {
        base, port, proc, uploads,
        log: () => log,
        async stop() {
            if (!exited) {
                proc.kill('SIGTERM');
                for (let i = 0; i < 50 && !exited; i++) await sleep(100);
                if (!exited) proc.kill('SIGKILL');
            }
            fs.rmSync(tmp, { recursive: true, force: true });
            // A sanitizer build (make test SAN=...) reports on stderr: the test fails.
            const report = log.search(/(ERROR|WARNING): \w+Sanitizer|runtime error:/);
            if (report >= 0) throw new Error(`arbord sanitizer report:\n${log.slice(Math.max(0, report - 200), report + 3000)}`);
        },
    };
}

/**
 * Launches Debian's chromium headless with a fresh profile. Collects console
 * errors and page errors in `errors`. dpr: device pixels per CSS pixel.
 */
export async function openBrowser({ viewport = { width: 1280, height: 800 }, mobile = false, colorScheme = 'dark', dpr = 1 } = {}) {
    const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'arbor-chromium-'));
    const context = await chromium.launchPersistentContext(profile, {
        executablePath: '/usr/bin/chromium',
        headless: true,
        args: ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
            '--disable-component-update', '--disable-sync'],
        viewport,
        deviceScaleFactor: dpr,
        isMobile: mobile,
        hasTouch: mobile,
        colorScheme,
        acceptDownloads: true,
    });
    const page = context.pages()[0] || await context.newPage();
    const errors = [];
    page.on('console', (m) => { if (m.type() === 'error') errors.push(`console: ${m.text()}`); });
    page.on('pageerror', (e) => errors.push(`pageerror: ${e.message}`));
    return {
        context, page, errors,
        async close() {
            await context.close().catch(() => {});
            fs.rmSync(profile, { recursive: true, force: true });
        },
    };
}

/** Runs fn(daemon, browser) with a fresh daemon and browser, always cleaning up. */
export async function withViewer(opts, fn) {
    const daemon = await startDaemon(opts.daemon || {});
    let browser;
    try {
        browser = await openBrowser(opts.browser || {});
        return await fn(daemon, browser);
    } catch (e) {
        const tail = daemon.log().slice(-1500);
        if (tail) e.message += `\n--- arbord log (tail) ---\n${tail}`;
        throw e;
    } finally {
        if (browser) await browser.close();
        await daemon.stop();
    }
}

export async function screenshot(page, name) {
    fs.mkdirSync(shotDir, { recursive: true });
    await page.screenshot({ path: path.join(shotDir, `${name}.png`), fullPage: true });
}

/**
 * Clicks Save PNG once it is offered; returns the PNG's bytes (kept in
 * build/e2e/<name>.png) and the file name the page gave it.
 */
export async function savePNG(page, name) {
    await page.waitForSelector('#save-png:not([disabled])', { timeout: 60000 });
    const [download] = await Promise.all([page.waitForEvent('download'), page.click('#save-png')]);
    const file = fs.readFileSync(await download.path());
    fs.mkdirSync(shotDir, { recursive: true });
    fs.writeFileSync(path.join(shotDir, `${name}.png`), file);
    return { file, filename: download.suggestedFilename() };
}

/** Width and height of a PNG's IHDR. */
export const pngSize = (buf) => [buf.readUInt32BE(16), buf.readUInt32BE(20)];

/** Every request body to /api/render (frames; costs apart) and /api/ray the page sends, in order. */
export function recordRequests(page) {
    const renders = [], rays = [], responses = [], costs = [];
    let inflight = 0, maxInflight = 0;
    page.on('request', (r) => {
        const u = new URL(r.url());
        if (u.pathname === '/api/render' && r.method() === 'POST') {
            const body = JSON.parse(r.postData() || '{}');
            if (body.format === 'costs') costs.push(body);
            else if (body.format !== 'json') {
                renders.push(body);
                inflight++;
                maxInflight = Math.max(maxInflight, inflight);
                r._arborFrame = true;
            }
        }
        if (u.pathname === '/api/ray') rays.push(JSON.parse(r.postData() || '{}'));
    });
    const done = (r) => { if (r._arborFrame) { r._arborFrame = false; inflight--; } };
    page.on('requestfinished', done);
    page.on('requestfailed', done);
    page.on('response', (res) => {
        const u = new URL(res.url());
        if (u.pathname === '/api/render') {
            responses.push({ status: res.status(), headers: res.headers(), body: res.request().postData() });
        }
    });
    return { renders, rays, responses, costs, maxInflight: () => maxInflight };
}

/** Waits until pane `index` shows a full (not quick) frame; returns its request camera. */
export async function waitFullFrame(page, index = 0, timeout = 30000) {
    const sel = `canvas.image[data-pane="${index}"][data-frame="full"]`;
    await page.waitForSelector(sel, { state: 'attached', timeout });
    return page.$eval(sel, (c) => JSON.parse(c.dataset.camera));
}

/** Waits until pane `index` shows a full frame, at rest, of another camera than `cam` (a request camera); returns it. */
export async function waitFrameMovedFrom(page, cam, index = 0, timeout = 30000) {
    await page.waitForFunction(([c0, i]) => {
        const c = document.querySelector(`canvas.image[data-pane="${i}"]`);
        return c && c.dataset.frame === 'full' && !window.arbor.moving && c.dataset.camera !== c0;
    }, [JSON.stringify(cam), index], { timeout });
    return waitFullFrame(page, index);
}

/** Resolves after the page has painted twice: whatever the last change scheduled is drawn. */
export const afterPaint = (page) => page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));

/**
 * Pixels of pane `index`'s frame canvas: size, a hash, the number of distinct
 * colours, and the bounding box of pixels that differ from bg (or from the
 * top-left pixel) by more than tol in any channel.
 */
export function framePixels(page, index = 0, bg = null, tol = 12) {
    return page.evaluate(({ index, bg, tol }) => {
        const c = document.querySelector(`canvas.image[data-pane="${index}"]`);
        const ctx = c.getContext('2d');
        const { width: w, height: h } = c;
        const d = ctx.getImageData(0, 0, w, h).data;
        const ref = bg || [d[0], d[1], d[2]];
        let x0 = w, y0 = h, x1 = -1, y1 = -1, fg = 0, hash = 2166136261;
        const colours = new Set();
        for (let y = 0; y < h; y++) {
            for (let x = 0; x < w; x++) {
                const i = (y * w + x) * 4;
                hash = Math.imul(hash ^ d[i] ^ (d[i + 1] << 8) ^ (d[i + 2] << 16), 16777619) >>> 0;
                if (colours.size < 5000) colours.add((d[i] << 16) | (d[i + 1] << 8) | d[i + 2]);
                if (Math.abs(d[i] - ref[0]) > tol || Math.abs(d[i + 1] - ref[1]) > tol || Math.abs(d[i + 2] - ref[2]) > tol) {
                    fg++;
                    if (x < x0) x0 = x;
                    if (x > x1) x1 = x;
                    if (y < y0) y0 = y;
                    if (y > y1) y1 = y;
                }
            }
        }
        return { w, h, hash, colours: colours.size, fg, bbox: x1 < 0 ? null : [x0, y0, x1 + 1, y1 + 1], ref };
    }, { index, bg, tol });
}

/** Bounding box of the drawn (non-transparent) pixels of pane `index`'s overlay, in frame pixels. */
export function overlayBox(page, index = 0, frameW, frameH) {
    return page.evaluate(({ index, frameW, frameH }) => {
        const o = document.querySelectorAll('canvas.overlay')[index];
        const { width: w, height: h } = o;
        const d = o.getContext('2d').getImageData(0, 0, w, h).data;
        let x0 = w, y0 = h, x1 = -1, y1 = -1, n = 0;
        for (let y = 0; y < h; y++) {
            for (let x = 0; x < w; x++) {
                if (d[(y * w + x) * 4 + 3] > 40) {
                    n++;
                    if (x < x0) x0 = x;
                    if (x > x1) x1 = x;
                    if (y < y0) y0 = y;
                    if (y > y1) y1 = y;
                }
            }
        }
        if (x1 < 0) return null;
        const sx = frameW / w, sy = frameH / h;
        return { n, bbox: [x0 * sx, y0 * sy, (x1 + 1) * sx, (y1 + 1) * sy] };
    }, { index, frameW, frameH });
}

export async function postJSON(base, p, body) {
    const r = await fetch(base + p, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
    const text = await r.text();
    let json = null;
    try { json = JSON.parse(text); } catch { /* not JSON */ }
    return { status: r.status, json, text };
}
