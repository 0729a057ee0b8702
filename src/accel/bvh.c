/* bvh.c - placeholder until the bvh builders land. */
#include "accel_impl.h"

static void *bvh_build(const arbor_mesh *m, const arbor_build_opts *o, arbor_tree_stats *s, arbor_err *e)
{
    (void)m;
    (void)o;
    (void)s;
    arbor_fail(e, ARBOR_ERR_INVALID, "bvh trees are not written yet");
    return (void *)0;
}

const arbor_accel_ops arbor_bvh_ops = {bvh_build, 0, 0, 0, 0, 0};
