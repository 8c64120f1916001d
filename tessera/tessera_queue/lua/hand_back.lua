-- A worker that must stop before its task is done gives the task back (KEYS: the job's,
-- job.lua. ARGV: id, entry, worker, now, task, what). The entry is acknowledged and the
-- same task queued again as a new entry, and idle workers are woken: another worker takes
-- it now instead of after the stopping worker's heartbeat expires and a reaper claims it.
-- Not a failure: the task's attempt count and the worker's failures are unchanged.
-- Returns 1 if the task was queued again, 0 if the job had ended (nothing to give back).
local id = ARGV[1]
local state = redis.call('HGET', K.job, 'state')
ack(K.queue, ARGV[2])
if (not state) or is_final(state) then return 0 end
redis.call('XADD', K.queue, '*', 'task', ARGV[5])
redis.call('HINCRBY', K.stats, 'handed_back', 1)
logline(K.log, ARGV[4], ARGV[6] .. ' handed back by stopping worker ' .. ARGV[3])
if state ~= 'paused' then make_ready(id) end
return 1
