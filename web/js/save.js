// save.js - Save PNG: the full frame of one pane as the daemon sent it (or as
// its strips assembled it), with the tree's boxes and the inspected ray drawn
// over it when the page shows them; in split view both panes' frames side by
// side in one PNG, each under its title, so the saved picture says which tree
// is which.

import { treeLabel } from './panels.js';
import { canvasView, drawContent } from './overlay.js';

const TITLE_PX = 28;  // the band above each frame holding its title
const GAP_PX = 8;     // between the frames

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

/** The panes' frames (blobs) side by side on the frames' background, each under its title. */
async function sideBySide(frames, blobs) {
    const bitmaps = await Promise.all(blobs.map((b) => createImageBitmap(b)));
    const canvas = document.createElement('canvas');
    canvas.width = bitmaps.reduce((w, b) => w + b.width, 0) + GAP_PX * (bitmaps.length - 1);
    canvas.height = TITLE_PX + Math.max(...bitmaps.map((b) => b.height));
    const ctx = canvas.getContext('2d');
    const bg = frames[0].req.background;
    ctx.fillStyle = `rgb(${bg.map((c) => Math.round(c * 255)).join(',')})`;
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    // light text on a dark background, dark on a light one
    ctx.fillStyle = bg[0] + bg[1] + bg[2] < 1.5 ? '#e6e8ec' : '#1b1f24';
    ctx.font = '600 15px system-ui, sans-serif';
    ctx.textBaseline = 'middle';
    let x = 0;
    bitmaps.forEach((b, i) => {
        ctx.fillText(titleOf(frames[i].req), x + 6, TITLE_PX / 2, b.width - 12);
        ctx.drawImage(b, x, TITLE_PX);
        x += b.width + GAP_PX;
        b.close();
    });
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

/** Downloads the panes' complete full frames (Pane.complete) as one PNG; light: the page's colour scheme. */
export async function savePanes(panes, light) {
    const frames = panes.map((p) => p.lastFull);
    const r = frames[0].req;
    const trees = frames.map((f) => `${f.req.accel}-${f.req.builder}`).join('-vs-');
    const blobs = await Promise.all(panes.map((p) => frameWithOverlay(p, light)));
    const blob = blobs.length === 1 ? blobs[0] : await sideBySide(frames, blobs);
    download(blob, `${r.model}-${trees}-${r.mode}-${r.width}x${r.height}.png`);
}
