-- A lockstep pass barrier's outcome. KEYS: the job's (job.lua). ARGV: id, pass, finished
-- ('1'/'0'), now, entry, accumulator bytes, then the next pass's tasks. Applied once per
-- pass (redeliveries of the barrier are dropped). Returns 1 if this completed the job, 0
-- if it queued the next pass, -1 if dropped.
local id = ARGV[1]
local state = redis.call('HGET', K.job, 'state')
local ret = -1
if state and not is_final(state)
   and tonumber(redis.call('HGET', K.job, 'decided_pass') or '-1') < tonumber(ARGV[2]) then
  redis.call('HSET', K.job, 'decided_pass', ARGV[2])
  redis.call('SET', K.passes, ARGV[6])
  -- Every tile of this pass is stored, so nothing reads its scene-pass product again (the
  -- next pass's is not computed yet: this barrier queues its scene task). The bytes go,
  -- the product:<pass> field stays; a late duplicate of one of its tiles finds its tile
  -- stored, or the pass decided (worker.py), and is dropped.
  local digest = redis.call('HGET', K.job, 'product:' .. ARGV[2])
  if digest then redis.call('HDEL', K.products, digest) end
  if ARGV[3] == '1' then
    local total = redis.call('HGET', K.job, 'tiles_total')
    redis.call('HSET', K.job, 'tiles_done', total)
    redis.call('HINCRBY', K.stats, 'tiles', tonumber(total))
    event(K.events, 'type', 'tile', 'tile', -1, 'pass_index', ARGV[2], 'tiles_done', total)
    redis.call('XACK', K.queue, '@WORKER_GROUP@', ARGV[5])
    finish(id, 'done', ARGV[4], nil)
    ret = 1
  else
    for i = 7, #ARGV do redis.call('XADD', K.queue, '*', 'task', ARGV[i]) end
    if state ~= 'paused' then make_ready(id) end
    logline(K.log, ARGV[4], 'pass ' .. ARGV[2] .. ' of every tile done; next pass queued')
    ret = 0
  end
end
ack(K.queue, ARGV[5])
return ret
