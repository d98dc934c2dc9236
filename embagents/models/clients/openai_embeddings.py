"""Sentence embeddings from an OpenAI-compatible ``/embeddings`` endpoint (llama.cpp's server, vLLM, Ollama, OpenAI).

The same ``embed(texts) -> (N, dim) float32`` as a local embedding model's
client, so Memory and SemanticRouter take either. Vectors are L2-normalised
here (servers differ on that; the memory compares unit vectors); a server
that answers one vector per token (llama.cpp's, for a model without a
pooling type) is mean-pooled.

Example::

    >>> client = OpenAIEmbeddingClient("http://127.0.0.1:8000", model="nomic-embed-text")
    >>> client.url
    'http://127.0.0.1:8000/v1/embeddings'
"""

from __future__ import annotations

import numpy as np

from embagents.models.clients.openai_http import OpenAIHTTPClient, OpenAIHTTPError

__all__ = ["OpenAIEmbeddingClient"]


class OpenAIEmbeddingClient(OpenAIHTTPClient):
    """Embeds texts with a server's ``POST {base_url}/v1/embeddings`` (errors as :class:`OpenAIHTTPClient`'s)."""

    def __init__(self, base_url: str, model: str = "local", api_key: str | None = None, timeout: float = 60.0,
                 name: str | None = None) -> None:
        super().__init__(base_url, model, api_key, timeout)
        self.url = self.api_root + "/embeddings"
        self.name = name or f"embeddings@{self.api_root}"

    def embed(self, texts: list[str]) -> np.ndarray:
        """Unit-length embeddings of ``texts``, one row each, in one request."""
        texts = list(texts)
        if not all(isinstance(t, str) for t in texts):
            raise ValueError(f"embed needs a list of strings, got {texts!r:.80}")
        if not texts:
            return np.zeros((0, 0), np.float32)
        with self._errors(self.url):
            reply = self._client().embeddings.create(model=self.model, input=texts, encoding_format="float")
        rows = sorted(reply.data, key=lambda d: d.index)
        if len(rows) != len(texts):
            raise OpenAIHTTPError(f"{self.url} answered {len(rows)} embeddings for {len(texts)} texts")
        # llama.cpp's server without a pooling type answers one vector per token: mean-pool them
        # (what sentence-transformers does for a sentence).
        vectors = np.stack([np.asarray(r.embedding, np.float32).reshape(-1, np.shape(r.embedding)[-1]).mean(0)
                            for r in rows])
        norms = np.linalg.norm(vectors, axis=1, keepdims=True)
        return vectors / np.where(norms > 0, norms, 1.0)
