"""Model clients that talk to inference servers (OpenAI-compatible HTTP, ...)."""
