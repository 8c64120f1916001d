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
-- Acknowledges and deletes a queue entry: the stream holds only open work. The queue is gone
-- once its job ended, and then there is nothing to acknowledge.
local function ack(queue, entry)
  if redis.call('EXISTS', queue) == 1 then
    redis.call('XACK', queue, '@WORKER_GROUP@', entry)
    redis.call('XDEL', queue, entry)
  end
end
