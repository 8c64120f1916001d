-- ARGV: id, now, error. Fails the job unless final. Returns the state before the call.
local state = redis.call('HGET', K.job, 'state')
if not state then return '' end
if not is_final(state) then finish(ARGV[1], 'failed', ARGV[2], ARGV[3]) end
return state
