-- One failed attempt at a tile pass. KEYS: the job's (job.lua), then the worker's
-- heartbeat key and the dead-letter stream. ARGV: id, field, tile, entry, worker, error,
-- now, max_attempts, blocklist_after, task.
-- Returns 'final', 'retry', 'blocklisted' or 'poisoned'.
local id = ARGV[1]
local worker, dead = KEYS[17], KEYS[18]
local state = redis.call('HGET', K.job, 'state')
ack(K.queue, ARGV[4])
if (not state) or is_final(state) then return 'final' end
local n = redis.call('HINCRBY', K.failures, 'tile:' .. ARGV[2], 1)
local wf = redis.call('HINCRBY', K.failures, 'worker:' .. ARGV[5], 1)
redis.call('HINCRBY', K.stats, 'failures', 1)
if redis.call('EXISTS', worker) == 1 then redis.call('HINCRBY', worker, 'failures', 1) end
event(K.events, 'type', 'failure', 'tile', ARGV[3], 'message', ARGV[6], 'worker', ARGV[5],
      'task', ARGV[2], 'attempt', n)
logline(K.log, ARGV[7], 'tile ' .. ARGV[3] .. ' attempt ' .. n .. ' failed on worker ' .. ARGV[5]
        .. ': ' .. ARGV[6])
local result = 'retry'
if wf >= tonumber(ARGV[9]) and redis.call('SADD', K.blocklist, ARGV[5]) == 1 then
  logline(K.log, ARGV[7], 'worker ' .. ARGV[5] .. ' is blocklisted for this job after ' .. wf
          .. ' failures')
  result = 'blocklisted'
end
if n >= tonumber(ARGV[8]) then
  redis.call('XADD', dead, 'MAXLEN', '~', @DEAD_LETTER_MAXLEN@, '*',
             'job', id, 'tile', ARGV[3], 'attempts', n, 'error', ARGV[6], 'task', ARGV[10])
  redis.call('HINCRBY', K.stats, 'poisoned', 1)
  finish(id, 'failed', ARGV[7], 'tile ' .. ARGV[3] .. ' failed ' .. n .. ' times; last error: '
         .. ARGV[6])
  return 'poisoned'
end
redis.call('XADD', K.queue, '*', 'task', ARGV[10])
if state ~= 'paused' then make_ready(id) end
return result
