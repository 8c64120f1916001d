-- Paused jobs leave the ready set; tiles already being rendered are still stored.
-- ARGV: id, now. Returns the state before the call.
local state = redis.call('HGET', K.job, 'state')
if not state then return '' end
if state == 'queued' or state == 'running' then
  redis.call('HSET', K.job, 'state', 'paused', 'resume_state', state)
  redis.call('ZREM', K.ready, ARGV[1])
  event(K.events, 'type', 'state', 'state', 'paused')
  logline(K.log, ARGV[2], 'job paused')
end
return state
