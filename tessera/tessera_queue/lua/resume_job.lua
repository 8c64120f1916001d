-- ARGV: id, now. Returns the state before the call.
local state = redis.call('HGET', K.job, 'state')
if not state then return '' end
if state == 'paused' then
  local back = redis.call('HGET', K.job, 'resume_state') or 'queued'
  redis.call('HSET', K.job, 'state', back)
  make_ready(ARGV[1])
  event(K.events, 'type', 'state', 'state', back)
  logline(K.log, ARGV[2], 'job resumed')
end
return state
