/*
 * report.h - the one JSON encoding of arbor's measurements, shared by the
 * CLI (`arbord stats --json`, `arbord bench --format json`) and the daemon,
 * so a script reading one reads the other.
 *
 * Each function returns a new cJSON object the caller owns and frees with
 * cJSON_Delete, or NULL when out of memory. Numbers that do not apply (NAN:
 * Embree's tree statistics, for instance) and strings that do not (NULL:
 * Embree's kernel) become JSON null. Keys:
 *   tree stats: model, triangles, accel, builder, layout ("binary" or
 *     "wide", arbor_layout), build_ms, nodes, leaves, empty_leaves,
 *     max_depth, mean_leaf_depth, mean_tris_per_leaf, refs, bytes, sah_cost:
 *     the shape of that one layout (build_ms is the whole tree's)
 *   bench row: model, scale, triangles, accel, builder, kernel, threads, build_ms,
 *     mean_leaf_depth, mean_tris_per_leaf, sah_cost, bytes_per_tri, render_ms,
 *     primary_mrays, diffuse_mrays, shadow_mrays, primary_hits,
 *     primary_tsum, and with ratios primary_ratio, diffuse_ratio,
 *     shadow_ratio (left out where there is none: Embree's own row)
 *   parse timing: model, bytes, triangles, parse_ms, mb_per_s
 */
#ifndef ARBOR_REPORT_H
#define ARBOR_REPORT_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/bench.h"

/* The statistics of one layout of a tree, which s must have
 * (arbor_tree_layout_stats). */
cJSON *arbor_report_tree_stats(const char *model, uint32_t triangles, arbor_accel_kind kind, arbor_builder builder,
                               const arbor_tree_stats *s, arbor_layout layout);

cJSON *arbor_report_bench_row(const arbor_bench_row *row, bool with_ratios);

cJSON *arbor_report_parse_timing(const char *model, const arbor_parse_timing *t);

#endif
