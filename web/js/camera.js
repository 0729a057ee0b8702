// camera.js - the renderer's camera maths (src/render/camera.c) in JS, so the
// page can project tree boxes over a frame and map pixels to rays exactly as
// arbord does. Vectors are [x, y, z] arrays.
//
// Orbit convention (arbor_camera_orbit): yaw and pitch in degrees, distance
// in units of the bounds' diagonal; dir = (cos p sin y, sin p, cos p cos y);
// eye = target + dir * distance * diagonal; look-at with world up (0, 1, 0).
// yaw = 0, pitch = 0 looks along -z. Pitch is clamped to +-89 degrees.
// Image: x right, y down, pixel (x, y) covers [x, x+1) x [y, y+1).

export const DEG2RAD = Math.PI / 180;
export const PITCH_LIMIT = 89;
export const WORLD_UP = [0, 1, 0];

export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const length = (a) => Math.sqrt(dot(a, a));
export const normalize = (a) => {
    const l = length(a);
    return l > 0 ? scale(a, 1 / l) : [0, 0, 0];
};

/** Centre and diagonal length of MODEL.bounds ({min, max}). */
export function boundsFrame(bounds) {
    const lo = bounds.min, hi = bounds.max;
    return { centre: scale(add(lo, hi), 0.5), diagonal: length(sub(hi, lo)) };
}

/** The orbit values that reproduce PROTOCOL.md's view (arbor_camera_orbit_protocol). */
export function protocolOrbit() {
    const d = normalize([0.5, 0.35, 1.0]);
    return {
        yaw: Math.atan2(d[0], d[2]) / DEG2RAD,
        pitch: Math.asin(d[1]) / DEG2RAD,
        distance: 1.307,
        fov: 45,
    };
}

/**
 * The view a newly chosen model opens in: the same direction and field of
 * view, about the model's centre. The distance stays unless it would put the
 * eye within half a diagonal of the centre (the sphere round the bounds), as
 * a pivot or a zoom into the old model leaves it; then it is the protocol's.
 */
export function viewOfNewModel(view) {
    return { ...view, target: null, distance: view.distance >= 0.5 ? view.distance : protocolOrbit().distance };
}

export const clampPitch = (p) => Math.max(-PITCH_LIMIT, Math.min(PITCH_LIMIT, p));

/** Unit vector from the target to the eye for yaw/pitch in degrees. */
export function orbitDirection(yawDeg, pitchDeg) {
    const yaw = yawDeg * DEG2RAD, pitch = clampPitch(pitchDeg) * DEG2RAD;
    return [Math.cos(pitch) * Math.sin(yaw), Math.sin(pitch), Math.cos(pitch) * Math.cos(yaw)];
}

/**
 * The view's eye and target in world space. view = {yaw, pitch, distance, fov,
 * target}, target null for the bounds' centre (the daemon's orbit camera) or a
 * point (a pan moved it; the page then sends a look-at camera).
 */
export function viewEyeTarget(bounds, view) {
    const { centre, diagonal } = boundsFrame(bounds);
    const target = view.target ? view.target.slice() : centre;
    const eye = add(target, scale(orbitDirection(view.yaw, view.pitch), view.distance * diagonal));
    return { eye, target };
}

/**
 * The view turned about its eye to yaw and pitch (degrees), the fly camera's
 * look: the eye stays where it is and the target swings round it at the
 * view's distance, so that orbiting afterwards turns about a point ahead.
 */
export function lookFromEye(bounds, view, yaw, pitch) {
    return fromEye(bounds, view, yaw, clampPitch(pitch), view.distance);
}

/**
 * The view with its target slid along the line of sight to `distance`
 * diagonals from the eye: the same picture, orbited about another point.
 */
export function reachTo(bounds, view, distance) {
    return fromEye(bounds, view, view.yaw, view.pitch, distance);
}

/** The view whose eye is view's and whose target lies distance diagonals from it towards yaw, pitch. */
function fromEye(bounds, view, yaw, pitch, distance) {
    const { eye } = viewEyeTarget(bounds, view);
    const reach = distance * boundsFrame(bounds).diagonal;
    return { ...view, yaw, pitch, distance, target: sub(eye, scale(orbitDirection(yaw, pitch), reach)) };
}

/**
 * The view moved, eye and target together, by the world vector
 * offset(basis, diagonal) returns: basis is the view's (forward, right and
 * up of the image), diagonal the bounds'.
 */
export function shiftView(bounds, view, offset) {
    const { eye, target } = viewEyeTarget(bounds, view);
    const basis = lookAt(eye, target, WORLD_UP, view.fov, 1, 1);
    return { ...view, target: add(target, offset(basis, boundsFrame(bounds).diagonal)) };
}

/**
 * The view moved by forward along the line of sight, right along the
 * image's right and up along the world's up, each in units of the bounds'
 * diagonal (so a step means the same on every model).
 */
export function moveView(bounds, view, forward, right, up) {
    return shiftView(bounds, view, (basis, diagonal) =>
        scale(add(add(scale(basis.forward, forward), scale(basis.right, right)), scale(WORLD_UP, up)), diagonal));
}

/**
 * The camera field of a render request for this view: the orbit form while
 * the target is the centre (exactly the daemon's orbit camera), else look-at.
 */
export function requestCamera(bounds, view) {
    const fov = view.fov;
    if (!view.target) {
        return { yaw: round6(view.yaw), pitch: round6(clampPitch(view.pitch)), distance: round6(view.distance), fov };
    }
    const { eye, target } = viewEyeTarget(bounds, view);
    return { eye: eye.map(round6), target: target.map(round6), up: WORLD_UP.slice(), fov };
}

function round6(v) {
    return Math.round(v * 1e6) / 1e6;
}

/** arbor_camera_look_at: an orthonormal basis plus the image size. */
export function lookAt(eye, target, worldUp, fovDeg, width, height) {
    const forward = normalize(sub(target, eye));
    const right = normalize(cross(forward, worldUp));
    const up = cross(right, forward);
    return { eye, forward, right, up, tanHalfFov: Math.tan(0.5 * fovDeg * DEG2RAD), width, height };
}

/**
 * The camera a request's `camera` field describes (orbit or look-at form),
 * as the renderer builds it for a model with these bounds.
 */
export function cameraFromRequest(bounds, cam, width, height) {
    if (cam.eye) return lookAt(cam.eye, cam.target, cam.up || WORLD_UP, cam.fov, width, height);
    const { centre, diagonal } = boundsFrame(bounds);
    const eye = add(centre, scale(orbitDirection(cam.yaw, cam.pitch), cam.distance * diagonal));
    return lookAt(eye, centre, WORLD_UP, cam.fov, width, height);
}

/** arbor_camera_ray's direction through image point (px, py). */
export function rayDirection(c, px, py) {
    const aspect = c.width / c.height;
    const sx = (2 * px / c.width - 1) * c.tanHalfFov * aspect;
    const sy = (1 - 2 * py / c.height) * c.tanHalfFov;
    return normalize(add(c.forward, add(scale(c.right, sx), scale(c.up, sy))));
}

/** World point -> camera space [x along right, y along up, z along forward]. */
export function toCamera(c, p) {
    const v = sub(p, c.eye);
    return [dot(v, c.right), dot(v, c.up), dot(v, c.forward)];
}

/** Camera-space point with z > 0 -> image point [px, py] (inverse of rayDirection). */
export function cameraToImage(c, q) {
    const aspect = c.width / c.height;
    const sx = q[0] / q[2], sy = q[1] / q[2];
    return [(sx / (c.tanHalfFov * aspect) + 1) * 0.5 * c.width, (1 - sy / c.tanHalfFov) * 0.5 * c.height];
}

/** World point -> image point, or null behind the eye. */
export function project(c, p) {
    const q = toCamera(c, p);
    return q[2] > 1e-9 ? cameraToImage(c, q) : null;
}

// the near plane of projectSegment, relative to the segment's depths (overlay.js tells when no edge of a box reaches it)
export const NEAR = 1e-6;

/** A world segment clipped to the front of the eye, as two image points, or null. */
export function projectSegment(c, a, b) {
    let qa = toCamera(c, a), qb = toCamera(c, b);
    const near = NEAR * (1 + Math.abs(qa[2]) + Math.abs(qb[2]));
    if (qa[2] < near && qb[2] < near) return null;
    if (qa[2] < near || qb[2] < near) {
        const t = (near - qa[2]) / (qb[2] - qa[2]);
        const m = [qa[0] + t * (qb[0] - qa[0]), qa[1] + t * (qb[1] - qa[1]), near];
        if (qa[2] < near) qa = m; else qb = m;
    }
    return [cameraToImage(c, qa), cameraToImage(c, qb)];
}

/** The eight corners of a box {min, max}. */
export function boxCorners(box) {
    const lo = box.min, hi = box.max, out = [];
    for (let i = 0; i < 8; i++) out.push([i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]]);
    return out;
}

/** Corner index pairs of a box's twelve edges. */
export const BOX_EDGES = [
    [0, 1], [2, 3], [4, 5], [6, 7],
    [0, 2], [1, 3], [4, 6], [5, 7],
    [0, 4], [1, 5], [2, 6], [3, 7],
];
