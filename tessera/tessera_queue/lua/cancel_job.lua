-- ARGV: id, now. Returns the state before the call ('' if there is no such job).
local state = redis.call('HGET', K.job, 'state')
if not state then return '' end
if not is_final(state) then finish(ARGV[1], 'cancelled', ARGV[2], nil) end
return state
