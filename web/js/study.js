// study.js - the course study's figures (../shared/STUDY.md, tables 1 to 4)
// for the models arbor has too, galleon and castle. The study measured seven
// trees (no BVH-SAH) on its own machine and ray tracer; the compare view shows
// them beside ours, labelled, never mixed into our figures, and only for a
// model of the study's size (an upload named castle may be another mesh).

export const STUDY_SOURCE = 'Gurlaskie, "Acceleration Structures for Ray Tracing: k-d Trees and BVHs" (STUDY.md), tables 1–4';

// Column order of the study's tables; bvh sah is absent there.
export const STUDY_TREES = [
    ['bvh', 'spatial'], ['bvh', 'median'], ['bvh', 'mean'],
    ['kd', 'spatial'], ['kd', 'median'], ['kd', 'mean'], ['kd', 'sah'],
];

// metric -> model -> seven values in STUDY_TREES order.
export const STUDY_TABLES = {
    // Table 1: the tree construction speed (ms)
    build_ms: {
        table: 1,
        galleon: [5, 79, 10, 22, 206, 28, 36060],
        castle: [17, 269, 27, 61, 643, 85, 251319],
    },
    // Table 2: the mean leaf depth
    mean_leaf_depth: {
        table: 2,
        galleon: [11, 11, 11, 15, 15, 15, 16],
        castle: [13, 13, 13, 18, 16, 16, 18],
    },
    // Table 3: the mean triangles per leaf
    mean_tris_per_leaf: {
        table: 3,
        galleon: [5, 2, 1, 19, 12, 12, 14],
        castle: [9, 2, 1, 23, 10, 10, 16],
    },
    // Table 4: the rendering performance (ms per frame)
    render_ms: {
        table: 4,
        galleon: [9906, 2829, 1395, 13179, 4588, 3816, 2911],
        castle: [16137, 2461, 1021, 9964, 3525, 2232, 2224],
    },
};

// The study's triangle counts for its models (figure 1).
export const STUDY_TRIANGLES = { galleon: 4698, castle: 13114 };

/** The number of the study's table of a metric, or 0 (none of its tables has it). */
export const studyTable = (metric) => STUDY_TABLES[metric]?.table || 0;

/** The study's figure for one tree, or null (no such model, metric or tree). */
export function studyFigure(model, metric, accel, builder) {
    const t = STUDY_TABLES[metric];
    if (!t || !t[model]) return null;
    const i = STUDY_TREES.findIndex(([a, b]) => a === accel && b === builder);
    return i < 0 ? null : t[model][i];
}

/** Whether the study measured this model: its name, and its triangle count where known. */
export const hasStudy = (model, triangles) => Object.prototype.hasOwnProperty.call(STUDY_TRIANGLES, model) &&
    (triangles === undefined || triangles === STUDY_TRIANGLES[model]);
