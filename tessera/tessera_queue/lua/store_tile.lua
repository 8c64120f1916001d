-- A rendered tile pass. KEYS: the job's (job.lua), then the worker's heartbeat key.
-- ARGV: id, field, data, seconds, final, next_task, now, worker, entry, tile, pass,
-- samples, n, then n (splat field, value) pairs.
-- final: '1' the tile is done; '0' queue next_task (its next pass); '2' a lockstep pass:
-- count it, and the tile that completes the pass queues next_task (the pass's barrier).
-- The splat pairs are the job's splat sums with this pass's splats added (read by the
-- caller under WATCH): written only with the tile, so that a pass is summed exactly once.
-- Returns 1 if this completed the job, 0 if not, -1 if the job is gone or final (dropped).
local id = ARGV[1]
local worker = KEYS[17]
-- Who stored the pass and how long it took ride on its event (the per-tile table of
-- GET /jobs/{id}/tasks folds them).
local by = {'worker', ARGV[8], 'seconds', string.format('%.3f', tonumber(ARGV[4]))}
local state = redis.call('HGET', K.job, 'state')
local ret = 0
if (not state) or is_final(state) then
  ret = -1
elseif redis.call('HSETNX', K.tiles, ARGV[2], ARGV[3]) == 1 then
  local n = tonumber(ARGV[13] or '0')
  for i = 0, n - 1 do redis.call('HSET', K.splats, ARGV[14 + 2 * i], ARGV[15 + 2 * i]) end
  redis.call('HINCRBYFLOAT', K.job, 'render_seconds', ARGV[4])
  redis.call('HINCRBY', K.job, 'passes_done', 1)
  redis.call('HINCRBY', K.stats, 'passes', 1)
  redis.call('HINCRBYFLOAT', K.stats, 'render_seconds', ARGV[4])
  if ARGV[5] == '1' then
    local done = redis.call('HINCRBY', K.job, 'tiles_done', 1)
    redis.call('HINCRBY', K.stats, 'tiles', 1)
    event(K.events, 'type', 'tile', 'tile', ARGV[10], 'pass_index', ARGV[11], 'samples', ARGV[12],
          'tiles_done', done, unpack(by))
    if done >= tonumber(redis.call('HGET', K.job, 'tiles_total')) then
      redis.call('XACK', K.queue, '@WORKER_GROUP@', ARGV[9])
      finish(id, 'done', ARGV[7], nil)
      ret = 1
    end
  elseif ARGV[5] == '2' then
    event(K.events, 'type', 'pass', 'tile', ARGV[10], 'pass_index', ARGV[11], 'samples', ARGV[12],
          unpack(by))
    local n = redis.call('HINCRBY', K.job, 'lockstep_tiles', 1)
    if n % tonumber(redis.call('HGET', K.job, 'tiles_total')) == 0 then
      redis.call('XADD', K.queue, '*', 'task', ARGV[6])
      if state ~= 'paused' then make_ready(id) end
    end
  else
    redis.call('XADD', K.queue, '*', 'task', ARGV[6])
    if state ~= 'paused' then make_ready(id) end
    event(K.events, 'type', 'pass', 'tile', ARGV[10], 'pass_index', ARGV[11], 'samples', ARGV[12],
          unpack(by))
  end
end
ack(K.queue, ARGV[9])
if ret >= 0 and redis.call('EXISTS', worker) == 1 then redis.call('HINCRBY', worker, 'tiles_done', 1) end
return ret
