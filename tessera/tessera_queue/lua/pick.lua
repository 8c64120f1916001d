-- The next task for a worker: the highest-priority job first, among equal priorities the
-- one served least. KEYS: ready. ARGV: worker, now, job key prefix.
-- The one script that builds keys from ids: which job it reads is what it decides, so
-- its keys cannot be named in advance (single-instance Redis; no cluster). The suffixes
-- are redis_schema's.
local me = ARGV[1]
local cands = redis.call('ZRANGE', KEYS[1], 0, 15)
for _, id in ipairs(cands) do
  local key = ARGV[3] .. id
  local state = redis.call('HGET', key, 'state')
  if state ~= 'queued' and state ~= 'running' then
    redis.call('ZREM', KEYS[1], id)
  elseif redis.call('SISMEMBER', key .. '@BLOCKLIST@', me) == 0 then
    local q = key .. '@QUEUE@'
    local got = false
    if redis.call('EXISTS', q) == 1 then
      local r = redis.call('XREADGROUP', 'GROUP', '@WORKER_GROUP@', me, 'COUNT', 1, 'STREAMS', q, '>')
      if r and r[1] and #r[1][2] > 0 then got = r[1][2][1] end
    end
    if got then
      redis.call('ZINCRBY', KEYS[1], 1, id)
      if state == 'queued' then
        redis.call('HSET', key, 'state', 'running')
        event(key .. '@EVENTS@', 'type', 'state', 'state', 'running')
        logline(key .. '@LOG@', ARGV[2], 'job running')
      end
      redis.call('HSETNX', key, 'started_at', ARGV[2])
      return {id, got[1], got[2][2], redis.call('HGET', key, 'started_at')}
    end
    -- Drained: whoever queues more work for it puts it back.
    redis.call('ZREM', KEYS[1], id)
  end
end
return false
