-- Changes a job's priority. A job waiting in the ready set moves to the new priority's
-- band at that band's lowest served count, as any job (re)entering the set does; a paused
-- or drained job takes the new band when it comes back (make_ready reads the field). A job
-- in a final state is left as it is. ARGV: id, now, priority (checked by the caller).
-- Returns the state before the call ('' when there is no such job).
local state = redis.call('HGET', K.job, 'state')
if not state then return '' end
if not is_final(state) then
  local before = priority()
  redis.call('HSET', K.job, 'priority', ARGV[3])
  if redis.call('ZSCORE', K.ready, ARGV[1]) then
    redis.call('ZREM', K.ready, ARGV[1])
    make_ready(ARGV[1])
  end
  logline(K.log, ARGV[2], 'priority changed from ' .. before .. ' to ' .. ARGV[3])
end
return state
