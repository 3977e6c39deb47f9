"""aar-dock: vision-based probe-and-drogue docking navigation (Luo et al. 2019) as a service."""

from app.numba_cache import configure_numba_cache

configure_numba_cache()
