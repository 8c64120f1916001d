-- Helpers shared by every Tessera script (prepended by tessera.redis_schema, which also
-- fills in the named constants once, when the scripts are loaded).
local function event(events, ...)
  redis.call('XADD', events, 'MAXLEN', '~', @EVENTS_MAXLEN@, '*', ...)
end
local function logline(log, now, text)
  redis.call('RPUSH', log, tostring(now) .. ' ' .. text)
  redis.call('LTRIM', log, -@LOG_MAXLEN@, -1)
end
local function is_final(state)
  return state == 'done' or state == 'failed' or state == 'cancelled'
end
