"""Recordings: one MCAP file per recording; see docs/recording.md."""
