// save.js - Save PNG: the full frame of one pane as the daemon sent it (or as
// its strips assembled it), with the tree's boxes and the inspected ray drawn
// over it when the page shows them; in split view both panes' frames side by
// side in one PNG, each under its title, so the saved picture says which tree
// is which, and under them the difference of their work when the page shows
// it for these frames (diff.js): its image, title, key and figures.

import { treeLabel } from './panels.js';
import { canvasView, drawContent } from './overlay.js';

const TITLE_PX = 28;  // the band above each frame holding its title
const GAP_PX = 8;     // between the frames, and above the difference's band
const PAD_PX = 6;     // text from the edges of its column
const ROW_PX = 20;    // a line of the difference's key or figures
const KEY_MIN_PX = 440; // the key's column at least: its longest lines fit unsqueezed beside a small frame
const TITLE_FONT = '600 15px system-ui, sans-serif';
const TEXT_FONT = '13px system-ui, sans-serif';
const MIN_FONT_PX = 9;

/**
 * Draws text at x, y in font (a CSS font whose size is in px), in a smaller
 * size if it does not fit width, down to MIN_FONT_PX: a smaller font reads
 * better than fillText's squeezing, which is left for what even that
 * overflows. Restores the font.
 */
function fitText(ctx, text, x, y, width, font) {
    const [, before, px, after] = /^(.*?)(\d+)px(.*)$/.exec(font);
    ctx.font = font;
    for (let size = Number(px); ctx.measureText(text).width > width && size > MIN_FONT_PX;) ctx.font = `${before}${--size}px${after}`;
    ctx.fillText(text, x, y, width);
    ctx.font = font;
}

/** Text colours on background bg (0..1), the page's: light on a dark one, dark on a light one. */
const inkOn = (bg) => (bg[0] + bg[1] + bg[2] < 1.5 ? { text: '#e6e8ec', muted: '#9aa3b2' } : { text: '#1b1f24', muted: '#5a6270' });

/** The rows of the difference's key beside its image: the colour bar, its ends, then its note, then its figures. */
const KEY_HEAD_ROWS = 2;
const noteRow = (i) => KEY_HEAD_ROWS + i;
const figureRow = (fig, i) => noteRow(fig.note.length) + i;
const keyRows = (fig) => figureRow(fig, fig.rows.length);

/** A frame's title, as its pane names it: tree, mode, size, samples. */
const titleOf = (req) => `${treeLabel(req)} · ${req.mode} · ${req.width}×${req.height} · ${req.spp} spp`;

const toPNG = (canvas) => new Promise((resolve, reject) =>
    canvas.toBlob((blob) => (blob ? resolve(blob) : reject(new Error('the browser made no PNG'))), 'image/png'));

/**
 * Pane p's full frame as a PNG, with what its overlay shows drawn over it in
 * the frame's own pixels (redrawn, not the page's scaled canvas), as the
 * page would draw it at one device pixel per frame pixel.
 */
async function frameWithOverlay(p, light) {
    const { frame, boxes, ray } = p.overlayContent();
    if (!frame || (!boxes && !ray)) return p.lastFull.blob;
    const bitmap = await createImageBitmap(p.lastFull.blob);
    const canvas = document.createElement('canvas');
    canvas.width = bitmap.width;
    canvas.height = bitmap.height;
    const ctx = canvas.getContext('2d');
    ctx.drawImage(bitmap, 0, 0);
    bitmap.close();
    drawContent(ctx, canvasView(frame.cam, canvas.width, canvas.height), { boxes, ray },
        { dpr: 1, light, heat: frame.req.mode === 'heat', bounds: p.app.model().bounds });
    return toPNG(canvas);
}

/**
 * The difference of the panes' work (CostDiff's figure) in a band from y
 * down: its title across, its image under the first frame at one pixel per
 * frame pixel, and under the second frame (column x, width) its key and figures.
 */
function drawDiff(ctx, fig, y, x, width, ink) {
    ctx.fillStyle = ink.text;
    fitText(ctx, fig.title, PAD_PX, y + TITLE_PX / 2, ctx.canvas.width - 2 * PAD_PX, TITLE_FONT);
    y += TITLE_PX;
    ctx.putImageData(fig.image, 0, y);
    x += PAD_PX;
    width -= 2 * PAD_PX;
    const mid = (row) => y + (row + 0.5) * ROW_PX;
    const bar = ctx.createLinearGradient(x, 0, x + width, 0);
    fig.stops.forEach((c, i) => bar.addColorStop(i / (fig.stops.length - 1), c));
    ctx.fillStyle = bar;
    ctx.fillRect(x, mid(0) - 7, width, 14);
    ctx.font = TEXT_FONT;
    ctx.fillStyle = ink.text;
    // the ends under the bar's ends, the middle under its middle, as the page's key
    fig.ticks.forEach((t, i, all) => {
        ctx.textAlign = i === 0 ? 'left' : i === all.length - 1 ? 'right' : 'center';
        ctx.fillText(t, x + (i * width) / (all.length - 1), mid(1));
    });
    ctx.textAlign = 'left';
    ctx.fillStyle = ink.muted;
    fig.note.forEach((line, i) => fitText(ctx, line, x, mid(noteRow(i)), width, TEXT_FONT));
    fig.rows.forEach((r, i) => {
        const valueWidth = ctx.measureText(r.value).width;
        ctx.fillStyle = ink.muted;
        fitText(ctx, r.label, x, mid(figureRow(fig, i)), width - valueWidth - PAD_PX, TEXT_FONT);
        ctx.fillStyle = ink.text;
        ctx.textAlign = 'right';
        ctx.fillText(r.value, x + width, mid(figureRow(fig, i)));
        ctx.textAlign = 'left';
    });
}

/** The panes' frames (blobs) side by side on the frames' background, each under its title; the difference's figure (or null) under them. */
async function sideBySide(frames, blobs, figure) {
    const bitmaps = await Promise.all(blobs.map((b) => createImageBitmap(b)));
    const xs = bitmaps.map((b, i) => bitmaps.slice(0, i).reduce((x, p) => x + p.width + GAP_PX, 0));
    const frameH = Math.max(...bitmaps.map((b) => b.height));
    const keyW = Math.max(bitmaps[1].width, KEY_MIN_PX);
    const canvas = document.createElement('canvas');
    canvas.width = Math.max(xs[xs.length - 1] + bitmaps[bitmaps.length - 1].width, figure ? xs[1] + keyW : 0);
    canvas.height = TITLE_PX + frameH + (figure ? GAP_PX + TITLE_PX + Math.max(figure.image.height, keyRows(figure) * ROW_PX) : 0);
    const ctx = canvas.getContext('2d');
    const bg = frames[0].req.background, ink = inkOn(bg);
    ctx.fillStyle = `rgb(${bg.map((c) => Math.round(c * 255)).join(',')})`;
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    ctx.fillStyle = ink.text;
    ctx.textBaseline = 'middle';
    bitmaps.forEach((b, i) => {
        fitText(ctx, titleOf(frames[i].req), xs[i] + PAD_PX, TITLE_PX / 2, b.width - 2 * PAD_PX, TITLE_FONT);
        ctx.drawImage(b, xs[i], TITLE_PX);
    });
    if (figure) drawDiff(ctx, figure, TITLE_PX + frameH + GAP_PX, xs[1], keyW, ink);
    for (const b of bitmaps) b.close();
    return toPNG(canvas);
}

function download(blob, name) {
    const a = document.createElement('a');
    a.href = URL.createObjectURL(blob);
    a.download = name;
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}

/**
 * Downloads the panes' complete full frames (Pane.complete) as one PNG, with
 * the difference of their work under them when diff (the CostDiff) shows it
 * for these frames; light: the page's colour scheme.
 */
export async function savePanes(panes, light, diff) {
    const frames = panes.map((p) => p.lastFull);
    // taken now: while the frames decode, the figure may be measured again for another view
    const figure = diff.figureOf(frames);
    const r = frames[0].req;
    const trees = frames.map((f) => `${f.req.accel}-${f.req.builder}`).join('-vs-');
    const blobs = await Promise.all(panes.map((p) => frameWithOverlay(p, light)));
    const blob = blobs.length === 1 ? blobs[0] : await sideBySide(frames, blobs, figure);
    download(blob, `${r.model}-${trees}-${r.mode}-${r.width}x${r.height}.png`);
}
