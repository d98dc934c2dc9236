"""Model clients that talk to inference servers (OpenAI-compatible HTTP, ...)."""

from embagents.clients.openai_embeddings import OpenAIEmbeddingClient
from embagents.clients.openai_http import OpenAIHTTPClient, OpenAIHTTPError

__all__ = ["OpenAIEmbeddingClient", "OpenAIHTTPClient", "OpenAIHTTPError"]
