/* kd.c - placeholder until the kd builders land. */
#include "accel_impl.h"

static void *kd_build(const arbor_mesh *m, const arbor_build_opts *o, arbor_tree_stats *s, arbor_err *e)
{
    (void)m;
    (void)o;
    (void)s;
    arbor_fail(e, ARBOR_ERR_INVALID, "kd trees are not written yet");
    return (void *)0;
}

const arbor_accel_ops arbor_kd_ops = {kd_build, 0, 0, 0, 0, 0};
