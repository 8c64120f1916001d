"""The farm's queue layer: every Redis key, hash field and event (redis_schema) and the
Lua scripts that move a job through its states (lua/*.lua). The worker and the service
both build on it; it builds only on tessera_base."""
