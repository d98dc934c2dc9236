"""Model clients that talk to inference servers: OpenAI-compatible chat (:mod:`.openai_http`), speech
(:mod:`.openai_audio`: transcription and synthesis), embeddings (:mod:`.openai_embeddings`)."""

from embagents.models.clients.openai_audio import OpenAISpeechClient, OpenAITranscriptionClient
from embagents.models.clients.openai_embeddings import OpenAIEmbeddingClient
from embagents.models.clients.openai_http import OpenAIHTTPClient, OpenAIHTTPError

__all__ = ["OpenAIEmbeddingClient", "OpenAIHTTPClient", "OpenAIHTTPError", "OpenAISpeechClient",
           "OpenAITranscriptionClient"]
