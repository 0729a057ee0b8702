/*
 * inspect.c - seeing inside a tree: its boxes at a depth
 * (GET /api/models/{name}/trees/{accel}/{builder}/boxes) and one primary
 * ray's path through it (POST /api/ray).
 */
#include "http.h"

void route_boxes(http_req *r, arbor_model *m, const char *accel, const char *builder)
{
    (void)m;
    (void)accel;
    (void)builder;
    http_reply_error(r, 501, "not_implemented", "tree boxes are not served yet");
}

void route_ray(http_req *r)
{
    http_reply_error(r, 501, "not_implemented", "ray paths are not served yet");
}
