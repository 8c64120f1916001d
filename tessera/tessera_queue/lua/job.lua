-- The keys of one job's scripts, in the order of redis_schema.job_script_keys. Every
-- script that moves a job gets them as KEYS, so that no key is rebuilt from a suffix.
local K = {job = KEYS[1], queue = KEYS[2], tiles = KEYS[3], events = KEYS[4], log = KEYS[5],
           failures = KEYS[6], blocklist = KEYS[7], passes = KEYS[8], splats = KEYS[9],
           ready = KEYS[10], active = KEYS[11], wake = KEYS[12], stats = KEYS[13],
           scene = KEYS[14], scene_jobs = KEYS[15], products = KEYS[16]}
-- Keys that expire together once the job is final (its retention).
local RETAINED = {K.job, K.tiles, K.events, K.log, K.failures, K.blocklist, K.passes, K.splats,
                  K.products}

local function priority()
  return redis.call('HGET', K.job, 'priority') or '@DEFAULT_PRIORITY@'
end
local wake_tokens = {}
for i = 1, 8 do wake_tokens[i] = '1' end
-- Puts the job (back) into the ready set, starting at its band's lowest served count.
local function make_ready(id)
  local lo = @BAND@ * (@MAX_PRIORITY@ - tonumber(priority()))
  local first = redis.call('ZRANGEBYSCORE', K.ready, lo, lo + @BAND@ - 1, 'WITHSCORES', 'LIMIT', 0, 1)
  local score = lo
  if #first > 0 then score = tonumber(first[2]) end
  redis.call('ZADD', K.ready, 'NX', score, id)
  -- Wakes idle workers now rather than at their next poll; capped, so it never grows.
  redis.call('RPUSH', K.wake, unpack(wake_tokens))
  redis.call('LTRIM', K.wake, -@WAKE_MAX@, -1)
end
-- A job that ends no longer needs its scene: the last one to end starts its retention.
local function release_scene(id)
  redis.call('SREM', K.scene_jobs, id)
  if redis.call('SCARD', K.scene_jobs) == 0 then
    local ttl = tonumber(redis.call('HGET', K.scene, 'retention') or '0')
    if ttl and ttl > 0 then redis.call('EXPIRE', K.scene, ttl) end
  end
end
-- Moves the job to a final state: its open work is dropped and its keys start to expire.
local function finish(id, state, now, err)
  if err then
    redis.call('HSET', K.job, 'state', state, 'finished_at', now, 'error', err)
  else
    redis.call('HSET', K.job, 'state', state, 'finished_at', now)
  end
  redis.call('ZREM', K.ready, id)
  redis.call('SREM', K.active, id)
  redis.call('DEL', K.queue)
  if err then
    event(K.events, 'type', 'state', 'state', state, 'message', err)
    logline(K.log, now, 'job ' .. state .. ': ' .. err)
  else
    event(K.events, 'type', 'state', 'state', state)
    logline(K.log, now, 'job ' .. state)
  end
  release_scene(id)
  local ttl = tonumber(redis.call('HGET', K.job, 'retention') or '0')
  if ttl and ttl > 0 then
    for _, key in ipairs(RETAINED) do redis.call('EXPIRE', key, ttl) end
  end
end
