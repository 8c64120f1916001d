-- A scene task's product. KEYS: the job's (job.lua). ARGV: id, pass, the product's SHA-256
-- (hex), the product, entry, now, the worker, its seconds, then the iteration's tile tasks. The first delivery to
-- arrive stores it (content-addressed) and queues the tiles; any other (a reclaimed or
-- redelivered scene task, which computed the same bytes) is only acknowledged. Returns 1
-- if this stored it, 0 if it was already stored, -1 if the job is gone or final.
local id = ARGV[1]
local state = redis.call('HGET', K.job, 'state')
local ret = -1
if state and not is_final(state) then
  if redis.call('HSETNX', K.job, 'product:' .. ARGV[2], ARGV[3]) == 1 then
    redis.call('HSETNX', K.products, ARGV[3], ARGV[4])
    redis.call('HINCRBY', K.job, 'scene_passes_stored', 1)
    for i = 9, #ARGV do redis.call('XADD', K.queue, '*', 'task', ARGV[i]) end
    if state ~= 'paused' then make_ready(id) end
    event(K.events, 'type', 'scene_pass', 'pass_index', ARGV[2], 'worker', ARGV[7],
          'seconds', string.format('%.3f', tonumber(ARGV[8])))
    logline(K.log, ARGV[6], 'scene pass ' .. ARGV[2] .. ' stored (' .. string.len(ARGV[4]) ..
            ' bytes); its tile passes queued')
    ret = 1
  else
    ret = 0
  end
end
ack(K.queue, ARGV[5])
return ret
