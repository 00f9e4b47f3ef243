"""Recordings (issue 14): one MCAP file per recording; see docs/recording.md."""
