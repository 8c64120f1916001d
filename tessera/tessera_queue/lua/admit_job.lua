-- A new job (its hash and queue written in the same transaction): it holds its scene,
-- which stops expiring until the last job that needs it ends, and enters the schedule.
-- ARGV: id. Returns 1 if the scene is stored, 0 if not.
redis.call('SADD', K.scene_jobs, ARGV[1])
redis.call('PERSIST', K.scene)
make_ready(ARGV[1])
return redis.call('EXISTS', K.scene)
