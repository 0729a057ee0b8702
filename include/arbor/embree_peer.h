/*
 * embree_peer.h - Intel Embree 3 as the benchmark peer: a scene over an
 * arbor mesh and a trace kernel for arbor_time_set, so Embree is timed by the
 * same loop, on the same rays and thread partition, as arbor's trees.
 *
 * Compiled in only with ARBOR_HAVE_EMBREE; without it arbor_embree_build
 * fails with "built without Embree; run `make bench-embree`" and the rest of
 * arbord works unchanged. The peer owns its device and scene; free it with
 * arbor_embree_free. It copies the mesh's arrays, so the mesh may go first.
 */
#ifndef ARBOR_EMBREE_PEER_H
#define ARBOR_EMBREE_PEER_H

#include <stdbool.h>
#include <stdint.h>

#include "arbor/err.h"
#include "arbor/mesh.h"
#include "arbor/raysets.h"

typedef struct arbor_embree_peer arbor_embree_peer;

/* True when this binary was built with Embree. */
bool arbor_embree_available(void);

/* A device limited to `threads` build threads (0 = Embree's default) and to
 * kernels of at most `max_isa` (NULL: the best the CPU has; else Embree's
 * max_isa: "sse2", "sse4.2", "avx", "avx2", "avx512"), and a triangle scene
 * at the default build quality; *commit_ms gets the rtcCommitScene time.
 * `robust` sets the scene's RTC_SCENE_FLAG_ROBUST: a traversal that loses
 * no box to rounding and a triangle test without the shortcuts that let
 * rays slip between neighbours. That is the Embree nearest to arbor's
 * exactness (not equal to it: Embree does not promise a watertight test,
 * nor one rule for ties), and its speed is what exactness costs Embree.
 * NULL with e filled on failure. */
arbor_embree_peer *arbor_embree_build(const arbor_mesh *m, int threads, const char *max_isa, bool robust,
                                      double *commit_ms, arbor_err *e);

/* The bytes the scene's build left allocated (its BVH, with the triangle
 * data its leaves hold), as the device's memory monitor counts them: the
 * device's total after rtcCommitScene less its total before (the geometry
 * buffers). 0 without Embree. */
uint64_t arbor_embree_bvh_bytes(const arbor_embree_peer *p);

/* "robust" when Embree reports the peer's scene in its robust mode
 * (rtcGetSceneFlags), else "default": the name of the peer's row. */
const char *arbor_embree_mode(const arbor_embree_peer *p);

/* The arbor_trace_kernel for a peer: rtcIntersect1 / rtcOccluded1 per ray. */
void arbor_embree_kernel(const void *peer, const arbor_ray *rays, size_t n, bool any_hit, arbor_tally *t);

void arbor_embree_free(arbor_embree_peer *p);

#endif
