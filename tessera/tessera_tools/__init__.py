"""Tools built on the foundations: the noise-aware image comparison (compare), the
error-versus-time bench (bench) and its Mitsuba 3 peer (peer_mitsuba)."""
