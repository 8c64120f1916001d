-- KEYS: scene, scene_jobs. ARGV: retention seconds (0: forever). A scene no job holds
-- expires `retention` after its last use; one that a job holds does not expire.
-- Returns 1 if the scene is stored.
if redis.call('EXISTS', KEYS[1]) == 0 then return 0 end
local ttl = tonumber(ARGV[1])
redis.call('HSET', KEYS[1], 'retention', ARGV[1])
if ttl > 0 and redis.call('SCARD', KEYS[2]) == 0 then
  redis.call('EXPIRE', KEYS[1], ttl)
else
  redis.call('PERSIST', KEYS[1])
end
return 1
