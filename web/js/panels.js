// panels.js - the stats table, the heat legend and the ray inspector's list.

/** Text made safe to put in HTML. */
export const esc = (s) => String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));

/** The decimals a number of magnitude a is shown with: `digits`, fewer from 100 up. */
const decimals = (a, digits) => (a >= 1000 ? 0 : a >= 100 ? 1 : digits);
const fixed = (v, d) => v.toLocaleString('en-US', { minimumFractionDigits: d, maximumFractionDigits: d });

export function fmt(v, digits = 2) {
    if (v === null || v === undefined || Number.isNaN(v)) return '—';
    if (typeof v !== 'number') return esc(v);
    if (Number.isInteger(v)) return v.toLocaleString('en-US');
    return fixed(v, decimals(Math.abs(v), digits));
}

/** "1 triangle", "3,152 triangles". */
export const triangles = (n) => `${(n ?? 0).toLocaleString('en-US')} triangle${n === 1 ? '' : 's'}`;

export function fmtBytes(b) {
    if (b === null || b === undefined) return '—';
    const units = ['B', 'KiB', 'MiB', 'GiB'];
    let i = 0, v = b;
    while (v >= 1024 && i < units.length - 1) { v /= 1024; i++; }
    return `${v.toFixed(i ? 1 : 0)} ${units[i]}`;
}

/** "BVH sah", "k-d median": a tree ({accel, builder}, or a request) for a person. */
export const treeLabel = (t) => `${t.accel === 'kd' ? 'k-d' : 'BVH'} ${t.builder}`;

// what the frame rows measure (their headers' tooltips)
const DAEMON_MS_WHY = "The daemon's render time (X-Render-Ms), summed over the frame's requests (its strips): each renders " +
    "on one worker, so this is the frame's cost on one core, whatever waited in the queue or rendered beside it. " +
    'Comparable between trees and panes.';
const WALL_MS_WHY = 'What the browser waited, from the first request of the frame to its last answer: the daemon renders ' +
    'strips side by side on its workers, and in split view shares them between the panes (taking their strips in turn). ' +
    "A heat frame's scale, measured at 1 spp before it, is not counted.";

/** The frame and tree statistics of every pane, one column each. */
export function renderStats(el, app) {
    const panes = app.panes;
    const cols = panes.map((p) => {
        const s = p.shown, st = p.stats && !p.stats.error ? p.stats : null;
        return {
            name: treeLabel(p.tree()),
            frameOf: s ? `${treeLabel(s.req)} · ${s.req.mode}` : '',
            stale: p.frameIsStale(),
            ms: s ? s.renderMs : null,
            mrays: s ? s.mrays : null,
            daemonMs: s ? s.daemonMs : null,
            daemonMrays: s ? s.daemonMrays : null,
            fps: app.moving ? p.fps : null,
            lastFps: p.fps,
            size: s ? `${s.req.width}×${s.req.height}${s.quick ? ' quick' : ''}` : null,
            st,
            err: p.stats && p.stats.error,
            building: !!p.building,
        };
    });
    const row = (label, f, key, why = '') =>
        `<tr${key ? ` data-key="${key}"` : ''}><th scope="row"${why ? ` title="${esc(why)}"` : ''}>${label}</th>${cols.map((c, i) => `<td data-pane="${i}">${f(c)}</td>`).join('')}</tr>`;
    // a frame of the tree or mode left behind keeps its numbers, greyed, until the new one comes
    const frame = (f) => (c) => (c.stale ? `<span class="muted">${f(c)}</span>` : f(c));
    const stat = (k, digits) => (c) => (c.st ? fmt(c.st[k], digits) : c.building ? 'building…' : '—');
    let html = '<div class="scroll"><table class="kv" id="stats-table">';
    if (cols.length > 1) html += `<thead><tr><th></th>${cols.map((c) => `<th scope="col">${esc(c.name)}</th>`).join('')}</tr></thead>`;
    html += '<tbody>';
    if (cols.some((c) => c.stale)) {
        html += row('Frame of', (c) => (c.stale ? `${esc(c.frameOf)} <span class="muted small">(previous)</span>` : esc(c.frameOf)), 'frame_of');
    }
    html += row('Render ms (daemon)', frame((c) => fmt(c.daemonMs)), 'render_ms', DAEMON_MS_WHY);
    html += row('Mrays/s (daemon)', frame((c) => fmt(c.daemonMrays)), 'mrays', DAEMON_MS_WHY);
    html += row('Wall ms (browser)', frame((c) => fmt(c.ms)), 'frame_ms', WALL_MS_WHY);
    html += row('Mrays/s (wall)', frame((c) => fmt(c.mrays)), 'mrays_wall', WALL_MS_WHY);
    html += row('FPS (orbiting)', (c) => (c.fps !== null && c.fps !== undefined ? fmt(c.fps, 1)
        : c.lastFps ? `<span class="muted">last ${fmt(c.lastFps, 1)}</span>` : '—'), 'fps');
    html += row('Frame size', frame((c) => c.size || '—'), 'size');
    html += `<tr><th colspan="${cols.length + 1}" scope="rowgroup" class="group">Tree${cols.length === 1 ? ': ' + esc(cols[0].name) : ''}</th></tr>`;
    html += row('Build ms', stat('build_ms'), 'build_ms');
    html += row('Nodes', stat('nodes'), 'nodes');
    html += row('Leaves', stat('leaves'), 'leaves');
    html += row('Empty leaves', stat('empty_leaves'), 'empty_leaves');
    html += row('Depth', stat('max_depth'), 'max_depth');
    html += row('Mean leaf depth', stat('mean_leaf_depth'), 'mean_leaf_depth');
    html += row('Mean tris per leaf', stat('mean_tris_per_leaf'), 'mean_tris_per_leaf');
    html += row('Refs / triangles', (c) => (c.st && c.st.triangles
        ? `${fmt(c.st.refs / c.st.triangles, 3)}${cols.length === 1 ? ` <span class="muted small">(${fmt(c.st.refs)} / ${fmt(c.st.triangles)})</span>` : ''}`
        : stat('refs')(c)), 'duplication');
    // a bvh's binary tree as built (API.md), though the daemon frees it once collapsed
    html += row('Bytes', (c) => (c.st ? fmtBytes(c.st.bytes) : stat('bytes')(c)), 'bytes');
    html += row('SAH cost', stat('sah_cost'), 'sah_cost');
    if (cols.some((c) => c.st && c.st.wide)) {
        // The bvh's rays traverse its binary tree collapsed into wide nodes; a k-d tree's, the tree above.
        html += `<tr><th colspan="${cols.length + 1}" scope="rowgroup" class="group">Traversed (wide) tree</th></tr>`;
        const wide = (k, f) => (c) => (!c.st ? stat(k)(c) : c.st.wide ? (f || ((v) => fmt(v)))(c.st.wide[k])
            : '<span class="muted">as above</span>');
        html += row('Nodes', wide('nodes'), 'wide_nodes');
        html += row('Leaves', wide('leaves'), 'wide_leaves');
        html += row('Depth', wide('max_depth'), 'wide_max_depth');
        html += row('Mean leaf depth', wide('mean_leaf_depth'), 'wide_mean_leaf_depth');
        html += row('Mean tris per leaf', wide('mean_tris_per_leaf'), 'wide_mean_tris_per_leaf');
        html += row('Bytes', wide('bytes', fmtBytes), 'wide_bytes');
        html += row('SAH cost (packs)', wide('sah_cost'), 'wide_sah_cost');
    }
    html += '</tbody></table></div>';
    for (const c of cols) if (c.err) html += `<p class="error small">${esc(c.err)}</p>`;
    el.innerHTML = html;
}

/**
 * The heat legend's ticks for scale s: [fraction of the bar, label]. Round
 * values (multiples of 1, 2 or 5 times a power of ten, about a fifth of s
 * apart), none so near the end that it crowds the end's label: s itself,
 * where white begins.
 */
export function heatTicks(s) {
    if (!(s > 0)) return [[0, '0'], [1, '?']];
    const raw = s / 5, pow = 10 ** Math.floor(Math.log10(raw));
    const step = [1, 2, 5, 10].map((m) => m * pow).find((v) => v >= raw * (1 - 1e-9));
    const digits = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
    // whole numbers from 10 up, thousands from 10,000: longer ones crowd the ticks of a narrow card
    const label = (v, d) => (v === 0 ? '0' : s >= 1e4 ? `${fmt(v / 1e3, 1)}k` : fmt(v, d));
    const ticks = [];
    for (let k = 0; k * step <= 0.85 * s; k++) {
        const v = Number((k * step).toFixed(digits));
        ticks.push([v / s, label(v, digits)]);
    }
    ticks.push([1, `${label(s < 10 ? s : Math.round(s), 1)}+`]);
    return ticks;
}

/** One bar of the heat legend, for the panes `panes` whose frames share scale s; title: the panes named above it. */
function legendRow(panes, s, title) {
    const ticks = heatTicks(s).map(([f, text]) => `<span style="left:${f * 100}%">${text}</span>`).join('');
    return `<div class="legend-row" data-pane="${panes.map((p) => p.index).join(' ')}" data-heat-scale="${s ?? ''}">
        ${title ? `<div class="small">${title}</div>` : ''}
        <div class="legend-bar" role="img" aria-label="Colour scale from blue at 0 through cyan, green, yellow and red to white at ${s ?? 'unknown'} node steps plus triangle tests per pixel"></div>
        <div class="legend-ticks">${ticks}</div>
      </div>`;
}

// the bottom of the scale: no ray costs 0 in a BVH, whose root every ray visits (API.md, POST /api/ray)
const BLUE = 'Blue: 0 and next to it. A ray that misses the model\'s bounds costs 0 in a k-d tree, 1 node step in a BVH (its root).';

/** Heat legend: the renderer's colour ramp with numbers from X-Heat-Scale; one bar for split panes sharing a scale. */
export function renderLegend(el, bars, app) {
    const panes = app.panes.filter((p) => p.shown && p.shown.req.mode === 'heat');
    if (app.state.mode !== 'heat' || panes.length === 0) {
        el.hidden = app.state.mode !== 'heat';
        if (app.state.mode === 'heat') bars.innerHTML = '<p class="muted small">waiting for a heat frame…</p>';
        return;
    }
    el.hidden = false;
    // the tree of the frame shown, which may be the one left behind until the new one's frame comes
    const name = (p) => `${esc(treeLabel(p.shown.req))}${p.shown.quick ? ' (quick frame)' : ''}` +
        `${p.frameIsStale() ? `: the previous tree's frame, until ${esc(treeLabel(p.tree()))}'s comes` : ''}`;
    const scale = panes[0].shown.heatScale;
    const shared = app.panes.length > 1 && panes.length === app.panes.length && panes.every((p) => p.shown.heatScale === scale);
    if (shared) {
        bars.innerHTML = legendRow(panes, scale, `Shared by both panes: ${panes.map(name).join(' and ')}`) +
            '<p class="muted small">One scale for both panes, the larger of their frames\' 99th percentiles (at 1 spp), so a colour is the same cost in each. ' +
            `White: at or above it. ${BLUE}</p>`;
        return;
    }
    bars.innerHTML = panes.map((p) => legendRow([p], p.shown.heatScale, app.panes.length > 1 || p.frameIsStale() ? name(p) : '')).join('') +
        `<p class="muted small">White: at or above the scale (the frame's 99th percentile). ${BLUE}</p>`;
}

/** "pixel (320, 240) of 640×480, BVH sah": where an inspected ray was asked for. */
const rayWhere = (r) => `pixel (${r.req.x}, ${r.req.y}) of ${r.req.width}×${r.req.height}, ${esc(treeLabel(r.req))}`;

/** "3 node steps + 14 triangle tests": a ray's counts in words. */
const rayCost = (counts) => `${fmt(counts.nodes)} node step${counts.nodes === 1 ? '' : 's'} + ` +
    `${fmt(counts.tris)} triangle test${counts.tris === 1 ? '' : 's'}`;

/**
 * The inspected ray in one line under the frame, where the click was: the
 * ray inspector's card is below the fold on a laptop and far down on a phone.
 * Its button takes the reader to the card (onDetails).
 */
export function renderRaySummary(el, app, onDetails) {
    const r = app.rayInspect;
    el.hidden = !r;
    if (!r) { el.innerHTML = ''; return; }
    const where = rayWhere(r);
    let text;
    if (r.pending) text = `<span class="muted">Tracing the ray of ${where}…</span>`;
    else if (r.error) text = `${where}: <span class="error">${esc(r.error.words || r.error.message)}</span>`;
    else {
        const d = r.data, hit = d.hit;
        text = `${where}: ${hit ? `hits triangle ${fmt(hit.triangle)} at t ${fmt(hit.t, 4)}` : 'misses the model'}` +
            ` · ${rayCost(d.counts || {})}`;
    }
    el.innerHTML = `<span class="ray-summary-text">${text}</span>` +
        (r.pending ? '' : ' <button type="button" class="link" id="ray-details">Details in the ray inspector</button>');
    const details = el.querySelector('#ray-details');
    if (details) details.addEventListener('click', onDetails);
}

/** The inspected ray: hit, counts, heat at the pixel, and every step in visiting order. */
export function renderRay(el, app) {
    const r = app.rayInspect;
    if (!r) {
        el.innerHTML = '<p class="muted">Click a pixel of the frame to trace its primary ray through the tree.</p>';
        return;
    }
    const where = rayWhere(r);
    if (r.pending) {
        el.innerHTML = `<p class="muted">Tracing the ray through ${where}…</p>`;
        return;
    }
    if (r.error) {
        const st = r.error.status;
        const missing = st === 404 || st === 501
            ? `<p class="muted small">This daemon does not trace single rays yet (<code>POST /api/ray</code> answered ${st}); the heat frame still shows each pixel's cost.</p>` : '';
        el.innerHTML = `<p class="small">${where}</p><p class="error" role="alert">${esc(r.error.words || r.error.message)}</p>${missing}`;
        return;
    }
    const d = r.data, steps = d.steps || [], counts = d.counts || {};
    const leaves = steps.filter((s) => s.leaf).length;
    const tested = steps.reduce((a, s) => a + (s.tris || 0), 0);
    // every component to one precision, that of the largest: (0.292, 0.000, 0.956), where fmt prints whole ones bare
    const v3 = (v) => {
        if (!v) return '—';
        const d = decimals(Math.max(...v.map(Math.abs)), 3);
        return `(${v.map((x) => fixed(x, d)).join(', ')})`;
    };
    let html = `<p class="small">${where}</p>`;
    html += `<table class="kv" id="ray-counts" data-nodes="${counts.nodes ?? ''}" data-tris="${counts.tris ?? ''}"><tbody>`;
    html += `<tr><th scope="row">Node steps</th><td class="ray-nodes">${fmt(counts.nodes)}</td></tr>`;
    html += `<tr><th scope="row">Triangle tests</th><td class="ray-tris">${fmt(counts.tris)}</td></tr>`;
    html += `<tr><th scope="row">Cost (steps + tests)</th><td>${fmt((counts.nodes ?? 0) + (counts.tris ?? 0))}</td></tr>`;
    html += `<tr><th scope="row">Boxes visited / leaves</th><td>${fmt(steps.length)} / ${fmt(leaves)}</td></tr>`;
    if (d.hit) {
        html += `<tr><th scope="row">Hit t</th><td>${fmt(d.hit.t, 4)}</td></tr>`;
        html += `<tr><th scope="row">Triangle</th><td>${fmt(d.hit.triangle)}</td></tr>`;
        html += `<tr><th scope="row">Point</th><td>${v3(d.hit.point)}</td></tr>`;
        html += `<tr><th scope="row">Normal</th><td>${v3(d.hit.normal)}</td></tr>`;
    } else {
        html += '<tr><th scope="row">Hit</th><td class="text">none: the ray leaves the model</td></tr>';
    }
    if (r.heat) {
        const h = r.heat;
        const same = h.mean_nodes === counts.nodes && h.mean_tris === counts.tris;
        html += `<tr id="ray-heat" data-nodes="${h.mean_nodes ?? ''}" data-tris="${h.mean_tris ?? ''}"><th scope="row">Heat mode at this pixel</th><td>${fmt(h.mean_nodes)} + ${fmt(h.mean_tris)}${same ? ' ✓ same' : ' ≠ differs'}</td></tr>`;
    } else if (r.heatError) {
        html += `<tr><th scope="row">Heat mode at this pixel</th><td class="text error small">${esc(r.heatError)}</td></tr>`;
    }
    html += '</tbody></table>';
    if (tested !== counts.tris && steps.length) {
        html += `<p class="muted small">Triangles listed in the steps: ${fmt(tested)}.</p>`;
    }
    html += `<h3>Steps in visiting order</h3><div class="steps scroll"><table class="kv" id="ray-steps"><thead><tr><th>#</th><th>depth</th><th>node</th><th>triangles</th></tr></thead><tbody>`;
    const show = steps.slice(0, 500);
    show.forEach((s, i) => {
        html += `<tr class="${s.leaf ? 'leaf' : 'inner'}"><td>${i + 1}</td><td>${fmt(s.depth)}</td><td>${s.leaf ? 'leaf' : 'inner'}</td><td>${s.leaf || s.tris ? fmt(s.tris) : ''}</td></tr>`;
    });
    html += '</tbody></table></div>';
    if (steps.length > show.length) html += `<p class="muted small">First ${show.length} of ${steps.length} steps listed.</p>`;
    html += '<p class="muted small">Drawn over the frame in the colours of the key under it.</p>';
    html += '<div class="buttons"><button type="button" id="ray-clear">Clear</button></div>';
    el.innerHTML = html;
    el.querySelector('#ray-clear').addEventListener('click', () => app.dismissRay());
}
