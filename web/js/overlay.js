// overlay.js - wireframes of tree boxes and a ray's visited boxes, drawn over
// a frame with the camera that frame used (camera.js, the renderer's maths).

import { BOX_EDGES, boxCorners, projectSegment, project } from './camera.js';

/** A colour per depth: a hue walk that keeps neighbouring depths apart. */
export function depthColour(depth, alpha = 1) {
    const hue = (depth * 47 + 190) % 360;
    return `hsla(${hue}, 85%, 58%, ${alpha})`;
}

/**
 * Draws boxes on a 2D context whose pixel grid is `sx` x `sy` times the
 * frame's (cam.width x cam.height). style(box, i) -> {colour, width} or null.
 * One path per style, stroked once: thousands of boxes share a few depths' colours.
 */
export function drawBoxes(ctx, cam, boxes, sx, sy, style) {
    const paths = new Map(); // "colour width" -> {s, path}
    for (let i = 0; i < boxes.length; i++) {
        const b = boxes[i];
        const s = style(b, i);
        if (!s) continue;
        const id = `${s.colour} ${s.width}`;
        let p = paths.get(id);
        if (!p) paths.set(id, p = { s, path: new Path2D() });
        const corners = boxCorners(b);
        for (const [i0, i1] of BOX_EDGES) {
            const seg = projectSegment(cam, corners[i0], corners[i1]);
            if (!seg) continue;
            p.path.moveTo(seg[0][0] * sx, seg[0][1] * sy);
            p.path.lineTo(seg[1][0] * sx, seg[1][1] * sy);
        }
    }
    for (const { s, path } of paths.values()) {
        ctx.strokeStyle = s.colour;
        ctx.lineWidth = s.width;
        ctx.stroke(path);
    }
}

/** The image-space rectangle [x0, y0, x1, y1] of a box's corners (all in front of the eye), or null. */
export function projectedRect(cam, box) {
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (const c of boxCorners(box)) {
        const p = project(cam, c);
        if (!p) return null;
        x0 = Math.min(x0, p[0]); y0 = Math.min(y0, p[1]);
        x1 = Math.max(x1, p[0]); y1 = Math.max(y1, p[1]);
    }
    return [x0, y0, x1, y1];
}

/** A cross-hair with a ring at image point p (frame pixels). */
export function drawMarker(ctx, p, sx, sy, colour) {
    const x = p[0] * sx, y = p[1] * sy, r = 7 * Math.max(1, sx * 0.6);
    ctx.lineWidth = 2;
    ctx.strokeStyle = 'rgba(0,0,0,.7)';
    ctx.beginPath();
    ctx.arc(x, y, r + 1, 0, Math.PI * 2);
    ctx.stroke();
    ctx.strokeStyle = colour;
    ctx.beginPath();
    ctx.arc(x, y, r, 0, Math.PI * 2);
    ctx.moveTo(x - 2 * r, y); ctx.lineTo(x - r, y);
    ctx.moveTo(x + r, y); ctx.lineTo(x + 2 * r, y);
    ctx.moveTo(x, y - 2 * r); ctx.lineTo(x, y - r);
    ctx.moveTo(x, y + r); ctx.lineTo(x, y + 2 * r);
    ctx.stroke();
}
