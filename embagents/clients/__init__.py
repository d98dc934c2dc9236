"""Model clients that talk to inference servers: OpenAI-compatible chat (:mod:`.openai_http`), transcription (:mod:`.openai_audio`)."""
