"""Stereo video: capture → encode once → fan out to every WebRTC peer."""
