-- wrk script for GET /search?clip=<random id>&k=10 (bench/bench_search.py runs it) or
-- another search path (bench/bench_moments.py: /search/moments).
-- Environment: MOCAP_BENCH_MAX_ID (ids 1..max are queried), MOCAP_BENCH_DESCRIPTOR,
-- MOCAP_BENCH_PATH (default /search).
-- Every response is checked: status 200 and a JSON body with a results list of 10 hits
-- (a "bad" count is printed at the end; the benchmark fails when it is not 0).

local max_id = tonumber(os.getenv("MOCAP_BENCH_MAX_ID") or "1000000")
local descriptor = os.getenv("MOCAP_BENCH_DESCRIPTOR") or "posture"
local path = os.getenv("MOCAP_BENCH_PATH") or "/search"
local threads = {}

function setup(thread)
   thread:set("id", #threads + 1)
   table.insert(threads, thread)
end

function init(args)
   bad = 0
   checked = 0
   math.randomseed(os.time() * 1000 + id)
end

function request()
   local clip = math.random(1, max_id)
   return wrk.format("GET", path .. "?clip=" .. clip .. "&k=10&descriptor=" .. descriptor)
end

function response(status, headers, body)
   checked = checked + 1
   if status ~= 200 then
      bad = bad + 1
      return
   end
   -- 10 hits, each with an id and a distance; the query clip is echoed first.
   local _, hits = string.gsub(body, '"distance":', "")
   if hits ~= 10 or not string.find(body, '"results":%[{"id":') then
      bad = bad + 1
   end
end

function done(summary, latency, requests)
   local total_bad, total_checked = 0, 0
   for _, thread in ipairs(threads) do
      total_bad = total_bad + thread:get("bad")
      total_checked = total_checked + thread:get("checked")
   end
   io.write(string.format("RESULT requests=%d errors=%d bad=%d checked=%d rps=%.1f " ..
      "p50_ms=%.3f p90_ms=%.3f p99_ms=%.3f max_ms=%.3f\n",
      summary.requests, summary.errors.status + summary.errors.connect + summary.errors.read +
      summary.errors.write + summary.errors.timeout, total_bad, total_checked,
      summary.requests / (summary.duration / 1e6),
      latency:percentile(50) / 1000, latency:percentile(90) / 1000,
      latency:percentile(99) / 1000, latency.max / 1000))
end
