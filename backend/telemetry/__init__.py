"""Inter-arrival and latency statistics for every stream."""
