"""robotsocket package."""
