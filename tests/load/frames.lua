-- wrk script for make loadtest: POST 256x256 frames to /api/render, orbiting around the
-- models named on the command line (wrk ... -s frames.lua URL -- model1 model2 ...),
-- counting answers by status over every thread. done() prints lines starting "LOAD "
-- that tests/load/run.sh reads.

local threads = {}
-- LOAD_BACKOFF_MS > 0: after a 503 the thread waits that long before its next request (a client
-- that honours Retry-After, roughly); 0 (the default) re-sends at once, as the issue's test asks.
local backoff = tonumber(os.getenv("LOAD_BACKOFF_MS") or "0") or 0

function setup(thread)
   thread:set("id", #threads)
   table.insert(threads, thread)
end

function init(args)
   models = {}
   for i = 1, #args do models[i] = args[i] end
   if #models == 0 then models = { "cornell" } end
   statuses = {}
   served = {}    -- per 200: queue+build+render+encode ms from Server-Timing
   rendered = {}  -- per 200: render ms
   n = 0
   pending_backoff = 0
end

function request()
   n = n + 1
   local m = models[(n + id) % #models + 1]
   local yaw = (n * 37 + id * 11) % 360
   local pitch = (n * 13) % 60 - 30
   local body = string.format(
      '{"model":"%s","width":256,"height":256,"camera":{"yaw":%d,"pitch":%d,"distance":1.6,"fov":45}}',
      m, yaw, pitch)
   return wrk.format("POST", "/api/render", { ["Content-Type"] = "application/json" }, body)
end

function response(status, headers, body)
   statuses[status] = (statuses[status] or 0) + 1
   if status == 200 then
      local st = headers["Server-Timing"] or headers["server-timing"]
      if st then
         local total = 0
         for name, dur in string.gmatch(st, "(%w+);dur=([%d%.]+)") do
            total = total + tonumber(dur)
            if name == "render" then rendered[#rendered + 1] = tonumber(dur) end
         end
         served[#served + 1] = total
      end
   end
   if status == 503 and backoff > 0 then pending_backoff = pending_backoff + 1 end
end

if backoff > 0 then
   function delay()
      if pending_backoff > 0 then
         pending_backoff = pending_backoff - 1
         return backoff
      end
      return 0
   end
end

local function pct(list, p)
   if #list == 0 then return 0 end
   table.sort(list)
   local i = math.max(1, math.min(#list, math.ceil(#list * p / 100)))
   return list[i]
end

function done(summary, latency, requests)
   local total = {}
   local served_all, rendered_all = {}, {}
   for _, t in ipairs(threads) do
      local s = t:get("statuses")
      for k, v in pairs(s) do total[k] = (total[k] or 0) + v end
      for _, v in ipairs(t:get("served")) do served_all[#served_all + 1] = v end
      for _, v in ipairs(t:get("rendered")) do rendered_all[#rendered_all + 1] = v end
   end
   local secs = summary.duration / 1e6
   local ok = total[200] or 0
   io.write(string.format("LOAD seconds %.2f\n", secs))
   io.write(string.format("LOAD requests %d\n", summary.requests))
   io.write(string.format("LOAD frames_per_s %.1f\n", ok / secs))
   io.write(string.format("LOAD p50_ms %.1f\n", latency:percentile(50) / 1000))
   io.write(string.format("LOAD p99_ms %.1f\n", latency:percentile(99) / 1000))
   io.write(string.format("LOAD frame_server_ms p50 %.1f p99 %.1f\n", pct(served_all, 50), pct(served_all, 99)))
   io.write(string.format("LOAD frame_render_ms p50 %.1f\n", pct(rendered_all, 50)))
   local codes = {}
   for k, _ in pairs(total) do table.insert(codes, k) end
   table.sort(codes)
   for _, k in ipairs(codes) do io.write(string.format("LOAD status %d %d\n", k, total[k])) end
   local e = summary.errors
   io.write(string.format("LOAD socket_errors %d connect %d read %d write %d timeout %d\n",
                          e.connect + e.read + e.write + e.timeout, e.connect, e.read, e.write, e.timeout))
end
