"""The binary real-time channel: message layouts, WebSocket endpoint, fan-out."""
