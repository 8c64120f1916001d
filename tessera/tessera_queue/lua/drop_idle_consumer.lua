-- Removes a consumer from a queue's group only if it holds no pending entries
-- (DELCONSUMER would silently drop them). KEYS: queue. ARGV: group, consumer.
-- Returns 1 if removed.
if redis.call('EXISTS', KEYS[1]) == 0 then return 0 end
local pending = redis.call('XPENDING', KEYS[1], ARGV[1], '-', '+', 1, ARGV[2])
if #pending > 0 then return 0 end
redis.call('XGROUP', 'DELCONSUMER', KEYS[1], ARGV[1], ARGV[2])
return 1
