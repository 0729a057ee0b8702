/*
 * kd_pack.c - the k-d tree's leaves laid out for the SIMD triangle test
 * (tri_pack.h). Every leaf of more than one triangle gets its list in
 * tri_index at a multiple of KD_PACK_LANES, and the packs from
 * packs[first / KD_PACK_LANES] on hold its triangles' corners,
 * KD_PACK_LANES to a pack, in the list's order; lanes past the leaf's count
 * are NaN, which never hit, and their tri_index entries UINT32_MAX, never
 * read. Done once the tree is built, so the builder and its threads know
 * nothing of it; a leaf of one triangle keeps it in the node and is tested
 * by the scalar test.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "kd_internal.h"

/* Index entries a leaf of n triangles takes: n rounded up to whole packs. */
static size_t kd_pack_room(uint32_t n) { return ((size_t)n + KD_PACK_LANES - 1) / KD_PACK_LANES * KD_PACK_LANES; }

/* Fills p with the corners of triangles tris[0..n) (n <= KD_PACK_LANES). */
static void kd_pack_fill(kd_pack *p, const arbor_mesh *m, const uint32_t *tris, uint32_t n)
{
    for (uint32_t l = 0; l < KD_PACK_LANES; l++) {
        arbor_vec3 c[3] = {{NAN, NAN, NAN}, {NAN, NAN, NAN}, {NAN, NAN, NAN}};
        if (l < n)
            arbor_mesh_tri(m, tris[l], &c[0], &c[1], &c[2]);
        for (int a = 0; a < 3; a++) {
            p->v[a][0][l] = c[a].x;
            p->v[a][1][l] = c[a].y;
            p->v[a][2][l] = c[a].z;
        }
    }
}

bool kd_pack_leaves(kd_tree *tree)
{
    size_t nindex = 0;
    for (size_t i = 0; i < tree->nnodes; i++) {
        kd_node n = tree->nodes[i];
        if (kd_node_kind(n) == KD_LEAF && kd_node_high(n) > 1)
            nindex += kd_pack_room(kd_node_high(n));
    }
    if (nindex > UINT32_MAX)
        return false;
    uint32_t *index = NULL;
    kd_pack *packs = NULL;
    if (nindex > 0) {
        index = malloc(nindex * sizeof *index);
        packs = aligned_alloc(_Alignof(kd_pack), nindex / KD_PACK_LANES * sizeof *packs);
        if (index == NULL || packs == NULL) {
            free(index);
            free(packs);
            return false;
        }
    }
    size_t at = 0;
    for (size_t i = 0; i < tree->nnodes; i++) {
        kd_node *n = &tree->nodes[i];
        uint32_t count = kd_node_high(*n);
        if (kd_node_kind(*n) != KD_LEAF || count <= 1)
            continue;
        const uint32_t *tris = tree->tri_index + n->first;
        memcpy(index + at, tris, count * sizeof *index);
        memset(index + at + count, 0xff, (kd_pack_room(count) - count) * sizeof *index);
        for (uint32_t j = 0; j < count; j += KD_PACK_LANES) {
            uint32_t lanes = count - j < KD_PACK_LANES ? count - j : KD_PACK_LANES;
            kd_pack_fill(&packs[(at + j) / KD_PACK_LANES], tree->mesh, tris + j, lanes);
        }
        n->first = (uint32_t)at;
        at += kd_pack_room(count);
    }
    free(tree->tri_index);
    tree->tri_index = index;
    tree->nindex = nindex;
    tree->packs = packs;
    tree->npacks = nindex / KD_PACK_LANES;
    return true;
}
