"""Every failure of the issue: status and {"error":{"code","message"}}; one test per case."""
import gzip
import json
import os
import re
import socket

from harness import (add_test, check, eq, expect_error, expect_ok, limits_daemon, main_daemon, multipart, test)

CAM = {"eye": [0, 1, 4], "target": [0, 1, 0], "up": [0, 1, 0], "fov": 45}
NUM = re.compile(r"\d")


def R(**kw):
    b = {"model": "cornell", "width": 16, "height": 12}
    b.update(kw)
    return b


def cam(**kw):
    c = dict(CAM)
    c.update(kw)
    return c


# (name, daemon, method, path, body, status, code, message must name)
# body: dict -> JSON; str/bytes -> sent as is (raw JSON text such as 1e999)
CASES = [
    # malformed and typed wrong
    ("malformed_json", "main", "POST", "/api/render", '{"model": "cornell", ', 400, "bad_request", None),
    ("json_not_object", "main", "POST", "/api/render", '[1, 2, 3]', 400, "bad_request", None),
    ("empty_body", "main", "POST", "/api/render", '', 400, "bad_request", None),
    ("json_trailing_garbage", "main", "POST", "/api/render", '{"model":"cornell"} x', 400, "bad_request", None),
    ("nan_literal", "main", "POST", "/api/render",
     '{"model":"cornell","camera":{"eye":[NaN,0,4],"target":[0,0,0],"up":[0,1,0],"fov":45}}',
     400, "bad_request", None),
    ("json_nul_in_string", "main", "POST", "/api/render", b'{"model":"cornell\x00junk","width":16,"height":12}',
     400, "bad_request", "NUL"),
    ("key_twice_in_camera", "main", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12,"camera":{"yaw":1,"yaw":2,"pitch":0,"distance":3,"fov":45}}',
     400, "bad_request", "yaw"),
    ("key_twice_in_region", "main", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12,"region":{"x":0,"x":1,"y":0,"w":4,"h":4}}', 400, "bad_request",
     re.compile(r"\bx\b")),
    ("key_twice_in_trees_body", "main", "POST", "/api/models/cornell/trees",
     '{"accel":"kd","accel":"bvh","builder":"median"}', 400, "bad_request", "accel"),
    ("key_twice_in_bench_body", "main", "POST", "/api/bench",
     '{"model":"cornell","model":"sphere","accel":["bvh"],"builder":["median"],"runs":1}', 400, "bad_request",
     "model"),
    ("object_of_65_keys", "main", "POST", "/api/render",
     json.dumps(dict(R(), camera={"k%d" % i: i for i in range(65)})), 400, "bad_request", "64"),
    ("unknown_field", "main", "POST", "/api/render", R(colour=1), 400, "bad_request", "colour"),
    ("unknown_camera_field", "main", "POST", "/api/render", R(camera=cam(zoom=2)), 400, "bad_request", "zoom"),
    ("unknown_region_field", "main", "POST", "/api/render", R(region={"x": 0, "y": 0, "w": 1, "h": 1, "z": 1}),
     400, "bad_request", re.compile(r"\bz\b")),
    ("boxes_query_key_twice", "main", "GET", "/api/models/cornell/trees/bvh/sah/boxes?depth=1&depth=2", None,
     400, "bad_request", ["depth", "twice"]),
    ("stats_query_key_twice", "main", "GET", "/api/stats?model=cornell&model=sphere", None,
     400, "bad_request", ["model", "twice"]),
    # a key without '=' would read as absent (?replace as false): named, not ignored
    ("stats_query_key_bare", "main", "GET", "/api/stats?model=cornell&accel", None,
     400, "bad_request", "accel needs a value"),
    ("boxes_query_key_bare", "main", "GET", "/api/models/cornell/trees/bvh/sah/boxes?depth", None,
     400, "bad_request", "depth needs a value"),
    ("upload_query_key_bare", "main", "PUT", "/api/models/bare?replace", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     400, "bad_request", "replace needs a value"),
    ("unknown_query_param", "main", "GET", "/api/render?model=cornell&width=16&height=12&colour=red", None,
     400, "bad_request", "colour"),
    # a query parameter a route does not take is a 400 naming it, never ignored (the refused PUT
    # leaves no file, _make checks)
    ("query_on_healthz", "main", "GET", "/healthz?verbose=1", None, 400, "bad_request", ["verbose", "none"]),
    ("query_on_readyz", "main", "GET", "/readyz?x=1", None, 400, "bad_request", "'x'"),
    ("query_on_metrics", "main", "GET", "/metrics?name=arbor", None, 400, "bad_request", "name"),
    ("query_on_models", "main", "GET", "/api/models?sort=size", None, 400, "bad_request", "sort"),
    ("query_on_model", "main", "GET", "/api/models/cornell?fields=name", None, 400, "bad_request", "fields"),
    ("query_on_upload_misspelt", "main", "PUT", "/api/models/misspelt?replce=1", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     400, "bad_request", ["replce", "replace"]),
    ("query_on_delete", "main", "DELETE", "/api/models/cornell?force=1", None, 400, "bad_request", "force"),
    ("query_on_trees", "main", "POST", "/api/models/cornell/trees?wait=false", {"accel": "bvh", "builder": "sah"},
     400, "bad_request", "wait"),
    ("query_on_render_post", "main", "POST", "/api/render?width=8", R(), 400, "bad_request", ["width", "POST"]),
    ("query_on_ray", "main", "POST", "/api/ray?accel=kd", {"model": "cornell"}, 400, "bad_request", "accel"),
    ("query_on_bench", "main", "POST", "/api/bench?runs=1", {"model": "cornell"}, 400, "bad_request", "runs"),
    ("query_on_job", "main", "GET", "/api/jobs/1?verbose=1", None, 400, "bad_request", "verbose"),
    ("width_string", "main", "POST", "/api/render", R(width="16"), 400, "bad_request", "width"),
    ("width_fraction", "main", "POST", "/api/render", R(width=16.5), 400, "bad_request", "width"),
    ("model_number", "main", "POST", "/api/render", {"model": 5}, 400, "bad_request", "model"),
    ("spp_bool", "main", "POST", "/api/render", R(spp=True), 400, "bad_request", "spp"),
    ("camera_array", "main", "POST", "/api/render", R(camera=[0, 1, 4]), 400, "bad_request", "camera"),
    ("background_string", "main", "POST", "/api/render", R(background="red"), 400, "bad_request", "background"),
    ("eye_two_values", "main", "POST", "/api/render", R(camera=cam(eye=[0, 1])), 400, "bad_request", "eye"),
    ("query_width_not_number", "main", "GET", "/api/render?model=cornell&width=abc&height=12", None,
     400, "bad_request", "width"),
    ("missing_model", "main", "POST", "/api/render", {"width": 16, "height": 12}, 400, "bad_request", "model"),
    # ranges
    ("width_0", "main", "POST", "/api/render", R(width=0), 400, "bad_request", "width"),
    ("width_8193", "main", "POST", "/api/render", R(width=8193, height=1), 400, "bad_request", "width"),
    ("height_0", "main", "POST", "/api/render", R(height=0), 400, "bad_request", "height"),
    ("height_8193", "main", "POST", "/api/render", R(width=1, height=8193), 400, "bad_request", "height"),
    ("width_negative", "main", "POST", "/api/render", R(width=-5), 400, "bad_request", "width"),
    ("spp_0", "main", "POST", "/api/render", R(spp=0), 400, "bad_request", "spp"),
    ("spp_65", "main", "POST", "/api/render", R(spp=65), 400, "bad_request", "spp"),
    ("max_bounces_17", "main", "POST", "/api/render", R(max_bounces=17), 400, "bad_request", "max_bounces"),
    ("ao_samples_0", "main", "POST", "/api/render", R(mode="ao", ao_samples=0), 400, "bad_request", "ao_samples"),
    ("ao_samples_257", "main", "POST", "/api/render", R(mode="ao", ao_samples=257), 400, "bad_request", "ao_samples"),
    ("seed_negative", "main", "POST", "/api/render", R(seed=-1), 400, "bad_request", ["seed", "9007199254740991"]),
    ("background_over_1", "main", "POST", "/api/render", R(background=[2, 0, 0]), 400, "bad_request", "background"),
    ("heat_scale_0", "main", "POST", "/api/render", R(mode="heat", heat_scale=0), 400, "bad_request", "heat_scale"),
    ("format_gif", "main", "POST", "/api/render", R(format="gif"), 400, "bad_request", "format"),
    ("format_costs_shaded", "main", "POST", "/api/render", R(format="costs"), 400, "bad_request",
     "format costs needs mode heat, not shaded"),
    ("stream_empty", "main", "POST", "/api/render", R(stream=""), 400, "bad_request", "stream"),
    ("stream_65_chars", "main", "POST", "/api/render", R(stream="s" * 65), 400, "bad_request", "stream"),
    ("fov_0", "main", "POST", "/api/render", R(camera=cam(fov=0)), 400, "bad_request", "fov"),
    ("fov_180", "main", "POST", "/api/render", R(camera=cam(fov=180)), 400, "bad_request", "fov"),
    ("orbit_fov_0", "main", "POST", "/api/render", R(camera={"yaw": 0, "pitch": 0, "distance": 1, "fov": 0}),
     400, "bad_request", "fov"),
    ("query_fov_180", "main", "GET", "/api/render?model=cornell&width=16&height=12&yaw=0&pitch=0&distance=1&fov=180",
     None, 400, "bad_request", "fov"),
    ("pitch_90", "main", "POST", "/api/render", R(camera={"yaw": 0, "pitch": 90, "distance": 1, "fov": 45}),
     400, "bad_request", "pitch"),
    ("distance_0", "main", "POST", "/api/render", R(camera={"yaw": 0, "pitch": 0, "distance": 0, "fov": 45}),
     400, "bad_request", "distance"),
    ("eye_inf_1e999", "main", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12,"camera":{"eye":[1e999,0,4],"target":[0,0,0],"up":[0,1,0],"fov":45}}',
     400, "bad_request", None),
    ("target_minus_inf", "main", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12,"camera":{"eye":[0,0,4],"target":[0,-1e999,0],"up":[0,1,0],"fov":45}}',
     400, "bad_request", None),
    ("yaw_inf", "main", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12,"camera":{"yaw":1e999,"pitch":0,"distance":1,"fov":45}}',
     400, "bad_request", None),
    ("fov_inf", "main", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12,"camera":{"eye":[0,0,4],"target":[0,0,0],"up":[0,1,0],"fov":1e999}}',
     400, "bad_request", None),
    ("query_eye_inf", "main", "GET", "/api/render?model=cornell&width=16&height=12&eye=0,inf,4&target=0,0,0&up=0,1,0&fov=45",
     None, 400, "bad_request", None),
    ("query_eye_nan", "main", "GET", "/api/render?model=cornell&width=16&height=12&eye=nan,0,4&target=0,0,0&up=0,1,0&fov=45",
     None, 400, "bad_request", None),
    ("eye_equals_target", "main", "POST", "/api/render", R(camera=cam(eye=[1, 2, 3], target=[1, 2, 3])),
     400, "bad_request", None),
    ("region_past_right", "main", "POST", "/api/render", R(region={"x": 10, "y": 0, "w": 7, "h": 1}),
     400, "bad_request", "region"),
    ("region_past_bottom", "main", "POST", "/api/render", R(region={"x": 0, "y": 11, "w": 1, "h": 2}),
     400, "bad_request", "region"),
    ("region_negative_x", "main", "POST", "/api/render", R(region={"x": -1, "y": 0, "w": 2, "h": 2}),
     400, "bad_request", "region"),
    ("region_empty", "main", "POST", "/api/render", R(region={"x": 0, "y": 0, "w": 0, "h": 2}),
     400, "bad_request", "region"),
    ("query_region_outside", "main", "GET", "/api/render?model=cornell&width=16&height=12&region=8,8,9,4", None,
     400, "bad_request", "region"),
    # unknown names
    ("unknown_model", "main", "POST", "/api/render", R(model="no-such-model"), 404, "not_found", "no-such-model"),
    ("unknown_model_get", "main", "GET", "/api/models/no-such-model", None, 404, "not_found", None),
    ("unknown_accel", "main", "POST", "/api/render", R(accel="octree"), 400, "bad_request", "octree"),
    ("unknown_builder", "main", "POST", "/api/render", R(builder="fast"), 400, "bad_request", "fast"),
    ("unknown_mode", "main", "POST", "/api/render", R(mode="wireframe"), 400, "bad_request", "wireframe"),
    ("trees_unknown_accel", "main", "POST", "/api/models/cornell/trees", {"accel": "octree", "builder": "sah"},
     400, "bad_request", "octree"),
    ("trees_unknown_model", "main", "POST", "/api/models/no-such-model/trees", {"accel": "bvh", "builder": "sah"},
     404, "not_found", None),
    ("stats_unknown_builder", "main", "GET", "/api/stats?model=cornell&accel=bvh&builder=fast", None,
     400, "bad_request", "fast"),
    ("boxes_unknown_model", "main", "GET", "/api/models/no-such-model/trees/bvh/sah/boxes?depth=1", None,
     404, "not_found", None),
    ("boxes_bad_depth", "main", "GET", "/api/models/cornell/trees/bvh/sah/boxes?depth=abc", None,
     400, "bad_request", "depth"),
    ("boxes_unknown_param", "main", "GET", "/api/models/cornell/trees/bvh/sah/boxes?depth=1&bogus=1", None,
     400, "bad_request", "bogus"),
    ("boxes_bad_flag", "main", "GET", "/api/models/cornell/trees/bvh/sah/boxes?depth=1&leaves=2", None,
     400, "bad_request", "leaves"),
    ("boxes_path_longer", "main", "GET", "/api/models/cornell/trees/bvh/sah/boxes/extra", None,
     404, "not_found", None),
    ("trees_path_longer", "main", "POST", "/api/models/cornell/boxes/trees", {"accel": "bvh", "builder": "sah"},
     404, "not_found", None),
    ("trees_path_deeper", "main", "POST", "/api/models/cornell/a/b/trees", {"accel": "bvh", "builder": "sah"},
     404, "not_found", None),
    ("boxes_path_shorter", "main", "GET", "/api/models/cornell/trees/bvh/sah", None, 404, "not_found", None),
    ("stats_unknown_param", "main", "GET", "/api/stats?foo=1", None, 400, "bad_request", "foo"),
    ("query_hex_number", "main", "GET", "/api/render?model=cornell&width=0x10&height=12", None,
     400, "bad_request", "0x10"),
    ("query_inf", "main", "GET", "/api/render?model=cornell&width=16&height=12&yaw=inf", None,
     400, "bad_request", "yaw"),
    # a path's bytes come back in the message: still UTF-8 (expect_error decodes strictly)
    ("not_utf8_in_message", "main", "GET", "/api/models/caf%e9", None, 404, "not_found", "caf?"),
    ("unknown_job", "main", "GET", "/api/jobs/987654", None, 404, "not_found", None),
    ("ray_pixel_outside", "main", "POST", "/api/ray", {"model": "cornell", "width": 16, "height": 12, "x": 16, "y": 0},
     400, "bad_request", None),
    ("bench_runs_0", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["sah"], "runs": 0},
     400, "bad_request", "runs"),
    ("bench_runs_21", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["sah"], "runs": 21},
     400, "bad_request", "runs"),
    ("bench_unknown_model", "main", "POST", "/api/bench", {"model": "no-such-model", "accel": ["bvh"], "builder": ["sah"],
                                                          "runs": 1}, 404, "not_found", None),
    ("bench_runs_huge", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["sah"],
                                                      "runs": 1e300}, 400, "bad_request", "runs"),
    # a name one longer than any model's is refused, not cut to the 64 characters of another model's
    ("bench_model_name_too_long", "main", "POST", "/api/bench", {"model": "c" * 64 + "x", "accel": ["bvh"],
                                                                "builder": ["sah"], "runs": 1}, 400, "bad_request",
     "is no model name"),
    ("bench_unknown_builder", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["fast"],
                                                            "runs": 1}, 400, "bad_request", "fast"),
    ("bench_embree_unknown_mode", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["sah"],
                                                                "runs": 1, "embree": "Robust"}, 400, "bad_request",
     'embree must be true, false or "robust"'),
    ("bench_embree_null", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["sah"],
                                                        "runs": 1, "embree": None}, 400, "bad_request", "embree"),
    ("bench_embree_number", "main", "POST", "/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["sah"],
                                                          "runs": 1, "embree": 1}, 400, "bad_request", "embree"),
    # paths and methods
    ("unknown_path", "main", "GET", "/api/no-such-thing", None, 404, "not_found", None),
    ("unknown_static_file", "main", "GET", "/no-such-file.html", None, 404, "not_found", None),
    ("model_name_invalid", "main", "PUT", "/api/models/bad%20name", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     400, "bad_request", None),
    ("model_name_too_long", "main", "PUT", "/api/models/" + "n" * 65, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     400, "bad_request", None),
    # the message names the name, not the path after it
    ("model_name_too_long_in_trees", "main", "POST", "/api/models/" + "n" * 65 + "/trees",
     {"accel": "bvh", "builder": "sah"}, 404, "not_found", "no model named '" + "n" * 65 + "'"),
    ("model_name_leading_dot", "main", "PUT", "/api/models/.hidden", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
     400, "bad_request", "'.'"),
    ("delete_unknown_model", "main", "DELETE", "/api/models/no-such-model", None, 404, "not_found", None),
    # limits (the limits daemon: --max-pixels 100000 --max-body 4K --max-upload 64K)
    ("pixels_over_max", "limits", "POST", "/api/render", R(width=400, height=300), 400, "bad_request", None),
    ("pixels_spp_over_max", "limits", "POST", "/api/render", R(width=200, height=200, spp=3), 400, "bad_request", None),
    ("pixels_ao_samples_over_max", "limits", "POST", "/api/render", R(width=100, height=100, mode="ao", ao_samples=16),
     400, "bad_request", None),
    ("query_pixels_over_max", "limits", "GET", "/api/render?model=cornell&width=400&height=300", None,
     400, "bad_request", None),
    ("body_over_max_body", "limits", "POST", "/api/render",
     '{"model":"cornell","width":16,"height":12}' + " " * 5000, 413, "too_large", None),
    ("ray_body_over_max_body", "limits", "POST", "/api/ray",
     '{"model":"cornell","width":16,"height":12,"x":1,"y":1}' + " " * 5000, 413, "too_large", None),
    ("bench_body_over_max_body", "limits", "POST", "/api/bench",
     '{"model":"cornell","accel":["bvh"],"builder":["sah"],"runs":1}' + " " * 5000, 413, "too_large", None),
    ("upload_over_max_upload", "limits", "PUT", "/api/models/big",
     "v 0 0 0\nv 1 0 0\nv 0 1 0\n" + "f 1 2 3\n" * 10000, 413, "too_large", None),
    ("upload_not_a_model", "limits", "PUT", "/api/models/png",
     b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\x00\x00\x00\x01\x08\x02\x00\x00\x00" + bytes(range(256)),
     415, "unsupported_media_type", None),
    ("upload_bad_obj_line_3", "limits", "PUT", "/api/models/badobj", "v 0 0 0\nv 1 0 0\nf 1 2 7\n",
     400, "bad_request", re.compile(r"(:3\b|line 3\b)")),
    ("upload_bad_number_line_4", "limits", "PUT", "/api/models/badnum", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 x 0\nf 1 2 3\n",
     400, "bad_request", re.compile(r"(:4\b|line 4\b)")),
    ("upload_empty", "limits", "PUT", "/api/models/empty", "", 400, "bad_request", None),
    ("upload_bad_gzip", "limits", "PUT", "/api/models/badgz", b"\x1f\x8b\x08\x00" + b"\x00" * 6 + b"garbage-not-deflate" * 10,
     400, "bad_request", None),
    ("upload_no_triangles", "limits", "PUT", "/api/models/notris", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", 400, "bad_request", None),
    ("upload_bad_ply", "limits", "PUT", "/api/models/badply",
     "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
     "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n",
     400, "bad_request", None),
]


def _make(name, which, method, path, body, status, code, contains):
    def fn():
        d = main_daemon() if which == "main" else limits_daemon()
        kw = {}
        if isinstance(body, dict):
            kw["js"] = body
        elif body is not None:
            kw["body"] = body if isinstance(body, bytes) else body.encode()
            if method == "POST":
                kw["headers"] = {"Content-Type": "application/json"}
        r = d.req(method, path, **kw)
        expect_error(r, status, code, contains)
        check(d.alive(), "daemon died after %s %s" % (method, path))
        if method == "PUT" and path.startswith("/api/models/"):
            name = path.split("/")[3].split("?")[0]
            left = [f for f in os.listdir(d.models_dir) if f.startswith(name + ".")]
            check(not left, "the refused upload left %s in the models folder" % left)
            if re.fullmatch(r"[A-Za-z0-9._-]{1,64}", name):
                expect_error(d.get("/api/models/" + name), 404, "not_found")
    return fn


with open(__file__, encoding="utf-8") as _f:
    _src = _f.read().splitlines()


def _line_of(text):
    for i, ln in enumerate(_src):
        if text in ln:
            return i + 1
    return 1


for case in CASES:
    add_test("test_error_" + case[0], _make(*case), __file__, _line_of('("%s",' % case[0]))


# methods: 405 with Allow

METHOD_CASES = [
    ("DELETE", "/api/render", {"GET", "POST"}),
    ("PUT", "/healthz", {"GET"}),
    ("POST", "/api/stats", {"GET"}),
    ("PATCH", "/api/models/cornell", {"GET", "PUT", "POST", "DELETE"}),
    ("GET", "/api/models/cornell/trees", {"POST"}),
    ("PUT", "/api/bench", {"POST"}),
    ("POST", "/metrics", {"GET"}),
]


def _make_method(method, path, allow):
    def fn():
        d = main_daemon()
        r = d.req(method, path, body=b"{}" if method in ("PUT", "POST", "PATCH") else None)
        expect_error(r, 405, "method_not_allowed")
        a = r.header("Allow")
        check(a is not None, "%s %s: 405 without Allow" % (method, path))
        got = {x.strip().upper() for x in a.split(",") if x.strip()}
        check(allow <= got and method not in got, "%s %s: Allow %r, expected %s" % (method, path, a, sorted(allow)))
    return fn


for m, p, a in METHOD_CASES:
    add_test("test_error_405_%s_%s" % (m.lower(), p.strip("/").replace("/", "_")), _make_method(m, p, a),
             __file__, _line_of('("%s", "%s"' % (m, p)))


@test
def test_error_put_of_a_multipart_body():
    """curl -X PUT -F file=@m.obj sends multipart/form-data: a 415 pointing to POST, not a model saved with
    the boundaries and part headers in its text."""
    d = limits_daemon()
    body, ctype = multipart([("model", "mp.obj", "model/obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")])
    expect_error(d.req("PUT", "/api/models/mp", body=body, headers={"Content-Type": ctype}), 415,
                 "unsupported_media_type", "POST")
    eq([f for f in os.listdir(d.models_dir) if f.startswith("mp.")], [], "files the refused PUT left")
    expect_error(d.req("GET", "/api/models/mp"), 404, "not_found")


@test
def test_error_upload_in_a_coding_not_read():
    """A body in a Content-Encoding the daemon does not decode (br, deflate; gzip but for a PUT of a model) is a
    415 naming it (RFC 9110 15.5.16), not bytes parsed as a model: these happen to be plain OBJ, and were saved
    as one."""
    d = limits_daemon()
    for coding in ("br", "deflate"):
        r = d.req("PUT", "/api/models/coded", body=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
                  headers={"Content-Encoding": coding})
        expect_error(r, 415, "unsupported_media_type", coding)
        expect_error(d.req("GET", "/api/models/coded"), 404, "not_found")
    # a multipart POST and a JSON body are never decoded: gzip there is a 415 too, not a confusing 400
    body, ctype = multipart([("model", "gz.obj", "model/obj", gzip.compress(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"))])
    r = d.req("POST", "/api/models/coded", body=body, headers={"Content-Type": ctype, "Content-Encoding": "gzip"})
    expect_error(r, 415, "unsupported_media_type", "gzip")
    r = d.req("POST", "/api/render", body=gzip.compress(b'{"model":"cornell","width":16,"height":12}'),
              headers={"Content-Type": "application/json", "Content-Encoding": "gzip"})
    expect_error(r, 415, "unsupported_media_type", "gzip")


@test
def test_error_post_of_a_form_body():
    """curl --data-binary @m.obj (no -H) sends application/x-www-form-urlencoded: a 415 naming the type a
    POST takes, not a 400 about a malformed multipart body."""
    d = limits_daemon()
    r = d.req("POST", "/api/models/form", body=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
              headers={"Content-Type": "application/x-www-form-urlencoded"})
    expect_error(r, 415, "unsupported_media_type", "multipart/form-data")
    expect_error(d.req("GET", "/api/models/form"), 404, "not_found")


@test
def test_error_pixels_at_max_is_accepted():
    """The limit is inclusive: width*height*spp == --max-pixels renders."""
    d = limits_daemon()
    expect_ok(d.post("/api/render", R(width=250, height=200, spp=2)))   # 100000
    expect_ok(d.post("/api/render", R(width=50, height=50, mode="ao", ao_samples=40)))  # 100000


@test
def test_error_body_at_max_body_is_accepted():
    d = limits_daemon()
    body = '{"model":"cornell","width":16,"height":12}'
    body += " " * (4096 - len(body))
    eq(len(body), 4096, "body length")
    expect_ok(d.req("POST", "/api/render", body=body.encode(), headers={"Content-Type": "application/json"}))


@test
def test_error_413_on_chunked_body():
    """A body over --max-body sent chunked (no Content-Length) is refused too."""
    d = limits_daemon()
    import http.client
    conn = http.client.HTTPConnection(d.host, d.port, timeout=30)
    try:
        chunk = b" " * 1000
        conn.putrequest("POST", "/api/render")
        conn.putheader("Content-Type", "application/json")
        conn.putheader("Transfer-Encoding", "chunked")
        conn.endheaders()
        payload = [b'{"model":"cornell",'] + [chunk] * 6 + [b'"width":16}']
        try:
            for p in payload:
                conn.send(b"%x\r\n%s\r\n" % (len(p), p))
            conn.send(b"0\r\n\r\n")
        except OSError:
            pass  # the daemon may answer and close before the rest is sent
        r = conn.getresponse()
        body = r.read()
        eq(r.status, 413, "chunked body of 6 KB over --max-body 4K: status (body %r)" % body[:200])
        eq(json.loads(body)["error"]["code"], "too_large", "error code")
    finally:
        conn.close()


@test
def test_error_endless_chunked_body_is_cut_off():
    """A chunked body that never ends is not read for ever: some megabytes past the limit the daemon
    closes the connection, and goes on serving."""
    d = limits_daemon()
    s = socket.create_connection((d.host, d.port), timeout=30)
    sent, err = 0, None
    try:
        s.sendall(b"POST /api/render HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n")
        chunk = b"10000\r\n" + b" " * 0x10000 + b"\r\n"
        while sent < (256 << 20):
            s.sendall(chunk)
            sent += 0x10000
    except OSError as e:
        err = e
    finally:
        s.close()
    check(err is not None, "the daemon read all of a %d MB body over a 4 KB limit" % (sent >> 20))
    check(sent < (64 << 20), "the daemon read %d MB before closing" % (sent >> 20))
    expect_ok(d.get("/healthz"))
